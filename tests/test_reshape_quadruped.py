"""Four-legged drawings: the AnimatedDrawings quadruped skeleton read, driven by a biped's motion,
drawn with its near legs in front (nnsf.reshape.quadruped)."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from nnsf.errors import InputError
from nnsf.reshape.formats import read_character
from nnsf.reshape.parts import PART_INDEX, PARTS
from nnsf.reshape.quadruped import (QUADRUPED_JOINTS, facing, quadruped_keypoints, quadruped_orders,
                                    retarget_quadruped)
from nnsf.skeleton import BONES, JOINT_INDEX as J

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
CHAR6 = SHARED / "animated-drawings" / "characters" / "char6"
WALK = SHARED / "bandai-namco-1" / "data" / "dataset-1_walk_normal_001.bvh"


def _pig(tmp_path: Path, drop: str | None = None) -> Path:
    """A hand-made side-view quadruped facing +x: an ellipse body, a round head at the right, four
    legs of two segments; AnimatedDrawings' joint names, its right (near) legs at larger x."""
    H, W = 160, 260
    mask = np.zeros((H, W), np.uint8)
    cv2.ellipse(mask, (120, 70), (80, 35), 0, 0, 360, 255, -1)
    cv2.circle(mask, (205, 55), 32, 255, -1)
    legs = {"left_b": 60, "right_b": 85, "left_f": 150, "right_f": 175}
    for x in legs.values():
        cv2.rectangle(mask, (x - 8, 90), (x + 8, 140), 255, -1)
    tex = np.dstack([np.full((H, W, 3), 225, np.uint8), mask])
    tex[mask == 0, :3] = 255
    joints = {"root": (120, 80), "hip": (120, 80), "torso": (200, 75), "neck": (205, 50)}
    for name, x in legs.items():
        side, end = name.split("_")
        joints[f"{side}_hip_{end}"] = (x, 95)
        joints[f"{side}_knee_{end}"] = (x, 117)
        joints[f"{side}_foot_{end}"] = (x, 137)
    cfg = {"width": W, "height": H,
           "skeleton": [{"name": n, "loc": list(v), "parent": None} for n, v in joints.items() if n != drop]}
    folder = tmp_path / "pig"
    folder.mkdir()
    cv2.imwrite(str(folder / "mask.png"), mask)
    cv2.imwrite(str(folder / "texture.png"), cv2.cvtColor(tex, cv2.COLOR_RGBA2BGRA))
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(cfg))
    return folder


def test_a_quadruped_skeleton_is_read_hind_legs_as_legs_front_legs_as_arms(tmp_path):
    ch = read_character(_pig(tmp_path))
    kp = ch.keypoints
    assert ch.body == "quadruped" and any("quadruped" in n for n in ch.notes)
    assert np.allclose(kp[J["r_hip"]], (85, 95)) and np.allclose(kp[J["l_ankle"]], (60, 137))
    assert np.allclose(kp[J["r_shoulder"]], (175, 95)) and np.allclose(kp[J["l_wrist"]], (150, 137))
    assert np.allclose(kp[J["pelvis"]], (72.5, 95)) and np.allclose(kp[J["thorax"]], (162.5, 95))
    assert np.allclose(kp[J["spine"]], (117.5, 95)) and np.allclose(kp[J["neck"]], (205, 50))
    # head_top: on from the neck along torso -> neck, inside the head
    assert kp[J["head_top"], 1] < 50 and ch.mask[int(kp[J["head_top"], 1]), int(kp[J["head_top"], 0])]


def test_a_quadruped_missing_a_leg_joint_is_refused_naming_it(tmp_path):
    with pytest.raises(InputError) as exc:
        read_character(_pig(tmp_path, drop="left_knee_f"))
    text = str(exc.value)
    assert "char_cfg.yaml" in text and "skeleton" in text and "left_knee_f" in text and "\n" not in text
    with pytest.raises(InputError, match="skeleton"):
        quadruped_keypoints({n: np.zeros(2) for n in QUADRUPED_JOINTS[:-1]}, np.ones((4, 4), bool), "x")


def test_a_quadruped_leg_joint_off_the_drawing_is_named_as_the_file_names_it(tmp_path):
    folder = _pig(tmp_path)
    cfg = yaml.safe_load((folder / "char_cfg.yaml").read_text())
    for j in cfg["skeleton"]:
        if j["name"] == "left_foot_f":
            j["loc"] = [250, 5]       # inside the image, off the drawing
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as exc:
        read_character(folder)
    assert "skeleton.left_foot_f.loc: expected a point on the drawing or within" in str(exc.value)


