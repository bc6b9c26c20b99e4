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
:data:`PIECES` (body, each arm, each leg) by duplicating the seam vertices;
each piece is then pinned by its own key points (:data:`PIECE_KEYPOINTS`,
the shoulder or hip on both sides of a seam) and a limb can move over the
body, which a renderer must then draw in depth order; its seams follow the
triangles, so they are jagged, and a bent elbow or knee still folds.

``split="layered"`` (:func:`layer_pieces`, the default of the ``reshape``
stage) fixes both: limb triangles are labelled by capsules of the limb's own
width (a drawn arm over the chest does not take the chest with it), each of
the ten segments (body, eight limb segments, head) is its own piece, cut
along a straight segment across each joint (:func:`joint_cuts`; the cut and a
half-elliptic collar arc are inserted into the triangulation so the seams are
smooth), each child carries a joint cap (a copy of the parent's triangles
inside the arc) that covers the wedge a bending joint opens, and the body
gets an inpainted underlay where a limb lay over it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy.spatial import Delaunay, cKDTree

from nnsf.errors import InputError
from nnsf.skeleton import JOINT_INDEX, LIMBS

#: Part names; ids index this tuple.  Limb parts follow ``nnsf.skeleton.LIMBS``
#: order, so part ``2 + i`` is limb ``i``.
PARTS: tuple[str, ...] = ("torso", "head") + tuple(LIMBS)
PART_INDEX = {name: i for i, name in enumerate(PARTS)}


def _bones_of_parts() -> list[tuple[int, int, int]]:
    """(parent key point, child key point, part id) for every bone used to label parts."""
    J = JOINT_INDEX
    torso = [("pelvis", "spine"), ("spine", "thorax"), ("pelvis", "r_hip"), ("pelvis", "l_hip"),
             ("thorax", "l_shoulder"), ("thorax", "r_shoulder")]
    head = [("thorax", "neck"), ("neck", "head_top")]
    out = [(J[a], J[b], PART_INDEX["torso"]) for a, b in torso]
    out += [(J[a], J[b], PART_INDEX["head"]) for a, b in head]
    out += [(a, b, PART_INDEX[name]) for name, (a, b) in LIMBS.items()]
    return out


PART_BONES = _bones_of_parts()

#: Pieces of a split mesh: the body (torso and head) and each whole limb.
PIECES: tuple[str, ...] = ("body", "l_arm", "r_arm", "l_leg", "r_leg")
#: Piece of each part, ``(10,)``, indexed by part id.
PART_PIECE = np.array([0, 0] + [PIECES.index(f"{name[0]}_{'arm' if 'arm' in name else 'leg'}")
                                for name in LIMBS], dtype=np.int64)
#: Key points that pin each piece: the body holds every point of the torso
#: and head, including the shoulders and hips where the limbs attach.
PIECE_KEYPOINTS: dict[str, tuple[int, ...]] = {
    "body": tuple(JOINT_INDEX[j] for j in ("pelvis", "r_hip", "l_hip", "spine", "thorax", "neck",
                                           "head_top", "l_shoulder", "r_shoulder")),
    "l_arm": tuple(JOINT_INDEX[j] for j in ("l_shoulder", "l_elbow", "l_wrist")),
    "r_arm": tuple(JOINT_INDEX[j] for j in ("r_shoulder", "r_elbow", "r_wrist")),
    "l_leg": tuple(JOINT_INDEX[j] for j in ("l_hip", "l_knee", "l_ankle")),
    "r_leg": tuple(JOINT_INDEX[j] for j in ("r_hip", "r_knee", "r_ankle")),
}

#: Pieces of a layered mesh (:func:`layer_pieces`): the body (torso), every
#: limb segment and the head, each on its own, so no joint can fold.
SEGMENTS: tuple[str, ...] = ("body",) + tuple(LIMBS) + ("head",)
#: Segment piece of each part, ``(10,)``, and the part of each segment, ``(10,)``.
PART_SEGMENT = np.array([0, len(SEGMENTS) - 1] + list(range(1, 1 + len(LIMBS))), dtype=np.int64)
SEGMENT_PART = np.array([0] + list(range(2, 2 + len(LIMBS))) + [1], dtype=np.int64)
SEGMENT_KEYPOINTS: tuple[tuple[int, ...], ...] = (
    (tuple(JOINT_INDEX[j] for j in ("pelvis", "r_hip", "l_hip", "spine", "thorax", "neck", "l_shoulder",
                                    "r_shoulder")),)
    + tuple((int(a), int(b)) for a, b in LIMBS.values())
    + ((JOINT_INDEX["neck"], JOINT_INDEX["head_top"]),))
