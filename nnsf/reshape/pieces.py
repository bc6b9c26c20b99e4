"""A drawn character cut into puppet pieces: where to cut, who owns each pixel, and joint tabs.

This is the layered mesh of :func:`nnsf.reshape.mesh.build_mesh` (``split=
"layered"`` and ``"limbs"``), built the way an animator cuts a drawing into a
paper puppet (docs/method.md §13.1):

1. **Cuts** (:func:`find_cuts`).  Every joint where a child piece hangs from
   its parent gets a straight cut across the drawing, from outline to
   outline:

   * at a shoulder or hip the cut sits where the limb *leaves the body*:
     walking along the upper bone from the elbow (knee) toward the body, the
     limb's cross-section (perpendicular to the bone, from the bone to the
     outline on each side) keeps the limb's own half-width until one side
     widens into the body (an armpit, a crotch, a skirt's hem); the cut is the
     last cross-section before that.  A limb whose outline never widens (a
     stick figure's arm, an arm hanging against the torso) is cut at the
     joint itself;
   * at an elbow or knee the cut passes through the joint, perpendicular to
     the mean direction of the two bones;
   * at the neck it is the narrowest cross-section between the thorax and a
     little above the neck key point (the drawing's neck, or where the head
     sits on the shoulders), when that is clearly narrower than the head;
     else through the neck key point.

   A cross-section stops at the outline, and where a pixel becomes nearer to
   another limb's bone than to its own (two legs drawn touching).

2. **Regions** (:func:`label_pieces`).  The mask, cut open along every cut,
   falls apart into connected pieces; each goes to the piece whose bones it
   holds.  Where a piece still touches another along the drawing (an arm
   lying against the torso, legs drawn together), its pixels are shared out
   by the nearest bone, a limb claiming no pixel farther from its bone than
   1.3 × its half-width.  Seams are therefore straight cuts or smooth
   bisectors, never the staircase of triangle edges.

3. **Tabs** (:func:`tab_region`).  A child piece continues under its parent
   as a paper puppet's limb does under the body: a capsule of the limb's
   half-width (at least half the cut) from the cut back to the pivot (the
   joint key point), ending in a disc around the pivot that reaches both ends
   of the cut, clipped to the parent's region.  A renderer draws it just
   before the parent, so at rest it is hidden, and when the joint turns it
   fills the wedge that opens between the two pieces.  Its texture is the
   limb's own fill continued (:func:`tab_texture`, OpenCV's Telea inpainting
   from the limb's non-ink pixels), so a limb swung away from the body takes
   no torso fill or torso ink with it.

Everything here runs once per character.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from nnsf.skeleton import JOINT_INDEX, LIMBS
from nnsf.reshape import mesh as meshmod
from nnsf.reshape import parts
from nnsf.reshape.drive import TORSO
from nnsf.reshape.regions import body_region_triangles, drawn_regions

J = JOINT_INDEX
#: Pieces of the layered mesh: the body, each limb segment and the head.
SEGMENT_NAMES: tuple[str, ...] = ("body",) + tuple(LIMBS) + ("head",)
HEAD = len(SEGMENT_NAMES) - 1
#: Bones that say where each piece is: the body's spine, its shoulder and hip
#: girdles; each segment's own bone; the head's neck-to-top.
PIECE_BONES: dict[int, tuple[tuple[int, int], ...]] = {
    0: ((J["pelvis"], J["spine"]), (J["spine"], J["thorax"]), (J["thorax"], J["l_shoulder"]),
        (J["thorax"], J["r_shoulder"]), (J["pelvis"], J["l_hip"]), (J["pelvis"], J["r_hip"])),
    HEAD: ((J["neck"], J["head_top"]),),
}
PIECE_BONES.update({1 + i: (ab,) for i, ab in enumerate(LIMBS.values())})
#: (joint, parent piece, child piece) for every joint where pieces meet.
JOINTS_OF_PIECES: tuple[tuple[int, int, int], ...] = tuple(
    (J[j], SEGMENT_NAMES.index(p), SEGMENT_NAMES.index(c)) for j, p, c in (
        ("l_shoulder", "body", "l_upper_arm"), ("l_elbow", "l_upper_arm", "l_forearm"),
        ("r_shoulder", "body", "r_upper_arm"), ("r_elbow", "r_upper_arm", "r_forearm"),
        ("l_hip", "body", "l_thigh"), ("l_knee", "l_thigh", "l_shin"),
        ("r_hip", "body", "r_thigh"), ("r_knee", "r_thigh", "r_shin"),
        ("neck", "body", "head")))
#: A limb's cross-section "widens into the body" when one side grows past
#: this factor × that side's own half-width (plus 1.5 px).
WIDEN = 1.6
#: A limb claims pixels up to this factor × its half-width from its bone.
CAPSULE = 1.3
#: Pixels by which each piece grows into its neighbours at rest, hiding the seams that open by a
#: pixel or two where a rigid segment meets the deformed body: this share of the drawing's height,
#: between 1 and 2 px (2 on drawings from about 250 px tall, 1 on a 128 px sprite).
OVERLAP = 0.006


@dataclass
class Cut:
    """A straight cut between a parent and a child piece.

    ``p``, ``q``: the ends on the outline (pixels); ``pivot``: the joint key
    point the child turns about; ``normal``: unit, pointing into the child;
    ``half_width``: the child's half-width (pixels).
    """

    joint: int
    parent: int
    child: int
    p: np.ndarray
    q: np.ndarray
    pivot: np.ndarray
    normal: np.ndarray
    half_width: float

    @property
    def mid(self) -> np.ndarray:
        return 0.5 * (self.p + self.q)

    def side(self, pts: np.ndarray) -> np.ndarray:
        """Signed distance ``(k,)`` of points to the cut's line, positive on the child's side."""
        return (np.atleast_2d(pts) - self.mid) @ self.normal

    def across(self, pts: np.ndarray) -> np.ndarray:
        """Whether points ``(k,)`` lie within the cut's span (projected on the cut, 2 px margin)."""
        d = self.q - self.p
        L = float(np.linalg.norm(d))
        t = (np.atleast_2d(pts) - self.mid) @ (d / max(L, 1e-9))
        return np.abs(t) <= 0.5 * L + 2.0


