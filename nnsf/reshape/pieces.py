"""A drawn character cut into puppet pieces: where to cut, who owns each pixel, and joint tabs.

This is the layered mesh of :func:`nnsf.reshape.layers.build_mesh` (``split=
"layered"`` and ``"limbs"``), built the way an animator cuts a drawing into a
paper puppet (docs/method.md §13.1):

1. **Cuts** (:mod:`nnsf.reshape.cuts`): one straight cut per joint, across the
   drawing from outline to outline.

2. **Regions** (:mod:`nnsf.reshape.piece_regions`): which piece owns each
   pixel of the mask cut open along the cuts.

3. **Tabs** (:func:`tab_region`).  A child piece continues under its parent
   as a paper puppet's limb does under the body: a capsule of the limb's
   half-width (at least half the cut) from the cut back to the pivot (the
   joint key point), ending in a disc around the pivot that reaches both ends
   of the cut, clipped to the parent's region.  A renderer draws it just
   before the parent, so at rest it is hidden, and when the joint turns it
   fills the wedge that opens between the two pieces.  Its texture is the
   limb's own fill continued (:func:`nnsf.reshape.tab_texture.tab_texture`, OpenCV's Telea inpainting
   from the limb's non-ink pixels), so a limb swung away from the body takes
   no torso fill or torso ink with it.

4. **Caps** (:func:`nnsf.reshape.tab_regions.cap_region`).  At an elbow or a
   knee the upper segment continues past the cut under the lower one, drawn
   just before it: where the joint folds far, the outer side of the bend
   shows the upper segment's round end.

Everything here runs once per character.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from nnsf.skeleton import LIMBS
from nnsf.reshape import mesh as meshmod
from nnsf.reshape import parts
from nnsf.reshape.drive import TORSO
from nnsf.reshape.cuts import Cut, HEAD, J, OVERLAP, PIECE_BONES, SEGMENT_NAMES, _dist, _lookup, _normal_of, _outline, _root_chord, _seg_dist, find_cuts, half_width, limb_reach, w_distal
from nnsf.reshape.piece_mesh import COVER, covered_share, triangulate_region  # noqa: F401  (covered_share: re-exported)
from nnsf.reshape.piece_regions import label_pieces, shoulder_bridges
from nnsf.reshape.tab_regions import cap_region, tab_region  # noqa: F401  (tab_region: re-exported)

PIECE_BONES.update({1 + i: (ab,) for i, ab in enumerate(LIMBS.values())})


# --------------------------------------------------------------------------- the mesh

@dataclass
class Tab:
    """A joint tab of a pieced mesh: its vertices follow the child's bone rigidly.

    ``vertices``: indices into the mesh's vertices; ``bone``: the child's
    key points ``(joint, next)`` whose rigid motion the tab follows (rotation
    about the joint); ``region``: the tab's pixels at rest ``(H, W)`` bool;
    ``piece``: the child piece (index into the mesh's ``piece_names``);
    ``part``: its part id; ``parent_part``: the part it hides under.
    """

    vertices: np.ndarray
    bone: tuple[int, int]
    region: np.ndarray
    piece: int
    part: int
    parent_part: int
    #: A follower (an extra arm, or its tab): the rest pivot ``(2,)`` it turns about, carried by
    #: the torso's pose, instead of the bone's first key point.
    pivot: np.ndarray | None = None
    #: The pixels whose fill a tab continues (default: its piece's label).
    fill: np.ndarray | None = None
    #: Whether the vertices show the drawing (a follower's own region) rather than a tab texture.
    drawn: bool = False
    #: The cut the tab lies behind (rest pixels) and the piece it hides under (None: a follower's tab).
    cut: Cut | None = None
    parent_piece: int | None = None


def move_pivots(mask: np.ndarray, keypoints: np.ndarray, cuts: list[Cut], reach: float = 0.5) -> np.ndarray:
    """Key points ``(17, 2)`` with each shoulder, hip and the neck moved onto its cut (``cuts`` updated).

    A paper puppet's limb turns about the pin where it meets the body.  The
    drawings' shoulder and hip key points often sit well inside the body
    (AnimatedDrawings' char1: 40 px inside the torso), so a limb turning about
    them swings a large part of itself out of the body's side.  When a key
    point lies farther from its cut than half the cut's length, the pivot is
    moved along the limb's upper bone to the point nearest the cut's middle (at most
    ``reach`` of the bone's length either way; for the neck, along the
    thorax-to-head-top line); the retargeting then chains the limb from
    there (docs/method.md §13.1).  Elbows and knees stay: their cuts pass
    through them.
    """
    kp = np.asarray(keypoints, dtype=np.float64).copy()
    m = np.asarray(mask, dtype=bool)
    for c in cuts:
        if c.parent != 0:
            continue
        # Only a key point farther from its cut than half the cut's length: nearer, a disc around
        # the key point covers the joint compactly, and the drawn pivot is kept.
        if float(np.linalg.norm(c.mid - kp[c.joint])) <= 0.5 * float(np.linalg.norm(c.p - c.q)):
            continue
        a, b = _child_bone(c.child)
        if c.child == HEAD:
            a, b = J["thorax"], J["head_top"]
        u = kp[b] - kp[a]
        if float(u @ u) < 1e-9:
            continue
        # The point of the bone's line nearest the cut's middle: on the line, so the limb's
        # drawn direction from the pivot is its bone's, and the retargeting turns it by the
        # motion's angle only.
        lam = float((c.mid - kp[a]) @ u) / float(u @ u)
        if c.child == HEAD:
            new = kp[a] + lam * u
            L = float(np.linalg.norm(kp[J["head_top"]] - kp[J["neck"]]))
            off = new - kp[J["neck"]]
            if np.linalg.norm(off) > reach * L:
                new = kp[J["neck"]] + off * (reach * L / np.linalg.norm(off))
            joint = J["neck"]
        else:
            new = kp[a] + float(np.clip(lam, -reach, reach)) * u
            joint = a
        if _lookup(m.astype(np.uint8), new[None])[0]:
            kp[joint] = new
            c.pivot = new.copy()
    return kp


def solid_mask(mask: np.ndarray, texture=None, level: int = 128) -> np.ndarray:
    """The mask's solid pixels ``(H, W)`` bool: alpha at least ``level`` (of 255), where ``texture`` has alpha.

    A sprite's anti-aliased edge bridges shapes drawn a pixel apart (the robot's claws touch its
    legs through it), so cuts and labels on the whole mask mix them up.  Without alpha, or when
    under half the mask is solid (soft strokes), the mask itself.
    """
    m, t = np.asarray(mask, dtype=bool), None if texture is None else np.asarray(texture)
    if t is None or t.ndim != 3 or t.shape[2] < 4:
        return m
    solid = m & (t[..., 3] >= level)
    return solid if solid.sum() >= 0.5 * m.sum() else m


def _fill_soft(label: np.ndarray, m: np.ndarray) -> np.ndarray:
    """``label`` of the solid pixels extended to every pixel of ``m``: each soft one takes its nearest piece."""
    from scipy.ndimage import distance_transform_edt

    miss, out = m & (label < 0), np.where(m, label, -1)
    if miss.any() and (label >= 0).any():
        _, (iy, ix) = distance_transform_edt(label < 0, return_indices=True)
        out[miss] = label[iy[miss], ix[miss]]
    return out


def _child_bone(child: int) -> tuple[int, int]:
    if child == HEAD:
        return J["neck"], J["head_top"]
    return LIMBS[list(LIMBS)[child - 1]]


def _filled(label: np.ndarray) -> np.ndarray:
    """The label image with every pixel (also outside the mask) given its nearest label."""
    from scipy.ndimage import distance_transform_edt

    if not (label >= 0).any():
        return label
    _, (iy, ix) = distance_transform_edt(label < 0, return_indices=True)
    return label[iy, ix]


def attach_tabs(tabs: list[Tab], core: np.ndarray, rest_kp: np.ndarray, keypoints: np.ndarray,
                rest_vertices: np.ndarray) -> np.ndarray:
    """Vertices ``(T, n, 2)``: the core's ``(T, n_core, 2)`` followed by every tab moved with its bone.

    A tab turns about its joint by the angle its child bone turned between the
    rest key points ``(17, 2)`` and each frame's ``(T, 17, 2)``, and the joint
    moves to its key point: v' = R (v − j₀) + j_t.  A follower (``Tab.pivot``)
    turns about its own pivot, which the torso's pose (:func:`torso_pose`)
    carries.  Vectorised over tabs and frames (one gather, no loop over tabs);
    :class:`TabMotion` prepares the rest-pose part once for many calls.
    """
    return TabMotion(tabs, rest_kp, rest_vertices)(core, keypoints)


class TabMotion:
    """:func:`attach_tabs` for one mesh and rest pose, with what depends on them alone prepared once.

    ``TabMotion(tabs, rest_kp, rest_vertices)(core, keypoints)`` equals
    ``attach_tabs(tabs, core, rest_kp, keypoints, rest_vertices)``; a rig
    streaming frame by frame calls it once per frame.
    """

    def __init__(self, tabs: list[Tab], rest_kp: np.ndarray, rest_vertices: np.ndarray):
        self.rest_kp = np.asarray(rest_kp, dtype=np.float64)
        self.n = len(rest_vertices)
        self.tabs = bool(tabs)
        if not tabs:
            return
        self.a = np.array([t.bone[0] for t in tabs])
        self.b = np.array([t.bone[1] for t in tabs])
        r = self.rest_kp[self.b] - self.rest_kp[self.a]  # (k, 2)
        self.rest_angle = np.arctan2(r[:, 1], r[:, 0])
        p0 = self.rest_kp[self.a].copy()
        self.follow = [i for i, t in enumerate(tabs) if t.pivot is not None]
        if self.follow:  # followers turn about their own pivot, carried by the torso
            self.follow_pivots = np.array([tabs[i].pivot for i in self.follow])
            p0[self.follow] = self.follow_pivots
        self.idx = np.concatenate([t.vertices for t in tabs])
        self.which = np.concatenate([np.full(len(t.vertices), i) for i, t in enumerate(tabs)])
        self.v = np.asarray(rest_vertices, dtype=np.float64)[self.idx] - p0[self.which]  # (m, 2)

    def __call__(self, core: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
        core = np.asarray(core, dtype=np.float64)
        kp = np.asarray(keypoints, dtype=np.float64)
        T = core.shape[0]
        out = np.empty((T, self.n, 2))
        out[:, :core.shape[1]] = core
        if not self.tabs:
            return out
        d = kp[:, self.b] - kp[:, self.a]  # (T, k, 2)
        ang = np.arctan2(d[..., 1], d[..., 0]) - self.rest_angle
        c, s = np.cos(ang), np.sin(ang)  # (T, k)
        pt = kp[:, self.a].copy()  # (T, k, 2)
        if self.follow:
            c0, ct, tc, ts = torso_pose(self.rest_kp, kp)
            q = self.follow_pivots - c0
            pt[:, self.follow] = ct[:, None] + np.stack([tc[:, None] * q[:, 0] - ts[:, None] * q[:, 1],
                                                          ts[:, None] * q[:, 0] + tc[:, None] * q[:, 1]], -1)
        which, v = self.which, self.v
        cc, ss = c[:, which], s[:, which]  # (T, m)
        out[:, self.idx, 0] = cc * v[:, 0] - ss * v[:, 1] + pt[:, which, 0]
        out[:, self.idx, 1] = ss * v[:, 0] + cc * v[:, 1] + pt[:, which, 1]
        return out


def torso_pose(rest_kp: np.ndarray, kp: np.ndarray):
    """The torso's rigid pose per frame: rest centroid ``(2,)``, frame centroids ``(T, 2)`` and the
    rotation's cos, sin ``(T,)``, fitted (2-D Procrustes) to the key points of
    :data:`nnsf.reshape.drive.TORSO`."""
    torso = list(TORSO)
    rest_kp = np.asarray(rest_kp, dtype=np.float64)
    K = np.asarray(kp, dtype=np.float64)
    c0 = rest_kp[torso].mean(0)
    a0 = rest_kp[torso] - c0
    ct = K[:, torso].mean(1)
    b = K[:, torso] - ct[:, None]
    ang = np.arctan2((a0[None, :, 0] * b[..., 1] - a0[None, :, 1] * b[..., 0]).sum(1), (a0[None] * b).sum((1, 2)))
    return c0, ct, np.cos(ang), np.sin(ang)


def follower_regions(mask: np.ndarray, keypoints: np.ndarray, label: np.ndarray, extra_limbs) -> list[dict]:
    """Each extra arm's pixels, cut and pivot (``extra_limbs``: :attr:`nnsf.reshape.character.Character.extra_limbs`).

    An extra arm is cut from the body as a driven arm is (:func:`_root_chord`,
    the skeleton with that side's arm replaced by the extra one); its region
    is the part of the body's pixels the cut separates holding its elbow and
    hand, limited to :func:`limb_reach` of its bones.
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    contour = _outline(m)
    dist = _dist(m)
    names = list(LIMBS)
    out = []
    for e in extra_limbs or ():
        side, joints = e["side"], np.asarray(e["joints"], dtype=np.float64)
        k2 = kp.copy()
        for jn, xy in zip(("shoulder", "elbow", "wrist"), joints):
            k2[J[f"{side}_{jn}"]] = xy
        child = names.index(f"{side}_upper_arm") + 1
        a, b = LIMBS[names[child - 1]]
        c_ = LIMBS[names[child]][1]
        w = w_distal(dist, k2, a, b, c_)
        chord = _root_chord(m, k2, contour, child, w)
        if chord is None:
            continue
        p, q = chord
        n = _normal_of(p, q, k2[c_] - 0.5 * (p + q))
        cut = Cut(J[f"{side}_shoulder"], 0, child, p, q, k2[a].copy(), n, w)
        img = np.zeros(m.shape, np.uint8)
        d = (q - p) / max(float(np.linalg.norm(q - p)), 1e-9)
        cv2.line(img, tuple(int(v) for v in np.rint(p - 3 * d)), tuple(int(v) for v in np.rint(q + 3 * d)), 1, 1)
        open_ = m & (img == 0)
        _, comp = cv2.connectedComponents(open_.astype(np.uint8), connectivity=4)
        pts = np.vstack([k2[a] + lam[:, None] * (k2[b] - k2[a]) for lam in (np.linspace(0.5, 1.0, 6),)]
                        + [k2[b] + np.linspace(0.0, 1.0, 6)[:, None] * (k2[c_] - k2[b])])
        ids = _lookup(comp.astype(np.int32), pts)
        ids = ids[ids > 0]
        if not len(ids):
            continue
        region = (comp == np.bincount(ids).argmax()) & (label == 0)
        reach = max(limb_reach(w, float(np.linalg.norm(k2[b] - k2[a]))),
                    limb_reach(half_width(dist, k2, b, c_), float(np.linalg.norm(k2[c_] - k2[b]))))
        ys, xs = np.nonzero(region)
        P = np.column_stack([xs, ys]).astype(np.float64)
        near = np.minimum(_seg_dist(P, k2[a], k2[b]), _seg_dist(P, k2[b], k2[c_]))
        blob = 2.5 * float(_lookup(dist, k2[c_][None])[0]) + 2.0  # the hand
        keep = (near <= reach) | (np.linalg.norm(P - k2[c_], axis=1) <= blob)
        region = np.zeros(m.shape, bool)
        region[ys[keep], xs[keep]] = True
        if region.sum() < 6:
            continue
        # The pivot on the cut when the key point lies deep in the body (as move_pivots).
        if float(np.linalg.norm(cut.mid - k2[a])) > 0.5 * float(np.linalg.norm(p - q)):
            u = k2[b] - k2[a]
            lam = float(np.clip(((cut.mid - k2[a]) @ u) / max(float(u @ u), 1e-12), -0.5, 0.5))
            cut.pivot = k2[a] + lam * u
        out.append({"name": e.get("name", side), "side": side, "cut": cut, "region": region})
    return out



def build_pieced_mesh(mask: np.ndarray, keypoints: np.ndarray, n_vertices: int = 800,
                      whole_limbs: bool = False, tab_margin: float | None = None, texture=None,
                      extra_limbs=(), **kwargs):
    """The layered mesh (``whole_limbs=False``) or whole-limb mesh of a drawing (module docstring).

    Every piece's region is triangulated on its own (grown by one pixel into
    its neighbours, so neighbouring pieces overlap by a pixel at rest and
    leave no crack), with one spacing for all; tabs follow, their vertices
    after all the pieces' (``Mesh.n_core``).  ``caps=False`` (keyword) leaves
    out the elbow and knee caps (``benchmarks/joint_caps.py`` compares).
    Returns a :class:`nnsf.reshape.mesh.Mesh`.
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    # Cuts and regions from the drawing's solid pixels; its soft edge then goes to the nearest piece
    # (:func:`solid_mask`).
    solid = solid_mask(m, texture)
    all_cuts = find_cuts(solid, kp)
    label = _fill_soft(label_pieces(solid, kp, all_cuts, texture=texture), m)
    overlay = np.zeros(m.shape, bool)
    bridge = shoulder_bridges(label, kp, solid)
    if texture is not None:
        # Limbs drawn over the body as shapes of their own: the body goes on under them, painted in.
        geo = _fill_soft(label_pieces(solid, kp, all_cuts), m)
        overlay = (geo == 0) & (label > 0) & (label != HEAD)
    # A whole-limb mesh cuts at the shoulders, hips and neck only; its parts still follow the
    # segments (for the depth order and the measures).
    cuts = [c for c in all_cuts if c.parent == 0] if whole_limbs else all_cuts
    pivots = move_pivots(m, kp, cuts)
    # Extra arms (AnimatedDrawings' char5): pieces of their own, taken out of the body.
    followers = follower_regions(m, kp, label, extra_limbs)
    for f in followers:
        label = np.where(f["region"], -1, label)
    h = meshmod.spacing_for(m, n_vertices)
    margin = tab_margin if tab_margin is not None else 0.0
    args = dict(min_angle=kwargs.get("min_angle", 15.0), simplify=kwargs.get("simplify", 0.75),
                jitter=kwargs.get("jitter", 0.0), smooth_sweeps=kwargs.get("smooth_sweeps", 3),
                seed=kwargs.get("seed", 0))
    if whole_limbs:
        names = parts.LIMB_PIECES
        piece_of = {0: 0, HEAD: len(names) - 1}
        piece_of.update({i: 1 + (i - 1) // 2 for i in range(1, HEAD)})
        piece_kp = parts.LIMB_PIECE_KEYPOINTS
    else:
        names = parts.SEGMENTS
        piece_of = {i: i for i in range(len(SEGMENT_NAMES))}
        piece_kp = parts.SEGMENT_KEYPOINTS
    ys = np.flatnonzero(m.any(axis=1))
    ov = int(np.clip(round(OVERLAP * (ys[-1] - ys[0] + 1)), 1, 2)) if len(ys) else 1
    grow = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * ov + 1, 2 * ov + 1))
    V, T, PC, PT = [], [], [], []
    count = 0
    near_cut = np.zeros(m.shape, np.uint8)
    for c in cuts:  # seams open where the pieces turn: along the cuts
        cv2.line(near_cut, tuple(int(v) for v in np.rint(c.p)), tuple(int(v) for v in np.rint(c.q)), 1,
                 2 * (2 * ov + 1) + 1)
    near_cut = near_cut.astype(bool)
    piece_arr = np.array([piece_of[i] for i in range(len(SEGMENT_NAMES))])
    piece_label = np.where(label >= 0, piece_arr[np.maximum(label, 0)], -1)
    near_seg = _filled(label)
    regions_core = []
    for pc in np.unique(piece_label[piece_label >= 0]):
        region = (piece_label == pc) | ((overlay | bridge) if pc == 0 else False)
        # Pieces grow ``ov`` px (:data:`OVERLAP`) into each other near the cuts (where seams open as the joints
        # turn), and a pixel elsewhere into the body and the body into them: a limb drawn over the
        # body that swings away leaves at most a pixel of its drawing behind.
        one = cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        two = cv2.dilate(region.astype(np.uint8), grow).astype(bool)
        two &= ((piece_label != 0) | near_cut) if pc != 0 else near_cut
        region = region | ((one | two) & m)
        if region.sum() >= 6:
            regions_core.append((int(pc), region))

    def triangulate_pieces(spacing, retry=True):
        out = []
        for pc, region in regions_core:
            vt = triangulate_region(region, spacing, args, retry=retry)
            if vt is not None:  # None: too small to triangulate (a sliver between two cuts)
                out.append((pc, *vt))
        return out

    # Each piece has its own outline, so the pieces hold more vertices than one mesh of the same
    # spacing: one rescaled pass brings the solved vertices to about ``n_vertices``.  The count
    # comes from one attempt per piece; the pass kept re-meshes finer a piece that came out
    # (nearly) empty (:func:`nnsf.reshape.piece_mesh.triangulate_region`).
    total = sum(len(v) for _, v, _ in triangulate_pieces(h, retry=False))
    if total and abs(total / n_vertices - 1) > 0.1:
        h = h * float(np.sqrt(total / n_vertices))
    pieces_tri = triangulate_pieces(h)
    for pc, v, t in pieces_tri:
        # Each triangle's part: the segment under its centroid (one of the piece's own).
        seg = _lookup(near_seg, v[t].mean(axis=1))
        own = np.flatnonzero(piece_arr == pc)
        seg = np.where(np.isin(seg, own), seg, own[0])
        V.append(v)
        T.append(t + count)
        count += len(v)
        PC.append(np.full(len(t), int(pc)))
        PT.append(parts.SEGMENT_PART[seg].astype(np.int64))
    n_core = count
    drawn_parts = set(np.concatenate(PT).tolist()) if PT else set()
    drawn = {seg for seg in range(len(SEGMENT_NAMES)) if int(parts.SEGMENT_PART[seg]) in drawn_parts}
    parent_of = {c.child: c.parent for c in cuts}

    def shown_parent(seg: int) -> int:
        """The nearest ancestor drawn with a region of its own (a tab hides under it)."""
        while seg in parent_of and seg not in drawn:
            seg = parent_of[seg]
        return seg

    tabs, collar = [], [np.full(sum(len(t) for t in T), -1)]
    tuck = hip_tucks(cuts, V, T, PC, piece_of)
    # The body samples the drawing with the limbs drawn over it painted out (layer 1, overlay_texture).
    layer = [np.concatenate([np.full(len(t), 1 if (overlay.any() and int(pc[0]) == 0) else 0, np.int64)
                             for t, pc in zip(T, PC)]) if T else np.zeros(0, np.int64)]
    regions = {}
    # Parents first (shoulders and hips before elbows and knees): a segment drawn too short to
    # hold its child's tab lends it its own tab.
    for cut in sorted(cuts, key=lambda c: c.parent != 0):
        if cut.parent == 0:
            regions[cut.child] = tab_region(label, cut, margin)
        else:
            under = regions.get(cut.parent, np.zeros(label.shape, bool))
            # An elbow's or knee's cut ends on the outline: the wedge a bend opens reaches the
            # outline, so this tab keeps no margin.
            regions[cut.child] = tab_region(label, cut, 0.0, under=under)
    # Elbow and knee caps: the upper segment's end rounded past its cut, under the lower one.
    caps = [] if not kwargs.get("caps", True) else [(cut, cap_region(label, cut)) for cut in cuts
                                   if cut.parent != 0 and cut.parent in drawn and cut.child in drawn]
    for k, (cut, region) in enumerate([(c, regions[c.child]) for c in cuts] + caps):
        cap = k >= len(cuts)
        # A tab is retried only when it gets no triangle at all: it hides under its parent, and a
        # finer one changes what a turning joint shows.
        vt = triangulate_region(region, max(h, 2.0), args, cover=0.0)
        if vt is None:
            continue
        v, t = vt
        idx = np.arange(count, count + len(v))
        V.append(v)
        T.append(t + count)
        count += len(v)
        own, hides = (cut.parent, cut.child) if cap else (cut.child, shown_parent(cut.parent))
        pc = piece_of[own]
        # A whole limb's tab follows its upper bone; a segment's, its own.
        PC.append(np.full(len(t), pc))
        part = int(parts.SEGMENT_PART[own])
        PT.append(np.full(len(t), part))
        layer.append(np.full(len(t), 3 + len(tabs), np.int64))
        under = int(parts.SEGMENT_PART[hides])
        collar.append(np.full(len(t), under))
        tabs.append(Tab(idx, _child_bone(own), region, pc, part, under, cut=None if cap else cut,
                        parent_piece=None if cap else piece_of[hides]))
    for f in followers:
        # The extra arm (the part of the driven arm of its side) and its tab.
        cut = f["cut"]
        part = int(parts.SEGMENT_PART[cut.child])
        a_b = _child_bone(cut.child)
        grown = f["region"] | (cv2.dilate(f["region"].astype(np.uint8), grow).astype(bool) & m & near_cut_f(cut, m, ov))
        tab = tab_region(np.where(f["region"], cut.child, label), cut, margin)
        # Both drawn just before the body (tab first): the extra arms stay behind the body and the
        # driven arms, so arms that turn together do not pile up in front.
        own = f["region"] | (cv2.dilate(f["region"].astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & m)
        for region, is_tab in ((tab, True), (own | grown, False)):
            vt = triangulate_region(region, h if not is_tab else max(h, 2.0), args, cover=0.0 if is_tab else COVER)
            if vt is None:
                continue
            v, t = vt
            idx = np.arange(count, count + len(v))
            V.append(v)
            T.append(t + count)
            count += len(v)
            PC.append(np.full(len(t), piece_of[cut.child]))
            PT.append(np.full(len(t), part))
            layer.append(np.full(len(t), 3 + len(tabs) if is_tab else 0, np.int64))
            collar.append(np.full(len(t), 0))
            tabs.append(Tab(idx, a_b, region, piece_of[cut.child], part, 0, pivot=cut.pivot.copy(),
                            fill=f["region"], drawn=not is_tab))
    mesh = meshmod.Mesh(vertices=np.vstack(V), triangles=np.vstack(T).astype(np.int64),
                        parts=np.concatenate(PT).astype(np.int64), spacing=h,
                        pieces=np.concatenate(PC).astype(np.int64), piece_names=names, piece_keypoints=piece_kp,
                        layer=np.concatenate(layer), collar=np.concatenate(collar).astype(np.int64),
                        tuck=np.r_[tuck, np.full(sum(len(t) for t in T) - len(tuck), -1)].astype(np.int64))
    mesh.n_core = n_core
    mesh.tabs = tabs
    mesh.pivots = pivots
    mesh.overlay = overlay
    mesh.labels = label
    mesh.cuts = cuts
    mesh.followers = [{"name": f["name"], "side": f["side"]} for f in followers]
    return mesh


#: Depth of the band of a thigh tucked under the body (:func:`hip_tucks`), as a share of the hip
#: cut's length.
TUCK = 0.35


def hip_tucks(cuts: list[Cut], V: list, T: list, PC: list, piece_of: dict) -> np.ndarray:
    """Part each core triangle tucks under, ``(t,)`` (−1: none): a thigh's band along its hip cut
    goes under the body.

    Legs hang from the body's bottom edge: drawn in front of the body, a thigh turning about its
    hip would lay its straight top edge over the belly (AnimatedDrawings' char1: a kite-shaped
    corner across the belt).  The band of the thigh's own triangles whose centroids lie within
    :data:`TUCK` × the cut's length of the hip cut (and within half the way to the knee) is drawn
    under the body instead (``Mesh.tuck``), so the thigh comes out from under the body's edge.
    Arms are left alone: an arm may be drawn over the chest at rest, and its band would vanish.
    """
    verts = np.vstack(V) if V else np.zeros((0, 2))
    out = [np.full(len(t), -1, np.int64) for t in T]
    knees = {c.parent: c for c in cuts if c.parent != 0}
    torso = int(parts.SEGMENT_PART[0])
    for c in cuts:
        if c.parent != 0 or "thigh" not in SEGMENT_NAMES[c.child]:
            continue
        depth = TUCK * float(np.linalg.norm(c.q - c.p))
        knee = knees.get(c.child)
        if knee is not None:
            depth = min(depth, 0.5 * float(c.side(knee.mid[None])[0]))
        for k, (t, p) in enumerate(zip(T, PC)):
            if len(t) and int(p[0]) == piece_of[c.child]:
                out[k][c.side(verts[t].mean(axis=1)) < depth] = torso
    return np.concatenate(out) if out else np.zeros(0, np.int64)


def near_cut_f(cut: Cut, m: np.ndarray, ov: int) -> np.ndarray:
    """Pixels near a cut (where its two sides overlap by ``ov`` px)."""
    img = np.zeros(m.shape, np.uint8)
    cv2.line(img, tuple(int(v) for v in np.rint(cut.p)), tuple(int(v) for v in np.rint(cut.q)), 1,
             2 * (2 * ov + 1) + 1)
    return img.astype(bool)
