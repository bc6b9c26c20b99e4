"""Which puppet piece owns each pixel of a drawn character (docs/method.md §13.1, step 2).

:func:`label_pieces`: the mask, cut open along every cut
(:mod:`nnsf.reshape.cuts`), falls apart into connected pieces; each goes to
the piece whose bones it holds.  Where a piece still touches another along
the drawing (an arm lying against the torso, legs drawn together), its
pixels are shared out by the nearest bone, a limb claiming no pixel farther
from its bone than 1.3 × its half-width, so seams are straight cuts or
smooth bisectors.  :func:`limb_regions` finds the drawn regions that belong
to one limb only.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.cuts import Cut, HEAD, J, PIECE_BONES, SEGMENT_NAMES, _dist, _lookup, _seg_dist, half_width, limb_reach
from nnsf.reshape.regions import body_region_triangles, drawn_regions
from nnsf.skeleton import LIMBS

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
    arm's root is the chest's; and beside a shoulder off the body, the body's
    colour above the neck cut's line is the body's (:func:`shoulder_fill`).
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
    _adopt_orphans(owners, comp, cuts, merged)
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
    if texture is not None:
        fill = shoulder_fill(label, kp, m, texture)
        if fill.any():  # what the head keeps of a shirt's shoulder may be a sliver now
            label = _open_big_pieces(np.where(fill, 0, label), m)
    return _one_component_each(label, m)


def _adopt_orphans(owners: np.ndarray, comp: np.ndarray, cuts: list[Cut], merged: dict) -> None:
    """A limb segment owning no component takes the unowned one beyond its cut (``owners`` updated).

    A segment votes with samples of its straight bone; a drawn stroke that curves
    away from it (AnimatedDrawings' char4: its right forearm bows 15 px off the
    elbow-to-wrist line) gets no vote, and without this its component would go to
    the nearest labelled pixel: the parent's, across the cut, so the parent would
    carry the whole limb rigidly.  The component must touch the cut's line, lie
    on the child's side of it and hold at least half a square of the cut's length.
    """
    H, W = comp.shape
    for c in cuts:
        child = merged.get(c.child, c.child)
        if child == 0 or owners[:, child].any():
            continue
        line = np.zeros((H, W), np.uint8)
        d = (c.q - c.p) / max(float(np.linalg.norm(c.q - c.p)), 1e-9)
        a, b = c.p - 3.0 * d, c.q + 3.0 * d
        cv2.line(line, tuple(int(v) for v in np.rint(a)), tuple(int(v) for v in np.rint(b)), 1, 3, cv2.LINE_8)
        touching = np.unique(comp[line.astype(bool)])
        best, best_n = -1, 0
        for ci in touching[touching > 0]:
            if owners[ci].any():
                continue
            yy, xx = np.nonzero(comp == ci)
            pts = np.column_stack([xx, yy]).astype(np.float64)
            # A limb segment, not a sliver left between two cuts (char1's hidden upper arms):
            # at least half a square of the cut's length.
            if len(pts) < 0.5 * float(np.sum((c.q - c.p) ** 2)):
                continue
            if float(np.median(c.side(pts))) > 0 and len(pts) > best_n:
                best, best_n = int(ci), len(pts)
        if best > 0:
            owners[best, child] = True


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


def shoulder_bridges(label: np.ndarray, keypoints: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The head's pixels that join an arm to the body, ``(H, W)`` bool, for the body to hold too.

    Some drawings hang an arm from the head's outline, not from the body's: a
    wide head's lower corners (the Kenney robot's shoulder pads) reach down
    past the body's top corners, and the shoulder key point lies
    farther from the body's own pixels than the upper arm's half-width (the
    arm's drawing does not reach the body).  The head turns about the neck,
    so when it does those corners leave, and the arm hangs apart from the body.
    The bridge is the head's pixels in the capsule from such a shoulder to
    the nearest body pixel, of the upper arm's half-width, that lie nearer
    to the shoulder than to the head's bone.  They stay the head's as well:
    given to the body as a layer under the head, the head keeps its outline,
    and a turned head uncovers them, not the paper.  ``label``: the pieces
    (:func:`label_pieces`), ``mask``: the drawing's solid pixels.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    lab = np.asarray(label)
    out = np.zeros(lab.shape, bool)
    hy, hx = np.nonzero(lab == HEAD)
    head = np.c_[hx, hy].astype(np.float64)
    to_head_bone = _seg_dist(head, kp[J["neck"]], kp[J["head_top"]])
    for s, b, w in _off_body_shoulders(lab, kp, mask):
        near = (_seg_dist(head, s, b) <= w) & (np.linalg.norm(head - s, axis=1) < to_head_bone)
        out[hy[near], hx[near]] = True
    return out


#: Largest step in any colour channel (0-255) between neighbouring pixels of one drawn area
#: (:func:`shoulder_fill`): flat-colour art changes by a few levels inside an area (shading,
#: anti-aliasing) and by tens across its edge.
COLOUR_STEP = 12


def _off_body_shoulders(label: np.ndarray, kp: np.ndarray, mask: np.ndarray):
    """``[(shoulder, nearest body pixel, upper arm half-width)]`` for each shoulder key point
    farther from the body's pixels than its upper arm's half-width (:func:`shoulder_bridges`)."""
    by, bx = np.nonzero(label == 0)
    if not len(by):
        return []
    body = np.c_[bx, by].astype(np.float64)
    dist = _dist(np.asarray(mask, dtype=bool))
    out = []
    for side in ("l", "r"):
        s, e = J[f"{side}_shoulder"], J[f"{side}_elbow"]
        w = half_width(dist, kp, s, e)
        d = np.linalg.norm(body - kp[s], axis=1)
        k = int(np.argmin(d))
        if d[k] > w:
            out.append((kp[s], body[k], w))
    return out


def shoulder_fill(label: np.ndarray, keypoints: np.ndarray, mask: np.ndarray, texture: np.ndarray) -> np.ndarray:
    """The head's pixels that are the body's drawing beside an off-body shoulder, ``(H, W)`` bool.

    The head takes everything on its side of the neck cut's line (:func:`label_pieces`),
    and on the Kenney women that is the shirt's shoulders: the head turned and
    carried a flap of shirt away.  Beside a shoulder that lies off the body
    (:func:`shoulder_bridges`), the head's pixels nearer that shoulder than
    the head's bone that the body's own colour area reaches (4-neighbour steps
    of at most :data:`COLOUR_STEP` in each channel, from the body's pixels)
    are the body's.  The colour area is the components of a sparse graph
    (SciPy's ``connected_components``): OpenCV's flood fill takes one seed,
    and the body's pixels are many.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    kp = np.asarray(keypoints, dtype=np.float64)
    lab = np.asarray(label)
    sides = _off_body_shoulders(lab, kp, mask)
    if not sides:
        return np.zeros(lab.shape, bool)
    yy, xx = np.mgrid[:lab.shape[0], :lab.shape[1]]
    pts = np.stack([xx, yy], -1).astype(np.float64)
    to_head = _seg_dist(pts, kp[J["neck"]], kp[J["head_top"]])
    near = np.zeros(lab.shape, bool)
    for s, _, _ in sides:
        near |= np.linalg.norm(pts - s, axis=-1) < to_head
    cand = (lab == 0) | ((lab == HEAD) & near)
    rgb = np.asarray(texture)[..., :3].astype(np.int16)
    idx = np.full(lab.shape, -1, np.int64)
    idx[cand] = np.arange(int(cand.sum()))
    rows, cols = [], []
    for a, b in ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :])):
        ok = cand[a] & cand[b] & (np.abs(rgb[a] - rgb[b]).max(axis=-1) <= COLOUR_STEP)
        rows.append(idx[a][ok])
        cols.append(idx[b][ok])
    r, c = np.concatenate(rows), np.concatenate(cols)
    n = int(cand.sum())
    _, comp = connected_components(coo_matrix((np.ones(len(r)), (r, c)), shape=(n, n)), directed=False)
    body_comps = np.unique(comp[(lab == 0)[cand]])
    reached = np.zeros(lab.shape, bool)
    reached[cand] = np.isin(comp, body_comps)
    return reached & (lab == HEAD)