#: Joints where a child piece overlaps its parent (:func:`layer_pieces`):
#: (joint, parent piece, child piece, collar scale), indices into ``JOINTS`` /
#: ``SEGMENTS``.  The scale is the cap's depth into the parent as a fraction
#: of half the cut: 0.6 covers the wedge of bends up to ~40° while a strongly
#: bent joint's cap pokes out less (at 1.0 the caps showed as grey bumps in a
#: run); the neck's is smaller: a drawn head is much wider than its neck.
COLLARS: tuple[tuple[int, int, int, float], ...] = tuple(
    (JOINT_INDEX[j], SEGMENTS.index(parent), SEGMENTS.index(child), scale) for j, parent, child, scale in (
        ("l_shoulder", "body", "l_upper_arm", 0.6), ("l_elbow", "l_upper_arm", "l_forearm", 0.6),
        ("r_shoulder", "body", "r_upper_arm", 0.6), ("r_elbow", "r_upper_arm", "r_forearm", 0.6),
        ("l_hip", "body", "l_thigh", 0.6), ("l_knee", "l_thigh", "l_shin", 0.6),
        ("r_hip", "body", "r_thigh", 0.6), ("r_knee", "r_thigh", "r_shin", 0.6),
        ("neck", "body", "head", 0.4)))
#: Pieces of a whole-limb mesh (``split="limbs"``, :func:`layer_pieces` with
#: ``whole_limbs=True``): the body, each whole limb (upper and lower segment
#: one deformable piece, bending at the elbow or knee) and the head.  Cut and
#: capped like the layered mesh at the shoulders, hips and neck only.
LIMB_PIECES: tuple[str, ...] = ("body", "l_arm", "r_arm", "l_leg", "r_leg", "head")
#: Whole-limb piece of each segment piece, ``(10,)``, indexed like :data:`SEGMENTS`.
SEGMENT_LIMB_PIECE = np.array([0] + [LIMB_PIECES.index(f"{n[0]}_{'arm' if 'arm' in n else 'leg'}")
                                     for n in LIMBS] + [len(LIMB_PIECES) - 1], dtype=np.int64)
LIMB_PIECE_KEYPOINTS: tuple[tuple[int, ...], ...] = (
    (SEGMENT_KEYPOINTS[0],) + tuple(PIECE_KEYPOINTS[n] for n in LIMB_PIECES[1:-1]) + (SEGMENT_KEYPOINTS[-1],))
#: Mesh kinds :func:`build_mesh` accepts (``True`` / ``False`` are aliases of split / connected).
MESH_KINDS = ("connected", "split", "layered", "limbs")
#: The torso polygon (key points, in order) under which limb triangles get an underlay.
TORSO_POLYGON = tuple(JOINT_INDEX[j] for j in ("l_hip", "pelvis", "r_hip", "r_shoulder", "thorax", "l_shoulder"))


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

    def boundary_vertices(self) -> np.ndarray:
        """Indices of vertices on the outline, sorted."""
        return np.unique(self.boundary_edges())


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


