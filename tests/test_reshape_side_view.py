"""A figure drawn from the side: found as such, one drawn arm for two, seen from the side, facing its way."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.reshape.animator import Animator
from stick_figure import stick_figure
from nnsf.reshape.character import Character
from nnsf.reshape.drive import biped_facing, drawn_from_side, retarget, seen_from_side
from nnsf.reshape.evaluation import _motion
from nnsf.reshape.parts import PART_INDEX
from nnsf.reshape.quadruped import facing
from nnsf.skeleton import JOINT_INDEX as J

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _side_figure(faces: int = -1) -> Character:
    """A body seen from the side facing ``faces`` (−1: towards −x): one arm drawn over the torso, the
    two arms' joints on each other, legs in a stride, feet pointing forwards, outlined parts."""
    H, W = 340, 240
    tex = np.zeros((H, W, 4), np.uint8)
    ink = (30, 30, 30, 255)

    def poly(points, colour, width):
        pts = np.array(points, np.int32)
        cv2.polylines(tex, [pts], False, ink, width + 4)
        cv2.polylines(tex, [pts], False, (*colour, 255), width)

    c = 120
    cv2.rectangle(tex, (c - 30, 60), (c + 30, 190), ink, -1)
    cv2.rectangle(tex, (c - 28, 62), (c + 28, 188), (230, 120, 40, 255), -1)          # the torso
    cv2.circle(tex, (c, 34), 27, ink, -1)
    cv2.circle(tex, (c, 34), 25, (240, 200, 150, 255), -1)                            # the head
    knee_f, ankle_f = (c + faces * 16, 250), (c + faces * 10, 310)
    knee_b, ankle_b = (c - faces * 14, 252), (c - faces * 30, 310)
    for knee, ankle in ((knee_b, ankle_b), (knee_f, ankle_f)):
        poly([(c, 190), knee, ankle], (90, 90, 100), 22)
        poly([ankle, (ankle[0] + faces * 26, ankle[1] + 8)], (60, 70, 180), 14)      # a foot, forwards
    arm = [(c, 72), (c - faces * 4, 128), (c + faces * 14, 176)]
    poly(arm, (250, 200, 60), 14)                                                     # the near arm
    mask = tex[..., 3] > 0
    kp = np.zeros((17, 2))
    for name, p in dict(pelvis=(c, 188), r_hip=(c - 2, 190), l_hip=(c + 2, 190), r_knee=knee_f, r_ankle=ankle_f,
                        l_knee=knee_b, l_ankle=ankle_b, spine=(c, 125), thorax=(c, 66), neck=(c, 58),
                        head_top=(c, 10), l_shoulder=arm[0], l_elbow=arm[1], l_wrist=arm[2],
                        r_shoulder=arm[0], r_elbow=arm[1], r_wrist=arm[2]).items():
        kp[J[name]] = p
    return Character("side", tex, mask, kp)


def _front_figure() -> Character:
    ch = _side_figure()
    kp = ch.keypoints.copy()
    for left, right in (("l_shoulder", "r_shoulder"), ("l_hip", "r_hip")):
        kp[J[left], 0] += 28
        kp[J[right], 0] -= 28
    return Character("front", ch.texture, ch.mask, kp)


def test_a_body_drawn_from_the_side_is_told_from_a_front_view_and_a_stick_figure():
    assert drawn_from_side(_side_figure().mask, _side_figure().keypoints)
    assert not drawn_from_side(_front_figure().mask, _front_figure().keypoints)
    stick = stick_figure(height=300)        # shoulders on one point, but no body to see from the side
    assert not drawn_from_side(stick.mask, stick.keypoints)


def test_the_facing_of_a_side_drawing_follows_its_feet():
    for faces in (-1, 1):
        ch = _side_figure(faces)
        assert biped_facing(ch.mask, ch.keypoints) == faces
    assert biped_facing(_front_figure().mask, _front_figure().keypoints) == 0.0


