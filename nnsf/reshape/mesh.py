"""One triangle mesh of a drawing's silhouette, cut only where a limb lies over another part.

:func:`triangulate` meshes the silhouette:

1. the outline (``cv2.findContours``: the outer contour and holes of more than a few pixels) of
   the mask grown by :data:`GROW` pixels, so that every drawn pixel, thin strokes included, lies
   inside a triangle (texels outside the mask are transparent, so the margin draws nothing), simplified
   with ``cv2.approxPolyDP`` and resampled with the global spacing ``h`` (from the target vertex
   count), shrinking where the silhouette is thin (about its local width, from
   ``cv2.distanceTransform``) so a thin limb gets triangles across it; every corner of the
   simplified outline is kept, so no drawn spike is cut off;
2. interior points on a hexagonal lattice of spacing ``h``, minus those too close to the outline,
   smoothed a few sweeps towards their Delaunay neighbours;
3. ``scipy.spatial.Delaunay`` of all points, keeping triangles whose centroid and edge midpoints
   lie in the silhouette (a stand-in for a constrained triangulation: no triangle bridges a
   concavity such as the gap between the legs); slivers lose their flattest corner and the points
   are triangulated again; drawn pixels left outside every triangle get points at least
   :data:`MIN_SPACING` apart (one per region at least), until none is.

:func:`cut` duplicates the vertices along chosen edges: the mesh stays one connected piece wherever
it is not cut, so the two sides of an uncut edge move together in every frame and no crack can open
there.  :func:`build_mesh` cuts only where a limb lies over another part in the drawing, and puts an
underlay of that part beneath every cut, so an opening cut shows the part beneath, never the page.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, shortest_path
from scipy.spatial import Delaunay, cKDTree

from nnsf.errors import InputError

#: The silhouette is meshed grown by this many pixels (texels outside the mask are transparent): the
#: simplified outline and the triangles kept along it then cover every drawn pixel, thin strokes and
#: pixels on the image's border too.
GROW = 2
#: A limb covers a part where that part's region, closed with a disc of this many limb radii,
#: reaches over it (:func:`_covered`): the disc bridges the limb's width (two radii) with room for
#: a limb that widens.
OVER_REACH = 1.5
#: The closest two mesh points may lie, pixels: a triangle thinner than a pixel is rasterised as a
#: pixel-wide needle sampling texels beside it, and a deformation stretches it.
MIN_SPACING = 2.0
#: A pixel of a part beside its underlay is a blend of a limb's edge over it when its colour lies within
#: this distance (RGB levels) of the segment between the part's colour and the limb's (anti-aliasing).
BLEND_TOL = 24.0


@dataclass
class Mesh:
    """A character's mesh at rest, in pixels.

    Attributes
    ----------
    vertices : ``(n, 2)`` float64, rest positions ``(x, y)``; also the texture coordinates.
    triangles : ``(t, 3)`` int64, counter-clockwise (positive signed area in x-right, y-down axes).
    parts : ``(t,)`` int64, the part of each triangle (:class:`nnsf.reshape.rig.Rig` part ids).
    layer : ``(t,)`` int64, 0 for the drawing's own triangles, 1 for the body underlay: copies of
        a limb's triangles drawn over the body, textured with the body painted in under the limb.
    spacing : the global vertex spacing ``h``, pixels.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    parts: np.ndarray
    layer: np.ndarray
    spacing: float

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed areas ``(..., t)`` of triangles over vertices ``(..., n, 2)``; positive = CCW."""
    p = vertices[..., triangles, :]
    e1, e2 = p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]
    return 0.5 * (e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0])


def triangle_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Interior angles ``(t, 3)`` in degrees, at each triangle's three corners."""
    p = vertices[triangles]
    a, b = np.roll(p, -1, axis=1) - p, np.roll(p, -2, axis=1) - p       # (t, 3, 2): the edges from each corner
    cos = (a * b).sum(2) / np.maximum(np.linalg.norm(a, axis=2) * np.linalg.norm(b, axis=2), 1e-12)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """Edges that belong to exactly one triangle, ``(b, 2)``, oriented as in their triangle."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    _, inv, counts = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True, return_counts=True)
    return e[counts[inv.ravel()] == 1]


def shared_edges(triangles: np.ndarray) -> np.ndarray:
    """Interior edges ``(e, 4)``: (triangle 1, its edge k, triangle 2, its edge k); edge k of a
    triangle runs from its corner k to corner k + 1."""
    t = len(triangles)
    e = np.concatenate([triangles[:, [k, (k + 1) % 3]] for k in range(3)])
    owner, local = np.tile(np.arange(t), 3), np.repeat(np.arange(3), t)
    _, inv = np.unique(np.sort(e, axis=1), axis=0, return_inverse=True)
    order = np.argsort(inv.ravel(), kind="stable")
    same = inv.ravel()[order][1:] == inv.ravel()[order][:-1]
    i, j = order[:-1][same], order[1:][same]
    return np.column_stack([owner[i], local[i], owner[j], local[j]])


# --------------------------------------------------------------------------- triangulation

def _lookup(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of ``img`` at points ``(k, 2)``; outside the image counts as 0."""
    H, W = img.shape
    ij = np.rint(pts).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    out = np.zeros(len(pts), dtype=img.dtype)
    out[ok] = img[ij[ok, 1], ij[ok, 0]]
    return out


def _fill_small_holes(mask: np.ndarray, min_hole_area: float) -> np.ndarray:
    """``mask`` (uint8) with its holes under ``min_hole_area`` px² filled: they are meshed over (their
    texels are transparent, so they still show), not given an outline of their own."""
    contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    out = mask.copy()
    for c, (_, _, _, parent) in zip(contours, hierarchy[0]):
        if parent >= 0 and cv2.contourArea(c) < min_hole_area:
            cv2.drawContours(out, [c], -1, 1, -1)
    return out


