"""Every puppet piece is meshed and moves with its own segment (docs/method.md §13.1).

A thin, slanted piece could lose every triangle to the triangulation's sliver test and then not
be drawn at all (AnimatedDrawings' char2: its left upper arm, so in the punch the forearm floated
beside the body); a segment whose drawn stroke bows away from its bone got no region and was
carried rigidly by its parent (char4's right forearm).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.reshape import mesh as meshmod
from nnsf.reshape.cuts import Cut, SEGMENT_NAMES
from nnsf.reshape.piece_regions import _adopt_orphans
from nnsf.reshape.piece_mesh import COVER, covered_share, triangulate_region as _triangulate_region

ARGS = dict(min_angle=15.0, simplify=0.75, jitter=0.0, smooth_sweeps=3, seed=0)


def _stroke(width: int, angle: float, length: float = 50.0) -> np.ndarray:
    img = np.zeros((120, 120), np.uint8)
    a = np.array([30.0, 60.0])
    b = a + length * np.array([np.cos(np.radians(angle)), np.sin(np.radians(angle))])
    cv2.line(img, tuple(int(v) for v in a), tuple(int(v) for v in b), 1, width)
    return img.astype(bool)


def test_covered_share_of_a_known_square():
    """Two triangles filling a 10 × 10 square cover all of it and half of a 10 × 20 rectangle."""
    region = np.zeros((40, 40), bool)
    region[10:20, 10:20] = True
    v = np.array([[10, 10], [19, 10], [19, 19], [10, 19]], float)
    t = np.array([[0, 1, 2], [0, 2, 3]])
    assert covered_share(region, v, t) == 1.0
    region[10:20, 20:30] = True
    assert covered_share(region, v, t) == pytest.approx(0.5)


@pytest.mark.parametrize("width,angle", [(3, 15.0), (5, 30.0), (6, 60.0), (4, 110.0)])
def test_a_thin_slanted_stroke_is_meshed_over_its_pixels(width, angle):
    """At the global spacing the plain triangulation of these strokes keeps (almost) nothing; the
    piece's triangulation covers at least COVER of its pixels, inside the stroke."""
    region = _stroke(width, angle)
    try:
        v, t, _ = meshmod._triangulate_at(region, 8.0, **ARGS)
        plain = covered_share(region, v, t)
    except Exception:  # no triangle left at all
        plain = 0.0
    assert plain < 0.5  # the failure this guards against
    v, t = _triangulate_region(region, 8.0, ARGS)
    assert covered_share(region, v, t) >= COVER
    # No triangle outside the stroke (its centroid within a pixel of it).
    grown = cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    c = np.rint(v[t].mean(axis=1)).astype(int)
    assert grown[c[:, 1], c[:, 0]].all()


def test_an_orphan_component_beyond_a_cut_goes_to_the_cuts_child():
    """Components: 1 the upper arm (left of x = 20), 2 the forearm beyond the elbow cut (no bone
    sample voted for it), 3 a blob elsewhere.  The forearm (child 2) owns nothing, so it takes
    component 2, which touches the cut and lies on its side; component 3 stays unowned."""
    comp = np.zeros((30, 60), np.int32)
    comp[10:20, 5:19] = 1
    comp[10:20, 21:45] = 2
    comp[0:4, 50:58] = 3
    cut = Cut(joint=0, parent=1, child=2, p=np.array([20.0, 9.0]), q=np.array([20.0, 20.0]),
              pivot=np.array([20.0, 15.0]), normal=np.array([1.0, 0.0]), half_width=5.0)
    owners = np.zeros((4, len(SEGMENT_NAMES)), bool)
    owners[1, 1] = True
    _adopt_orphans(owners, comp, [cut], {})
    assert owners[2, 2] and not owners[3].any() and owners[:, 2].sum() == 1
    # A child that owns a component already keeps exactly that.
    owners = np.zeros((4, len(SEGMENT_NAMES)), bool)
    owners[1, 1] = owners[3, 2] = True
    _adopt_orphans(owners, comp, [cut], {})
    assert not owners[2].any()



