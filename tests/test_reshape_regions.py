"""Whole-limb meshes (``split="limbs"``) and the drawing's ink regions in part assignment."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.reshape import metrics
from nnsf.reshape.character import Character, stick_figure
from nnsf.reshape.layers import build_mesh
from nnsf.reshape.mesh import triangle_adjacency
from nnsf.reshape.parts import LIMB_PIECES, PART_INDEX
from nnsf.reshape.regions import body_region_triangles, drawn_regions
from nnsf.reshape.rig import Rig
from nnsf.skeleton import JOINT_INDEX as J


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (p - c) @ R.T + c


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=360)


@pytest.fixture(scope="module")
def limbs_mesh(figure):
    return build_mesh(figure.mask, figure.keypoints, 500, split="limbs", texture=figure.texture)


# --------------------------------------------------------------------------- regions

def test_drawn_regions_splits_the_mask_at_ink_lines_down_the_middle():
    tex = np.full((40, 60, 4), 200, np.uint8)
    tex[:, 28:33, :3] = 20              # a dark line, columns 28..32
    mask = np.ones((40, 60), bool)
    mask[:, 55:] = False
    lab = drawn_regions(tex, mask)
    assert (lab[:, 55:] == -1).all()
    left, right = lab[5, 5], lab[5, 50]
    assert left != right and left >= 0 and right >= 0
    assert (lab[:, :30] == left).all() and (lab[:, 31:55] == right).all()  # the line is split at its middle
    # a speck smaller than min_area is not a region of its own
    tex[10:12, 10:12, :3] = 20
    tex[10:12, 10:12, :3] = 20
    assert set(np.unique(drawn_regions(tex, mask))) == {-1, left, right}


def _arm_behind_body():
    """A figure whose left upper arm starts inside the body's drawn outline, behind it.

    The body (grey 170) is outlined in ink; the arm (light 230) is a separate
    outlined region that only begins outside the body.  The shoulder key point
    lies inside the body, so the arm's capsule covers body pixels.
    """
    ch = stick_figure(height=360)
    kp = ch.keypoints
    H, W = ch.mask.shape
    yy, xx = np.mgrid[:H, :W]
    tex = np.zeros((H, W, 4), np.uint8)
    tex[..., 3] = 255
    tex[..., :3] = 230
    body_box = (xx > kp[J["l_shoulder"], 0] + 12) | (xx < kp[J["r_shoulder"], 0] - 12)
    body = (~body_box) & (yy > kp[J["neck"], 1]) & (yy < kp[J["pelvis"], 1] + 10)
    tex[body, :3] = 170
    import cv2
    ink = cv2.morphologyEx(body.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
    tex[ink, :3] = 10
    mask = ch.mask | body
    return Character(name="behind", texture=tex, mask=mask, keypoints=kp, source="<test>"), body


def test_limb_capsules_give_the_body_back_its_drawn_region():
    ch, body = _arm_behind_body()
    kp = ch.keypoints
    plain = build_mesh(ch.mask, kp, 600, split="layered")
    drawn = build_mesh(ch.mask, kp, 600, split="layered", texture=ch.texture)

    def arm_on_body(m):
        c = m.vertices[m.triangles].mean(axis=1)
        ij = np.rint(c).astype(int)
        on = body[ij[:, 1], ij[:, 0]]
        arm = (m.parts == PART_INDEX["l_upper_arm"]) & (m.layer == 0) & (m.collar < 0)
        return int((arm & on).sum())

    # the cut where the arm leaves the body keeps the chest with the body even without the drawing
    # (the old capsule labels took some of it), and the drawing's region keeps it there too
    assert arm_on_body(plain) == 0
    assert arm_on_body(drawn) == 0
    flags = body_region_triangles(drawn.vertices, drawn.triangles, kp, ch.texture, ch.mask)
    assert flags.any()


def test_a_region_shared_by_body_and_limb_says_nothing(figure):
    # the stick figure is one flat colour: body and limbs are one region, so no triangle is forced
    m = build_mesh(figure.mask, figure.keypoints, 400)
    assert not body_region_triangles(m.vertices, m.triangles, figure.keypoints, figure.texture, figure.mask).any()


# --------------------------------------------------------------------------- whole-limb pieces

def test_limbs_mesh_has_one_connected_piece_per_whole_limb(limbs_mesh):
    m = limbs_mesh
    assert m.piece_names == LIMB_PIECES and set(np.unique(m.pieces)) == set(range(len(LIMB_PIECES)))
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    for pc in range(len(LIMB_PIECES)):  # the solved triangles (joint tabs are groups of their own)
        tri = m.triangles[(m.pieces == pc) & m.core_triangles]
        a, b = triangle_adjacency(tri)
        n = len(tri)
        assert connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)[0] == 1
    # upper arm and forearm share vertices (no cut at the elbow), the arm and the body none
    def verts(part=None, piece=None):
        sel = np.ones(len(m.triangles), bool)
        if part is not None:
            sel &= (m.parts == PART_INDEX[part]) & (m.collar < 0)
        if piece is not None:
            sel &= m.pieces == LIMB_PIECES.index(piece)
        return set(m.triangles[sel].ravel().tolist())
    assert verts("l_upper_arm") & verts("l_forearm")
    assert not (verts(piece="l_arm") & verts(piece="body"))


@pytest.mark.parametrize("deg", [90.0, 130.0])
def test_subkeys_act_on_a_whole_limb_and_keep_its_segments_straight(figure, limbs_mesh, deg):
    kp = np.stack([_bend(figure.keypoints, d) for d in np.linspace(0, deg, 6)])
    ours = Rig.build(figure, handle_set="subkeys", mesh=limbs_mesh, propagation="limb-frame")
    base = Rig.build(figure, handle_set="keypoints", mesh=limbs_mesh)
    Vo, Vb = ours.animate(kp), base.animate(kp)
    m = limbs_mesh
    # both bend the limb (the elbow joins two segments of one deformable piece)
    assert metrics.arap_energy(m.vertices, Vb[-1], m.triangles) > 1.0
    assert np.abs(Vo - Vb).max() > 1.0
    bo = metrics.deformed_bending(ours, Vo, kp)[-1, 0:2]    # l_upper_arm, l_forearm
    bb = metrics.deformed_bending(base, Vb, kp)[-1, 0:2]
    rest = metrics.limb_bending(ours.rest_omega)[0:2]
    # subkeys keep both segments' drawn curvature; key points alone let them bow
    assert np.all(np.abs(bo - rest) < 0.05)
    assert np.abs(bb - rest).max() > 2 * np.abs(bo - rest).max()


def _bend(kp, deg):
    out = kp.copy()
    out[J["l_wrist"]] = _rot(kp[J["l_wrist"]], kp[J["l_elbow"]], deg)
    return out