def build_mesh(mask: np.ndarray, keypoints: np.ndarray, n_vertices: int = 800, split=False,
               collar: float = 1.0, texture=None, extra_limbs=(), **kwargs) -> Mesh:
    """Triangulate ``mask`` (:func:`triangulate_mask`) and label parts (:func:`label_parts`).

    ``split``: ``False`` / ``"connected"`` (one connected mesh), ``True`` /
    ``"split"`` (limbs cut loose along nearest-bone seams, :func:`split_pieces`),
    ``"layered"`` (every segment its own piece with overlapping collars and a
    body underlay, :func:`layer_pieces`) or ``"limbs"`` (the same, but each
    whole limb one deformable piece: cut only at the shoulders, hips and neck).

    ``extra_limbs``: arms beyond the skeleton's two (a layered or whole-limb
    mesh gives each a piece that turns with the driven arm of its side,
    :func:`nnsf.reshape.pieces.follower_regions`).

    ``texture`` ``(H, W, 3|4)``: the drawing.  With it, the limb capsules of
    the layered and limbs meshes give back to the body the triangles whose
    ink-bounded region of the drawing is the body's (:func:`drawn_regions`),
    so e.g. the chest next to an arm drawn behind it stays with the chest.
    """
    if split not in (False, True) + MESH_KINDS:
        raise InputError("build_mesh", "split", "False, True, 'connected', 'split', 'layered' or 'limbs'", split)
    kp = np.asarray(keypoints, dtype=float)
    if split in ("layered", "limbs"):
        from nnsf.reshape.pieces import build_pieced_mesh

        margin = None
        if texture is not None:
            # Tabs keep the paper margin and 0.4 % of the drawing's height (1-2 px) inside the
            # parent's outline.
            from nnsf.reshape.render import outline_style

            style = outline_style(texture, mask)
            ys = np.flatnonzero(np.asarray(mask, bool).any(axis=1))
            margin = (style[2] if style is not None else 0.0) + float(np.clip(0.004 * np.ptp(ys), 1.0, 2.0))
        return build_pieced_mesh(mask, kp, n_vertices=n_vertices, whole_limbs=split == "limbs",
                                 tab_margin=margin, texture=texture, extra_limbs=extra_limbs, **kwargs)
    layered = split in ("layered", "limbs")
    cuts = joint_cuts(mask, kp) if layered else []
    if split == "limbs":
        cuts = [c for c in cuts if c["parent"] == 0]
    vertices, triangles, h = triangulate_mask(mask, n_vertices=n_vertices, cuts=cut_segments(cuts),
                                              **kwargs)
    parts = label_parts(vertices, triangles, kp)
    region_body = body_rim = None
    if layered:
        capsule = label_parts(vertices, triangles, kp, limb_radii(mask, kp) + 0.5 * h)
        # A limb the capsules leave without triangles (thin, on a coarse mesh)
        # keeps its nearest-bone triangles.
        empty = [p for p in range(2, len(PARTS)) if not (capsule == p).any()]
        parts = np.where(np.isin(parts, empty), parts, capsule)
        if texture is not None:
            region_body = body_region_triangles(vertices, triangles, kp, texture, mask)
            body_rim = ink_rim_triangles(vertices, triangles, region_body, kp, texture, mask)
            parts = np.where(region_body & (parts >= 2), label_parts(vertices, triangles, kp, np.zeros(8) - 1),
                             parts)
    mesh = Mesh(vertices=vertices, triangles=triangles, parts=parts, spacing=h)
    if layered:
        return layer_pieces(mesh, kp, mask, collar=collar, cuts=cuts, whole_limbs=split == "limbs",
                            body_triangles=region_body, body_rim=body_rim)
    return split_pieces(mesh, kp) if split in (True, "split") else mesh


def drawn_regions(texture: np.ndarray, mask: np.ndarray, ink: float = 0.55, min_area: float = 0.002) -> np.ndarray:
    """Ink-bounded regions of a drawing: a label ``(H, W)`` int, −1 outside ``mask``.

    Ink is a pixel darker than ``ink`` × the median luminance of the mask;
    the regions are the connected components (4-neighbour) of the rest of
    the mask with at least ``min_area`` × the mask's area; every other mask
    pixel (ink, specks) takes the label of the nearest region pixel, so a
    line between two regions is split down its middle.
    """
    from scipy.ndimage import distance_transform_edt

    m = np.asarray(mask, dtype=bool)
    out = np.full(m.shape, -1, np.int64)
    if not m.any():
        return out
    fill = m & ~ink_pixels(texture, m, ink)
    n, lab = cv2.connectedComponents(fill.astype(np.uint8), connectivity=4)
    area = np.bincount(lab.ravel(), minlength=n)
    big = np.flatnonzero(area >= max(min_area * m.sum(), 1))
    big = big[big > 0]
    if len(big) == 0:
        out[m] = 0
        return out
    keep = np.isin(lab, big)
    _, (iy, ix) = distance_transform_edt(~keep, return_indices=True)
    out[m] = lab[iy[m], ix[m]]
    return out


