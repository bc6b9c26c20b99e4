"""Where a drawn character is cut into puppet pieces: one straight cut per joint (docs/method.md §13.1, step 1).

:func:`find_cuts`: every joint where a child piece hangs from its parent
gets a straight cut across the drawing, from outline to outline -- at a
shoulder or hip where the limb leaves the body (the last cross-section
before one side widens into the body), at an elbow or knee through the
joint, perpendicular to the mean direction of the two bones, at the neck the
narrowest cross-section between the thorax and a little above the neck key
point (:func:`_neck_cut`).  A cross-section (:func:`cross_sections`) stops at
the outline, and where a pixel becomes nearer to another limb's bone than
to its own.  The pieces themselves are :mod:`nnsf.reshape.piece_regions`,
the tabs and the mesh :mod:`nnsf.reshape.pieces`.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from nnsf.skeleton import JOINT_INDEX, LIMBS

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
            cuts.append(_neck_cut(m, kp, dist))
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
            # As far as the drawing is thick at the joint: a drawn stroke that curves away from the
            # straight bone (AnimatedDrawings' char4: its right forearm) has a bone half-width of a
            # pixel, and a cut that short would not part the two segments.
            wj = max(w, float(_lookup(dist, centre[None])[0]))
            e = cross_sections(m, centre[None], d, 2.5 * wj + 2, own=(kp[pa], kp[b]), others=others)[0]
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
    # tip's distance to the outline, or 60 % of the segment).  Its half-width is at least the
    # upper's near the joint: measured on the bone, it sees only the near side of a limb whose
    # key points run off its middle, and char1's left leg then lost the outline beside its knee,
    # so the run stopped there and the hip cut fell on the knee cut.
    blob = max(0.6 * L_low, 2.5 * float(_lookup(dist, tip[None])[0]) + 2.0)
    low = (who == lower) & ((d <= limb_reach(max(w_low, w), L_low)) | (np.linalg.norm(contour - tip, axis=1) <= blob))
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


def _neck_cut(m: np.ndarray, kp: np.ndarray, dist: np.ndarray) -> Cut:
    """The neck: the narrowest cross-section from the thorax to a little above the neck key
    point, when clearly narrower than the head, else the cross-section through the neck key point."""
    th, nk, top = kp[J["thorax"]], kp[J["neck"]], kp[J["head_top"]]
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
