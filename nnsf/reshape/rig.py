"""A character's parts: which triangle belongs to which part, and where parts stay joined.

:class:`Rig` holds the rest key points (the 17 of :data:`nnsf.skeleton.JOINTS`, then three per
arm the skeleton has beyond the two it drives), the bones that make up each part
(:data:`nnsf.reshape.parts.PART_BONES` plus the extra arms'), each part's parent and the joint it
hangs from, and each bone's radius.

* **Labels** (:meth:`Rig.segment`): a watershed of the drawing seeded along the bones, so parts end
  at the drawing's own lines; where it leaves a pixel, the part whose band (:meth:`Rig.band_scores`)
  the pixel lies relatively deepest in.  :meth:`Rig.scores` is the signed distance to each region.
* **Joints** (:meth:`Rig.cuts`): a part and the part it hangs from are never cut apart along
  their root cross-section (within :data:`ROOT_DEPTH` child radii of the line through the joint
  across the child's bone); there the two share vertices, so the joint bends as one piece of paper
  and cannot crack.  Elsewhere a boundary is only a candidate: :mod:`nnsf.reshape.mesh` cuts it
  where one part lies over the other in the drawing, with an underlay beneath.
* **One limb drawn for two** (:func:`coincident_limbs`): a figure drawn from the side, its two arms
  given the same joints, shows one arm; the left part takes it, the right is :attr:`Rig.hidden`.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy import ndimage

from nnsf.reshape.parts import JOINS, PART_BONES, PARTS
from nnsf.skeleton import JOINT_INDEX as J, N_JOINTS

#: How far from a child's root cross-section (the line through its joint across its bone) its
#: boundary with its parent stays joined, in units of the child's radius: the cut across a limb at
#: its joint is shared whole, however wide; beyond it the boundary may be cut where the child lies
#: over its parent (a fist folded on its arm).
ROOT_DEPTH = 1.0
#: An upper limb segment is at most this many times as thick as the segment below it.
UPPER_TO_LOWER = 1.5

#: The driven arm of each side: (shoulder, elbow, wrist) key points.
ARMS = {"l": (J["l_shoulder"], J["l_elbow"], J["l_wrist"]), "r": (J["r_shoulder"], J["r_elbow"], J["r_wrist"])}


def distance_transform(mask: np.ndarray) -> np.ndarray:
    """Distance ``(H, W)`` float32 from each mask pixel to the nearest pixel outside (0 outside)."""
    return cv2.distanceTransform(np.pad(np.asarray(mask, np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]


def sample(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Nearest-pixel values of ``img`` ``(H, W)`` at points ``(..., 2)`` (outside: the nearest border pixel)."""
    pts = np.asarray(pts, dtype=np.float64)
    H, W = img.shape
    ij = np.clip(np.rint(pts.reshape(-1, 2)), 0, [W - 1, H - 1]).astype(np.int64)
    return img[ij[:, 1], ij[:, 0]].reshape(pts.shape[:-1])


def coincident_limbs(keypoints: np.ndarray, bones: np.ndarray, radius: np.ndarray) -> tuple[int, ...]:
    """The right limb's parts ``(k,)`` where a pair's two chains are drawn as one (each key point within
    half the thinner limb's radius of its twin): the left part takes the drawn limb whole, the
    right draws nothing (docs/method.md §12, a figure drawn from the side)."""
    kp = np.asarray(keypoints, dtype=np.float64)
    hidden = []
    for left, right in ((("l_upper_arm", "l_forearm"), ("r_upper_arm", "r_forearm")),
                        (("l_thigh", "l_shin"), ("r_thigh", "r_shin"))):
        ids = [[PARTS.index(n) for n in side] for side in (left, right)]
        chain = [np.unique(bones[np.isin(bones[:, 2], side), :2]) for side in ids]
        r = min(radius[np.isin(bones[:, 2], ids[0] + ids[1])])
        if len(chain[0]) == len(chain[1]) and np.linalg.norm(kp[chain[0]] - kp[chain[1]], axis=1).max() <= 0.5 * r:
            hidden += ids[1]
    return tuple(hidden)


