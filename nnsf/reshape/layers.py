"""Layering a mesh: straight cuts at the joints, joint caps, and the mesh kinds (:func:`build_mesh`).

:func:`build_mesh` makes a character's mesh of any kind (:data:`MESH_KINDS`):
connected, split into pieces, pieced (the paper-puppet mesh of
:mod:`nnsf.reshape.pieces`), or **layered** (:func:`layer_pieces`, the
default of the ``reshape`` stage): limb triangles are labelled by capsules of
the limb's own width, each of the ten segments is its own piece, cut along a
straight segment across each joint (:func:`joint_cuts`; the cut and a
half-elliptic collar arc are inserted into the triangulation so the seams
are smooth), each child carries a joint cap (a copy of the parent's
triangles inside the arc) that covers the wedge a bending joint opens, and
the body gets an inpainted underlay where a limb lay over it (docs/method.md §11).
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.errors import InputError
from nnsf.reshape.mesh import Mesh, _clean_pieces, _components, _lookup, label_parts, limb_radii, split_pieces, triangle_adjacency, triangulate_mask
from nnsf.reshape.parts import COLLARS, LIMB_PIECES, LIMB_PIECE_KEYPOINTS, PARTS, PART_INDEX, PART_SEGMENT, SEGMENTS, SEGMENT_KEYPOINTS, SEGMENT_LIMB_PIECE, SEGMENT_PART, TORSO_POLYGON
from nnsf.reshape.pieces import build_pieced_mesh
from nnsf.reshape.regions import body_region_triangles, ink_rim_triangles
from nnsf.reshape.render import outline_style

#: Mesh kinds :func:`build_mesh` accepts (``True`` / ``False`` are aliases of split / connected).
MESH_KINDS = ("connected", "split", "layered", "limbs")


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
        margin = None
        if texture is not None:
            # Tabs keep the paper margin and 0.4 % of the drawing's height (1-2 px) inside the
            # parent's outline.

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