def _walker(T: int = 40, amp: float = 30.0, forward: float = 1.0) -> np.ndarray:
    """A biped seen from the side in image coordinates (y down), facing ``forward`` (+1: +x): each
    thigh swings ±amp° about hanging straight down, in opposite phase, the shin trailing it by 15°
    (the knee ahead of the hip-ankle line); a still, upright spine."""
    P = np.zeros((T, 17, 2))
    P[:, J["pelvis"]] = (0.0, 0.0)
    P[:, J["spine"]], P[:, J["thorax"]] = (0.0, -0.25), (0.0, -0.5)
    P[:, J["neck"]], P[:, J["head_top"]] = (0.02, -0.6), (0.02, -0.75)
    for s in ("l_", "r_"):
        P[:, J[s + "shoulder"]], P[:, J[s + "elbow"]], P[:, J[s + "wrist"]] = (0, -0.5), (0, -0.25), (0.05, -0.05)
    ph = np.linspace(0, 2 * np.pi, T, endpoint=False)
    for side, sgn in (("r_", 1.0), ("l_", -1.0)):
        phi = np.radians(amp) * sgn * np.sin(ph)
        psi = phi - np.radians(15.0)
        P[:, J[side + "hip"]] = (0.0, 0.0)
        P[:, J[side + "knee"]] = np.stack([0.45 * np.sin(phi) * forward, 0.45 * np.cos(phi)], -1)
        P[:, J[side + "ankle"]] = P[:, J[side + "knee"]] + np.stack([0.45 * np.sin(psi) * forward,
                                                                     0.45 * np.cos(psi)], -1)
    return P


def _drawn_pig() -> np.ndarray:
    ch_kp = np.zeros((17, 2))
    for side, x0 in (("r", 85.0), ("l", 60.0)):
        ch_kp[J[f"{side}_hip"]], ch_kp[J[f"{side}_knee"]], ch_kp[J[f"{side}_ankle"]] = (x0, 95), (x0, 117), (x0 + 3, 137)
    for side, x0 in (("r", 175.0), ("l", 150.0)):
        ch_kp[J[f"{side}_shoulder"]], ch_kp[J[f"{side}_elbow"]], ch_kp[J[f"{side}_wrist"]] = (x0, 95), (x0, 117), (x0 - 3, 137)
    ch_kp[J["pelvis"]], ch_kp[J["thorax"]] = (72.5, 95), (162.5, 95)
    ch_kp[J["spine"]], ch_kp[J["neck"]], ch_kp[J["head_top"]] = (117.5, 95), (205, 50), (206, 25)
    return ch_kp


def _angle(v):
    return np.arctan2(v[..., 1], v[..., 0])


def _swing(theta):
    m = np.arctan2(np.sin(theta).mean(), np.cos(theta).mean())
    return np.angle(np.exp(1j * (theta - m)))


def test_legs_swing_about_their_drawn_pose_front_legs_with_the_other_sides_leg():
    rest = _drawn_pig()
    P = _walker()
    assert facing(P) == 1.0
    Q = retarget_quadruped(P, rest)
    # Lengths are the drawing's; the body is rigid and keeps its drawn orientation (a still spine).
    for p, c in BONES:
        if p in (J["r_hip"], J["r_knee"], J["l_hip"], J["l_knee"], J["r_shoulder"], J["r_elbow"],
                 J["l_shoulder"], J["l_elbow"]):
            assert np.allclose(np.linalg.norm(Q[:, c] - Q[:, p], axis=1), np.linalg.norm(rest[c] - rest[p]))
    body = [J[j] for j in ("pelvis", "spine", "thorax", "neck", "head_top", "r_hip", "l_shoulder")]
    d = Q[:, body] - Q[:, [J["pelvis"]]]
    assert np.allclose(d, (rest[body] - rest[J["pelvis"]])[None], atol=1e-9)
    # Each leg bone turns from its drawn direction by exactly its driver's swing.
    for (a, b), (c, e) in ((("r_hip", "r_knee"), ("r_hip", "r_knee")), (("l_knee", "l_ankle"), ("l_knee", "l_ankle")),
                           (("l_shoulder", "l_elbow"), ("r_hip", "r_knee")),
                           (("r_elbow", "r_wrist"), ("l_knee", "l_ankle"))):
        got = _angle(Q[:, J[b]] - Q[:, J[a]]) - _angle(rest[J[b]] - rest[J[a]])
        want = _swing(_angle(P[:, J[e]] - P[:, J[c]]))
        assert np.allclose(np.angle(np.exp(1j * (got - want))), 0, atol=1e-9), (a, b)
    # Diagonal pairs step together: the left front and right hind thighs turn alike.
    lf = _angle(Q[:, J["l_elbow"]] - Q[:, J["l_shoulder"]]) - _angle(rest[J["l_elbow"]] - rest[J["l_shoulder"]])
    rh = _angle(Q[:, J["r_knee"]] - Q[:, J["r_hip"]]) - _angle(rest[J["r_knee"]] - rest[J["r_hip"]])
    assert np.allclose(lf, rh) and np.ptp(lf) > np.radians(50)