@dataclass
class Rig:
    """The parts of one character at rest (module docstring).

    Attributes
    ----------
    keypoints : ``(K, 2)`` rest key points, pixels: the 17, then (shoulder, elbow, hand) per extra arm.
    bones : ``(B, 3)`` int64, ``(a, b, part)``: key-point segments and the part each belongs to.
    radius : ``(B,)`` bone radii, pixels.
    parts : part names; ids index it.
    parent, joint : ``(P,)`` each part's parent part and the key point it hangs from (−1 for the torso).
    extra_sides : ``"l"`` or ``"r"`` per extra arm: the driven arm it turns with.
    """

    keypoints: np.ndarray
    bones: np.ndarray
    radius: np.ndarray
    parts: tuple[str, ...]
    parent: np.ndarray
    joint: np.ndarray
    extra_sides: tuple[str, ...] = ()
    #: Parts whose seam with their parent is never cut: they move as one (a head that keeps its
    #: drawn angle to the body, ``head: torso``), so a cut would only open pinholes between them.
    fused: tuple[int, ...] = ()
    #: Parts that get no pixels: the second of two limbs drawn as one (:func:`coincident_limbs`).
    hidden: tuple[int, ...] = ()
    #: Limb segments the body is drawn over (a skirt over the thighs, YAML ``depth: [torso over left_leg]``).
    covered: tuple[int, ...] = ()
    #: ``(H, W)`` int16, the part of each drawn pixel (−1 off the drawing), :meth:`segment`.
    labels: np.ndarray | None = None

    @classmethod
    def build(cls, character) -> "Rig":
        """The rig of a :class:`~nnsf.reshape.character.Character` (its mask, key points, extra arms)."""
        kp = [np.asarray(character.keypoints, dtype=np.float64)]
        bones = [list(b) for b in PART_BONES]
        parts = list(PARTS)
        parent = [-1] + [0] * (len(PARTS) - 1)
        joint = [-1] * len(PARTS)
        for p, c, j in JOINS:
            parent[c], joint[c] = p, j
        sides = []
        for k, arm in enumerate(character.extra_limbs):
            base = N_JOINTS + 3 * k
            kp.append(np.asarray(arm["joints"], dtype=np.float64).reshape(3, 2))
            upper, fore = len(parts), len(parts) + 1
            parts += [f"{arm['side']}_extra_upper_arm_{k + 1}", f"{arm['side']}_extra_forearm_{k + 1}"]
            bones += [[base, base + 1, upper], [base + 1, base + 2, fore]]
            parent += [0, upper]
            joint += [base, base + 1]
            sides.append(arm["side"])
        kp = np.vstack(kp)
        bones = np.array(bones, dtype=np.int64)
        dist = distance_transform(character.mask)
        lam = np.linspace(0.25, 0.75, 9)[:, None, None]
        along = kp[bones[:, 0]][None] + lam * (kp[bones[:, 1]] - kp[bones[:, 0]])[None]   # (9, B, 2)
        radius = np.maximum(np.median(sample(dist, along), axis=0), 1.0)
        # An upper segment is no thicker than UPPER_TO_LOWER times the segment it carries.
        for b, (_, _, part) in enumerate(bones):
            lower = [i for i, (_, _, q) in enumerate(bones) if parent[q] == part and q != part and part != 0]
            if lower:
                radius[b] = min(radius[b], UPPER_TO_LOWER * min(radius[i] for i in lower))
        fused = (PARTS.index("head"),) if getattr(character, "head", None) == "torso" else ()
        hidden = coincident_limbs(kp, bones, radius)
        covered = tuple(sorted({p for over, under in character.depth if 0 in over for p in under if p >= 2}))
        rig = cls(kp, bones, radius.astype(np.float64), tuple(parts), np.array(parent), np.array(joint),
                  tuple(sides), fused, hidden, covered)
        rig.labels = rig.segment(character.texture, character.mask)
        return rig

    def segment(self, texture: np.ndarray, mask: np.ndarray, joints=()) -> np.ndarray:
        """The part of every drawn pixel ``(H, W)`` int16 (−1 off the drawing): a watershed of the drawing.

        Each part is seeded by its bones' middles (λ from 0.2 to 0.8, half their radius thick, thin
        bones over thick ones) and flooded over the drawing by ``cv2.watershed``, which grows regions
        through flat colour first and meets at the drawing's edges: a limb ends where its outline,
        or a change of colour, is drawn.  Where nothing is drawn between two parts they meet half
        way.  A pixel the watershed leaves on a boundary, or gives to a part whose band
        (:meth:`band_scores`) lies farther than that part's radius away, takes the band's part.
        """
        mask = np.asarray(mask, dtype=bool)
        H, W = mask.shape
        image = np.ascontiguousarray(texture[..., 2::-1])
        markers = np.zeros((H, W), np.int32)
        a, b = self.keypoints[self.bones[:, 0]], self.keypoints[self.bones[:, 1]]
        # A seed is no thicker than the lines drawn about its bone allow: a limb drawn inside the
        # body's silhouette (an arm across the chest) has the silhouette's depth as its radius, and
        # a seed that wide would flood the body.
        # Edges of each colour channel: two flat colours of one luminance (a green arm on an orange
        # shirt) have no edge in grey, and the arm's seed grew as wide as the body.
        edges = np.any([cv2.Canny(np.ascontiguousarray(texture[..., c]), 50, 150) > 0 for c in range(3)], axis=0)
        room = distance_transform(mask & ~edges)
        lam = np.linspace(0.2, 0.8, 7)[:, None, None]
        reach = np.median(sample(room, a[None] + lam * (b - a)[None]), axis=0)
        seed = np.minimum(self.radius, np.maximum(reach, 1.0))
        u = (b - a) / np.maximum(np.linalg.norm(b - a, axis=1), 1e-9)[:, None]
        # A bone that ends its limb (at the wrist, the ankle) owns its end key point and a seed's
        # width beyond: a hand drawn over the body, its outline closing it off from the forearm,
        # was flooded from the body's seeds around it, and stayed on the body when the arm moved.
        chain, shown = self.chains(), ~np.isin(self.bones[:, 2], self.hidden)
        last = np.array([j not in self.bones[self.bones[:, 2] != q, 0] and chain[q] >= 0 for _, j, q in self.bones])
        start, ends = a + 0.2 * (b - a), np.where(last[:, None], b + seed[:, None] * u, a + 0.8 * (b - a))
        # A covered limb is seeded from its end on, two radii long, half a radius thick (a foot below a skirt):
        # its flood meets the body's at the hem; the split along its bones (below) gives its segments their shares.
        under = np.isin(self.bones[:, 2], self.covered)
        start, shown = np.where((under & last)[:, None], b, start), shown & (~under | last)
        seed = np.where(under, self.radius, seed)
        ends = np.where((under & last)[:, None], b + 2 * seed[:, None] * u, ends)
        for k in [k for k in np.argsort(-seed, kind="stable") if shown[k]]:
            cv2.line(markers, tuple(np.rint(start[k] * 16).astype(int)), tuple(np.rint(ends[k] * 16).astype(int)),
                     int(self.bones[k, 2]) + 1, max(1, int(0.5 * seed[k])), cv2.LINE_8, 4)
        # A limb drawn over another part (an arm across the chest, a hand on the hip) owns the pixels
        # about its bones beyond its root: other limbs' and the body's seeds there (the spine's line
        # under the arm) are dropped.  Its last bone reaches past its end by two radii (the hand).
        hand = np.full((H, W), -1, np.int32)
        for k in np.flatnonzero((chain[self.bones[:, 2]] >= 0) & shown):
            part, tip = self.bones[k, 2], b[k] + 2.0 * seed[k] * u[k] * last[k]
            band = cv2.line(np.zeros((H, W), np.uint8), tuple(np.rint(start[k] * 16).astype(int)),
                            tuple(np.rint(tip * 16).astype(int)), 1, max(1, int(2 * seed[k])), cv2.LINE_8, 4)
            other = (markers > 0) & ((owner := chain[np.maximum(markers - 1, 0)]) != chain[part])
            markers[(band > 0) & other] = 0
            # A hand on the body is wider than its arm: the body's seeds within two widths of the
            # wrist.  And a hand is drawn in any size: the body's seeds ahead of the wrist within four
            # widths that the arm's flood takes when they are left out (the drawing joins them to the
            # hand by a weaker edge than to the rest of the body) lie on the hand too.
            if last[k]:
                cv2.circle(band, tuple(np.rint(b[k] * 16).astype(int)), int(32 * seed[k]), 1, -1, cv2.LINE_8, 4)
                markers[(band > 0) & other & (owner < 0)] = 0
                cv2.ellipse(hand, tuple(np.rint(b[k] * 16).astype(int)), (int(64 * seed[k]),) * 2,
                            np.degrees(np.arctan2(u[k, 1], u[k, 0])), -90, 90, int(chain[part]), -1, cv2.LINE_8, 4)
        doubt = (hand >= 0) & (markers > 0) & (chain[np.maximum(markers - 1, 0)] < 0)
        trial = np.where(doubt | ~mask, np.where(mask, 0, self.n_parts + 1), markers).astype(np.int32)
        cv2.watershed(image, trial)
        markers[doubt & (np.append(chain, -1)[np.clip(trial - 1, 0, self.n_parts)] == hand)] = 0
        for c in joints:    # the parent's seed at the joint a child hangs from (end of this method)
            cv2.circle(markers, tuple(np.rint(self.keypoints[self.joint[c]] * 16).astype(int)),
                       int(16 * seed[self.bones[:, 2] == c][0]), int(self.parent[c]) + 1, -1, cv2.LINE_8, 4)
        seeds = markers.copy()
        markers[~mask] = self.n_parts + 1
        cv2.watershed(image, markers)
        labels = np.where(mask, markers - 1, -1).astype(np.int16)
        # A flood that ran far outside its part's band (through a region no other seed reached) and
        # the watershed's boundary pixels take the band's part.
        near = np.zeros((self.n_parts, H, W), np.uint8)
        reach = np.maximum(2.0, self.part_radius())
        for k, ((i, _, p), r) in enumerate(zip(self.bones, self.radius)):
            n, grow = np.array([-u[k, 1], u[k, 0]]), reach[p]
            # Nothing behind the joint a limb hangs from on a limb (a forearm flooded round the elbow
            # folds on itself), but a covered limb's (seeded from its end, all its length is one flood).
            back = 0.0 if (i == self.joint[p] and self.parent[p] > 0 and not under[k]) else grow
            tip = b[k] + (grow + 2 * r * (under & last)[k]) * u[k]    # past a covered limb's seed
            box = np.array([a[k] - back * u[k] + (r + grow) * n, tip + (r + grow) * n,
                            tip - (r + grow) * n, a[k] - back * u[k] - (r + grow) * n])
            cv2.fillConvexPoly(near[p], np.rint(box * 16).astype(np.int32), 1, cv2.LINE_8, 4)
            near[p] |= (hand == chain[p]) & last[k]   # and its hand
        own = np.take_along_axis(near, np.clip(labels, 0, self.n_parts - 1)[None].astype(np.intp), 0)[0] > 0
        ys, xs = np.nonzero(mask & ~(own & (labels >= 0) & (labels < self.n_parts)))
        labels[ys, xs] = np.argmin(self.band_scores(np.column_stack([xs, ys])), axis=1)
        # A strip of a part thinner than 5 px more than 2 px from its bones (a stroke of outline the
        # flood ran along) would hang between seams, and a piece of a part cut off from its seeds
        # would move with a limb it does not touch: both are flooded again from the parts around
        # them, through the drawing only (a claw beside a leg stays with its hand).
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
        core = cv2.polylines(np.zeros((H, W), np.uint8), np.rint(self.keypoints[self.bones[:, :2]] * 16).astype(np.int32),
                             False, 1, 5, cv2.LINE_8, 4)
        loose = np.zeros((H, W), bool)
        for p in range(self.n_parts):
            region = (labels == p).astype(np.uint8)
            loose |= (region > 0) & (cv2.morphologyEx(region, cv2.MORPH_OPEN, disc) == 0) & (core == 0)
            n, comp = cv2.connectedComponents(region & ~loose.astype(np.uint8), connectivity=8)
            seeded = np.unique(comp[(seeds == p + 1) & (comp > 0)])
            if n > 2 and len(seeded):
                loose |= (comp > 0) & ~np.isin(comp, seeded)
        loose &= mask
        if loose.any() and (mask & ~loose).any():
            flood = np.where(mask & ~loose, labels + 1, np.where(mask, 0, self.n_parts + 1)).astype(np.int32)
            # The page steps into the drawing only after every step within it (colours halved, the page white).
            inside = flood.copy()
            cv2.watershed(np.where(mask[..., None], image // 2, 255).astype(np.uint8), inside)
            cv2.watershed(image, flood)
            # The watershed's boundary pixels, and drawn pixels the page's flood took, take the nearest part's;
            # where that lies across the page (a fist beside the hair), the nearest that reaches them through the drawing.
            off = (flood <= 0) | (flood > self.n_parts)
            dist, (iy, ix) = ndimage.distance_transform_edt(off, return_indices=True)
            jy, jx = ndimage.distance_transform_edt((inside <= 0) | (inside > self.n_parts), return_distances=False, return_indices=True)
            labels[mask] = (flood[iy, ix][mask] - 1).astype(np.int16)
            ys, xs = np.nonzero(mask & (dist > 1.5))   # a nearest pixel beside one is never across the page
            across = ~np.all([mask[np.rint(ys + f * (iy[ys, xs] - ys)).astype(int), np.rint(xs + f * (ix[ys, xs] - xs)).astype(int)]
                              for f in np.linspace(0, 1, int(np.ceil(dist[ys, xs].max(initial=0))) + 2)], axis=0)
            labels[ys[across], xs[across]] = inside[jy, jx][ys[across], xs[across]] - 1
        for c in {chain[p] for p in self.covered}:    # a covered limb's flood goes to its nearest segment
            mine = np.flatnonzero(chain == c)
            ys, xs = np.nonzero(np.isin(labels, mine))
            pts = np.column_stack([xs, ys]).astype(np.float64)
            labels[ys, xs] = mine[np.argmin([np.linalg.norm(pts - self.nearest_on_bones(p, pts), axis=1) for p in mine], axis=0)]
        # A limb over the joints a part's children hang from (a hand over the hips) took the part's seeds
        # there and cut the children off it: the part is seeded at the joint of each such child, once.
        lost = [c for c in np.flatnonzero(self.parent >= 0) if chain[c] not in chain[list(self.covered)] and (labels == c).any() and not (
                cv2.dilate((labels == c).astype(np.uint8), np.ones((3, 3), np.uint8)) & (labels == self.parent[c])).any()]
        return self.segment(texture, mask, lost) if lost and not len(joints) else labels

    @property
    def n_parts(self) -> int:
        return len(self.parts)

    def chains(self) -> np.ndarray:
        """Each part's limb ``(P,)``: the part that hangs from the body above it, −1 for the body and
        the head."""
        out = np.full(self.n_parts, -1, dtype=np.int64)
        for p in range(self.n_parts):
            q = p
            while q >= 0 and self.parent[q] > 0:
                q = self.parent[q]
            out[p] = q if self.parent[p] >= 0 and q != PARTS.index("head") else -1
        return out

    def covered_radius(self) -> np.ndarray:
        """``(P,)`` each covered limb segment's half-width, pixels (else 0): its bones' radius, at most the
        widest its limb is drawn where it shows (about a hidden bone the drawing's depth is the body's)."""
        out = np.zeros(self.n_parts)
        for p in self.covered:     # the limb's drawn pixels' largest distance to anything else
            shown = np.pad(np.isin(self.labels, self.covered_limb(p)), 1).astype(np.uint8)
            out[p] = min(self.part_radius()[p], cv2.distanceTransform(shown, cv2.DIST_L2, 3).max())
        return out

    def covered_limb(self, part: int) -> list[int]:
        """The covered segments of ``part``'s limb, root first."""
        return [q for q in self.covered if self.chains()[q] == self.chains()[part]]

    def continued(self, part: int, points: np.ndarray) -> np.ndarray:
        """Where the drawing shows what a covered limb segment hides at ``points`` ``(k, 2)``, pixels: the same
        offset across its bone from the limb's first cross-section that shows (2 px on from its drawn pixel
        nearest its root, but for 2 %): a leg under a skirt goes on as it is drawn below the hem."""
        mine = self.covered_limb(part)
        ys, xs = np.nonzero(np.isin(self.labels, mine))
        if not len(xs):
            return np.full(np.shape(points), -1.0)
        px = np.column_stack([xs, ys]).astype(np.float64)
        first = px[np.argsort(np.linalg.norm(px - self.keypoints[self.joint[mine[0]]], axis=1))[len(px) // 50]]
        on = [self.nearest_on_bones(q, first[None])[0] for q in mine]
        i = int(np.argmin([np.linalg.norm(first - c) for c in on]))
        (ua, ub), (va, vb) = (self.keypoints[self.bones[self.bones[:, 2] == q][0, :2]] for q in (mine[i], part))
        u, v = (ub - ua) / max(np.linalg.norm(ub - ua), 1e-9), (vb - va) / max(np.linalg.norm(vb - va), 1e-9)
        across = (np.asarray(points, np.float64) - va) @ np.array([-v[1], v[0]])     # pixels, to the bone's left
        return on[i] + 2.0 * u + across[:, None] * np.array([-u[1], u[0]])

    def part_radius(self) -> np.ndarray:
        """``(P,)`` the largest radius of each part's bones, pixels."""
        out = np.zeros(self.n_parts)
        np.maximum.at(out, self.bones[:, 2], self.radius)
        return out

    # ------------------------------------------------------------------ labels and seams

    def scores(self, points: np.ndarray) -> np.ndarray:
        """``(k, P)`` score of each point ``(k, 2)`` for each part: its signed distance (pixels) to the
        part's region of :attr:`labels`, negative inside (:meth:`band_scores` without labels)."""
        if self.labels is None:
            return self.band_scores(points)
        pts = np.asarray(points, dtype=np.float64)
        out = np.full((len(pts), self.n_parts), np.inf)
        for p in range(self.n_parts):
            region = (self.labels == p).astype(np.uint8)
            if region.any():
                inside = cv2.distanceTransform(region, cv2.DIST_L2, 3)
                outside = cv2.distanceTransform(1 - region, cv2.DIST_L2, 3)
                out[:, p] = sample(outside - inside, pts)
        return out

    def band_scores(self, points: np.ndarray) -> np.ndarray:
        """``(k, P)`` score of each point ``(k, 2)`` for each part: the lowest over the part's bones.

        A bone stands for the band of its radius along its segment, with flat ends (a rectangle).  A
        point inside it scores −depth / radius, in [−1, 0] (depth: its distance to the band's edge),
        so the thin core of a limb wins over a wide body around it; a point outside scores its
        distance to the band in pixels, so any inside beats every outside.
        """
        pts = np.asarray(points, dtype=np.float64)
        a, b = self.keypoints[self.bones[:, 0]], self.keypoints[self.bones[:, 1]]
        d = b - a
        L = np.maximum(np.linalg.norm(d, axis=1), 1e-9)
        u = d / L[:, None]
        rel = pts[:, None, :] - a[None]                                  # (k, B, 2)
        along = (rel * u[None]).sum(-1)                                  # (k, B)
        perp = np.abs(rel[..., 0] * u[None, :, 1] - rel[..., 1] * u[None, :, 0])
        over = np.maximum(np.maximum(-along, along - L[None]), 0.0)
        side = np.maximum(perp - self.radius[None], 0.0)
        depth = np.minimum(np.minimum(along, L[None] - along), self.radius[None] - perp)
        score = np.where((over > 0) | (side > 0), np.hypot(over, side), -depth / self.radius[None])
        out = np.full((len(pts), self.n_parts), np.inf)
        for p in range(self.n_parts):
            sel = self.bones[:, 2] == p
            if sel.any() and p not in self.hidden + self.covered:   # no band of a limb drawn as its twin or under the body
                out[:, p] = score[:, sel].min(axis=1)
        return out

    def nearest_on_bones(self, part: int, points: np.ndarray) -> np.ndarray:
        """The nearest point ``(k, 2)`` of ``part``'s bones (rest key-point segments) to each of ``points`` ``(k, 2)``."""
        bones = self.bones[self.bones[:, 2] == part]
        a, d = self.keypoints[bones[:, 0]], self.keypoints[bones[:, 1]] - self.keypoints[bones[:, 0]]
        t = np.clip(np.einsum("kbx,bx->kb", points[:, None] - a[None], d) / np.maximum((d * d).sum(1), 1e-12), 0, 1)
        near = a[None] + t[..., None] * d[None]                              # (k, B, 2)
        best = np.argmin(np.linalg.norm(points[:, None] - near, axis=2), axis=1)
        return near[np.arange(len(points)), best]

    def root_distance(self, points: np.ndarray, child: int, radius=None) -> np.ndarray:
        """``(k,)`` how far points ``(k, 2)`` lie from ``child``'s root cross-section, in units of its
        radius: |(x − joint) · u| / r, with u the direction of the child's bone that leaves the joint
        and r ``radius`` (pixels; default :meth:`part_radius`)."""
        j = self.joint[child]
        bone = next((b for b in self.bones if b[2] == child and b[0] == j), None)
        if bone is None:
            return np.full(len(points), np.inf)
        u = self.keypoints[bone[1]] - self.keypoints[j]
        u = u / max(float(np.linalg.norm(u)), 1e-9)
        r = self.part_radius()[child] if radius is None else radius
        return np.abs((np.asarray(points, np.float64) - self.keypoints[j]) @ u) / max(float(r), 1e-9)

    def cuts(self, midpoints: np.ndarray, p: np.ndarray, q: np.ndarray, radius=None) -> np.ndarray:
        """Which edges ``(e,)`` may be cut: edge midpoints ``(e, 2)`` between triangles of parts ``p``, ``q``.

        A part and the part it hangs from stay joined along their whole boundary across the joint:
        the edges within :data:`ROOT_DEPTH` child radii of the line through the joint across the
        child's bone (its root cross-section), and everywhere if the child is fused.  Every other
        edge between two parts is a candidate; the mesh cuts only the candidates where one part
        lies over the other (:func:`nnsf.reshape.mesh.build_mesh`).  ``radius`` ``(P,)``: each part's
        own half-width in pixels where known (> 0), else :meth:`part_radius` (the drawing's distance
        transform, which sees the silhouette, not a limb drawn inside it).
        """
        out = p != q
        for a, b in {(int(x), int(y)) for x, y in zip(p[out], q[out])}:
            child = b if self.parent[b] == a else a if self.parent[a] == b else -1
            if child < 0:
                continue
            sel = np.flatnonzero(out & (p == a) & (q == b))
            if child in self.fused:
                out[sel] = False
                continue
            r = radius[child] if radius is not None and radius[child] > 0 else None
            out[sel[self.root_distance(midpoints[sel], child, r) <= ROOT_DEPTH]] = False
        return out

    # ------------------------------------------------------------------ extra arms

    def full_keypoints(self, keypoints: np.ndarray) -> np.ndarray:
        """Key points ``(T, 17, 2)`` → ``(T, K, 2)`` with every extra arm placed.

        An extra arm's shoulder is carried by the torso (the rotation of the thorax → pelvis line
        about the thorax); each of its two bones keeps its drawn length and turns from its drawn
        direction by the angle its side's driven bone has turned from rest.
        """
        kp = np.asarray(keypoints, dtype=np.float64)
        if not self.extra_sides:
            return kp
        rest = self.keypoints
        T = len(kp)
        out = np.concatenate([kp, np.zeros((T, len(rest) - N_JOINTS, 2))], axis=1)

        def turn(v0, v):  # angle (T,) from rest vector v0 (2,) to vectors v (T, 2)
            return np.arctan2(v[:, 1], v[:, 0]) - np.arctan2(v0[1], v0[0])

        def rotate(v, ang):  # (2,) or (T, 2) by (T,)
            c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
            return np.stack([c[:, 0] * v[..., 0] - s[:, 0] * v[..., 1], s[:, 0] * v[..., 0] + c[:, 0] * v[..., 1]], -1)

        spine = turn(rest[J["pelvis"]] - rest[J["thorax"]], kp[:, J["pelvis"]] - kp[:, J["thorax"]])
        for k, side in enumerate(self.extra_sides):
            b = N_JOINTS + 3 * k
            sh, el, wr = ARMS[side]
            out[:, b] = kp[:, J["thorax"]] + rotate(rest[b] - rest[J["thorax"]], spine)
            up = turn(rest[el] - rest[sh], kp[:, el] - kp[:, sh])
            fore = turn(rest[wr] - rest[el], kp[:, wr] - kp[:, el])
            out[:, b + 1] = out[:, b] + rotate(rest[b + 1] - rest[b], up)
            out[:, b + 2] = out[:, b + 1] + rotate(rest[b + 2] - rest[b + 1], fore)
        return out
