"""Hips of the layered mesh: where a thigh is cut from the body, and its top tucked under it."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.frames import render
from nnsf.reshape.character import Character, load_animated_drawings
from nnsf.reshape.cuts import SEGMENT_NAMES, find_cuts
from nnsf.reshape.parts import PART_INDEX, PARTS
from nnsf.reshape.pieces import solid_mask
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import build_rig
from nnsf.skeleton import JOINT_INDEX as J

CHAR1 = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters" / "char1"
TORSO, THIGH = PART_INDEX["torso"], PART_INDEX["l_thigh"]


@pytest.fixture(scope="module")
def rex_rig():
    rgba, mask, kp = render.render_character("rex", 512)
    ch = Character(name="rex", texture=rgba, mask=mask, keypoints=kp, source="<rendered rex>")
    return ch, build_rig(ch, "ours", "layered", 800, 4)


def _thigh_turned(ch, rig, deg):
    """Vertices with the left leg turned ``deg`` degrees about its hip."""
    kp = ch.keypoints.copy()
    c, a = kp[J["l_hip"]].copy(), np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    for j in ("l_knee", "l_ankle"):
        kp[J[j]] = (kp[J[j]] - c) @ R.T + c
    return rig.animate(kp[None])[0]


def _renders(ch, rig, V, order):
    """The frame and its part labels with the hip tucks, and without them."""
    out = []
    for tucks in (True, False):
        r = MeshRenderer.for_mesh(rig.mesh, ch)
        if not tucks:
            r._tucked = {}
        out.append(r.render_labelled(V, order, labels=True))
    return out


@pytest.mark.parametrize("deg", [-40.0, -30.0, 30.0, 40.0])
def test_a_thigh_in_front_of_the_body_goes_under_its_bottom_edge(rex_rig, deg):
    """Drawn after the body, a thigh turned about its hip used to lay its straight top edge over
    the body (a corner across the belly); the band along its hip cut now goes under the body,
    which keeps every pixel of its own region (7 px in from its edge).  Without the tucks the
    same frame shows the thigh over the body: the measure sees the corner."""
    ch, rig = rex_rig
    assert (rig.mesh.tuck[rig.mesh.parts == THIGH] == TORSO).any()
    assert set(rig.mesh.parts[rig.mesh.tuck >= 0].tolist()) == {THIGH, PART_INDEX["r_thigh"]}
    body = cv2.erode((rig.mesh.labels == 0).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    order = [TORSO] + [p for p in range(len(PARTS)) if p != TORSO]
    (_, tucked), (_, plain) = _renders(ch, rig, _thigh_turned(ch, rig, deg), order)
    assert int(((tucked == THIGH) & body).sum()) == 0
    assert int(((plain == THIGH) & body).sum()) > 20


def test_a_thigh_behind_the_body_and_the_rest_pose_draw_as_before(rex_rig):
    """The tucks change nothing where the thigh is drawn before the body anyway, nor at rest."""
    ch, rig = rex_rig
    behind = [THIGH, TORSO] + [p for p in range(len(PARTS)) if p not in (THIGH, TORSO)]
    (a, _), (b, _) = _renders(ch, rig, _thigh_turned(ch, rig, 25.0), behind)
    assert np.array_equal(a, b)
    front = [TORSO] + [p for p in range(len(PARTS)) if p != TORSO]
    (a, _), (b, _) = _renders(ch, rig, rig.mesh.vertices, front)
    assert np.abs(a.astype(int) - b.astype(int)).max() <= 1


@pytest.mark.skipif(not CHAR1.is_dir(), reason="../shared/data (AnimatedDrawings char1) not present")
def test_char1_left_thigh_is_cut_at_its_hip():
    """char1's left leg widens up to the belt, and its key points run off-centre: measured from the
    shin's bone, the outline beside the knee looked too far away to be the leg's, so the run of
    the leg's outline stopped at the knee and the hip cut fell on the knee cut (the body carried
    the thigh: it had no pixel of its own).  The hip cut now crosses the thigh's bone in its upper half."""
    ch = load_animated_drawings(CHAR1)
    kp = np.asarray(ch.keypoints, float)
    cut = next(c for c in find_cuts(solid_mask(np.asarray(ch.mask, bool), ch.texture), kp)
               if c.parent == 0 and SEGMENT_NAMES[c.child] == "l_thigh")
    a, b = kp[J["l_hip"]], kp[J["l_knee"]]
    lam = float((cut.mid - a) @ (b - a) / ((b - a) @ (b - a)))
    assert lam < 0.5
    rig = build_rig(ch, "ours", "layered", 800, 4)
    assert int((rig.mesh.labels == SEGMENT_NAMES.index("l_thigh")).sum()) > 5000