def _dist(mask: np.ndarray) -> np.ndarray:
    return cv2.distanceTransform(np.pad(mask.astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]


def _lookup(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    H, W = img.shape[:2]
    ij = np.rint(np.asarray(pts)).astype(np.int64)
    ok = (ij[..., 0] >= 0) & (ij[..., 0] < W) & (ij[..., 1] >= 0) & (ij[..., 1] < H)
    out = np.zeros(ij.shape[:-1], dtype=img.dtype)
    out[ok] = img[ij[ok][:, 1], ij[ok][:, 0]]
    return out


def _seg_dist(pts: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    d = b - a
    t = np.clip(((pts - a) @ d) / max(float(d @ d), 1e-12), 0.0, 1.0)
    return np.linalg.norm(pts - (a + t[..., None] * d), axis=-1)


def half_width(dist: np.ndarray, kp: np.ndarray, a: int, b: int, span=(0.3, 0.7)) -> float:
    """A limb's half-width (pixels): the median distance to the outline along the middle of its bone."""
    lam = np.linspace(*span, 7)[:, None]
    return max(float(np.median(_lookup(dist, kp[a] + lam * (kp[b] - kp[a])))), 1.0)


def cross_sections(mask: np.ndarray, centres: np.ndarray, direction: np.ndarray, reach: float,
                   own=None, others=()) -> np.ndarray:
    """Extents ``(k, 2)`` (pixels) of the mask from each centre ``(k, 2)`` along ±``direction``.

    A walk stops at the first pixel outside the mask, or nearer to one of
    ``others`` (bone segments ``(a, b)``) than to ``own`` (a bone segment);
    at most ``reach``.
    """
    steps = np.arange(0.0, reach + 0.5, 0.5)
    out = np.empty((len(centres), 2))
    for k, sgn in enumerate((1.0, -1.0)):
        pts = centres[:, None, :] + sgn * steps[None, :, None] * direction  # (k, s, 2)
        inside = _lookup(mask.astype(np.uint8), pts).astype(bool)
        if own is not None and others:
            d_own = _seg_dist(pts, *own)
            for a, b in others:
                inside &= _seg_dist(pts, a, b) >= d_own
        stop = np.where(inside.all(axis=1), len(steps) - 1, np.argmin(inside, axis=1))
        out[:, k] = steps[np.maximum(stop - 1, 0)] + 0.5 * (stop > 0)
    return out


def _limb_bones(kp, exclude=()) -> list[tuple[np.ndarray, np.ndarray]]:
    """Bone segments of the limbs not in ``exclude``; a forearm's or shin's reaches a third past
    its wrist or ankle key point (the hand or foot)."""
    out = []
    for name, (a, b) in LIMBS.items():
        if name in exclude:
            continue
        tip = kp[b] + (kp[b] - kp[a]) / 3.0 if name.endswith(("forearm", "shin")) else kp[b]
        out.append((kp[a], tip))
    return out


def find_cuts(mask: np.ndarray, keypoints: np.ndarray, whole_limbs: bool = False) -> list[Cut]:
    """The cuts between the pieces (module docstring), one per joint of :data:`JOINTS_OF_PIECES`.

    ``whole_limbs``: only the shoulders, hips and neck (each limb one piece).
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    dist = _dist(m)
    names = list(LIMBS)
    contour = _outline(m)
    cuts = []
    for joint, parent, child in JOINTS_OF_PIECES:
        if whole_limbs and parent != 0:
            continue
        if child == HEAD:
            cuts.append(_neck_cut(m, kp, dist, contour))
            continue
        a, b = LIMBS[names[child - 1]]
        u = kp[b] - kp[a]
        L = float(np.linalg.norm(u))
        if L < 1e-6:
            continue
        u /= L
        w = half_width(dist, kp, a, b)
        limb = names[child - 1]
        side = limb[:2]
        own_limb = [n for n in names if n.startswith(side) and (("arm" in n) == ("arm" in limb))]
        others = _limb_bones(kp, exclude=own_limb)
        if parent == 0:
            chord = _root_chord(m, kp, contour, child, w_distal(dist, kp, a, b, LIMBS[names[child]][1]))
            if chord is not None:
                p, q = chord
                n = kp[LIMBS[names[child]][1]] - 0.5 * (p + q)  # toward the hand or foot
                cuts.append(Cut(joint, parent, child, p, q, kp[joint].copy(), _normal_of(p, q, n), w))
                continue
            n = u
            d = np.array([-n[1], n[0]])
            centre = kp[joint]
            e = cross_sections(m, centre[None], d, 2.5 * w + 2, own=(kp[a], kp[b]), others=others)[0]
        else:
            pa, pb = LIMBS[names[parent - 1]]
            up = kp[pb] - kp[pa]
            s = up / max(np.linalg.norm(up), 1e-9) + u
            n = s / np.linalg.norm(s) if np.linalg.norm(s) > 1e-3 else u
            d = np.array([-n[1], n[0]])
            centre = kp[joint]
            e = cross_sections(m, centre[None], d, 2.5 * w + 2, own=(kp[pa], kp[b]), others=others)[0]
        p, q = centre + e[0] * d, centre - e[1] * d
        cuts.append(Cut(joint, parent, child, p, q, kp[joint].copy(), n, w))
    return cuts


def limb_reach(w: float, length: float) -> float:
    """How far from its bone a limb's drawing may lie (pixels): :data:`CAPSULE` × its half-width
    plus a pixel, and at least a fifth of the bone's length (a drawn stroke wanders off the
    straight line between two key points)."""
    return max(CAPSULE * w + 1.0, 0.2 * length)


def _normal_of(p: np.ndarray, q: np.ndarray, toward: np.ndarray) -> np.ndarray:
    """Unit normal of the segment p-q on the side of ``toward``."""
    d = q - p
    n = np.array([-d[1], d[0]]) / max(float(np.linalg.norm(d)), 1e-9)
    return n if float(n @ toward) >= 0 else -n


def w_distal(dist: np.ndarray, kp: np.ndarray, a: int, b: int, c: int) -> float:
    """A limb's own half-width: its upper segment's toward the elbow (knee), which is rarely inside
    the body, and at most 1.5 × the lower segment's (a skirt or sleeve around a thigh or arm is not
    the limb)."""
    return min(half_width(dist, kp, a, b, span=(0.55, 0.75)), half_width(dist, kp, a, b, span=(0.75, 0.95)),
               1.5 * half_width(dist, kp, b, c))


def _outline(m: np.ndarray) -> np.ndarray:
    """The outer outline of the largest component, ``(k, 2)`` float, one point per pixel step."""
    cs, _ = cv2.findContours(m.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    return max(cs, key=cv2.contourArea)[:, 0, :].astype(np.float64)


def _nearest_piece(pts: np.ndarray, kp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Piece whose bone is nearest to each point ``(k,)``, and that distance ``(k,)``."""
    best = np.full(len(pts), np.inf)
    who = np.zeros(len(pts), np.int64)
    for pc, bones in PIECE_BONES.items():
        for a, b in bones:
            d = _seg_dist(pts, kp[a], kp[b])
            closer = d < best
            best[closer], who[closer] = d[closer], pc
    return who, best


def _segment_inside(m: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """For segments ``p``-``q`` (each ``(k, 2)``): whether all points along them are mask pixels."""
    t = np.linspace(0.05, 0.95, 12)[None, :, None]
    pts = p[:, None, :] + t * (q - p)[:, None, :]
    return _lookup(m.astype(np.uint8), pts).astype(bool).all(axis=1)


def _root_chord(m, kp, contour, child, w) -> tuple[np.ndarray, np.ndarray] | None:
    """Where a limb leaves the body: the shortest chord joining the two ends of the limb's outline.

    The limb's outline is the run of outline points whose nearest bone is
    one of the limb's two and that lie within :data:`CAPSULE` × (its
    half-width near the elbow or knee, ``w``, plus a pixel) of it: a skirt or
    a torso around the top of a thigh or arm is not the limb's.  The chord
    joins a point near each end of that run (within 1.5 w along the outline),
    lies inside the mask, and crosses the upper bone before its middle.
    """
    names = list(LIMBS)
    upper, lower = child, child + 1
    who, d = _nearest_piece(contour, kp)
    a, b = LIMBS[names[upper - 1]]
    # A drawn limb wanders off its key-point line: allow 15 % of the bone's length.
    reach = limb_reach(w, float(np.linalg.norm(kp[b] - kp[a])))
    c = LIMBS[names[lower - 1]][1]
    tip = kp[c]
    L_low = float(np.linalg.norm(kp[c] - kp[b]))
    dist = _dist(m)
    w_low = half_width(dist, kp, b, c)
    # The lower segment's own outline, and its hand or foot around the tip (as far as 2.5 × the
    # tip's distance to the outline, or 60 % of the segment).
    blob = max(0.6 * L_low, 2.5 * float(_lookup(dist, tip[None])[0]) + 2.0)
    low = (who == lower) & ((d <= limb_reach(w_low, L_low)) | (np.linalg.norm(contour - tip, axis=1) <= blob))
    member = low | ((who == upper) & (d <= reach))
    run = _run_around(member, contour, tip)
    if run is None:
        return None
    i, k = run
    L = float(np.linalg.norm(kp[b] - kp[a]))
    win = max(int(round(max(1.5 * w, 0.25 * L))), 3)
    # No longer than the limb is wide (with the widening allowance): a chord across a skirt is not the leg's.
    return _shortest_chord(m, contour, i, k, win, kp[a], kp[b], 1.05, max_len=max(2 * WIDEN * w + 2, 0.25 * L))


def _run_around(member: np.ndarray, contour: np.ndarray, point: np.ndarray):
    """Ends ``(i, k)`` (indices, i ≤ k, cyclic) of the run of ``member`` holding the outline point nearest ``point``."""
    n = len(contour)
    if member.all() or not member.any():
        return None
    start = int(np.argmin(np.linalg.norm(contour - point, axis=1)))
    if not member[start]:
        return None
    i = start
    while member[(i - 1) % n] and (start - i) < n:
        i -= 1
    k = start
    while member[(k + 1) % n] and (k - start) < n:
        k += 1
    return i, k


def _shortest_chord(m, contour, i, k, win, a, b, lam_max, max_len=np.inf):
    """The shortest chord inside the mask from near outline index ``i`` to near ``k`` (± ``win``),
    crossing the line a→b at most ``lam_max`` of the way from a; None without one."""
    n = len(contour)
    A = contour[np.arange(i - win, i + win + 1) % n]
    B = contour[np.arange(k - win, k + win + 1) % n]
    P = np.repeat(A, len(B), axis=0)
    Q = np.tile(B, (len(A), 1))
    length = np.linalg.norm(P - Q, axis=1)
    ok = (length > 1.0) & (length <= max_len) & _segment_inside(m, P, Q)
    # The chord crosses the bone's line before lam_max of its length.
    u = b - a
    mid = 0.5 * (P + Q)
    lam = ((mid - a) @ u) / max(float(u @ u), 1e-12)
    ok &= lam <= lam_max
    # ... and crosses it, not runs along it: at least 45 degrees to the bone.
    cosang = np.abs((Q - P) @ u) / np.maximum(length * np.linalg.norm(u), 1e-9)
    ok &= cosang <= 0.71
    if not ok.any():
        return None
    best = int(np.argmin(np.where(ok, length, np.inf)))
    return P[best].copy(), Q[best].copy()


def _neck_cut(m: np.ndarray, kp: np.ndarray, dist: np.ndarray, contour=None) -> Cut:
    """The neck: the shortest chord joining the ends of the head's outline (the outline points
    nearest the head's bone), else the narrowest cross-section from the thorax to a little
    above the neck key point."""
    th, nk, top = kp[J["thorax"]], kp[J["neck"]], kp[J["head_top"]]
    if contour is not None and False:
        who, _ = _nearest_piece(contour, kp)
        run = _run_around(who == HEAD, contour, top)
        if run is not None:
            i, k = run
            span = np.linalg.norm(contour[i % len(contour)] - contour[k % len(contour)])
            chord = _shortest_chord(m, contour, i, k, max(int(round(0.4 * span)), 3), top, th, 1.2)
            if chord is not None:
                p, q = chord
                n = _normal_of(p, q, top - th)
                return Cut(J["neck"], 0, HEAD, p, q, nk.copy(), n, max(0.5 * float(np.linalg.norm(p - q)), 1.0))
    axis = top - th
    L = float(np.linalg.norm(axis))
    n = axis / max(L, 1e-9)
    d = np.array([-n[1], n[0]])
    others = _limb_bones(kp)
    head_w = cross_sections(m, (0.5 * (nk + top))[None], d, L, own=(th, top), others=others)[0].sum()
    s_neck = float((nk - th) @ n)
    s_top = float((top - th) @ n)
    s = np.arange(0.25 * s_neck, min(s_neck + 0.3 * (s_top - s_neck), s_top) + 0.5, 0.5)
    centres = th + s[:, None] * n
    ext = cross_sections(m, centres, d, L, own=(th, top), others=others)
    width = ext.sum(axis=1)
    k = int(np.argmin(width))
    if width[k] < 0.8 * head_w and s[k] > 0:
        centre, e = centres[k], ext[k]
    else:
        centre = th + s_neck * n
        e = cross_sections(m, centre[None], d, L, own=(th, top), others=others)[0]
    p, q = centre + e[0] * d, centre - e[1] * d
    w = 0.5 * float(np.linalg.norm(p - q))
    return Cut(J["neck"], 0, HEAD, p, q, nk.copy(), n, max(w, 1.0))


def _bone_samples(kp: np.ndarray, piece: int, per: int = 24) -> np.ndarray:
    lam = np.linspace(0.0, 1.0, per)[:, None]
    out = []
    for a, b in PIECE_BONES[piece]:
        if piece in (0, HEAD):
            out.append(kp[a] + lam * (kp[b] - kp[a]))
        else:  # a limb segment: its own bone, ends left out (they touch the neighbours)
            out.append(kp[a] + (0.15 + 0.8 * lam) * (kp[b] - kp[a]))
    return np.vstack(out)


def label_pieces(mask: np.ndarray, keypoints: np.ndarray, cuts: list[Cut], whole_limbs: bool = False,
                 texture=None) -> np.ndarray:
    """Piece of every mask pixel ``(H, W)`` int (−1 outside), indices into :data:`SEGMENT_NAMES`.

    With ``whole_limbs`` a limb's two segments share the upper one's index.
    With ``texture``, a region of the drawing bounded by its lines that holds
    the body's spine and no limb's bone (:func:`nnsf.reshape.mesh.body_region_triangles`)
    stays the body's, even inside a limb's reach: a chest drawn in front of an
    arm's root is the chest's.
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    H, W = m.shape
    dist = _dist(m)
    pieces = list(range(len(SEGMENT_NAMES)))
    merged = {}
    if whole_limbs:
        for i in range(1, HEAD, 2):
            merged[i + 1] = i
    # Cut the mask open along every cut and take 4-connected components.
    cut_img = np.zeros((H, W), np.uint8)
    for c in cuts:
        # Drawn 3 px past each end: an end on a grazing outline must not leave a gap around it.
        d = (c.q - c.p) / max(float(np.linalg.norm(c.q - c.p)), 1e-9)
        a, b = c.p - 3.0 * d, c.q + 3.0 * d
        cv2.line(cut_img, tuple(int(v) for v in np.rint(a)), tuple(int(v) for v in np.rint(b)), 1, 1,
                 cv2.LINE_8)
    open_ = m & (cut_img == 0)
    n, comp = cv2.connectedComponents(open_.astype(np.uint8), connectivity=4)
    # Which pieces' bones lie in each component (a bone sample on a cut counts for no one).
    votes = np.zeros((n, len(pieces)))
    for pc in pieces:
        pts = _bone_samples(kp, pc)
        for c in cuts:  # a piece's samples beyond its own cuts say nothing
            if c.child == pc:
                pts = pts[c.side(pts) >= 0]
            elif c.parent == pc:  # the body's bones elsewhere may lie beyond the line of a cut
                pts = pts[~((c.side(pts) > 0) & (c.across(pts) if pc == 0 else True))]
        lab = _lookup(comp.astype(np.int32), pts)
        ok = _lookup(open_.astype(np.uint8), pts).astype(bool)
        np.add.at(votes, (lab[ok], np.full(ok.sum(), merged.get(pc, pc))), 1.0)
    votes[0] = 0
    # A piece owns a component holding a quarter of its samples, or most of them.
    share = votes / np.maximum(votes.sum(axis=0, keepdims=True), 1.0)
    best = share == share.max(axis=0, keepdims=True)
    votes = np.where((share >= 0.25) | (best & (votes > 0)), votes, 0.0)
    label = np.full((H, W), -1, np.int64)
    # Nearest-bone labels, for components holding several pieces' bones.
    radius = {pc: limb_reach(half_width(dist, kp, *PIECE_BONES[pc][0]),
                             float(np.linalg.norm(np.subtract(*kp[list(PIECE_BONES[pc][0])]))))
              for pc in range(1, HEAD)}
    ys, xs = np.nonzero(m)
    pts = np.column_stack([xs, ys]).astype(np.float64)
    near = np.full((len(pts), len(pieces)), np.inf)
    for pc in pieces:
        for a, b in PIECE_BONES[pc]:
            tip = kp[b]
            if pc in radius and pc % 2 == 0:
                # A forearm or shin: its hand or foot reaches past the wrist or ankle key point
                # (a third of the segment).
                tip = kp[b] + (kp[b] - kp[a]) / 3.0
            dd = _seg_dist(pts, kp[a], tip)
            if pc in radius:
                dd = np.where(dd <= radius[pc], dd, np.inf)
            tgt = merged.get(pc, pc)
            near[:, tgt] = np.minimum(near[:, tgt], dd)
    # Head and body part along the neck cut's line: the head side is the head's (or a limb's,
    # by its capsule), the other side the body's.
    neck = [c for c in cuts if c.child == HEAD]
    if neck:
        up = neck[0].side(pts) > 0
        near[:, HEAD] = np.where(up, near[:, HEAD], np.inf)
        near[:, 0] = np.where(up, np.inf, near[:, 0])
    pix_comp = comp[ys, xs]
    owners = votes > 0
    for ci in range(1, n):
        sel = pix_comp == ci
        own = np.flatnonzero(owners[ci])
        if len(own) == 1:
            label[ys[sel], xs[sel]] = own[0]
        elif len(own) > 1:
            d = near[sel][:, own]
            pick = own[np.argmin(d, axis=1)]
            # Pixels no capsule reaches go to the body, or else to the nearest piece.
            none = ~np.isfinite(d).any(axis=1)
            if none.any():
                fallback = (HEAD if HEAD in own else 0) if 0 not in own else 0
                pick[none] = fallback if fallback in own else own[0]
            label[ys[sel], xs[sel]] = pick
    # Cut lines and components without bones: the neighbouring piece (nearest labelled pixel).
    label = _fill_unlabelled(label, m)
    if texture is not None:
        body_only = body_region_triangles(None, None, kp, texture, m, pixels=True)
        label = np.where(body_only & (label > 0) & (label != HEAD), 0, label)
        for seg, region in limb_regions(texture, m, kp).items():
            label = np.where(region & (label == 0), seg, label)
    label = _open_big_pieces(label, m)
    return _one_component_each(label, m)


def limb_regions(texture: np.ndarray, mask: np.ndarray, keypoints: np.ndarray) -> dict[int, np.ndarray]:
    """Regions of the drawing, bounded by its lines, that are one arm's only, ``{segment: (H, W) bool}``.

    A region (:func:`nnsf.reshape.mesh.drawn_regions`) belongs to a limb
    limb when it holds points of its bones (upper segments λ ∈ [0.6, 0.95],
    lower ones λ ∈ [0.1, 0.9]) and no point of the spine, the neck or another
    limb: an arm drawn over the chest as a shape of its own.  The pixels of
    such a region that the cuts gave the body go to the limb's upper segment.
    Only arms: legs hang from the body's bottom edge, where a line between
    leg and body is the body's outline (AnimatedDrawings' char1: its belly
    band), not a leg drawn over it.  Those pixels go with the limb even past the cut where its
    outline leaves the body, and the body under them is painted in
    (:func:`overlay_texture`).
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    m = np.asarray(mask, dtype=bool)
    lab = drawn_regions(texture, m)

    def regions_along(a, b, lo, hi):
        lam = np.linspace(lo, hi, 9)[:, None]
        pts = kp[a] + lam * (kp[b] - kp[a])
        r = _lookup(lab, pts)
        return set(r[_lookup(m.astype(np.uint8), pts) > 0].tolist()) - {-1}

    body = set()
    for a, b in (("pelvis", "spine"), ("spine", "thorax"), ("thorax", "neck")):
        body |= regions_along(J[a], J[b], 0.0, 1.0)
    owner: dict[int, set] = {}
    for i, (name, (a, b)) in enumerate(LIMBS.items()):
        if "arm" not in name:  # legs hang from the body's bottom; arms are drawn over the chest
            continue
        upper = "upper" in name or "thigh" in name
        for r in regions_along(a, b, *((0.6, 0.95) if upper else (0.1, 0.9))):
            owner.setdefault(r, set()).add(1 + i)
    out = {}
    for r, segs in owner.items():
        # One limb's (its two segments count as one: no line need part them at the elbow).
        if r in body or len({(s_ - 1) // 2 for s_ in segs}) != 1:
            continue
        seg = min(segs)
        out[seg] = out.get(seg, np.zeros(m.shape, bool)) | (lab == r)
    return out


def _open_big_pieces(label: np.ndarray, m: np.ndarray) -> np.ndarray:
    """The body's and head's thin slivers (narrower than 1.5 % of the drawing's height, at least
    2 px) go to the piece next to them: a strip of outline the head hid at rest must not stick
    out as a spike when the head turns.  Limbs keep theirs (a stick figure's arm is all sliver)."""
    ys = np.flatnonzero(m.any(axis=1))
    r = max(int(round(0.015 * (ys[-1] - ys[0] + 1))), 2) if len(ys) else 2
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    out = label.copy()
    for pc in (0, HEAD):
        region = (label == pc).astype(np.uint8)
        if not region.any():
            continue
        kept = cv2.morphologyEx(region, cv2.MORPH_OPEN, ker).astype(bool)
        # Only slivers next to another piece: the outline itself may be thin anywhere.
        loose = region.astype(bool) & ~kept
        if loose.any():
            n, comp = cv2.connectedComponents(loose.astype(np.uint8), connectivity=4)
            near_other = cv2.dilate(((label >= 0) & (label != pc)).astype(np.uint8), np.ones((3, 3), np.uint8))
            drop = np.zeros(label.shape, bool)
            for k in range(1, n):
                blob = comp == k
                if (near_other.astype(bool) & blob).any():
                    drop |= blob
            if drop.any():
                from scipy.ndimage import distance_transform_edt

                other = (out >= 0) & (out != pc)
                _, (iy, ix) = distance_transform_edt(~other, return_indices=True)
                out[drop] = out[iy[drop], ix[drop]]
    return out


def _fill_unlabelled(label: np.ndarray, m: np.ndarray) -> np.ndarray:
    from scipy.ndimage import distance_transform_edt

    miss = m & (label < 0)
    if not miss.any() or not (label >= 0).any():
        return label
    _, (iy, ix) = distance_transform_edt(label < 0, return_indices=True)
    out = label.copy()
    out[miss] = label[iy[miss], ix[miss]]
    return out


def _one_component_each(label: np.ndarray, m: np.ndarray) -> np.ndarray:
    """Every piece one 4-connected region: stray islands join the piece around them."""
    out = label.copy()
    for _ in range(3):
        changed = False
        for pc in np.unique(out[out >= 0]):
            n, comp, stats, _ = cv2.connectedComponentsWithStats((out == pc).astype(np.uint8), connectivity=4)
            if n <= 2:
                continue
            keep = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
            stray = (comp > 0) & (comp != keep)
            out[stray] = -1
            changed = True
        if not changed:
            break
        out = _fill_unlabelled_excluding(out, m)
    return out


def _fill_unlabelled_excluding(label, m):
    """Fill unlabelled mask pixels from their labelled neighbours, growing step by step."""
    out = label.copy()
    k = np.ones((3, 3), np.uint8)
    for _ in range(max(m.shape)):
        miss = m & (out < 0)
        if not miss.any():
            break
        # Grow each label by one pixel into the missing pixels (the largest label id wins ties).
        grown = cv2.dilate((out + 1).astype(np.float32), k).astype(np.int64) - 1
        fill = miss & (grown >= 0)
        if not fill.any():
            break
        out[fill] = grown[fill]
    return out


# --------------------------------------------------------------------------- tabs

def tab_region(label: np.ndarray, cut: Cut, margin: float = 0.0, band: float | None = None,
               under: np.ndarray | None = None) -> np.ndarray:
    """The child's tab under its parent ``(H, W)`` bool (module docstring).

    ``margin``: away from the cut (farther than ``band``, default a quarter
    of the cut's length, at least 3 px), the tab keeps this far (pixels) inside the
    parent's outline, so a small turn of the joint does not slide a sliver of
    it out along the parent's edge.  ``under`` ``(H, W)`` bool: pixels the
    tab may also cover (the parent's own tab: a parent segment may be drawn
    shorter than the tab).
    """
    if band is None:
        band = max(0.25 * float(np.linalg.norm(cut.p - cut.q)), 3.0)
    H, W = label.shape
    rho = max(0.5 * float(np.linalg.norm(cut.p - cut.q)), 1.0)
    m = cut.mid
    piv = cut.pivot
    reach = max(float(np.linalg.norm(cut.p - piv)), float(np.linalg.norm(cut.q - piv)))
    rho_piv = rho if float(np.linalg.norm(m - piv)) >= rho else max(rho, reach)
    lo = np.floor(np.minimum(m, piv) - max(rho, rho_piv) - 2).astype(int)
    hi = np.ceil(np.maximum(m, piv) + max(rho, rho_piv) + 2).astype(int)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [W - 1, H - 1])
    out = np.zeros((H, W), bool)
    if np.any(hi < lo):
        return out
    yy, xx = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    pts = np.stack([xx, yy], -1).astype(np.float64)
    inside = (_seg_dist(pts, m, piv) <= rho) | (np.linalg.norm(pts - piv, axis=-1) <= rho_piv)
    depth_ = (pts - m) @ cut.normal
    parent_side = depth_ <= 0.5
    parent = label[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] == cut.parent
    if under is not None:  # a parent drawn too short to hold the tab: what lies under it as well
        parent |= under[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    # Within the drawing: at rest a tab must hide entirely under the pieces drawn over it.
    grow = cv2.dilate(parent.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    inner = cv2.distanceTransform(np.pad((label >= 0).astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    grow &= inner[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] >= 2.0
    if margin > 0:
        # Inside the parent's outline by ``margin``, except in the band along the cut, where the
        # tab fills the wedge a turning joint opens.
        grow &= (inner[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] > margin) | (depth_ >= -band)
    out[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] = inside & parent_side & grow
    return out


def ink_mask(texture: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The drawing's lines ``(H, W)`` bool: mask pixels darker than the midpoint of line and fill.

    Line luminance: the 5th percentile inside the mask; fill: the median.  A
    pixel is ink when darker than their midpoint.
    """
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return m.copy()
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    line, fill = np.percentile(lum[m], 5), np.median(lum[m])
    return m & (lum < 0.5 * (line + fill))


def tab_texture(texture: np.ndarray, label: np.ndarray, child: int, tab: np.ndarray,
                ink: np.ndarray) -> np.ndarray:
    """RGBA ``(H, W, 4)`` uint8: the child's fill continued over ``tab`` (opaque there, clear elsewhere)."""
    H, W = label.shape
    out = np.zeros((H, W, 4), np.uint8)
    if not tab.any():
        return out
    ys, xs = np.nonzero(tab)
    pad = int(max(np.ptp(ys), np.ptp(xs))) + 8
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, H)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, W)
    # The limb's fill: its pixels away from any line (2 px), so no ink bleeds into the tab.
    lines = cv2.dilate(ink[y0:y1, x0:x1].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    own = (label[y0:y1, x0:x1] == child) & ~lines
    if own.sum() < 4:
        own = (label[y0:y1, x0:x1] == child) & ~ink[y0:y1, x0:x1]
    if own.sum() < 4:
        own = label[y0:y1, x0:x1] == child
    rgb = np.ascontiguousarray(texture[y0:y1, x0:x1, :3]).copy()
    if own.any():
        rgb[~own] = np.median(rgb[own], axis=0).astype(np.uint8)
        unknown = (~own).astype(np.uint8)
        rgb = cv2.inpaint(rgb, unknown, 5, cv2.INPAINT_TELEA)
    out[y0:y1, x0:x1, :3] = rgb
    out[..., 3] = np.where(tab, 255, 0)
    return out


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
    carries.  Vectorised over tabs and frames (one gather, no loop over tabs).
    """
    core = np.asarray(core, dtype=np.float64)
    kp = np.asarray(keypoints, dtype=np.float64)
    rest_kp = np.asarray(rest_kp, dtype=np.float64)
    T = core.shape[0]
    n = len(rest_vertices)
    out = np.empty((T, n, 2))
    out[:, :core.shape[1]] = core
    if not tabs:
        return out
    a = np.array([t.bone[0] for t in tabs])
    b = np.array([t.bone[1] for t in tabs])
    r = rest_kp[b] - rest_kp[a]  # (k, 2)
    d = kp[:, b] - kp[:, a]  # (T, k, 2)
    ang = np.arctan2(d[..., 1], d[..., 0]) - np.arctan2(r[:, 1], r[:, 0])
    c, s = np.cos(ang), np.sin(ang)  # (T, k)
    p0 = rest_kp[a].copy()
    pt = kp[:, a].copy()  # (T, k, 2)
    follow = [i for i, t in enumerate(tabs) if t.pivot is not None]
    if follow:  # followers turn about their own pivot, carried by the torso
        c0, ct, tc, ts = torso_pose(rest_kp, kp)
        P = np.array([tabs[i].pivot for i in follow])
        q = P - c0
        p0[follow] = P
        pt[:, follow] = ct[:, None] + np.stack([tc[:, None] * q[:, 0] - ts[:, None] * q[:, 1],
                                                 ts[:, None] * q[:, 0] + tc[:, None] * q[:, 1]], -1)
    idx = np.concatenate([t.vertices for t in tabs])
    which = np.concatenate([np.full(len(t.vertices), i) for i, t in enumerate(tabs)])
    v = rest_vertices[idx] - p0[which]  # (m, 2)
    cc, ss = c[:, which], s[:, which]  # (T, m)
    out[:, idx, 0] = cc * v[:, 0] - ss * v[:, 1] + pt[:, which, 0]
    out[:, idx, 1] = ss * v[:, 0] + cc * v[:, 1] + pt[:, which, 1]
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
    after all the pieces' (``Mesh.n_core``).  Returns a
    :class:`nnsf.reshape.mesh.Mesh`.
    """
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    all_cuts = find_cuts(m, kp)
    label = label_pieces(m, kp, all_cuts, texture=texture)
    overlay = np.zeros(m.shape, bool)
    if texture is not None:
        # Limbs drawn over the body as shapes of their own: the body goes on under them, painted in.
        geo = label_pieces(m, kp, all_cuts)
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
        region = (piece_label == pc) | (overlay if pc == 0 else False)
        # Pieces grow ``ov`` px (:data:`OVERLAP`) into each other near the cuts (where seams open as the joints
        # turn), and a pixel elsewhere into the body and the body into them: a limb drawn over the
        # body that swings away leaves at most a pixel of its drawing behind.
        one = cv2.dilate(region.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        two = cv2.dilate(region.astype(np.uint8), grow).astype(bool)
        two &= ((piece_label != 0) | near_cut) if pc != 0 else near_cut
        region = region | ((one | two) & m)
        if region.sum() >= 6:
            regions_core.append((int(pc), region))

    def triangulate_pieces(spacing):
        out = []
        for pc, region in regions_core:
            try:
                v, t, _ = meshmod._triangulate_at(region, spacing, **args)
            except (ValueError, IndexError):  # too small to triangulate (a sliver between two cuts)
                continue
            if len(t):
                out.append((pc, v, t))
        return out

    pieces_tri = triangulate_pieces(h)
    # Each piece has its own outline, so the pieces hold more vertices than one mesh of the same
    # spacing: one rescaled pass brings the solved vertices to about ``n_vertices``.
    total = sum(len(v) for _, v, _ in pieces_tri)
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
    for k, cut in enumerate(cuts):
        region = regions[cut.child]
        if region.sum() < 6:
            continue
        try:
            v, t, _ = meshmod._triangulate_at(region, max(h, 2.0), **args)
        except (ValueError, IndexError):
            continue
        if len(t) == 0:
            continue
        idx = np.arange(count, count + len(v))
        V.append(v)
        T.append(t + count)
        count += len(v)
        pc = piece_of[cut.child]
        # A whole limb's tab follows its upper bone; a segment's, its own.
        PC.append(np.full(len(t), pc))
        part = int(parts.SEGMENT_PART[cut.child])
        PT.append(np.full(len(t), part))
        layer.append(np.full(len(t), 3 + len(tabs), np.int64))
        under = int(parts.SEGMENT_PART[shown_parent(cut.parent)])
        collar.append(np.full(len(t), under))
        tabs.append(Tab(idx, _child_bone(cut.child), region, pc, part, under))
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
            if region.sum() < 6:
                continue
            try:
                v, t, _ = meshmod._triangulate_at(region, h if not is_tab else max(h, 2.0), **args)
            except (ValueError, IndexError):
                continue
            if len(t) == 0:
                continue
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
                        layer=np.concatenate(layer), collar=np.concatenate(collar).astype(np.int64))
    mesh.n_core = n_core
    mesh.tabs = tabs
    mesh.pivots = pivots
    mesh.overlay = overlay
    mesh.labels = label
    mesh.cuts = cuts
    mesh.followers = [{"name": f["name"], "side": f["side"]} for f in followers]
    return mesh


def near_cut_f(cut: Cut, m: np.ndarray, ov: int) -> np.ndarray:
    """Pixels near a cut (where its two sides overlap by ``ov`` px)."""
    img = np.zeros(m.shape, np.uint8)
    cv2.line(img, tuple(int(v) for v in np.rint(cut.p)), tuple(int(v) for v in np.rint(cut.q)), 1,
             2 * (2 * ov + 1) + 1)
    return img.astype(bool)
