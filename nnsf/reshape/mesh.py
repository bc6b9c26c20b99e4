"""Triangulate a character's silhouette and split the triangles into body parts.

The mesh is built in five steps, each chosen to keep triangles well shaped:

1. the outline (``cv2.findContours``, outer contour plus holes of more than a
   few pixels), simplified with ``cv2.approxPolyDP`` to drop the pixel
   staircase, and resampled with a spacing that is the global spacing ``h``
   (derived from the target vertex count) but shrinks where the silhouette is
   thin (about one local width, from ``cv2.distanceTransform``), so a thin
   stick-figure arm still gets triangles across it instead of slivers;
2. interior points on a hexagonal grid of spacing ``h`` (the lattice of
   equilateral triangles), minus the points too close to the outline;
3. a few Laplacian smoothing sweeps of the interior points over their
   Delaunay neighbours (boundary fixed), which evens out the band between
   the outline and the grid;
4. ``scipy.spatial.Delaunay`` of all points, keeping the triangles whose
   centroid and edge midpoints lie in the silhouette (a cheap stand-in for a
   constrained triangulation: it removes triangles that bridge concavities
   such as the gap between the legs);
5. sliver removal: a triangle with a minimum angle under ``min_angle`` loses
   its vertex nearest the opposite edge (interior points first) and the
   points are triangulated again; the few slivers that survive are dropped.

Parts: every triangle gets the id of its nearest bone's part (Euclidean
distance from the centroid to the bone segments of the 17-point skeleton).
By default the mesh stays **connected** across part seams (vertices are
shared): smooth, but a limb turned far toward the body folds the mesh at the
inside of the joint (an arm raised ~75° or more).  ``split=True`` cuts it into
:data:`~nnsf.reshape.parts.PIECES` (body, each arm, each leg) by duplicating the seam vertices;
each piece is then pinned by its own key points (:data:`~nnsf.reshape.parts.PIECE_KEYPOINTS`,
the shoulder or hip on both sides of a seam) and a limb can move over the
body, which a renderer must then draw in depth order; its seams follow the
triangles, so they are jagged, and a bent elbow or knee still folds.

``split="layered"`` (:func:`nnsf.reshape.layers.layer_pieces`, the default of the ``reshape``
stage) fixes both: limb triangles are labelled by capsules of the limb's own
width (a drawn arm over the chest does not take the chest with it), each of
the ten segments (body, eight limb segments, head) is its own piece, cut
along a straight segment across each joint (:func:`nnsf.reshape.layers.joint_cuts`; the cut and a
half-elliptic collar arc are inserted into the triangulation so the seams are
smooth), each child carries a joint cap (a copy of the parent's triangles
inside the arc) that covers the wedge a bending joint opens, and the body
gets an inpainted underlay where a limb lay over it.

This module triangulates and labels parts (:func:`triangulate_mask`,
:func:`label_parts`, :func:`split_pieces`); the part tables are
:mod:`nnsf.reshape.parts`, the drawn regions :mod:`nnsf.reshape.regions`,
the layered mesh and :func:`~nnsf.reshape.layers.build_mesh` (every mesh
kind) :mod:`nnsf.reshape.layers`, the paper-puppet pieces
:mod:`nnsf.reshape.pieces`.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import Delaunay, cKDTree

from nnsf.errors import InputError
from nnsf.skeleton import LIMBS
from nnsf.reshape.parts import PART_BONES, PART_PIECE, PIECES, PIECE_KEYPOINTS


@dataclass
class Mesh:
    """A triangle mesh of a silhouette, in pixels.

    Attributes
    ----------
    vertices : ndarray, shape (n, 2), float64
        Rest positions ``(x, y)`` in pixels.  They double as texture
        coordinates when the deformed mesh is drawn.
    triangles : ndarray, shape (t, 3), int64
        Vertex indices, counter-clockwise in (x, y) axes, i.e. positive
        signed area ``(b - a) × (c - a) > 0``.
    parts : ndarray, shape (t,), int64
        Part id per triangle, an index into :data:`PARTS`.
    spacing : float
        The global vertex spacing ``h`` in pixels.
    pieces : ndarray, shape (t,), int64
        Connected piece per triangle, an index into :data:`PIECES`.  All 0
        for a connected mesh; :func:`split_pieces` cuts the limbs loose.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    parts: np.ndarray
    spacing: float
    pieces: np.ndarray | None = None
    #: Names of the pieces (:data:`PIECES` for :func:`split_pieces`,
    #: :data:`SEGMENTS` for :func:`layer_pieces`).
    piece_names: tuple[str, ...] = PIECES
    #: Key points pinning each piece, one tuple per name in ``piece_names``.
    piece_keypoints: tuple[tuple[int, ...], ...] | None = None
    #: Texture layer per triangle ``(t,)``: 0 the drawing, 1 the inpainted
    #: underlay (body triangles under a limb drawn over the body), 2 the
    #: body's outline only (copies of a limb's triangles on the body's ink rim,
    #: textured with the body's drawn regions and the ink, see ``render.rim_texture``).
    layer: np.ndarray | None = None
    #: For a collar copy (:func:`layer_pieces`) the part id of the parent it
    #: overlaps, else −1, ``(t,)``; a renderer draws a collar just before its
    #: parent part, so it fills the joint's gap but never covers the parent.
    collar: np.ndarray | None = None
    #: For a piece's own triangle, the part it goes under whenever the piece is drawn in front of
    #: that part, else −1, ``(t,)``: a thigh's band along its hip cut under the body
    #: (:func:`nnsf.reshape.pieces.hip_tucks`).
    tuck: np.ndarray | None = None
    #: Vertices ``[:n_core]`` are deformed (ARAP); the rest belong to joint
    #: tabs (:mod:`nnsf.reshape.pieces`), moved rigidly with their child's
    #: bone after the solve.  None: every vertex is deformed.
    n_core: int | None = None
    #: The tabs (:class:`nnsf.reshape.pieces.Tab`) of a pieced mesh.
    tabs: list = field(default_factory=list)
    #: Piece of every pixel of the drawing at rest ``(H, W)`` (pieced meshes), −1 outside.
    labels: np.ndarray | None = None
    #: The cuts between the pieces (:class:`nnsf.reshape.pieces.Cut`).
    cuts: list = field(default_factory=list)
    #: Rest key points ``(17, 2)`` with the pivots moved onto the cuts
    #: (:func:`nnsf.reshape.pieces.move_pivots`); a rig drives the mesh with these.
    pivots: np.ndarray | None = None
    #: Pixels ``(H, W)`` of limbs drawn over the body (the body's layer-1 texture paints them out).
    overlay: np.ndarray | None = None

    def __post_init__(self):
        if self.collar is None:
            self.collar = np.full(len(self.triangles), -1, dtype=np.int64)
        if self.tuck is None:
            self.tuck = np.full(len(self.triangles), -1, dtype=np.int64)
        if self.pieces is None:
            self.pieces = np.zeros(len(self.triangles), dtype=np.int64)
        if self.layer is None:
            self.layer = np.zeros(len(self.triangles), dtype=np.int64)
        if self.piece_keypoints is None:
            self.piece_keypoints = tuple(PIECE_KEYPOINTS.get(n, ()) for n in self.piece_names)

    @property
    def n_vertices(self) -> int:
        return len(self.vertices)

    @property
    def core(self) -> int:
        """How many vertices the deformation solves for (all but the tabs')."""
        return self.n_vertices if self.n_core is None else int(self.n_core)

    @property
    def core_triangles(self) -> np.ndarray:
        """Whether each triangle ``(t,)`` is deformed (not a tab's)."""
        return np.all(self.triangles < self.core, axis=1)

    @property
    def is_split(self) -> bool:
        """Whether the limbs are separate pieces (duplicated seam vertices)."""
        return bool(np.any(self.pieces != 0))

    def vertex_pieces(self) -> np.ndarray:
        """Piece of every vertex ``(n,)`` (each vertex of a split mesh is in one piece)."""
        out = np.zeros(self.n_vertices, dtype=np.int64)
        out[self.triangles.ravel()] = np.repeat(self.pieces, 3)
        return out

    def boundary_edges(self) -> np.ndarray:
        """Edges used by one triangle only, ``(b, 2)`` vertex indices."""
        return boundary_edges(self.triangles)