def _contours(mask: np.ndarray) -> list[np.ndarray]:
    """Outer contour of the largest component and its holes, ``(k, 2)`` float each."""
    contours, hierarchy = cv2.findContours(mask.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    hierarchy = hierarchy[0]
    outer = max((i for i in range(len(contours)) if hierarchy[i][3] < 0), key=lambda i: cv2.contourArea(contours[i]))
    keep = [outer] + [i for i in range(len(contours)) if hierarchy[i][3] == outer]
    return [contours[i][:, 0, :].astype(np.float64) for i in keep]


def _resample_closed(poly: np.ndarray, spacing_at) -> np.ndarray:
    """A closed polygon ``(k, 2)``: its corners, and points between them no farther apart than
    ``spacing_at(points)`` (pixels).  Keeping every corner keeps every spike of the outline."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        L = float(np.linalg.norm(b - a))
        k = max(1, int(np.ceil(L / float(spacing_at(0.5 * (a + b)[None])[0]))))
        out.append(a + (np.arange(k) / k)[:, None] * (b - a))
    return np.vstack(out)


def _hex_grid(mask: np.ndarray, h: float) -> np.ndarray:
    """Points of a hexagonal lattice with spacing ``h`` inside ``mask``, ``(k, 2)``."""
    H, W = mask.shape
    dy = h * np.sqrt(3) / 2
    ys = np.arange(dy / 2, H, dy)
    X, Y = np.meshgrid(np.arange(0.0, W + h, h), ys)
    X = X + (np.arange(len(ys))[:, None] % 2) * (h / 2)
    pts = np.column_stack([X.ravel(), Y.ravel()])
    return pts[_lookup(mask.astype(np.uint8), pts).astype(bool)]


def _delaunay_inside(points: np.ndarray, inside: np.ndarray, loose: np.ndarray) -> np.ndarray:
    """Delaunay triangles ``(t, 3)`` (CCW) whose centroid lies in ``inside`` and edge midpoints in ``loose``."""
    tri = Delaunay(points).simplices.astype(np.int64)
    p = points[tri]
    keep = _lookup(inside, p.mean(axis=1)).astype(bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        keep &= _lookup(loose, 0.5 * (p[:, a] + p[:, b])).astype(bool)
    tri = tri[keep]
    flip = triangle_areas(points, tri) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def _smooth_interior(points: np.ndarray, fixed: np.ndarray, inside: np.ndarray, sweeps: int) -> np.ndarray:
    """Move free points half way to the mean of their Delaunay neighbours; a point stays in the mask."""
    pts = points.copy()
    for _ in range(sweeps):
        tri = Delaunay(pts).simplices
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e = np.concatenate([e, e[:, ::-1]])
        acc = np.zeros_like(pts)
        np.add.at(acc, e[:, 0], pts[e[:, 1]])
        deg = np.bincount(e[:, 0], minlength=len(pts)).astype(float)
        new = np.where(fixed[:, None], pts, 0.5 * pts + 0.5 * acc / np.maximum(deg, 1)[:, None])
        ok = _lookup(inside, new).astype(bool) | fixed
        pts[ok] = new[ok]
    return pts


def spacing_for(mask: np.ndarray, n_vertices: int) -> float:
    """Global spacing ``h`` (pixels) for about ``n_vertices`` vertices: a hexagonal lattice holds one
    point per √3/2 h² of area and the outline one per h of perimeter."""
    area = float(mask.sum())
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    perimeter = sum(cv2.arcLength(c, True) for c in contours)
    a, b, c = area / (np.sqrt(3) / 2), perimeter, -float(n_vertices)
    return 2 * a / (-b + np.sqrt(b * b - 4 * a * c))


def triangulate(mask: np.ndarray, n_vertices: int = 800, min_angle: float = 15.0,
                simplify: float = 0.75) -> tuple[np.ndarray, np.ndarray, float]:
    """Triangulate a silhouette (module docstring): ``(vertices (n, 2), triangles (t, 3), h)``.

    ``mask`` ``(H, W)`` bool; ``n_vertices`` the target count (thin parts and detailed outlines are
    meshed finer, so the result may exceed it); interior points that make a triangle with an angle
    under ``min_angle`` degrees are dropped; ``simplify`` is the outline's ``cv2.approxPolyDP``
    tolerance in pixels.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        raise InputError("mask", "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    if n_vertices < 20:
        raise InputError("triangulate", "n_vertices", "at least 20", n_vertices)
    pad = GROW + 2
    grown = cv2.dilate(np.pad(mask.astype(np.uint8), pad),
                       cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * GROW + 1, 2 * GROW + 1)))
    drawn = np.pad(mask, pad)
    vertices, tri, h = _triangulate_at(grown, drawn, spacing_for(grown, n_vertices), min_angle, simplify)
    miss = len(vertices) / n_vertices
    if abs(miss - 1) > 0.05:  # the lattice loses points near the outline: one rescaled pass
        vertices, tri, h = _triangulate_at(grown, drawn, h * np.sqrt(miss), min_angle, simplify)
    return vertices - pad, tri, h