def test_a_shoulder_off_the_body_gets_a_bridge_under_the_head():
    """A wide head whose lower corners (pads) reach down beside the body's top, the left arm hung
    under its pad 8 px from the body, the right shoulder on the body.  The bridge is the pad's
    pixels between the left shoulder and the body: with it the body reaches the arm, without it
    only the head joins them.  The right side gets none, nor does the head's top."""
    from nnsf.reshape.cuts import HEAD
    from nnsf.reshape.piece_regions import shoulder_bridges
    from nnsf.skeleton import JOINT_INDEX as J

    label = np.full((100, 100), -1, np.int64)
    label[15:50, 25:76] = HEAD
    label[50:59, 25:36] = HEAD                       # the pads
    label[50:59, 65:76] = HEAD
    label[50:81, 36:65] = 0                          # the body, its top between the pads
    label[59:76, 68:77] = 1                          # the left upper arm, under its pad
    kp = np.zeros((17, 2))
    kp[J["neck"]], kp[J["head_top"]] = (50, 48), (50, 18)
    kp[J["l_shoulder"]], kp[J["l_elbow"]] = (72, 61), (72, 73)
    kp[J["r_shoulder"]], kp[J["r_elbow"]] = (40, 55), (40, 70)
    bridge = shoulder_bridges(label, kp, label >= 0)
    assert bridge.any() and (label[bridge] == HEAD).all()
    assert not bridge[:, :50].any() and not bridge[:48].any()

    def joined(extra):
        n, comp = cv2.connectedComponents(((label == 0) | (label == 1) | extra).astype(np.uint8))
        return comp[70, 50] == comp[70, 72]

    assert joined(bridge) and not joined(np.zeros_like(bridge))
    # A shoulder on the body (the right one here, or both) needs no bridge.
    kp[J["l_shoulder"]] = (62, 55)
    assert not shoulder_bridges(label, kp, label >= 0).any()



def test_the_body_s_colour_above_the_neck_line_beside_an_off_body_shoulder_is_the_body_s():
    """A head (colour 200) labelled down to its shoulders; beside the left shoulder, off the body,
    a patch of the shirt's colour (60, shaded in steps of 5) that the head's label took, joined to
    the shirt below.  It goes to the body; the head's own colour, a shirt-coloured patch that
    does not touch the shirt, and the side of a shoulder on the body stay the head's."""
    from nnsf.reshape.cuts import HEAD
    from nnsf.reshape.piece_regions import shoulder_fill
    from nnsf.skeleton import JOINT_INDEX as J

    label = np.full((100, 100), -1, np.int64)
    label[15:50, 25:76] = HEAD
    label[50:59, 25:36] = HEAD
    label[50:59, 65:76] = HEAD
    label[50:81, 36:65] = 0
    label[59:76, 68:77] = 1
    tex = np.zeros((100, 100, 4), np.uint8)
    tex[..., 3] = 255 * (label >= 0)
    tex[label >= 0, :3] = 200
    tex[50:81, 36:65, :3] = 60                          # the shirt
    tex[44:59, 58:76, :3] = (60 + 5 * (np.arange(44, 59) % 3))[:, None, None]   # its left shoulder
    tex[20:24, 60:64, :3] = 60                          # a patch apart from it
    tex[44:59, 25:42, :3] = 60                          # the right shoulder's
    kp = np.zeros((17, 2))
    kp[J["neck"]], kp[J["head_top"]] = (50, 48), (50, 18)
    kp[J["l_shoulder"]], kp[J["l_elbow"]] = (72, 61), (72, 73)
    kp[J["r_shoulder"]], kp[J["r_elbow"]] = (40, 55), (40, 70)
    fill = shoulder_fill(label, kp, label >= 0, tex)
    assert fill[52:59, 66:76].all() and (label[fill] == HEAD).all()
    assert not fill[tex[..., 0] == 200].any() and not fill[20:24].any() and not fill[:, :50].any()
    # No shoulder off the body: nothing moves.
    kp[J["l_shoulder"]] = (62, 55)
    assert not shoulder_fill(label, kp, label >= 0, tex).any()


# --------------------------------------------------------------------------- the real drawings

_CHARS = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters"
needs_data = pytest.mark.skipif(not (_CHARS / "char2").is_dir() or not (_CHARS / "char4").is_dir(),
                                reason="../shared/data (AnimatedDrawings char2, char4) not present")


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (np.asarray(p, float) - c) @ R.T + c


@pytest.fixture(scope="module")
def char2_rig():
    from nnsf.reshape.formats import read_character
    from nnsf.reshape.rig import Rig

    ch = read_character(_CHARS / "char2")
    return ch, Rig.build(ch, n_vertices=800, split="layered", handle_set="keypoints")


