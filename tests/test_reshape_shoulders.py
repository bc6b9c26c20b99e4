"""The body's silhouette at the shoulders and hips of a layered mesh when the limbs swing away (rex, real rendering)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nnsf.frames import render
from nnsf.reshape import depth
from nnsf.reshape.parts import PART_INDEX
from nnsf.reshape.regions import drawn_regions
from nnsf.reshape.render import MeshRenderer, underlay_texture
from nnsf.reshape.stage import build_rig
from nnsf.reshape.character import Character
from nnsf.skeleton import JOINT_INDEX as J


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (p - c) @ R.T + c


@pytest.fixture(scope="module")
def rex():
    rgba, mask, kp = render.render_character("rex", 512)
    return Character(name="rex", texture=rgba, mask=mask, keypoints=kp, source="<rendered rex>")


@pytest.fixture(scope="module")
def rig(rex):
    return build_rig(rex, "ours", "layered", 800, 4, "limb-frame")


def _body_drawing(ch):
    """The torso and head as drawn, with their own outline: the drawing's ink-bounded
    regions on the spine and neck, plus the ink within 2 px of them."""
    tex, mask, kp = ch.texture, ch.mask, ch.keypoints
    lab = drawn_regions(tex, mask)
    pts = [kp[a] + t * (kp[b] - kp[a]) for a, b in ((J["pelvis"], J["spine"]), (J["spine"], J["thorax"]),
                                                      (J["thorax"], J["neck"])) for t in np.linspace(0, 1, 9)]
    body = np.isin(lab, [lab[int(round(y)), int(round(x))] for x, y in pts])
    lum = tex[..., :3].astype(float) @ np.array([0.299, 0.587, 0.114])
    ink = mask & (lum < 0.55 * np.median(lum[mask]))
    near = cv2.distanceTransform((~body).astype(np.uint8), cv2.DIST_L2, 3) <= 2
    return (body | (ink & near)) & mask


def _pose(ch, joint, limb, deg):
    kp = ch.keypoints.copy()
    for side, sgn in (("l", -1), ("r", 1)):
        for j in limb:
            kp[J[f"{side}_{j}"]] = _rot(kp[J[f"{side}_{j}"]], kp[J[f"{side}_{joint}"]], sgn * deg)
    return kp


@pytest.mark.parametrize("joint, limb, deg, max_missing", [
    ("shoulder", ("elbow", "wrist"), 150.0, 15),   # arms raised over the head
    ("hip", ("knee", "ankle"), 80.0, 30),          # legs swung out sideways
])
def test_body_keeps_its_outlined_silhouette_where_a_limb_swings_away(rex, rig, joint, limb, deg, max_missing):
    """The torso stays still; where an arm (or thigh) lay against it, the torso must still show its
    fill and its outline (no notch), and no torso-textured fragment may stick out of it."""
    V = rig.animate(_pose(rex, joint, limb, deg)[None])[0]
    r = MeshRenderer.for_mesh(rig.mesh, rex)
    body = r.render(V, [PART_INDEX["torso"], PART_INDEX["head"]])[..., 3] > 127
    expected = _body_drawing(rex)
    H, W = rex.mask.shape
    yy, xx = np.mgrid[:H, :W]
    rgba = r.render(V, depth.default_order())
    _, _, ids = r.maps(V, depth.default_order())
    m = rig.mesh
    t = np.maximum(ids, 0)
    # torso-textured: the body's own triangles (a limb's joint tab hides under the torso but is
    # textured with the limb's fill, nnsf.reshape.pieces.tab_texture)
    torso_tex = (ids >= 0) & (rgba[..., 3] > 127) & (m.pieces[t] == 0) & (m.layer[t] < 3)
    outside = torso_tex & ~(cv2.dilate(expected.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0)
    for side in ("l", "r"):
        c = rex.keypoints[J[f"{side}_{joint}"]]
        win = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 < 30 ** 2
        missing = int((expected & win & ~body).sum())
        assert missing <= max_missing, (side, joint, missing)
    # rex's left arm hangs behind the torso: its cap must not carry torso fill out with it
    if joint == "shoulder":
        c = rex.keypoints[J["l_shoulder"]]
        win = (xx - c[0]) ** 2 + (yy - c[1]) ** 2 < 30 ** 2
        assert int((outside & win).sum()) <= 8


def test_joint_tabs_leave_the_rest_drawing_unchanged(rex, rig):
    """Each limb's tab hides under its parent: at rest, in any depth order, the frame is the same
    with and without the tabs (what they add shows only where a joint turns)."""
    m = rig.mesh
    tab = ~m.core_triangles
    assert tab.any() and np.all(m.collar[tab] >= 0) and np.all(m.parts[tab] != m.collar[tab])
    keep = ~tab
    texture = rex.texture
    r = MeshRenderer(m.vertices, m.triangles, m.parts, texture, rex.mask, layer=m.layer, behind=m.collar,
                     textures=MeshRenderer.for_mesh(m, rex)._tab_textures)
    r0 = MeshRenderer(m.vertices, m.triangles[keep], m.parts[keep], texture, rex.mask, layer=m.layer[keep],
                      behind=m.collar[keep])
    for order in (depth.default_order(), depth.default_order()[::-1]):
        a = r.render(m.vertices, order)
        b = r0.render(m.vertices, order)
        assert np.array_equal(a[..., 3] > 127, b[..., 3] > 127)
        # colours equal up to a level or two (a pixel on a seam may show the tab's fill, the
        # limb's colour continued, instead of the limb itself)
        assert np.abs(a.astype(int) - b.astype(int))[a[..., 3] > 127].max() <= 2