def _triangulate_at(m8: np.ndarray, drawn: np.ndarray, h: float, min_angle: float, simplify: float):
    m8 = _fill_small_holes(m8, 4 * h * h)
    # Half-width of the silhouette near each pixel: the distance transform's maximum over about h.
    dist = cv2.distanceTransform(np.pad(m8, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    k = max(3, int(2 * round(h) + 1))
    radius = cv2.dilate(dist, np.ones((k, k), np.uint8))   # a square: separable, fast on big drawings

    def spacing_at(pts):  # across a strip 2r wide, equilateral triangles have sides ≈ 2r·2/√3
        return np.clip(2.3 * _lookup(radius, pts), MIN_SPACING, h)

    boundary = []
    for c in _contours(m8):
        poly = cv2.approxPolyDP(c.astype(np.float32).reshape(-1, 1, 2), simplify, True)[:, 0, :]
        boundary.append(_resample_closed((poly if len(poly) >= 3 else c).astype(np.float64), spacing_at))
    boundary = np.vstack(boundary)
    interior = _hex_grid(m8, h)
    if len(interior):
        interior = interior[cKDTree(boundary).query(interior)[0] > 0.6 * spacing_at(interior)]
    points = np.vstack([boundary, interior])
    fixed = np.arange(len(points)) < len(boundary)
    points = _smooth_interior(points, fixed, m8, 3)
    # The simplified outline may overhang the pixels by its tolerance: midpoints are tested loosely.
    loose = cv2.dilate(m8, np.ones((3, 3), np.uint8))
    for _ in range(8):
        tri = _delaunay_inside(points, m8, loose)
        ang = triangle_angles(points, tri)
        bad = np.flatnonzero(ang.min(axis=1) < min_angle)
        # A sliver's widest corner sits nearly on the opposite edge: removing it removes the sliver.
        # An outline point may go too: the outline lies GROW px outside the drawing, and a drawn
        # pixel left uncovered gets a point of its own below.
        if not len(bad):
            break
        keep = ~np.isin(np.arange(len(points)), tri[bad, np.argmax(ang[bad], axis=1)])
        points, fixed = points[keep], fixed[keep]
    tri = _delaunay_inside(points, m8, loose)
    for _ in range(3):
        # Where the outline's edges are not Delaunay edges a triangle across them may be dropped and
        # leave drawn pixels uncovered: the corners of those regions become points, and Delaunay conforms.
        # Corners a pixel apart make slivers: a region's corner farthest from the points, others MIN_SPACING away.
        missed = (drawn & (_raster(points, tri, m8.shape) < 0)).astype(np.uint8)
        if not missed.any():
            break
        for c in cv2.findContours(missed, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)[0]:
            for i, k in enumerate(np.argsort(-cKDTree(points).query(c[:, 0])[0], kind="stable")):
                if i == 0 or cKDTree(points).query(c[k, 0])[0] >= MIN_SPACING:
                    points = np.vstack([points, c[k, 0]])
        tri = _delaunay_inside(points, m8, loose)
    tri = tri[triangle_areas(points, tri) > 1e-6]
    # The largest edge-connected group of triangles is the character.
    labels = _components(tri)
    tri = tri[labels == np.argmax(np.bincount(labels))]
    used, inv = np.unique(tri, return_inverse=True)
    return points[used], inv.reshape(tri.shape), h


# --------------------------------------------------------------------------- cutting

def cut(triangles: np.ndarray, cut_edges: np.ndarray, pairs: np.ndarray):
    """Duplicate vertices so the mesh comes apart along the chosen interior edges.

    ``pairs`` ``(e, 4)``: :func:`shared_edges` of ``triangles`` ``(t, 3)``; ``cut_edges`` ``(e,)``
    bool, which of them to cut.  Every vertex gets one copy per group of its triangles that are
    joined through uncut edges around it (corners joined through an uncut edge are one vertex).
    Returns the new triangles ``(t, 3)`` and the original vertex of each new one ``(n',)``.
    """
    t = len(triangles)
    keep = pairs[~np.asarray(cut_edges, dtype=bool)]
    t1, k1, t2 = keep[:, 0], keep[:, 1], keep[:, 2]
    a, b = triangles[t1, k1], triangles[t1, (k1 + 1) % 3]
    rows, cols = [], []
    for v, k in ((a, k1), (b, (k1 + 1) % 3)):
        local2 = np.argmax(triangles[t2] == v[:, None], axis=1)
        rows.append(3 * t1 + k)
        cols.append(3 * t2 + local2)
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    n_corners = 3 * t
    _, group = connected_components(coo_matrix((np.ones(len(rows)), (rows, cols)),
                                               shape=(n_corners, n_corners)), directed=False)
    # Number the copies in the order of the original vertices, so an uncut mesh keeps its numbering.
    corner_vertex = triangles.ravel()
    first = np.full(group.max() + 1, -1, dtype=np.int64)
    origin_of_group = np.zeros(group.max() + 1, dtype=np.int64)
    origin_of_group[group] = corner_vertex
    order = np.lexsort((np.arange(len(origin_of_group)), origin_of_group))
    first[order] = np.arange(len(order))
    return first[group].reshape(t, 3), origin_of_group[order]


# --------------------------------------------------------------------------- the character's mesh

def _components(triangles: np.ndarray) -> np.ndarray:
    """Component id ``(t,)`` of each triangle, triangles joined by shared edges (a piece that touches
    another at one vertex only would turn about it freely)."""
    t = len(triangles)
    pairs = shared_edges(triangles)
    return connected_components(coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 2])), shape=(t, t)),
                                directed=False)[1]