def test_a_motion_facing_the_other_way_is_mirrored_so_the_knees_bend_forwards():
    ch = _side_figure(faces=-1)
    T = 12
    motion = np.repeat(ch.keypoints[None], T, axis=0)
    motion[..., 0] *= -1.0                                   # the same pose facing +x
    assert facing(motion) == 1.0 and facing(ch.keypoints[None]) == -1.0
    out = retarget(motion, ch.keypoints, facing=-1.0)
    assert facing(out) == -1.0
    assert np.allclose(out[0], ch.keypoints, atol=1e-6)       # its own pose, facing its own way
    assert facing(retarget(motion, ch.keypoints)) == 1.0      # unknown facing: left as it is


def test_two_arms_drawn_as_one_give_the_drawing_to_one_part_and_the_other_pins_nothing():
    ch = _side_figure()
    a = Animator(ch, n_vertices=500)
    hidden = {PART_INDEX["r_upper_arm"], PART_INDEX["r_forearm"]}
    assert set(a.rig.hidden) == hidden
    assert not np.isin(a.rig.labels, list(hidden)).any()
    assert not np.isin(a.mesh.parts, list(hidden)).any()
    # Swinging only the hidden arm changes nothing drawn.
    still = np.repeat(ch.keypoints[None], 2, axis=0)
    moved = still.copy()
    moved[1, [J["r_elbow"], J["r_wrist"]]] += np.array([40.0, -30.0])
    assert np.allclose(a.deformer.run(still), a.deformer.run(moved), atol=1e-6)
    # Swinging the drawn arm moves the whole drawn arm, hand included, not a shard of it.
    swung = still.copy()
    sh = ch.keypoints[J["l_shoulder"]]
    ang = np.radians(-70.0)
    R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    chain = [J["l_elbow"], J["l_wrist"]]
    swung[1, chain] = (ch.keypoints[chain] - sh) @ R.T + sh
    V = a.deformer.run(swung)
    arm = np.isin(a.mesh.parts, [PART_INDEX["l_upper_arm"], PART_INDEX["l_forearm"]]) & (a.mesh.layer == 0)
    verts = np.unique(a.mesh.triangles[arm])
    far = np.linalg.norm(a.mesh.vertices[verts] - sh, axis=1) > 40
    moved_by = np.linalg.norm(V[1, verts[far]] - V[0, verts[far]], axis=1)
    assert np.median(moved_by) > 30



def test_a_figure_whose_yaml_says_which_way_it_faces_is_seen_from_the_side():
    """A three-quarter body (shoulders and hips drawn apart) is not found to be drawn from the side;
    its character YAML's ``facing`` says it is."""
    ch = _front_figure()
    assert not seen_from_side(ch)
    for way in ("left", "right"):
        ch.facing = way
        assert seen_from_side(ch)


def test_a_punch_is_seen_from_the_side_and_goes_out_the_way_the_figure_faces():
    """With ``facing``, a BVH punch is seen from the side and mirrored to face the figure's way: the
    punching hand goes out ahead of its shoulder on that side (without it, the motion's front view)."""
    bvh = "bandai-namco-1/data/dataset-1_punch_normal_001.bvh"
    if not (SHARED / bvh).is_file():
        pytest.skip(f"Bandai-Namco punch not found under {SHARED}")
    ch = _front_figure()
    assert _motion(bvh, [str(SHARED)], ch)[4] == "front"
    arm = np.linalg.norm(ch.keypoints[J["l_wrist"]] - ch.keypoints[J["l_shoulder"]])
    for way, sign in (("left", -1.0), ("right", 1.0)):
        ch.facing = way
        _, points, _, _, view = _motion(bvh, [str(SHARED)], ch)
        assert view == "side"
        kp = Animator(ch, n_vertices=300).retarget(points[:240])
        reach = {s: kp[:, J[f"{s}_wrist"], 0] - kp[:, J[f"{s}_shoulder"], 0] for s in "lr"}
        # The punch: the hand and frame reaching farthest from its shoulder along x, either way.
        s, t = max(((s, int(np.argmax(np.abs(r)))) for s, r in reach.items()), key=lambda st: abs(reach[st[0]][st[1]]))
        assert np.sign(reach[s][t]) == sign and abs(reach[s][t]) > 0.5 * arm, (way, s, t, reach[s][t])