def body_region_triangles(vertices, triangles, keypoints, texture, mask, pixels: bool = False) -> np.ndarray:
    """Triangles ``(t,)`` that lie in a region of the drawing (:func:`drawn_regions`) that is the body's only.

    A region is the body's when it holds a point of the spine or neck
    (pelvis–spine–thorax–neck, sampled), and a limb's when it holds a point of
    the limb's outer bone (upper segment λ ∈ [0.6, 0.95], lower segment
    λ ∈ [0.1, 0.9]).  A region that is both (a limb not separated from the
    body by a line, as in many sketches) says nothing and is not returned.
    ``pixels``: return the pixels ``(H, W)`` of those regions instead.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    lab = drawn_regions(texture, mask)
    J = JOINT_INDEX

    def regions_along(a, b, lo, hi):
        lam = np.linspace(lo, hi, 9)[:, None]
        pts = kp[a] + lam * (kp[b] - kp[a])
        r = _lookup(lab, pts)
        return set(r[_lookup(np.asarray(mask, np.uint8), pts) > 0].tolist()) - {-1}

    body = set()
    for a, b in (("pelvis", "spine"), ("spine", "thorax"), ("thorax", "neck")):
        body |= regions_along(J[a], J[b], 0.0, 1.0)
    limb = set()
    for name, (a, b) in LIMBS.items():
        upper = "upper" in name or "thigh" in name
        limb |= regions_along(a, b, *((0.6, 0.95) if upper else (0.1, 0.9)))
    only_body = np.array(sorted(body - limb), dtype=np.int64)
    if pixels:
        return np.isin(lab, only_body)
    c = np.asarray(vertices)[np.asarray(triangles)].mean(axis=1)
    return np.isin(_lookup(lab, c), only_body)


def ink_pixels(texture, mask, ink: float = 0.55) -> np.ndarray:
    """Ink of a drawing ``(H, W)`` bool: mask pixels darker than ``ink`` × the mask's median luminance."""
    m = np.asarray(mask, dtype=bool)
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    return m & (lum < ink * np.median(lum[m])) if m.any() else m.copy()