def _clean_labels(triangles: np.ndarray, parts: np.ndarray, pairs: np.ndarray, parent=None, held=None) -> np.ndarray:
    """Each part one edge-connected region: a smaller island joins the part it borders most, among
    its own part's parent and children when it borders one (``parent`` ``(P,)``): a piece of one leg
    cut off where the legs were drawn close does not join the other leg and leave with it.  An
    island with a triangle ``held`` ``(t,)`` bool (holding a key point of its part's bones) stays."""
    parts = parts.copy()
    t = len(triangles)
    for _ in range(10):
        same = parts[pairs[:, 0]] == parts[pairs[:, 2]]
        g = coo_matrix((np.ones(same.sum()), (pairs[same, 0], pairs[same, 2])), shape=(t, t))
        _, comp = connected_components(g, directed=False)
        size = np.bincount(comp)
        biggest = {}
        for c in np.argsort(-size):
            biggest.setdefault(int(parts[np.flatnonzero(comp == c)[0]]), int(c))
        islands = [c for c in range(len(size)) if biggest[int(parts[np.flatnonzero(comp == c)[0]])] != c
                   and (held is None or not held[comp == c].any())]
        if not islands:
            break
        for c in islands:
            tri = comp == c
            edge = tri[pairs[:, 0]] != tri[pairs[:, 2]]
            other = np.where(tri[pairs[edge, 0]], parts[pairs[edge, 2]], parts[pairs[edge, 0]])
            if parent is not None and len(other):
                own = int(parts[tri][0])
                kin = (other == parent[own]) | (parent[other] == own)
                if kin.any():
                    other = other[kin]
            if len(other):
                parts[tri] = np.bincount(other).argmax()
    return parts


def split_seams(vertices: np.ndarray, triangles: np.ndarray, scores: np.ndarray, clamp: float = 0.2,
                chains=None, min_angle: float = 15.0):
    """Split triangles so the boundary between two parts follows the zero of their score difference.

    ``scores`` ``(n, P)``: each vertex's score per part (:meth:`nnsf.reshape.rig.Rig.scores`); a vertex
    belongs to its lowest.  An edge whose ends belong to parts p and q gets a vertex where s_p − s_q
    changes sign (linear along the edge, kept ``clamp`` of the edge from its ends so no sliver is made);
    a triangle with two parts becomes a triangle and a quad (split along its other diagonal where that
    lifts a least angle under ``min_angle`` degrees), one with three a fan about its centroid.  The
    boundary is then a smooth curve, not a staircase of triangle edges (a jagged edge once the parts
    move apart).  Returns ``(vertices, triangles, part per triangle, the triangle each came from)``;
    the mesh stays conforming (every new vertex is shared by both triangles of its edge).
    """
    n = len(vertices)
    lab = np.argmin(scores, axis=1)
    E = np.concatenate([triangles[:, [k, (k + 1) % 3]] for k in range(3)])
    uniq, inv = np.unique(np.sort(E, axis=1), axis=0, return_inverse=True)
    a, b = uniq[:, 0], uniq[:, 1]
    cross = np.flatnonzero(lab[a] != lab[b])
    p, q = lab[a[cross]], lab[b[cross]]
    fa = scores[a[cross], p] - scores[a[cross], q]
    fb = scores[b[cross], p] - scores[b[cross], q]
    with np.errstate(all="ignore"):
        t = np.clip(np.nan_to_num(fa / (fa - fb), nan=0.5), clamp, 1 - clamp)
    new = vertices[a[cross]] + t[:, None] * (vertices[b[cross]] - vertices[a[cross]])
    mid = np.full(len(uniq), -1, dtype=np.int64)
    mid[cross] = n + np.arange(len(cross))
    M = mid[inv.ravel()].reshape(3, -1).T                       # (t, 3): edge k = corner k → k + 1
    L = lab[triangles]
    kinds = (L[:, 0] != L[:, 1]).astype(int) + (L[:, 1] != L[:, 2]) + (L[:, 2] != L[:, 0])
    tris, parts, src = [triangles[kinds == 0]], [L[kinds == 0, 0]], [np.flatnonzero(kinds == 0)]
    two = np.flatnonzero(kinds == 2)
    if len(two):
        # The lone corner k differs from both others; rotate it to the front.
        Lt = L[two]
        k = np.where(Lt[:, 0] != Lt[:, 1], np.where(Lt[:, 0] != Lt[:, 2], 0, 1), 2)
        c0, c1, c2 = (triangles[two, (k + i) % 3] for i in range(3))
        m01, m20 = M[two, k], M[two, (k + 2) % 3]
        # The quad (m01, c1, c2, m20): with the seam near the lone corner, the diagonal m01-c2 can leave a
        # sliver (which a deformation collapses into a needle); then the other one, if its least angle is larger.
        A, B, allv = np.stack([m01, c1, c2, m01, c2, m20], 1), np.stack([m01, c1, m20, c1, c2, m20], 1), np.vstack([vertices, new])
        least = [triangle_angles(allv, Q.reshape(-1, 3)).min(1).reshape(-1, 2).min(1) for Q in (A, B)]
        Q = np.where(((least[0] >= min_angle) | (least[0] >= least[1]))[:, None], A, B)
        tris += [np.column_stack([c0, m01, m20]), Q[:, :3], Q[:, 3:]]
        parts += [lab[c0], lab[c1], lab[c1]]
        src += [two, two, two]
    three = np.flatnonzero(kinds == 3)
    if len(three):
        g = n + len(cross) + np.arange(len(three))
        # The fan's centre: its centroid; where two different limbs meet (``chains``: each part's
        # limb, −1 for the body), where the three corners' parts score alike, the scores linear over
        # the triangle as along its edges: a centroid deep in one limb would hand a stroke of it to
        # the other, to be carried away across the gap drawn between them.
        tri3 = triangles[three]
        own = L[three]                                                  # (k, 3) corner parts
        Sc = scores[tri3[:, :, None], own[:, None, :]]                  # (k, corner, part)
        A = np.stack([Sc[:, :, 0] - Sc[:, :, 1], Sc[:, :, 1] - Sc[:, :, 2], np.ones_like(Sc[:, :, 0])], 1)
        rhs = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (len(three), 3))
        with np.errstate(all="ignore"):
            lam = np.linalg.solve(A + 1e-9 * np.eye(3), rhs[..., None])[..., 0]
        lam = np.where(np.isfinite(lam), lam, 1 / 3)
        lam = np.clip(lam, clamp, 1.0)
        lam /= lam.sum(axis=1, keepdims=True)
        centre = vertices[tri3].mean(axis=1)
        if chains is not None:
            ch = np.asarray(chains)[own]
            apart = ((ch[:, :, None] != ch[:, None, :]) & (ch[:, :, None] >= 0) & (ch[:, None, :] >= 0)).any((1, 2))
            centre[apart] = np.einsum("kc,kcx->kx", lam[apart], vertices[tri3[apart]])
        new = np.vstack([new, centre])
        for k in range(3):
            ck, cn = triangles[three, k], triangles[three, (k + 1) % 3]
            tris += [np.column_stack([ck, M[three, k], g]), np.column_stack([M[three, k], cn, g])]
            parts += [lab[ck], lab[cn]]
            src += [three, three]
    return np.vstack([vertices, new]), np.vstack(tris), np.concatenate(parts), np.concatenate(src)