def triangle_areas(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Signed areas ``(..., t)`` of triangles over vertices ``(..., n, 2)``; positive = CCW."""
    p = vertices[..., triangles, :]
    e1, e2 = p[..., 1, :] - p[..., 0, :], p[..., 2, :] - p[..., 0, :]
    return 0.5 * (e1[..., 0] * e2[..., 1] - e1[..., 1] * e2[..., 0])


def triangle_angles(vertices: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Interior angles ``(t, 3)`` in degrees, at each triangle's three corners."""
    p = vertices[triangles]
    out = np.empty(triangles.shape)
    for k in range(3):
        a = p[:, (k + 1) % 3] - p[:, k]
        b = p[:, (k + 2) % 3] - p[:, k]
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        out[:, k] = np.degrees(np.arctan2(np.abs(cross), (a * b).sum(axis=1)))
    return out


def boundary_edges(triangles: np.ndarray) -> np.ndarray:
    """Edges that belong to exactly one triangle, ``(b, 2)``, oriented as in their triangle."""
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(e, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return e[counts[inv.ravel()] == 1]


# --------------------------------------------------------------------------- outline

def _contours(mask: np.ndarray, min_hole_area: float) -> list[np.ndarray]:
    """Outer contour of the largest component and its holes, ``(k, 2)`` float each."""
    m = mask.astype(np.uint8)
    contours, hierarchy = cv2.findContours(m, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    if not contours:
        raise InputError("mask", "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    hierarchy = hierarchy[0]
    outers = [i for i in range(len(contours)) if hierarchy[i][3] < 0]
    outer = max(outers, key=lambda i: cv2.contourArea(contours[i]))
    keep = [outer] + [i for i in range(len(contours))
                      if hierarchy[i][3] == outer and cv2.contourArea(contours[i]) >= min_hole_area]
    return [contours[i][:, 0, :].astype(np.float64) for i in keep]


def _resample_closed(poly: np.ndarray, spacing_at) -> np.ndarray:
    """Resample a closed polygon ``(k, 2)`` with a spacing that varies along it.

    ``spacing_at(points) -> spacings`` gives the wanted spacing in pixels.
    Samples sit at equal steps of ∫ ds / spacing(s), evaluated on a dense
    (half-pixel) walk along the polygon.
    """
    closed = np.vstack([poly, poly[:1]])
    seg = np.linalg.norm(np.diff(closed, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    total = s[-1]
    dense_s = np.linspace(0.0, total, max(int(np.ceil(total / 0.5)), 8), endpoint=False)
    dense = np.column_stack([np.interp(dense_s, s, closed[:, 0]), np.interp(dense_s, s, closed[:, 1])])
    density = 1.0 / spacing_at(dense)
    step = total / len(dense_s)
    count = np.concatenate([[0.0], np.cumsum(density) * step])
    n = max(int(round(count[-1])), 3)
    targets = np.arange(n) * (count[-1] / n)
    ts = np.interp(targets, count, np.append(dense_s, total))
    return np.column_stack([np.interp(ts, s, closed[:, 0]), np.interp(ts, s, closed[:, 1])])


def _hex_grid(mask: np.ndarray, h: float, rng: np.random.Generator, jitter: float) -> np.ndarray:
    """Points of a hexagonal lattice with spacing ``h`` inside ``mask``, ``(k, 2)``."""
    H, W = mask.shape
    dy = h * np.sqrt(3) / 2
    ys = np.arange(dy / 2, H, dy)
    xs = np.arange(0.0, W + h, h)
    X, Y = np.meshgrid(xs, ys)
    X = X + (np.arange(len(ys))[:, None] % 2) * (h / 2)
    pts = np.column_stack([X.ravel(), Y.ravel()])
    if jitter > 0:
        pts = pts + rng.uniform(-jitter, jitter, pts.shape) * h
    ij = np.rint(pts).astype(int)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    pts, ij = pts[ok], ij[ok]
    return pts[mask[ij[:, 1], ij[:, 0]]]


def _lookup(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of ``img`` at points ``(k, 2)``; outside the image counts as 0."""
    H, W = img.shape
    ij = np.rint(pts).astype(np.int64)
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    out = np.zeros(len(pts), dtype=img.dtype)
    out[ok] = img[ij[ok, 1], ij[ok, 0]]
    return out


# --------------------------------------------------------------------------- triangulation

def _triangulate(points: np.ndarray, inside: np.ndarray, inside_loose: np.ndarray) -> np.ndarray:
    """Delaunay triangles ``(t, 3)`` (CCW) whose centroid and edge midpoints are in the mask."""
    tri = Delaunay(points).simplices.astype(np.int64)
    p = points[tri]
    keep = _lookup(inside, p.mean(axis=1)).astype(bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        keep &= _lookup(inside_loose, 0.5 * (p[:, a] + p[:, b])).astype(bool)
    tri = tri[keep]
    flip = triangle_areas(points, tri) < 0
    tri[flip] = tri[flip][:, [0, 2, 1]]
    return tri


def triangle_adjacency(triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of triangles ``(a, b)`` (each ``(k,)``) that share an edge."""
    t = len(triangles)
    e = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    key = np.sort(e, axis=1)
    owner = np.tile(np.arange(t), 3)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    order = np.argsort(inv, kind="stable")
    same = inv[order][1:] == inv[order][:-1]
    return owner[order][1:][same], owner[order][:-1][same]


def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    g = coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n))
    return connected_components(g, directed=False)[1]


def _largest_piece(triangles: np.ndarray) -> np.ndarray:
    """Keep the largest edge-connected group of triangles."""
    labels = _components(len(triangles), *triangle_adjacency(triangles))
    if labels.max() == 0:
        return triangles
    return triangles[labels == np.argmax(np.bincount(labels))]


def _compact(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = np.unique(triangles)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[triangles]


def _smooth_interior(points: np.ndarray, fixed: np.ndarray, inside: np.ndarray, sweeps: int) -> np.ndarray:
    """Move free points toward the mean of their Delaunay neighbours (boundary fixed)."""
    pts = points.copy()
    for _ in range(sweeps):
        tri = Delaunay(pts).simplices
        e = np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]])
        e = np.concatenate([e, e[:, ::-1]])
        acc = np.zeros_like(pts)
        np.add.at(acc, e[:, 0], pts[e[:, 1]])
        deg = np.bincount(e[:, 0], minlength=len(pts)).astype(float)
        target = acc / np.maximum(deg, 1)[:, None]
        new = np.where(fixed[:, None], pts, 0.5 * pts + 0.5 * target)
        # A point whose move would leave the silhouette stays where it was.
        ok = _lookup(inside, new).astype(bool) | fixed
        pts[ok] = new[ok]
    return pts


def spacing_for(mask: np.ndarray, n_vertices: int) -> float:
    """Global spacing ``h`` (pixels) that gives about ``n_vertices`` vertices.

    A hexagonal lattice holds one point per ``√3/2 h²`` of area and the
    outline one per ``h`` of perimeter: solve
    ``area / (√3/2 h²) + perimeter / h = n`` for ``h``.
    """
    area = float(mask.sum())
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    perimeter = sum(cv2.arcLength(c, True) for c in contours)
    # With u = 1/h: (area / (√3/2)) u² + perimeter u − n = 0; take the positive root.
    a, b, c = area / (np.sqrt(3) / 2), perimeter, -float(n_vertices)
    u = (-b + np.sqrt(b * b - 4 * a * c)) / (2 * a)
    return 1.0 / u


def triangulate_mask(mask: np.ndarray, n_vertices: int = 800, min_angle: float = 15.0,
                     simplify: float = 0.75, jitter: float = 0.0, smooth_sweeps: int = 3,
                     seed: int = 0, cuts=()) -> tuple[np.ndarray, np.ndarray, float]:
    """Triangulate a silhouette.

    Parameters
    ----------
    mask : ndarray, shape (H, W), bool
    n_vertices : int
        Target vertex count (hundreds to a few thousand).  Thin parts are
        meshed finer than the global spacing, so the result can exceed it.
    min_angle : float
        Degrees; no triangle of the result has a smaller angle.
    simplify : float
        ``cv2.approxPolyDP`` tolerance in pixels.
    jitter : float
        Random offset of the interior lattice points, as a fraction of ``h``.

    Returns
    -------
    vertices : ndarray, shape (n, 2), float64, pixels
    triangles : ndarray, shape (t, 3), int64, counter-clockwise
    spacing : float, pixels
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        raise InputError("mask", "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    if n_vertices < 20:
        raise InputError("triangulate_mask", "n_vertices", "at least 20", n_vertices)
    args = (min_angle, simplify, jitter, smooth_sweeps, seed, tuple(cuts))
    vertices, tri, h = _triangulate_at(mask, spacing_for(mask, n_vertices), *args)
    # The lattice loses points near the outline and thin parts gain some, so
    # the count misses the target by 10-15 %; one rescaled pass fixes that.
    miss = len(vertices) / n_vertices
    if abs(miss - 1) > 0.05:
        vertices, tri, h = _triangulate_at(mask, h * np.sqrt(miss), *args)
    return vertices, tri, h


def _cut_points(cuts, spacing_at, h: float) -> np.ndarray:
    """Points along cut segments ``[(p, q), ...]`` at about half the local spacing, ends excluded."""
    out = []
    for p, q in cuts:
        p, q = np.asarray(p, float), np.asarray(q, float)
        L = float(np.linalg.norm(q - p))
        sp = 0.5 * min(float(spacing_at(0.5 * (p + q)[None])[0]), h)
        k = int(np.ceil(L / max(sp, 1e-9)))
        if k < 2:
            continue
        t = np.arange(1, k) / k
        out.append(p + t[:, None] * (q - p))
    return np.vstack(out) if out else np.zeros((0, 2))


def _seg_distance(points: np.ndarray, cuts) -> np.ndarray:
    """Distance ``(k,)`` from each point to the nearest cut segment (inf without cuts)."""
    d = np.full(len(points), np.inf)
    for p, q in cuts:
        p, q = np.asarray(p, float), np.asarray(q, float)
        e = q - p
        t = np.clip(((points - p) @ e) / max(float(e @ e), 1e-12), 0, 1)
        d = np.minimum(d, np.linalg.norm(points - (p + t[:, None] * e), axis=1))
    return d


def _triangulate_at(mask, h, min_angle, simplify, jitter, smooth_sweeps, seed, cuts=()):
    rng = np.random.default_rng(seed)
    m8 = mask.astype(np.uint8)
    # Half-width of the silhouette near each pixel: the distance transform's
    # maximum over a neighbourhood about h wide (the medial radius nearby).
    dist = cv2.distanceTransform(np.pad(m8, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    k = max(3, int(2 * round(h) + 1))
    radius = cv2.dilate(dist, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)))
    h_min = 2.0
    # Across a strip of width 2r, equilateral triangles have sides ≈ 2r·2/√3.
    def spacing_at(pts):
        return np.clip(2.3 * _lookup(radius, pts), h_min, h)

    boundary = []
    for c in _contours(mask, min_hole_area=4 * h * h):
        poly = cv2.approxPolyDP(c.astype(np.float32).reshape(-1, 1, 2), simplify, True)[:, 0, :]
        if len(poly) < 3:
            poly = c
        boundary.append(_resample_closed(poly.astype(np.float64), spacing_at))
    boundary = np.vstack(boundary)
    interior = _hex_grid(mask, h, rng, jitter)
    if len(interior):
        d, _ = cKDTree(boundary).query(interior)
        interior = interior[d > 0.6 * spacing_at(interior)]
    # Cut lines (seams between pieces of a layered mesh): fixed points at half
    # the spacing and no lattice point closer than that, so Delaunay keeps
    # the short edges between consecutive cut points and the seam is straight.
    cut_pts = _cut_points(cuts, spacing_at, h)
    if len(cut_pts):
        cut_pts = cut_pts[cKDTree(boundary).query(cut_pts)[0] > 0.4 * spacing_at(cut_pts)]
        cut_pts = cut_pts[_lookup(mask.astype(np.uint8), cut_pts).astype(bool)]
    if len(cut_pts) and len(interior):
        interior = interior[_seg_distance(interior, cuts) > 0.6 * spacing_at(interior)]
    points = np.vstack([boundary, cut_pts, interior])
    fixed = np.zeros(len(points), dtype=bool)
    fixed[: len(boundary) + len(cut_pts)] = True
    points = _smooth_interior(points, fixed, mask, smooth_sweeps)
    # Triangles may overhang the pixel silhouette by the polygon tolerance,
    # so edge midpoints are tested against a slightly grown mask.
    loose = cv2.dilate(m8, np.ones((3, 3), np.uint8)).astype(bool)

    for _ in range(8):
        tri = _triangulate(points, mask, loose)
        ang = triangle_angles(points, tri)
        bad = np.flatnonzero(ang.min(axis=1) < min_angle)
        if bad.size == 0:
            break
        # In a sliver the corner with the largest angle sits nearly on the
        # opposite edge; removing that point removes the sliver.
        corner = tri[bad, np.argmax(ang[bad], axis=1)]
        drop = np.zeros(len(points), dtype=bool)
        drop[corner] = True
        points, fixed = points[~drop], fixed[~drop]
    tri = _triangulate(points, mask, loose)
    tri = tri[triangle_angles(points, tri).min(axis=1) >= min_angle]
    tri = _largest_piece(tri)
    vertices, tri = _compact(points, tri)
    return vertices, tri, h


def limb_radii(mask: np.ndarray, keypoints: np.ndarray, scale: float = 1.3, span=(0.5, 0.8)) -> np.ndarray:
    """A capsule radius per limb ``(8,)``, pixels: ``scale`` × the limb's half-width.

    The half-width is the median of the mask's distance transform at
    ``span`` fractions along the bone: the outer part of a limb, which is
    usually free of the body, unlike the root where a drawn arm may lie over
    the chest.
    """
    dist = cv2.distanceTransform(np.pad(np.asarray(mask, np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    kp = np.asarray(keypoints, dtype=np.float64)
    lam = np.linspace(*span, 5)[:, None]
    out = []
    for a, b in LIMBS.values():
        pts = kp[a] + lam * (kp[b] - kp[a])
        out.append(scale * float(np.median(_lookup(dist, pts))))
    return np.array(out)


def label_parts(vertices: np.ndarray, triangles: np.ndarray, keypoints: np.ndarray,
                limb_radius: np.ndarray | None = None) -> np.ndarray:
    """Part id ``(t,)`` per triangle: the part of the bone nearest its centroid.

    keypoints : ``(17, 2)`` rest key points, pixels.
    limb_radius : optional ``(8,)`` capsule radii (:func:`limb_radii`): a
        limb bone only claims triangles within its radius, so a drawn arm
        lying over the chest does not take the chest's texture with it.
    """
    c = vertices[triangles].mean(axis=1)  # (t, 2)
    a = keypoints[[p for p, _, _ in PART_BONES]]  # (B, 2)
    b = keypoints[[q for _, q, _ in PART_BONES]]
    d = b - a
    t = np.einsum("tbk,bk->tb", c[:, None, :] - a[None], d) / np.maximum((d * d).sum(axis=1), 1e-12)
    closest = a[None] + np.clip(t, 0, 1)[..., None] * d[None]
    dist = np.linalg.norm(c[:, None, :] - closest, axis=2)
    part_of_bone = np.array([part for _, _, part in PART_BONES])
    if limb_radius is not None:
        limb = part_of_bone >= 2
        radius = np.asarray(limb_radius, dtype=np.float64)[np.maximum(part_of_bone - 2, 0)]
        dist = np.where(limb[None] & (dist > radius[None]), np.inf, dist)
    return part_of_bone[np.argmin(dist, axis=1)]


def _clean_pieces(triangles: np.ndarray, pieces: np.ndarray, vertices: np.ndarray,
                  keypoints: np.ndarray, names=PIECES, piece_keypoints=None) -> np.ndarray:
    """Make every piece one edge-connected group of triangles.

    Nearest-bone labels can leave islands (a few arm-labelled triangles on the
    torso's edge); an island of a split mesh would have no handle.  Each
    piece keeps the group nearest its own key points; other groups join the
    piece most of their neighbours belong to.
    """
    if piece_keypoints is None:
        piece_keypoints = [PIECE_KEYPOINTS[n] for n in names]
    pieces = pieces.copy()
    a, b = triangle_adjacency(triangles)
    centroids = vertices[triangles].mean(axis=1)
    for _ in range(len(triangles)):
        same = pieces[a] == pieces[b]
        labels = _components(len(triangles), a[same], b[same])
        stray = np.zeros(len(triangles), dtype=bool)
        for pc in range(len(names)):
            groups = np.unique(labels[pieces == pc])
            if len(groups) <= 1:
                continue
            kp = keypoints[list(piece_keypoints[pc])]
            dist = [np.linalg.norm(centroids[labels == g][:, None] - kp[None], axis=2).min() for g in groups]
            keep = groups[int(np.argmin(dist))]
            stray |= (pieces == pc) & (labels != keep)
        if not stray.any():
            break
        # Give each stray triangle the commonest piece among its non-stray neighbours; repeat
        # until every island has been absorbed.
        votes = np.zeros((len(triangles), len(names)))
        for x, y in ((a, b), (b, a)):
            ok = stray[x] & ~stray[y]
            np.add.at(votes, (x[ok], pieces[y[ok]]), 1.0)
        has = stray & (votes.sum(1) > 0)
        pieces[has] = np.argmax(votes[has], axis=1)
    return pieces


def split_pieces(mesh: Mesh, keypoints: np.ndarray) -> Mesh:
    """Cut the limbs loose: duplicate every vertex shared by two pieces.

    Returns a new :class:`Mesh` whose triangles keep their parts; ``pieces``
    says which of :data:`PIECES` each belongs to, and a vertex belongs to one
    piece only.  The duplicates sit at the same rest position (the same
    texture coordinate), so the rest mesh looks the same; deformed, an arm
    can swing over the torso instead of folding the armpit.  Each piece is
    one connected group of triangles (see :func:`_clean_pieces`).
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    pieces = _clean_pieces(mesh.triangles, PART_PIECE[mesh.parts], mesh.vertices, kp)
    # One new vertex per (old vertex, piece) pair in use.
    pairs = np.stack([mesh.triangles.ravel(), np.repeat(pieces, 3)], axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    triangles = inv.ravel().reshape(-1, 3).astype(np.int64)
    return Mesh(vertices=mesh.vertices[uniq[:, 0]].copy(), triangles=triangles, parts=mesh.parts.copy(),
                spacing=mesh.spacing, pieces=pieces)