def body_line(keypoints, texture, mask, ink: float = 0.55) -> np.ndarray:
    """The body's drawing with its own outline, ``(H, W)`` bool.

    The body's drawn regions (:func:`body_region_triangles`) plus the ink
    within one line width of them; the width is twice the ink's typical
    (90th percentile) medial distance, plus a pixel.  :func:`drawn_regions`
    splits a line between the body and a limb down its middle, so without
    this the limb would take the outer half of the body's outline.
    """
    m = np.asarray(mask, dtype=bool)
    body = body_region_triangles(None, None, keypoints, texture, m, pixels=True)
    dark = ink_pixels(texture, m, ink)
    if not dark.any() or not body.any():
        return body
    dist = cv2.distanceTransform(np.pad(dark.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    width = 2.0 * float(np.percentile(dist[dark], 90)) + 1.0
    near = cv2.distanceTransform((~body).astype(np.uint8), cv2.DIST_L2, 3) <= width
    return body | (dark & near)


def ink_rim_triangles(vertices, triangles, body_triangles, keypoints, texture, mask) -> np.ndarray:
    """Triangles ``(t,)`` not in ``body_triangles`` that cover a pixel of the body's outline (:func:`body_line`).

    :func:`layer_pieces` gives the body a copy of those a limb owns, textured
    with :func:`body_line` only (``Mesh.layer`` 2), so a limb swung away
    leaves the body outlined instead of notched.
    """
    tri = np.asarray(triangles)
    bt = np.asarray(body_triangles, dtype=bool)
    line = body_line(keypoints, texture, mask)
    owner = np.full(line.shape, -1, np.int32)
    V = np.rint(np.asarray(vertices)).astype(np.int32)
    for k in np.flatnonzero(~bt):
        cv2.fillPoly(owner, [V[tri[k]]], int(k))
    out = np.zeros(len(tri), dtype=bool)
    out[owner[line & (owner >= 0)]] = True  # owners are non-body triangles only
    return out


def _limb_half_width(mask: np.ndarray, keypoints: np.ndarray, a: int, b: int) -> float:
    """Half-width (pixels) of the limb a→b: the mask's distance transform at ¼ and ½ along it."""
    dist = cv2.distanceTransform(np.pad(mask.astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    pts = keypoints[a] + np.array([[0.25], [0.5]]) * (keypoints[b] - keypoints[a])
    return float(np.median(_lookup(dist, pts)))


def joint_cuts(mask: np.ndarray, keypoints: np.ndarray, reach: float = 1.25) -> list[dict]:
    """Straight seams between the pieces of a layered mesh, one per joint of :data:`COLLARS`.

    The cut passes through the joint, across the limb: perpendicular to the
    child bone at a shoulder or hip, perpendicular to the mean direction of
    the two bones at an elbow or knee.  It runs each way until it leaves the
    mask, but at most ``reach`` × the child's half-width (so at a shoulder
    whose arm hangs beside the torso it does not cut into the torso).

    Returns dicts with ``joint``, ``parent``, ``child`` (indices), ``p``,
    ``q`` (segment ends, pixels), ``normal`` (unit, pointing to the child)
    and ``half_width`` (pixels).
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    out = []
    for joint, parent, child, scale in COLLARS:
        ja, jb = SEGMENT_KEYPOINTS[child]
        uc = kp[jb] - kp[ja]
        Lc = float(np.linalg.norm(uc))
        if Lc < 1e-6:
            continue
        uc = uc / Lc
        n = uc
        if parent != 0:
            pa, pb = SEGMENT_KEYPOINTS[parent]
            up = kp[pb] - kp[pa]
            if np.linalg.norm(up) > 1e-6:
                s_ = up / np.linalg.norm(up) + uc
                if np.linalg.norm(s_) > 1e-3:
                    n = s_ / np.linalg.norm(s_)
        d = np.array([-n[1], n[0]])
        hw = _limb_half_width(m, kp, ja, jb)
        cap = reach * max(hw, 1.0)
        steps = np.arange(0.0, cap + 0.25, 0.25)
        ends = []
        for sgn in (1.0, -1.0):
            inside = points_in(m, kp[joint] + sgn * steps[:, None] * d)
            ends.append(steps[np.argmin(inside)] if not inside.all() else steps[-1])
        p, q = kp[joint] + ends[0] * d, kp[joint] - ends[1] * d
        # The collar: a half-disc on the parent's side with the cut as its diameter.
        mid, R = 0.5 * (p + q), 0.5 * float(np.linalg.norm(p - q))
        dh = (p - mid) / max(R, 1e-12)
        theta = np.linspace(0.0, np.pi, 13)
        # The arc bounding the collar: a half-ellipse, the cut as its long axis,
        # reaching ``scale`` × R into the parent.
        arc = mid + R * np.cos(theta)[:, None] * dh - scale * R * np.sin(theta)[:, None] * n
        out.append({"joint": joint, "parent": parent, "child": child, "p": p, "q": q, "normal": n,
                    "half_width": hw, "centre": mid, "radius": R, "arc": arc, "collar": scale})
    return out


def cut_segments(cuts: list[dict], arcs: bool = True) -> list[tuple[np.ndarray, np.ndarray]]:
    """The straight segments to insert into a triangulation: each cut, and its collar arc."""
    segs = [(c["p"], c["q"]) for c in cuts]
    if arcs:
        segs += [(c["arc"][i], c["arc"][i + 1]) for c in cuts for i in range(len(c["arc"]) - 1)]
    return segs


def points_in(mask: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Whether points ``(k, 2)`` fall on foreground pixels of ``mask`` (nearest pixel)."""
    return _lookup(mask.astype(np.uint8), np.atleast_2d(pts)).astype(bool)


def _relabel_at_cuts(triangles, vertices, pieces, cuts) -> np.ndarray:
    """Give triangles near each cut the piece of their side of it (parent or child)."""
    pieces = pieces.copy()
    c = vertices[triangles].mean(axis=1)
    for cut in cuts:
        p, q, n = cut["p"], cut["q"], cut["normal"]
        d = q - p
        L = float(np.linalg.norm(d))
        if L < 1e-9:
            continue
        d = d / L
        r = c - p
        along = r @ d
        across = r @ n
        zone = ((along >= 0) & (along <= L) & (np.abs(across) <= max(cut["radius"], 1.0))
                & np.isin(pieces, (cut["parent"], cut["child"])))
        pieces[zone & (across > 0)] = cut["child"]
        pieces[zone & (across <= 0)] = cut["parent"]
    return pieces


def layer_pieces(mesh: Mesh, keypoints: np.ndarray, mask: np.ndarray, collar: float = 1.0,
                 cuts=None, underlay_shrink: float = 0.85, whole_limbs: bool = False,
                 body_triangles=None, body_rim=None) -> Mesh:
    """Cut a connected mesh into :data:`SEGMENTS` that overlap, so limbs neither fold nor tear.

    * every limb segment (upper arm, forearm, thigh, shin) and the body
      (torso and head) become separate pieces, each pinned by its own key
      points: a bent elbow or a limb swung over the body cannot fold a
      triangle across a joint;
    * **straight seams**: each joint of :data:`COLLARS` is cut along a
      straight segment across the limb (:func:`joint_cuts`; its points were
      inserted into the triangulation by :func:`build_mesh`), and triangles
      near it take the piece of their side;
    * **collars**: the child piece also takes a copy of the parent's
      triangles in the half-disc (radius ``collar`` × half the cut's length)
      on the parent's side of the cut, bounded by an inserted arc (same
      texture coordinates): a round joint cap that covers the wedge opening
      between the two pieces when the joint bends.  ``Mesh.collar`` names
      each collar's parent part; a renderer draws it just before that part,
      so it fills the wedge but never covers the parent's drawing;
    * **underlay**: limb triangles lying over the torso (inside both the
      key-point polygon :data:`TORSO_POLYGON` shrunk by ``underlay_shrink``
      and the convex hull of the torso's own triangles) are copied into the
      body with ``layer`` 1; a
      renderer textures them from an inpainted drawing (the body as it would
      look without the limb), so a limb drawn across the chest leaves no
      hole when it moves away;
    * **rim**: limb triangles covering the body's own outline
      (``body_rim``, from :func:`ink_rim_triangles`) are copied into the
      body with ``layer`` 2 (textured with :func:`body_line` only, drawn
      before every part), so a limb swung away leaves the body outlined.
      Shoulder and hip collars leave out ``body_triangles``: a cap cut from
      the torso's own drawing would carry torso fill out with the limb.

    Vertices are then duplicated per piece as in :func:`split_pieces`.

    ``whole_limbs``: merge each limb's two segments into one piece
    (:data:`LIMB_PIECES`), which bends at the elbow or knee; give it the
    cuts of the shoulders, hips and neck only.  ``body_triangles`` ``(t,)``:
    triangles that must stay with the body even next to a cut (from
    :func:`body_region_triangles`).
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    tri0, V0 = mesh.triangles, mesh.vertices
    if cuts is None:
        cuts = joint_cuts(mask, kp)
        if whole_limbs:
            cuts = [c for c in cuts if c["parent"] == 0]
    seg = _relabel_at_cuts(tri0, V0, PART_SEGMENT[mesh.parts], cuts)
    if body_triangles is not None:
        # The drawing says these belong to the body (or head), whatever the cut zone says.
        bt = np.asarray(body_triangles, dtype=bool)
        seg = np.where(bt & (seg != 0) & (seg != len(SEGMENTS) - 1), PART_SEGMENT[mesh.parts], seg)
    seg = _clean_pieces(tri0, seg, V0, kp, SEGMENTS, SEGMENT_KEYPOINTS)
    # Parts follow the pieces (a relabelled triangle is drawn with its piece).
    parts0 = SEGMENT_PART[seg]
    a, b = triangle_adjacency(tri0)
    centroids = V0[tri0].mean(axis=1)
    extra_tri, extra_piece, extra_part, extra_layer, collar_parent = [], [], [], [], []
    for cut in cuts:
        parent, child = cut["parent"], cut["child"]
        # Parent triangles in the half-disc on the parent's side of the cut
        # (its boundary arc was inserted into the triangulation: a smooth edge).
        R = cut["radius"]
        rel = centroids - cut["centre"]
        dh = (cut["p"] - cut["centre"]) / max(R, 1e-12)
        u, v = rel @ dh, -(rel @ cut["normal"])
        depth_ = collar * cut.get("collar", 1.0) * R
        near = (seg == parent) & (v >= 0) & ((u / max(R, 1e-12)) ** 2 + (v / max(depth_, 1e-12)) ** 2 < 1)
        if body_triangles is not None and parent == 0 and child != len(SEGMENTS) - 1:
            # Where the drawing outlines the limb apart from the body, a cap
            # cut from the body's drawing would carry torso fill and ink out
            # with the limb (loose fragments beside a raised arm): the limb's
            # own drawn end is its cap.
            near &= ~np.asarray(body_triangles, dtype=bool)
        if not near.any():
            continue
        # Keep only collar triangles connected (through the collar) to the child.
        use = near | (seg == child)
        ok = use[a] & use[b]
        labels = _components(len(tri0), a[ok], b[ok])
        child_groups = np.unique(labels[seg == child])
        near &= np.isin(labels, child_groups)
        idx = np.flatnonzero(near)
        extra_tri.append(tri0[idx])
        extra_piece.append(np.full(len(idx), child))
        extra_part.append(np.full(len(idx), SEGMENT_PART[child]))
        collar_parent.append(int(SEGMENT_PART[parent]))
        extra_layer.append(np.zeros(len(idx), np.int64))
    # The torso polygon, shrunk toward its centre: drawn shoulders and hips sit
    # on the body's outline, and an underlay must not stick out of the body.
    # The underlay region: the convex hull of the torso's own triangles (the
    # chest as drawn, where a limb lies over it), cut to the key-point torso
    # polygon shrunk toward its centre, so the underlay never sticks out of
    # the body when the limb moves away.
    n_collars = len(extra_tri)
    poly = kp[list(TORSO_POLYGON)]
    poly = (poly.mean(0) + underlay_shrink * (poly - poly.mean(0))).astype(np.float32)
    hull = cv2.convexHull(poly)
    torso_pts = V0[np.unique(tri0[(seg == 0) & (mesh.parts == PART_INDEX["torso"])])].astype(np.float32)
    hull2 = cv2.convexHull(torso_pts) if len(torso_pts) >= 3 else hull
    inside = np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0
                       and cv2.pointPolygonTest(hull2, (float(x), float(y)), False) >= 0 for x, y in centroids])
    # Not next to the outline: there the limb is the body's edge at rest, and
    # an underlay would show as an inkless bump once the limb moves away.
    edge = cv2.distanceTransform(np.pad(mask.astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    inside &= _lookup(edge, centroids) > 2.0 * mesh.spacing
    if body_rim is not None:
        # The body's outline where it meets a limb (:func:`ink_rim_triangles`)
        # belongs to both: the limb keeps it, the body gets a copy, so a limb
        # swung away leaves the body's silhouette outlined, not notched.
        rim = np.asarray(body_rim, dtype=bool) & (seg != 0) & (seg != len(SEGMENTS) - 1)
        if rim.any():
            use = rim | (seg == 0)
            ok = use[a] & use[b]
            labels = _components(len(tri0), a[ok], b[ok])
            rim &= np.isin(labels, np.unique(labels[seg == 0]))
            idx = np.flatnonzero(rim)
            extra_tri.append(tri0[idx])
            extra_piece.append(np.zeros(len(idx), np.int64))
            extra_part.append(np.full(len(idx), PART_INDEX["torso"]))
            extra_layer.append(np.full(len(idx), 2, np.int64))
    under = inside & (seg != 0)
    if under.any():
        # Keep underlay triangles connected to the body's own triangles.
        use = under | (seg == 0)
        ok = use[a] & use[b]
        labels = _components(len(tri0), a[ok], b[ok])
        body_groups = np.unique(labels[seg == 0])
        under &= np.isin(labels, body_groups)
        idx = np.flatnonzero(under)
        extra_tri.append(tri0[idx])
        extra_piece.append(np.zeros(len(idx), np.int64))
        extra_part.append(np.full(len(idx), PART_INDEX["torso"]))
        extra_layer.append(np.ones(len(idx), np.int64))
    tris = np.concatenate([tri0] + extra_tri)
    pieces = np.concatenate([seg] + extra_piece).astype(np.int64)
    parts = np.concatenate([parts0] + extra_part).astype(np.int64)
    layer = np.concatenate([np.zeros(len(tri0), np.int64)] + extra_layer)
    is_collar = np.concatenate([np.full(len(tri0), -1, np.int64)] + [
        np.full(len(e), collar_parent[k] if k < n_collars else -1, np.int64) for k, e in enumerate(extra_tri)])
    names, piece_kp = SEGMENTS, SEGMENT_KEYPOINTS
    if whole_limbs:
        pieces = SEGMENT_LIMB_PIECE[pieces]
        names, piece_kp = LIMB_PIECES, LIMB_PIECE_KEYPOINTS
    pairs = np.stack([tris.ravel(), np.repeat(pieces, 3)], axis=1)
    uniq, inv = np.unique(pairs, axis=0, return_inverse=True)
    return Mesh(vertices=V0[uniq[:, 0]].copy(), triangles=inv.ravel().reshape(-1, 3).astype(np.int64),
                parts=parts, spacing=mesh.spacing, pieces=pieces, piece_names=names,
                piece_keypoints=piece_kp, layer=layer, collar=is_collar)
