"""experiments/crack_origins.py: each origin of a crack, on hand-made meshes whose answer is known.

Real renderer, real crack measure; the drawings, meshes and poses are built here, so the test
reads no data.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from nnsf.reshape.mesh import Mesh
from nnsf.reshape.render import Renderer

_spec = importlib.util.spec_from_file_location(
    "crack_origins", Path(__file__).resolve().parents[1] / "experiments" / "crack_origins.py")
co = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(co)

SIZE = (70, 80)


def drawing(*boxes, alpha=255):
    """Texture and mask of filled boxes ``(x0, y0, x1, y1)`` (inclusive), flat colour."""
    mask = np.zeros(SIZE, bool)
    for x0, y0, x1, y1 in boxes:
        mask[y0:y1 + 1, x0:x1 + 1] = True
    tex = np.zeros(SIZE + (4,), np.uint8)
    tex[mask] = (200, 120, 40, alpha)
    return tex, mask


def rect_mesh(rects, parts=None) -> Mesh:
    """Two triangles per rectangle ``(x0, y0, x1, y1)``; one part per rectangle unless ``parts``."""
    V, T, P = [], [], []
    for p, (x0, y0, x1, y1) in zip(parts or range(len(rects)), rects):
        k = len(V)
        V += [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        T += [(k, k + 3, k + 2), (k, k + 2, k + 1)]
        P += [p, p]
    return Mesh(np.array(V, float), np.array(T), np.array(P), np.zeros(len(T), int), 10.0)


def origins(tex, mask, mesh, V, order):
    renderer = Renderer(mesh, tex, mask, SIZE)
    n, labels = co.crack_labels(renderer.render(V, order))
    fp = co.Footprint(renderer, mesh, tex, mask, None)(V, order, np.ones(SIZE, bool))
    return n, labels, co.classify(labels, n, fp)


def slot_case(mesh=None):
    """A block with a 3 px slot open downwards (part 0) and a bar below it (part 1); each part's
    mesh covers its mask grown by 2 px, as the project's meshes do.  The bar is moved up 6 px
    until it closes the slot's mouth: the slot, the drawing's own page, is enclosed."""
    tex, mask = drawing((10, 10, 59, 29), (5, 36, 64, 45))
    mask[20:30, 33:36] = False                      # the slot: rows 20..29, columns 33..35
    tex[~mask] = 0
    mesh = mesh or rect_mesh([(8, 8, 61, 31), (3, 34, 66, 47)])
    V = mesh.vertices.copy()
    V[mesh.triangles[mesh.parts == 1].ravel()] -= (0, 6)
    return tex, mask, mesh, V


def test_a_slot_of_page_closed_by_another_part_is_a_page_crack_of_the_gap():
    tex, mask, mesh, V = slot_case()
    rest = Renderer(mesh, tex, mask, SIZE).render(mesh.vertices, [1, 0])
    assert co.crack_labels(rest)[0] == 0            # open at rest: no crack
    n, labels, c = origins(tex, mask, mesh, V, [1, 0])
    assert n == 1 and (labels > 0).sum() == 30 and labels[20:30, 33:36].all()
    assert co.ORIGINS[c["origin"][0]] == "page" and co.PAGE_KINDS[c["page_kind"][0]] == "gap"
    # Page all of it: the slot's mouth row, which a 7 px disc below the block still reaches, is margin.
    assert c["page"][0] == 30 and c["gap"][0] + c["margin"][0] == 30 and c["gap"][0] >= 27
    assert c["opening"][0] == c["thinned"][0] == 0 and not c["mixed"][0]


def test_the_topmost_triangle_decides_which_page_a_pixel_shows():
    tex, mask, mesh, V = slot_case()
    n, _, c = origins(tex, mask, mesh, V, [0, 1])   # the bar on top: its margin covers the slot's end
    assert n == 1 and co.ORIGINS[c["origin"][0]] == "page"
    assert c["margin"][0] == 6 and c["gap"][0] == 24   # 2 rows of the bar's margin over the slot
    assert co.PAGE_KINDS[c["page_kind"][0]] == "gap"


def test_a_cut_that_opens_is_an_opening():
    tex, mask = drawing((10, 10, 50, 50))
    # A square cut from (30, 10) down to (30, 50): the centre vertex is two vertices, one a side.
    V = np.array([(10, 10), (30, 10), (50, 10), (50, 50), (30, 50), (10, 50), (30, 30), (30, 30)], float)
    T = np.array([(0, 6, 1), (0, 5, 6), (5, 4, 6), (1, 7, 2), (2, 7, 3), (3, 7, 4)])
    mesh = Mesh(V, T, np.zeros(6, int), np.zeros(6, int), 10.0)
    assert co.crack_labels(Renderer(mesh, tex, mask, SIZE).render(V, [0]))[0] == 0
    moved = V.copy()
    moved[6] -= (1.5, 0)
    moved[7] += (1.5, 0)
    n, labels, c = origins(tex, mask, mesh, moved, [0])
    assert n == 1 and co.ORIGINS[c["origin"][0]] == "opening"
    assert c["opening"][0] == (labels > 0).sum() > 0 and c["page"][0] == 0
    assert c["tear"][0]                             # the drawing on both sides: it tore
    assert c["beyond"][0] == 0


def test_distance_of_a_texel_outside_its_triangle():
    tri = np.array([[[0, 0], [10, 0], [0, 10]]] * 4, float)
    p = np.array([[2, 2], [5, -3], [-4, -3], [10, 10]], float)
    assert np.allclose(co._outside(p, tri), [0, 3, 5, np.sqrt(50)])
    assert np.allclose(co._outside(p, tri[:, ::-1]), [0, 3, 5, np.sqrt(50)])   # either winding


def test_page_the_mesh_leaves_uncovered_is_an_opening_but_no_tear():
    # The block's mesh leaves the slot's middle column out: the mesh's page margin shows beside it.
    block = rect_mesh([(8, 8, 61, 19), (8, 20, 33, 31), (35, 20, 61, 31), (3, 34, 66, 47)], [0, 0, 0, 1])
    tex, mask, mesh, V = slot_case(block)
    n, labels, c = origins(tex, mask, mesh, V, [1, 0])
    assert n == 1 and labels[20:30, 33:36].all() and co.ORIGINS[c["origin"][0]] == "opening"
    assert 0 < c["opening"][0] <= 10 and not c["tear"][0]


def test_a_faint_stroke_in_the_drawing_is_thinned():
    tex, mask = drawing((10, 10, 50, 50))
    tex[20:41, 30, 3] = 60                          # a faint line inside the mask
    mesh = rect_mesh([(10, 10, 50, 50)])
    n, labels, c = origins(tex, mask, mesh, mesh.vertices, [0])
    assert n == 1 and (labels > 0).sum() == 21
    assert co.ORIGINS[c["origin"][0]] == "thinned" and c["thinned"][0] == 21 and c["edge"][0] == 0