@needs_data
def test_char2_upper_arm_is_meshed_and_turns_with_the_arm(char2_rig):
    """char2's left upper arm (a thin stroke) has triangles covering its region; turning the left
    arm by 50° about its shoulder draws the region turned by 50° about the shoulder's pivot, and
    leaves the shoulder's joint disc solid (the forearm does not float beside the body)."""
    from nnsf.reshape.artefacts import JOINTS_CHECKED, joint_gaps, joint_radii
    from nnsf.reshape.render import MeshRenderer
    from nnsf.skeleton import JOINT_INDEX as J

    ch, rig = char2_rig
    m = rig.mesh
    seg = SEGMENT_NAMES.index("l_upper_arm")
    region = m.labels == seg
    core = (m.triangles < m.n_core).all(axis=1) & (m.pieces == seg)
    assert region.sum() > 500 and core.sum() > 0
    assert covered_share(region, m.vertices, m.triangles[core]) >= COVER
    kp = rig.rest_keypoints.copy()
    piv = kp[J["l_shoulder"]]
    for j in ("l_elbow", "l_wrist"):
        kp[J[j]] = _rot(kp[J[j]], piv, 50.0)
    V = rig.animate(kp[None])[0]
    r = MeshRenderer.for_mesh(m, ch)
    cov = r.render(V)[..., 3] >= 128
    ys, xs = np.nonzero(region)
    moved = np.rint(_rot(np.column_stack([xs, ys]), piv, 50.0)).astype(int)
    H, W = cov.shape
    ok = (moved[:, 0] >= 0) & (moved[:, 0] < W) & (moved[:, 1] >= 0) & (moved[:, 1] < H)
    assert ok.all()
    assert cov[moved[:, 1], moved[:, 0]].mean() >= 0.95
    radii = joint_radii(ch.mask, rig.rest_keypoints)
    k = list(JOINTS_CHECKED).index(J["l_shoulder"])
    assert joint_gaps(cov, rig.drive(kp)[[J["l_shoulder"]]], radii[[k]]) <= 4


@needs_data
def test_char4_forearm_drawn_off_its_bone_is_its_own_piece():
    """char4's right forearm bows off its elbow-to-wrist line: it is a piece of its own (not the
    upper arm's), beyond the elbow cut, and the upper arm keeps to its side of that cut."""
    from nnsf.reshape.formats import read_character
    from nnsf.reshape.layers import build_mesh

    ch = read_character(_CHARS / "char4")
    m = build_mesh(ch.mask, ch.keypoints, 800, split="layered", texture=ch.texture, extra_limbs=ch.extra_limbs)
    up, fore = SEGMENT_NAMES.index("r_upper_arm"), SEGMENT_NAMES.index("r_forearm")
    assert (m.labels == fore).sum() > 1500
    elbow = next(c for c in m.cuts if c.child == fore)
    ys, xs = np.nonzero(m.labels == up)
    assert np.percentile(elbow.side(np.column_stack([xs, ys]).astype(float)), 99) <= 2.0
    # Every segment with a region is meshed over it.
    core = (m.triangles < m.n_core).all(axis=1)
    for seg in range(len(SEGMENT_NAMES)):
        region = m.labels == seg
        if region.sum() >= 50:
            assert covered_share(region, m.vertices, m.triangles[core & (m.pieces == seg)]) >= COVER, SEGMENT_NAMES[seg]


def test_an_elbow_tab_reaches_the_outline_in_the_band_along_its_cut():
    """A straight horizontal arm, 11 px thick (rows 15-25), cut across at x = 40: the forearm's tab
    under the upper arm reaches the outline's second row next to the cut (the outer corner a bend
    opens), but keeps off it farther along the upper arm and at a knee; never the outermost row
    (at rest the tab hides under the parent's edge)."""
    from nnsf.reshape.cuts import Cut, SEGMENT_NAMES
    from nnsf.reshape.pieces import tab_region

    label = np.full((40, 80), -1)
    label[15:26, 10:40] = SEGMENT_NAMES.index("l_upper_arm")
    label[15:26, 40:70] = SEGMENT_NAMES.index("l_forearm")

    def tab(child: str, parent: str):
        lab = np.where(label == SEGMENT_NAMES.index("l_upper_arm"), SEGMENT_NAMES.index(parent),
                       np.where(label >= 0, SEGMENT_NAMES.index(child), -1))
        cut = Cut(joint=12, parent=SEGMENT_NAMES.index(parent), child=SEGMENT_NAMES.index(child),
                  p=np.array([40.0, 15.0]), q=np.array([40.0, 25.0]), pivot=np.array([37.0, 20.0]),
                  normal=np.array([1.0, 0.0]), half_width=5.0)
        return tab_region(lab, cut, 0.0)

    elbow = tab("l_forearm", "l_upper_arm")
    assert elbow[16, 37:41].any() and elbow[24, 37:41].any()      # the second rows next to the cut
    assert not elbow[16, 10:33].any() and not elbow[24, 10:33].any()  # not farther along
    assert not elbow[:16].any() and not elbow[25:].any()           # never the outermost row
    knee = tab("l_shin", "l_thigh")
    assert not knee[16].any() and not knee[24].any() and knee[17, 37:40].any()