def build_mesh(character, rig, n_vertices: int = 800) -> Mesh:
    """The character's mesh (docs/method.md §13): triangulated, labelled by ``rig`` (:func:`split_seams`,
    :func:`_clean_labels`), cut where a limb lies over another part (:func:`_lying_over`, not across a
    joint: :meth:`~nnsf.reshape.rig.Rig.cuts`) yet one connected piece, with underlays beneath every
    cut (:func:`_underlays`, textured by :func:`underlay_texture`)."""
    V, T, h = triangulate(character.mask, n_vertices)
    V, T, parts, _ = split_seams(V, T, rig.scores(V), chains=rig.chains())
    pairs = shared_edges(T)
    shape = np.asarray(character.mask).shape
    # The triangles holding a key point of their part's bones: a piece of a part holding one (the body
    # above and below an arm drawn across it) is that part, not an island to hand to a neighbour.
    on = _lookup(_raster(V, T, shape, np.arange(len(T))), rig.keypoints[rig.bones[:, :2]].reshape(-1, 2))
    on = on[(on >= 0) & (parts[on] == np.repeat(rig.bones[:, 2], 2))]
    parts = _clean_labels(T, parts, pairs, rig.parent, np.isin(np.arange(len(T)), on))
    a, b = T[pairs[:, 0], pairs[:, 1]], T[pairs[:, 0], (pairs[:, 1] + 1) % 3]
    cover, radius = _covered(V, T, parts, shape)
    candidates = rig.cuts(0.5 * (V[a] + V[b]), parts[pairs[:, 0]], parts[pairs[:, 2]], radius)
    cut_edges, under = _lying_over(V, T, parts, pairs, candidates, cover, rig)
    # Two parts that share no joint, which the mesh joins only across the page (its margin bridging a gap
    # between a hand and a leg, a fist and the hair), lie apart in the drawing: cut, with nothing beneath.
    p, q, m8 = parts[pairs[:, 0]], parts[pairs[:, 2]], np.asarray(character.mask, np.uint8)
    drawn = np.any([_lookup(m8, V[a] + f * (V[b] - V[a])) > 0 for f in np.linspace(0, 1, 5)], axis=0)
    for x, y in {(min(i, j), max(i, j)) for i, j in zip(p, q) if i != j and rig.parent[i] != j and rig.parent[j] != i}:
        sel = candidates & ~cut_edges & (((p == x) & (q == y)) | ((p == y) & (q == x)))
        cut_edges |= sel & ~drawn[sel].any()
    # A limb the body is drawn over (a leg under a skirt) is a layer beneath it, cut from every part but its
    # own segments; its length hidden under them (their triangles within its radius of its bones) is painted in.
    hid, chain = np.isin(parts, rig.covered), rig.chains()[parts]
    apart = (hid[pairs[:, 0]] != hid[pairs[:, 2]]) & (chain[pairs[:, 0]] != chain[pairs[:, 2]])
    cut_edges, under = cut_edges | apart, np.where(apart, -1, under)
    centre, reach = V[T].mean(axis=1), rig.covered_radius() + 0.5 * h
    hidden = np.array([(t, p) for p in rig.covered for t in np.flatnonzero((parts != p) & (
        np.linalg.norm(centre - rig.nearest_on_bones(p, centre), axis=1) <= reach[p]))], np.int64).reshape(-1, 2).T
    # A cut ending inside the mesh where a third part meets both sides leaves limb and part beneath
    # one vertex there, which drags the part after the limb (a forearm folded back along its upper
    # arm over the body): the limb's edges with that part are cut too, or where a joint keeps them, the part's.
    t1, k1, t2, k2 = pairs.T
    for side in (0, 1):
        T2, _ = cut(T, cut_edges, pairs)
        c = np.flatnonzero(cut_edges & (under >= 0))
        pinned = np.r_[T2[t1[c], k1[c]] == T2[t2[c], (k2[c] + 1) % 3], T2[t1[c], (k1[c] + 1) % 3] == T2[t2[c], k2[c]]]
        two = np.tile(np.column_stack([np.where(p[c] == under[c], q[c], p[c]), under[c]]), (2, 1))[pinned]
        for v, o, u in set(zip(np.r_[a[c], b[c]][pinned], two[:, side], two[:, 1 - side])):
            cut_edges |= candidates & ((a == v) | (b == v)) & ((p == o) != (q == o)) & (p != u) & (q != u)
    tree = np.flatnonzero(rig.parent >= 0)
    hops = shortest_path(coo_matrix((np.ones(len(tree)), (tree, rig.parent[tree])), (rig.n_parts,) * 2),
                         unweighted=True, directed=False)       # between two parts in the rig's tree
    for _ in range(50):
        # A piece the cuts set apart, and no underlay joins to the rest (the body's, beneath an arm
        # over the hips, joins the body above and below it), is joined back where it touches its
        # nearest kin (a leg to the other leg, not to a hand lying over it).
        T2, origin = cut(T, cut_edges, pairs)
        copied = np.hstack([_underlays(V, T, parts, pairs, np.where(cut_edges, under, -1), cover), hidden])
        tris, layer, all_parts, origin = _assemble(T, T2, origin, parts, *copied, rig.n_parts, len(V))
        comp = _components(tris)
        loose = ((comp != np.bincount(comp[layer == 0]).argmax())    # but a covered limb's piece, under the body
                 & ~np.isin(comp, comp[np.isin(all_parts, rig.covered)]))[layer == 0]
        if not loose.any():
            break
        edge = cut_edges & (loose[pairs[:, 0]] | loose[pairs[:, 2]])
        cut_edges &= ~(edge & (hops[p, q] == hops[p, q][edge].min()))
    # An underlay patch that shares no edge with its part would float; an underlay triangle centred on the page (a copy of
    # a limb's rim across a gap of page) shows only the edge it samples, a fleck once the limb has gone: both are left out.
    on = _lookup(m8, V[origin[tris]].mean(axis=1)) > 0
    keep = (np.isin(comp, comp[layer == 0]) | np.isin(all_parts, rig.covered)) & ((layer == 0) | on)
    tris, layer, all_parts = tris[keep], layer[keep], all_parts[keep]
    used, inv = np.unique(tris, return_inverse=True)
    return Mesh(vertices=V[origin[used]], triangles=inv.reshape(tris.shape), parts=all_parts, layer=layer, spacing=float(h))