def test_a_motion_walking_the_other_way_is_mirrored_first():
    rest = _drawn_pig()
    P = _walker(forward=1.0)
    M = P.copy()
    M[..., 0] *= -1.0
    assert facing(M) == -1.0
    assert np.allclose(retarget_quadruped(M, rest), retarget_quadruped(P, rest))


def test_near_legs_in_front_far_legs_behind_the_body():
    order = np.array([PART_INDEX[p] for p in ("r_thigh", "torso", "l_forearm", "head", "r_upper_arm",
                                               "l_thigh", "r_shin", "l_shin", "l_upper_arm", "r_forearm")])
    out = quadruped_orders(np.tile(order, (3, 1)), _drawn_pig())   # faces +x: its right side is near
    names = [PARTS[p] for p in out[0]]
    assert names == ["l_forearm", "l_thigh", "l_shin", "l_upper_arm", "torso", "head",
                     "r_thigh", "r_upper_arm", "r_shin", "r_forearm"]
    assert (out == out[0]).all()
    mirrored = _drawn_pig() * np.array([-1.0, 1.0])   # faces -x: its left side is near
    names = [PARTS[p] for p in quadruped_orders(order[None], mirrored)[0]]
    assert names[:4] == ["r_thigh", "r_upper_arm", "r_shin", "r_forearm"] and names[4:6] == ["torso", "head"]


@pytest.mark.skipif(not CHAR6.is_dir() or not WALK.is_file(),
                    reason="../shared/data (AnimatedDrawings char6, Bandai-Namco walk) not present")
def test_char6_walks_in_one_piece():
    """The AnimatedDrawings pig, 60 frames of a walk seen from the side: its legs step, its body
    stays whole (no piece of 10 px or more apart).  Enclosed page is at most a sliver: the page
    drawn between two legs closes in when they cross (up to ~40 px), no more."""
    from nnsf.datasets.bvh_source import load_clip
    from nnsf.reshape.animator import Animator, canvas
    from nnsf.reshape.artefacts import FrameMeasures

    ch = read_character(CHAR6)
    assert ch.body == "quadruped"
    clip = load_clip(WALK, fps=30, azimuth=90.0)
    a = Animator(ch, 800)
    anim = a.animate(clip.points[:60], clip.depth[:60])
    kp = anim.keypoints
    assert np.ptp(kp[:, J["r_ankle"], 0]) > 15 and np.ptp(kp[:, J["l_wrist"], 0]) > 15  # the feet step
    off, size = canvas(anim.frames, shape=ch.shape)
    r = a.renderer(size)
    measure = FrameMeasures(ch.texture, ch.mask, ch.keypoints)
    from nnsf.reshape.artefacts import coverage, detached

    for t in range(0, 60, 6):
        img = r.render(anim.frames[t] + off, anim.orders[t])
        got = measure(img, kp[t] + off)
        assert detached(coverage(img), min_area=10) == 0 and got["crack_px"] <= 40, (t, got)


def test_nnsf_animate_runs_a_quadruped_and_says_what_does_not_apply(tmp_path):
    """The user's command on the hand-made pig: a GIF and a sheet are written,
    and ``--arms drawing`` (which a quadruped ignores) is said in a note, not silently dropped."""
    from nnsf.animate.animation import animate_files

    res = animate_files(_pig(tmp_path), "synthetic:max/walk/12", arms="drawing",
                        out=tmp_path / "pig.gif", progress=False)
    assert (tmp_path / "pig.gif").is_file() and (tmp_path / "pig_sheet.png").is_file()
    assert any("quadruped" in n and "--arms drawing" in n for n in res.notes)
