"""Triangulating silhouettes and labelling body parts."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.reshape.character import load_animated_drawings, stick_figure
from nnsf.reshape.layers import build_mesh
from nnsf.reshape.mesh import boundary_edges, label_parts, triangle_angles, triangle_areas, triangulate_mask
from nnsf.reshape.parts import PARTS
from nnsf.skeleton import JOINT_INDEX as J
from nnsf.skeleton import LIMBS

CHARACTERS = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters"
MIN_ANGLE = 15.0


def _lookup(mask, pts):
    ij = np.rint(pts).astype(int)
    return mask[ij[..., 1], ij[..., 0]]


def _check_mesh(mask, V, T, min_angle=MIN_ANGLE):
    """No triangle outside the mask, well shaped, counter-clockwise, one piece."""
    assert V.dtype == np.float64 and T.dtype == np.int64
    assert np.array_equal(np.unique(T), np.arange(len(V)))     # no unused vertices
    p = V[T]
    assert _lookup(mask, p.mean(axis=1)).all()                  # centroids inside
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):                       # no edge bridges a gap
        assert _lookup(grown, 0.5 * (p[:, a] + p[:, b])).all()
    assert triangle_angles(V, T).min() >= min_angle
    assert np.all(triangle_areas(V, T) > 0)
    # Covers the silhouette: the simplified outline loses under a pixel along the edge.
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    perimeter = sum(cv2.arcLength(c, True) for c in contours)
    assert triangle_areas(V, T).sum() > mask.sum() - 1.5 * perimeter
    # A closed outline: every outline vertex has exactly two outline edges.
    E = boundary_edges(T)
    deg = np.bincount(E.ravel(), minlength=len(V))
    assert set(np.unique(deg[deg > 0])) <= {2, 4}


@pytest.mark.parametrize("n", [300, 1500])
def test_stick_figure_mesh(n):
    fig = stick_figure(height=360)
    mesh = build_mesh(fig.mask, fig.keypoints, n_vertices=n)
    _check_mesh(fig.mask, mesh.vertices, mesh.triangles)
    assert abs(mesh.n_vertices / n - 1) < 0.15
    assert mesh.parts.shape == (len(mesh.triangles),)
    assert set(np.unique(mesh.parts)) == set(range(len(PARTS)))
    # The triangle at the middle of each limb belongs to that limb.
    c = mesh.vertices[mesh.triangles].mean(axis=1)
    for name, (a, b) in LIMBS.items():
        mid = 0.5 * (fig.keypoints[a] + fig.keypoints[b])
        assert PARTS[mesh.parts[np.argmin(np.linalg.norm(c - mid, axis=1))]] == name
    head = fig.keypoints[J["head_top"]] + [0.0, 5.0]
    assert PARTS[mesh.parts[np.argmin(np.linalg.norm(c - head, axis=1))]] == "head"


def test_holes_are_not_meshed_and_thin_strips_get_real_triangles():
    mask = np.zeros((200, 300), np.uint8)
    cv2.circle(mask, (100, 100), 80, 1, -1)
    cv2.circle(mask, (100, 100), 30, 0, -1)           # a hole
    cv2.line(mask, (170, 100), (290, 60), 1, 5)       # a thin strip, 5 px wide
    mask = mask.astype(bool)
    V, T, h = triangulate_mask(mask, n_vertices=600)
    _check_mesh(mask, V, T)
    assert not _lookup(mask, np.array([100.0, 100.0]))
    inside_hole = np.linalg.norm(V[T].mean(axis=1) - [100, 100], axis=1) < 28
    assert not inside_hole.any()
    on_strip = V[T].mean(axis=1)[:, 0] > 200
    assert on_strip.sum() >= 20                         # meshed finer than h across the strip
    assert h > 5


def test_empty_mask_is_an_input_error():
    with pytest.raises(InputError, match="empty mask"):
        triangulate_mask(np.zeros((50, 50), bool))


def test_label_parts_nearest_bone():
    fig = stick_figure(height=200)
    kp = fig.keypoints
    V = np.array([kp[J["l_elbow"]], kp[J["l_elbow"]] + [1, 0], kp[J["l_elbow"]] + [0, 1],
                  kp[J["spine"]], kp[J["spine"]] + [1, 0], kp[J["spine"]] + [0, 1]])
    parts = label_parts(V, np.array([[0, 1, 2], [3, 4, 5]]), kp)
    assert PARTS[parts[1]] == "torso"
    assert PARTS[parts[0]] in ("l_upper_arm", "l_forearm")


@pytest.mark.parametrize("name", ["char1", "char2", "char4"])
def test_drawn_characters_mesh(name):
    if not (CHARACTERS / name).is_dir():
        pytest.skip(f"AnimatedDrawings example characters not found at {CHARACTERS}")
    ch = load_animated_drawings(CHARACTERS / name)
    mesh = build_mesh(ch.mask, ch.keypoints, n_vertices=800)
    _check_mesh(ch.mask, mesh.vertices, mesh.triangles)
    assert abs(mesh.n_vertices / 800 - 1) < 0.15


def test_split_mesh_cuts_the_limbs_loose():
    from nnsf.reshape.mesh import split_pieces, triangle_adjacency
    from nnsf.reshape.parts import PIECES

    fig = stick_figure(height=300)
    whole = build_mesh(fig.mask, fig.keypoints, n_vertices=500)
    assert not whole.is_split and np.all(whole.pieces == 0)
    cut = split_pieces(whole, fig.keypoints)
    assert cut.is_split and set(np.unique(cut.pieces)) == set(range(len(PIECES)))
    assert len(cut.triangles) == len(whole.triangles) and np.array_equal(cut.parts, whole.parts)
    # Same rest geometry triangle by triangle; only seam vertices were duplicated.
    np.testing.assert_array_equal(cut.vertices[cut.triangles], whole.vertices[whole.triangles])
    assert whole.n_vertices < cut.n_vertices < whole.n_vertices + 0.2 * whole.n_vertices
    # No vertex is shared by two pieces, and every piece is one connected group.
    vp = cut.vertex_pieces()
    assert np.all(vp[cut.triangles] == cut.pieces[:, None])
    a, b = triangle_adjacency(cut.triangles)
    assert np.all(cut.pieces[a] == cut.pieces[b])
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    n, _ = connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(len(cut.triangles),) * 2),
                                directed=False)
    assert n == len(PIECES)