def _assemble(T, T2, origin, parts, copied, owner, n_parts, n):
    """``T2`` (vertices ``origin``) and underlay copies of ``T[copied]`` in parts ``owner``: tris, layer, parts, origin"""
    lookup = np.full((n_parts, n), -1, dtype=np.int64)
    lookup[np.repeat(parts, 3), origin[T2.ravel()]] = T2.ravel()
    extra = np.unique(np.column_stack([np.repeat(owner, 3), T[copied].ravel()]), axis=0).reshape(-1, 2)
    extra = extra[lookup[extra[:, 0], extra[:, 1]] < 0]       # an underlay's own vertices, new copies
    lookup[extra[:, 0], extra[:, 1]] = len(origin) + np.arange(len(extra))
    return (np.vstack([T2, lookup[owner[:, None], T[copied]]]), np.repeat(np.array([0, 1]), [len(T2), len(copied)]),
            np.concatenate([parts, owner]), np.concatenate([origin, extra[:, 1]]))


def _raster(V: np.ndarray, T: np.ndarray, shape, values=None) -> np.ndarray:
    """``(H, W)`` int32: each triangle ``(t, 3)`` filled with its value ``(t,)`` (default 0), −1 elsewhere."""
    img = np.full(shape, -1, np.int32)
    values = np.zeros(len(T), np.int64) if values is None else values
    for tri, v in zip(np.rint(V[T] * 16).astype(np.int32), values.tolist()):
        cv2.fillConvexPoly(img, tri, int(v), cv2.LINE_8, 4)
    return img


def _covered(V, T, parts, shape) -> tuple[dict, np.ndarray]:
    """Where each limb covers another part in the drawing, ``{(under, limb): (H, W) bool}``, and each
    limb's half-width ``(P,)`` in pixels (the largest distance inside its region, 0 for the body and
    the head).

    A limb of radius r lies over a part where that part is drawn on both sides of it: the part's
    region closed with a disc of radius :data:`OVER_REACH` × r (by distance transforms), which
    bridges the limb's width, covers the limb there.  A limb beside a part (two legs pressed
    together, an arm hanging at the body's side) is bridged only in the corner where they meet.
    """
    lab = _raster(V, T, shape, parts)
    present = sorted(set(np.unique(parts).tolist()))
    radius = np.zeros(int(parts.max()) + 1)
    out = {}
    for o in present:
        if o < 2:          # the body and the head lie over nothing
            continue
        y0, y1, x0, x1 = _box(lab == o, 0)
        # The limb's own half-width, from its region (the drawing's distance transform does not
        # see a limb drawn inside the body's silhouette).
        radius[o] = float(cv2.distanceTransform(np.pad((lab[y0:y1, x0:x1] == o).astype(np.uint8), 1),
                                                cv2.DIST_L2, 3).max())
        R = max(2, int(round(OVER_REACH * radius[o])))
        y0, y1, x0, x1 = _box(lab == o, R)
        limb = lab[y0:y1, x0:x1] == o
        # The closing by distance transforms (a pixel within R of the region, then one farther
        # than R from everything not within R): the same disc closing at a cost that does not grow
        # with R.  The box reaches 2R past the limb, so the box's edge changes nothing on it.
        near = cv2.distanceTransform((~limb).astype(np.uint8), cv2.DIST_L2, 5) <= 2 * R
        for u in present:
            region = lab[y0:y1, x0:x1] == u
            if u == o or not (region & near).any():
                continue
            grown = cv2.distanceTransform((~region).astype(np.uint8), cv2.DIST_L2, 5) <= R
            closed = cv2.distanceTransform(grown.astype(np.uint8), cv2.DIST_L2, 5) > R
            f = closed & limb
            if f.any():
                full = np.zeros(shape, bool)
                full[y0:y1, x0:x1] = f
                out[(u, o)] = full
    return out, radius


def _box(sel: np.ndarray, pad: int):
    """``(y0, y1, x0, x1)`` of ``sel``'s (non-empty) bounding box grown by ``2 pad``."""
    ys, xs = np.nonzero(sel)
    H, W = sel.shape
    return (max(ys.min() - 2 * pad, 0), min(ys.max() + 2 * pad + 1, H),
            max(xs.min() - 2 * pad, 0), min(xs.max() + 2 * pad + 1, W))


def _lying_over(V, T, parts, pairs, candidates, cover, rig):
    """Which of the ``candidates`` ``(e,)`` interior edges (``pairs`` ``(e, 4)``) to cut, and the part
    lying under each cut ``(e,)`` (−1 where no underlay is needed): an edge between a limb and a part
    it lies over (:func:`_covered`, the limb's middle beside it; ``rig`` a :class:`~nnsf.reshape.rig.Rig`),
    so an opening shows the part's underlay, never the page (docs/method.md §13, Cuts).
    """
    p, q = parts[pairs[:, 0]], parts[pairs[:, 2]]
    ends = V[np.stack([T[pairs[:, 0], pairs[:, 1]], T[pairs[:, 0], (pairs[:, 1] + 1) % 3]])]
    mid, length = ends.mean(axis=0), np.linalg.norm(ends[1] - ends[0], axis=1)
    cut_edges = np.zeros(len(pairs), bool)
    under = np.full(len(pairs), -1, dtype=np.int64)
    # Where limbs cover each part.  The limb's middle beside an edge may lie in the next segment of
    # the same limb (at an elbow), so any limb's cover counts; grown by 2 px, since the bones'
    # joints lie on the boundary between segments, a pixel either side.
    covered = {}
    for (u, _), f in cover.items():
        covered[u] = covered.get(u, np.zeros(f.shape, np.uint8)) | f.astype(np.uint8)
    covered = {u: cv2.dilate(g, np.ones((5, 5), np.uint8)) for u, g in covered.items()}
    joined = lambda u, o: u == o or rig.parent[o] == u or rig.parent[u] == o
    between = lambda u, o: candidates & (((p == u) & (q == o)) | ((p == o) & (q == u)))
    for (u, o) in sorted(cover):
        sel = np.flatnonzero(between(u, o) & ~cut_edges)
        if not len(sel):
            continue
        # Covered at the limb's middle beside the edge (the nearest point of its bones), not
        # only in the corner where it meets the part: the limb can move away by its width and
        # still uncover only underlay.  An edge past the joint the limb shares with the part
        # (behind a thigh's hip, past its knee into the shin) has that joint for its nearest
        # point, which lies on their boundary, in the corner the closing fills: there the limb
        # lies beside the part, not over it, and a cut would tear open as the joint bends.
        near = rig.nearest_on_bones(o, mid[sel])
        j = rig.joint[o] if rig.parent[o] == u else rig.joint[u] if rig.parent[u] == o else -1
        beside = np.abs(near - rig.keypoints[j]).max(axis=1) < 1e-6 if j >= 0 else np.zeros(len(sel), bool)
        hit = sel[(_lookup(covered[u], near) > 0) & ~beside]
        cut_edges[hit], under[hit] = True, u
    # A limb cut from a part along most of their boundary lies over it, a layer of its own: it is cut
    # from every part it shares no joint with.  The edges left joined where it runs out from under
    # the part's outline, or along a part it only touches, dragged a fan of that part after it.
    for o in sorted({o for u, o in cover if not joined(u, o)
                        and length[between(u, o) & cut_edges].sum() >= 0.5 * length[between(u, o)].sum() > 0}):
        for u in (u for u in range(rig.n_parts) if not joined(u, o)):
            under[between(u, o) & ~cut_edges] = u
            cut_edges |= between(u, o)
    return cut_edges, under


def _underlays(V, T, parts, pairs, under, cover) -> tuple[np.ndarray, np.ndarray]:
    """The triangles to copy into underlays ``(c,)`` and the part each copy goes to ``(c,)``: a cut
    limb's triangles where it covers a part (:func:`_covered`), and every limb triangle touching a cut
    by an edge or a corner, copied into each part beneath (docs/method.md §13, Underlays).
    """
    centre = V[T].mean(axis=1)
    cut = np.flatnonzero(under >= 0)
    u = under[cut]
    o = np.where(parts[pairs[cut, 0]] == u, parts[pairs[cut, 2]], parts[pairs[cut, 0]])
    ends = np.column_stack([T[pairs[cut, 0], pairs[cut, 1]], T[pairs[cut, 0], (pairs[cut, 1] + 1) % 3]])
    tri, to = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
    for uu, oo in sorted({(int(x), int(y)) for x, y in zip(u, o)}):
        over = _lookup(cover[(uu, oo)].astype(np.uint8), centre) > 0 if (uu, oo) in cover else False
        sel = np.flatnonzero((parts == oo) & (np.isin(T, ends[(u == uu) & (o == oo)]).any(axis=1) | over))
        tri.append(sel)
        to.append(np.full(len(sel), uu))
    both = np.unique(np.column_stack([np.concatenate(to), np.concatenate(tri)]).astype(np.int64), axis=0)
    return both[:, 1], both[:, 0]


def _fill_pixels(texture: np.ndarray, region: np.ndarray, deep: int) -> np.ndarray:
    """``(H, W)`` bool: the pixels of ``region`` more than ``deep`` px inside it whose colour, binned 16
    levels a channel, is its most common one or makes up a tenth of them and fills a disc of radius
    ``deep`` (a flat colour of the part, not its ink: an outline or a line drawn across it)."""
    own = cv2.erode(region.astype(np.uint8), np.ones((2 * deep + 1,) * 2, np.uint8)) > 0
    if not own.any():
        return own
    _, inv, counts = np.unique(texture[own][:, :3] >> 4, axis=0, return_inverse=True, return_counts=True)
    binned = np.full(own.shape, -1)
    binned[own] = inv.ravel()
    thick = lambda b: cv2.distanceTransform(np.pad((binned == b).astype(np.uint8), 1), cv2.DIST_L2, 5).max() >= deep
    return np.isin(binned, [b for b in np.flatnonzero(counts >= 0.1 * own.sum()) if thick(b)] + [int(np.argmax(counts))])


def underlay_texture(texture: np.ndarray, mask: np.ndarray, mesh: Mesh, rig=None) -> np.ndarray | None:
    """The drawing ``(H, W, 4)`` with each part's colours laid, opaque, where its underlay lies (None
    without one). A pixel takes the colour of the nearest of the part's fill pixels (:func:`_fill_pixels`):
    neither ink nor a line drawn across the part (a belt) runs in, as an inpainting would let it; a shirt
    and the trousers below it each go on under a hand on the hip. Within a triangle spacing of the underlay,
    on the part's own triangles (:func:`underlay_ring` samples them here), the limb's edge left there takes
    the part's colours too: pixels ``rig``'s labels give another part, and blends (within
    :data:`BLEND_TOL`) of the part's colour and another part's fill, its anti-aliased outline. A limb
    covered by the body (``rig``'s) goes on as it is drawn where it shows (:meth:`~nnsf.reshape.rig.Rig.continued`).
    """
    if not (mesh.layer == 1).any():
        return None
    H, W = mask.shape
    out = texture.copy()
    deep = max(2, int(round(0.5 * mesh.spacing)))
    labels = rig.labels if rig is not None and rig.labels is not None else np.full((H, W), -1)
    colour = lambda y, x: texture[y, x, :3].astype(np.float64)
    for p in np.unique(mesh.parts[mesh.layer == 1]):
        region = _raster(mesh.vertices, mesh.triangles[(mesh.layer == 1) & (mesh.parts == p)], (H, W)) >= 0
        if rig is not None and p in rig.covered:    # the limb as drawn where it shows, carried on, and a few
            # texels past its triangles (their edges sample there: the drawing left there shows as lines)
            ys, xs = np.nonzero(cv2.dilate(region.astype(np.uint8), np.ones((5, 5), np.uint8)))
            sx, sy = np.clip(np.rint(rig.continued(p, np.column_stack([xs, ys]))).astype(int) + 1, 0, [W + 1, H + 1]).T
            shows = np.isin(np.pad(rig.labels, 1, constant_values=-1)[sy, sx], rig.covered_limb(p))   # +1: padded, off the image is no limb
            out[ys, xs] = np.where(shows[:, None], np.pad(texture, ((1, 1), (1, 1), (0, 0)))[sy, sx], 0)
            continue
        drawn = _raster(mesh.vertices, mesh.triangles[(mesh.layer == 0) & (mesh.parts == p)], (H, W)) >= 0
        fill = _fill_pixels(texture, drawn & np.asarray(mask, bool), deep)
        if not fill.any():
            continue
        near = ndimage.distance_transform_edt(~fill, return_distances=False, return_indices=True)
        reach = 2 * int(round(mesh.spacing)) + 1
        band = (cv2.dilate(region.astype(np.uint8), np.ones((reach, reach), np.uint8)) > 0) & drawn & ~region
        others = np.zeros((H, W), bool)
        for o in np.setdiff1d(labels[cv2.dilate(band.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0], [-1, p]):
            others |= _fill_pixels(texture, labels == o, deep)
        ys, xs = np.nonzero(band)
        edge = (labels[ys, xs] != p) & (labels[ys, xs] >= 0)     # no labels (no rig): no edge to find
        if others.any():    # how far each colour lies from the segment between the part's and the other's
            oy, ox = ndimage.distance_transform_edt(~others, return_distances=False, return_indices=True)
            c, f = colour(ys, xs), colour(near[0][ys, xs], near[1][ys, xs])
            d = colour(oy[ys, xs], ox[ys, xs]) - f
            t = np.clip(((c - f) * d).sum(1) / np.maximum((d * d).sum(1), 1e-9), 0.0, 1.0)
            edge |= np.linalg.norm(c - f - t[:, None] * d, axis=1) < BLEND_TOL
        band[ys[~edge], xs[~edge]] = False
        # Opaque over the underlay's triangles, within the drawing (the renderer masks it): what a cut beside it shows.
        out[region | band, :3] = texture[near[0][region | band], near[1][region | band], :3]
        out[region, 3] = 255
    return out


def underlay_ring(mesh: Mesh, rig=None) -> np.ndarray:
    """``(t,)`` bool: the drawn triangles of a part that share a corner with its underlay (not a covered
    limb's, ``rig``'s); they sample :func:`underlay_texture`, which holds their part's colours where the
    limb's edge was drawn."""
    under = (mesh.layer == 1) & ~np.isin(mesh.parts, getattr(rig, "covered", ()))
    mark = np.zeros((int(mesh.parts.max()) + 1, mesh.n_vertices), bool)
    mark[np.repeat(mesh.parts[under], 3), mesh.triangles[under].ravel()] = True
    return (mesh.layer == 0) & mark[mesh.parts[:, None], mesh.triangles].any(axis=1)
