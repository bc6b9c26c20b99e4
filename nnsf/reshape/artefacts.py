"""What a viewer sees in a rendered frame: holes, tears, outline breaks, spikes, limb widths.

Every measure works on one rendered frame, in pixels, from the renderer's
output: the coverage ``(H, W)`` bool (alpha ≥ 128), the visible part of each
pixel ``(H, W)`` int (−1 = background; from the triangle-id image of
:meth:`nnsf.reshape.render.MeshRenderer.maps`) and the RGB image.

* :func:`holes` — background pixels enclosed by the character: connected
  components (4-connected) of non-character pixels that do not touch the
  image border; their pixel count and how many are larger than 4 px².
* :func:`tears` — background pixels within ``radius`` (3 px) of where two
  parts joined in the drawing meet (:data:`ADJACENT`), *and* between them:
  the nearest pixels of the two parts lie on opposite sides (the angle at the
  pixel between the two is more than 120°), *and* in a narrow gap: inside
  the morphological closing of the drawn pixels by a disc of ``radius``.
  The last two leave out the inside corner of a bent elbow or an armpit
  (there both parts lie on the same side) and the pixel nicks of an open
  corner where two parts meet on the outline, which are drawing, not tears;
  a crack between two parts has them on opposite sides, a few pixels apart.
* :func:`detached` — drawn components apart from the largest (3 px² or
  more): bits of the character floating free of it.
* :func:`outline_continuity` — the share of the outer outline's pixels with
  ink within 2 px (ink: darker than 0.55 × the rest drawing's median
  luminance, the rule of :func:`nnsf.reshape.mesh.ink_pixels`); compare it
  with the rest pose's share.
* :func:`outline_turning` / :func:`count_spikes` — the turning angle of the
  outer outline over ±``step`` px of arc; a spike is a run of outline points
  turning more than a threshold taken from the rest pose's outline (its
  99.5th percentile): sharper than nearly anything the artist drew.
* :func:`limb_widths` — the width of each limb's own coverage (its triangles
  rasterised alone, so a limb behind the torso is still measured) across the
  bone at :data:`STATIONS` along each segment; :func:`width_profile_stats`
  compares them with the rest pose's (relative change, its magnitude, the
  profile's roughness along the limb and its frame-to-frame jitter).

Hand-written where no library call does it: component statistics, distance
transforms and contours are OpenCV's / SciPy's; what is counted is ours.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from nnsf.reshape.parts import PARTS, PART_INDEX
from nnsf.skeleton import JOINT_INDEX, LIMBS

#: Part pairs joined in the drawing (parent, child): where a tear can open.
ADJACENT: tuple[tuple[int, int], ...] = tuple((PART_INDEX[a], PART_INDEX[b]) for a, b in (
    ("torso", "head"), ("torso", "l_upper_arm"), ("torso", "r_upper_arm"), ("torso", "l_thigh"),
    ("torso", "r_thigh"), ("l_upper_arm", "l_forearm"), ("r_upper_arm", "r_forearm"),
    ("l_thigh", "l_shin"), ("r_thigh", "r_shin")))
#: Fractions along each limb segment where its width is measured.
STATIONS = np.array([0.2, 0.35, 0.5, 0.65, 0.8])
#: The four limbs as (upper part, lower part) and their key points (root, joint, end).
LIMB_CHAINS: tuple[tuple[str, tuple[int, int], tuple[int, int, int]], ...] = tuple(
    (side, (PART_INDEX[f"{side}_upper_arm" if k == "arm" else f"{side}_thigh"],
            PART_INDEX[f"{side}_forearm" if k == "arm" else f"{side}_shin"]),
     tuple(JOINT_INDEX[j] for j in ((f"{side}_shoulder", f"{side}_elbow", f"{side}_wrist") if k == "arm"
                                    else (f"{side}_hip", f"{side}_knee", f"{side}_ankle"))))
    for k in ("arm", "leg") for side in ("l", "r"))
LIMB_NAMES = tuple(f"{'left' if s == 'l' else 'right'}_{'arm' if 'forearm' in PARTS[p[1]] else 'leg'}"
                   for s, p, _ in LIMB_CHAINS)
assert len(LIMBS) == 8


# --------------------------------------------------------------------------- holes and tears

def detached(coverage: np.ndarray, min_area: int = 3) -> int:
    """Drawn components (8-connected) of ``coverage`` ``(H, W)`` bool apart from the largest, of at
    least ``min_area`` px: bits floating free of the character (a sealed sliver in a gap)."""
    _, _, st, _ = cv2.connectedComponentsWithStats(np.asarray(coverage, np.uint8), connectivity=8)
    return int((np.sort(st[1:, cv2.CC_STAT_AREA])[::-1][1:] >= min_area).sum())


def holes(coverage: np.ndarray, min_area: int = 4) -> tuple[int, int]:
    """Background pixels enclosed by the character, and how many enclosed components exceed ``min_area`` px².

    ``coverage`` ``(H, W)`` bool.  A background component (4-connected) that
    touches the image border is the outside, not a hole.
    """
    bg = (~np.asarray(coverage, dtype=bool)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bg, connectivity=4)
    if n <= 1:
        return 0, 0
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    inner = np.setdiff1d(np.arange(1, n), border)
    areas = stats[inner, cv2.CC_STAT_AREA]
    return int(areas.sum()), int((areas > min_area).sum())


#: Every pair of parts joined in the skeleton, both orders (for :func:`hole_kinds`).
_JOINED = frozenset(ADJACENT) | frozenset((b, a) for a, b in ADJACENT)


def hole_borders(coverage: np.ndarray, labels: np.ndarray, min_area: int = 4):
    """Each enclosed hole larger than ``min_area`` px²: ``(area, parts, contacts)``.

    ``parts``: the set of parts on its rim (the drawn pixels 8-adjacent to
    it); ``contacts``: the set of unordered part pairs ``(a, b)`` that touch
    each other *on* the rim (two 8-neighbouring rim pixels of different
    parts), where the loop around the hole passes from one part to the next.
    Drawn pixels without a part (``labels < 0`` inside ``coverage``: filled
    by the seal) take the nearest part's label.
    """
    cov = np.asarray(coverage, dtype=bool)
    lab = np.asarray(labels)
    bg = (~cov).astype(np.uint8)
    n, comp, stats, _ = cv2.connectedComponentsWithStats(bg, connectivity=4)
    if n <= 1:
        return []
    border = np.unique(np.concatenate([comp[0], comp[-1], comp[:, 0], comp[:, -1]]))
    outside = set(border.tolist())
    inner = [i for i in range(1, n) if i not in outside and stats[i, cv2.CC_STAT_AREA] > min_area]
    if not inner:
        return []
    part = np.where(cov, lab, -1)
    orphan = cov & (part < 0)
    if orphan.any() and (part >= 0).any():  # nearest labelled pixel (SciPy's exact EDT with indices)
        _, (iy, ix) = ndimage.distance_transform_edt(part < 0, return_indices=True)
        part = np.where(orphan, part[iy, ix], part)
    H, W = cov.shape
    out = []
    for i in inner:
        x, y, w, h = stats[i, :4]
        y0, y1, x0, x1 = max(y - 2, 0), min(y + h + 2, H), max(x - 2, 0), min(x + w + 2, W)
        hole = (comp[y0:y1, x0:x1] == i).astype(np.uint8)
        rim = cv2.dilate(hole, np.ones((3, 3), np.uint8)).astype(bool) & ~hole.astype(bool)
        p = np.where(rim, part[y0:y1, x0:x1], -1)
        parts = set(np.unique(p[p >= 0]).tolist())
        contacts = set()
        for dy, dx in ((0, 1), (1, 0), (1, 1), (1, -1)):  # every 8-neighbour pair once
            hh, ww = p.shape
            a = p[:hh - dy, max(-dx, 0):ww - max(dx, 0)]
            b = p[dy:, max(dx, 0):ww - max(-dx, 0)]
            m = (a >= 0) & (b >= 0) & (a != b)
            contacts |= {(min(u, v), max(u, v)) for u, v in set(zip(a[m].tolist(), b[m].tolist()))}
        out.append((int(stats[i, cv2.CC_STAT_AREA]), parts, contacts))
    return out


def hole_kinds(coverage: np.ndarray, labels: np.ndarray, min_area: int = 4) -> tuple[int, int]:
    """Holes larger than ``min_area`` px² as ``(seam, pose)`` counts (:func:`hole_borders`).

    A **pose** hole is background the pose encloses: somewhere on its rim
    two parts *not* joined in the skeleton (:data:`ADJACENT`) touch (a hand
    against the chest or the face, two crossing shins), so the loop around
    it closes through a contact the drawing does not have.  Every other hole
    is a **seam** hole (a defect): inside one part, or on a rim whose parts
    meet only where the skeleton joins them (a crack between head and
    torso, a hole at a shoulder).
    """
    seam = pose = 0
    for _, parts, contacts in hole_borders(coverage, labels, min_area):
        if any(c not in _JOINED for c in contacts):
            pose += 1
        else:
            seam += 1
    return seam, pose


def joint_gaps(coverage: np.ndarray, centres: np.ndarray, radii: np.ndarray, per_joint: bool = False):
    """Pixels of the joint discs ``(k,)`` (centre ``(k, 2)`` px, radius ``(k,)`` px) not drawn.

    ``per_joint``: also each disc's own undrawn pixels ``(k,)`` int (discs
    that overlap count their common pixels in each), as ``(total, each)``.

    A drawn joint is solid around its pivot: at rest the disc of each joint
    (shoulders, elbows, hips, knees, neck) of radius 0.8 × the drawing's
    half-width there lies inside the silhouette, and a notch or crack where
    two parts meet shows as undrawn pixels in it, whatever caused it.
    """
    cov = np.asarray(coverage, dtype=bool)
    H, W = cov.shape
    gap = np.zeros((H, W), np.uint8)
    each = np.zeros(len(np.asarray(radii)), np.int64)
    for j, ((x, y), r) in enumerate(zip(np.asarray(centres, dtype=np.float64), np.asarray(radii, dtype=np.float64))):
        if r < 0.5 or not (np.isfinite(x) and np.isfinite(y)):
            continue
        if per_joint:
            one = np.zeros((H, W), np.uint8)
            cv2.circle(one, (int(round(x * 8)), int(round(y * 8))), int(round(r * 8)), 1, -1, cv2.LINE_8, 3)
            each[j] = int((one.astype(bool) & ~cov).sum())
            gap |= one
        else:
            cv2.circle(gap, (int(round(x * 8)), int(round(y * 8))), int(round(r * 8)), 1, -1, cv2.LINE_8, 3)
    total = int((gap.astype(bool) & ~cov).sum())
    return (total, each) if per_joint else total


#: Joints whose discs :func:`joint_gaps` checks: where two parts turn against each other.
JOINTS_CHECKED = tuple(JOINT_INDEX[j] for j in ("l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_hip", "r_hip",
                                                 "l_knee", "r_knee", "neck"))


def joint_radii(mask: np.ndarray, rest_keypoints: np.ndarray, share: float = 0.8) -> np.ndarray:
    """Radius (px) of each joint's disc, :data:`JOINTS_CHECKED` order: ``share`` × the drawing's
    distance to its outline at the joint (the disc lies inside the drawing at rest)."""
    m = np.asarray(mask, dtype=np.uint8)
    dist = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    kp = np.asarray(rest_keypoints, dtype=np.float64)[list(JOINTS_CHECKED)]
    H, W = m.shape
    ij = np.clip(np.rint(kp).astype(int), 0, [W - 1, H - 1])
    return share * dist[ij[:, 1], ij[:, 0]]


def two_parts_near(labels: np.ndarray, reach: int) -> np.ndarray:
    """Pixels ``(H, W)`` bool with two different parts within ``reach`` px (Chebyshev), from labels (−1 empty).

    Grey-level max and min filters of the label image (empty pixels left out
    of each): they differ where the window holds two parts.
    """
    lab = np.asarray(labels).astype(np.int16)  # OpenCV's morphology takes 16-bit, not 32-bit, integers
    k = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    big = 1 << 14
    hi = cv2.dilate(lab, k, borderType=cv2.BORDER_CONSTANT, borderValue=-1)
    lo = cv2.erode(np.where(lab < 0, big, lab).astype(np.int16), k, borderType=cv2.BORDER_CONSTANT,
                   borderValue=big)
    return (hi >= 0) & (lo < big) & (hi != lo)


def _part_edges(lab: np.ndarray) -> dict[int, np.ndarray]:
    """(row, col) of each part's pixels with a 4-neighbour of another label, ``{part: (k, 2)}``."""
    e = np.zeros(lab.shape, bool)
    e[:-1] |= lab[:-1] != lab[1:]
    e[1:] |= lab[1:] != lab[:-1]
    e[:, :-1] |= lab[:, :-1] != lab[:, 1:]
    e[:, 1:] |= lab[:, 1:] != lab[:, :-1]
    e &= lab >= 0
    yx = np.argwhere(e)
    v = lab[yx[:, 0], yx[:, 1]]
    return {int(p): yx[v == p] for p in np.unique(v)}


def tear_pixels(labels: np.ndarray, radius: float = 3.0, pairs=ADJACENT, min_angle: float = 120.0,
                background=None, by_pair: bool = False):
    """Tear pixels ``(H, W)`` bool from a visible-part image ``(H, W)`` int (−1 background); module docstring.

    ``by_pair``: also the tear pixels of each pair of ``pairs`` ``(len(pairs),)``
    int, as ``(pixels, counts)`` (a pixel between three parts counts for each pair).

    ``background`` ``(H, W)`` bool: what counts as background (default
    ``labels < 0``).  Candidates come from :func:`two_parts_near`; the
    distances and directions to each part are exact (k-d trees of the
    parts' edge pixels).
    """
    from scipy.spatial import cKDTree

    lab = np.asarray(labels)
    bg = lab < 0 if background is None else np.asarray(background, dtype=bool)
    out = np.zeros(lab.shape, bool)
    counts = np.zeros(len(pairs), np.int64)
    cand = bg & two_parts_near(lab, int(np.ceil(radius)))
    if cand.any():
        # Narrow gaps only: inside the closing of the drawn pixels by a disc of ``radius``.
        # An open (obtuse) corner between two parts is outline, not a gap, even
        # where pixel rounding puts its nearest points on opposite sides.
        k = 2 * int(np.ceil(radius)) + 1
        closed = cv2.morphologyEx((~bg).astype(np.uint8), cv2.MORPH_CLOSE,
                                  cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
        cand &= closed
    if not cand.any():
        return (out, counts) if by_pair else out
    yx = np.argwhere(cand)
    edges = _part_edges(lab)
    trees = {}
    cos_max = np.cos(np.radians(min_angle))
    for i, (a, b) in enumerate(pairs):
        if a not in edges or b not in edges:
            continue
        vs = []
        for p in (a, b):
            if p not in trees:
                trees[p] = cKDTree(edges[p])
            d, k = trees[p].query(yx, distance_upper_bound=radius + 1e-9)
            ok = np.isfinite(d)
            v = np.zeros((len(yx), 2))
            v[ok] = edges[p][k[ok]] - yx[ok]
            vs.append((ok, v))
        (oka, va), (okb, vb) = vs
        both = oka & okb
        if not both.any():
            continue
        cos = (va[both] * vb[both]).sum(1) / np.maximum(
            np.linalg.norm(va[both], axis=1) * np.linalg.norm(vb[both], axis=1), 1e-9)
        hit = yx[both][cos < cos_max]
        out[hit[:, 0], hit[:, 1]] = True
        counts[i] = len(hit)
    return (out, counts) if by_pair else out


def tears(labels: np.ndarray, radius: float = 3.0, background=None) -> int:
    """Number of tear pixels (:func:`tear_pixels`)."""
    return int(tear_pixels(labels, radius, background=background).sum())


# --------------------------------------------------------------------------- outline

def ink_threshold(texture: np.ndarray, mask: np.ndarray) -> float:
    """Luminance (0-255) below which a pixel is ink: Otsu's threshold (``cv2.threshold``) of the
    luminance in the band along the drawing's outline (up to 4 % of its height deep), where the
    outline's line and the fill next to it are the two classes.  (The renderer's own outline
    estimate, ``nnsf.reshape.render.outline_style``, is not used: a measure does not borrow the
    method's features.)"""
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return 0.0
    ys = np.flatnonzero(m.any(axis=1))
    inner = cv2.distanceTransform(np.pad(m.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    band = m & (inner <= max(0.04 * (ys[-1] - ys[0] + 1), 3.0))
    vals = np.clip(np.rint(lum[band]), 0, 255).astype(np.uint8).reshape(-1, 1)
    thr, _ = cv2.threshold(vals, 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
    return float(thr)


def outline_reach(mask: np.ndarray) -> int:
    """How near the edge (px) an outline's ink may be: 1 % of the drawing's height, at least 2
    (scanned drawings keep a few pixels of paper around the line)."""
    ys = np.flatnonzero(np.asarray(mask, dtype=bool).any(axis=1))
    return max(int(round(0.01 * (ys[-1] - ys[0] + 1))), 2) if len(ys) else 2


def outline_continuity(coverage: np.ndarray, rgb: np.ndarray, threshold: float, reach: int = 2) -> float:
    """Share of the outer outline's pixels with ink (luminance < ``threshold``) within ``reach`` px; NaN if empty."""
    cov = np.asarray(coverage, dtype=bool)
    if not cov.any():
        return float("nan")
    cs, _ = cv2.findContours(cov.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    edge = np.zeros(cov.shape, np.uint8)
    cv2.drawContours(edge, cs, -1, 1, 1)  # the outer outline only
    edge = edge.astype(bool)
    lum = np.asarray(rgb)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    ink = (lum < threshold) & cov
    k = 2 * reach + 1
    near = cv2.dilate(ink.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))).astype(bool)
    return float(near[edge].mean())


def outline_turning(coverage: np.ndarray, step: float = 4.0) -> np.ndarray:
    """Turning angle (degrees, 0..180) at points every pixel of arc along the largest outer outline.

    The angle between the chords to the points ``step`` px of arc before and
    after; empty when there is no outline.
    """
    cov = np.asarray(coverage, dtype=np.uint8)
    cs, _ = cv2.findContours(cov, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not cs:
        return np.zeros(0)
    c = max(cs, key=cv2.contourArea)[:, 0, :].astype(np.float64)
    if len(c) < 8:
        return np.zeros(0)
    closed = np.vstack([c, c[:1]])
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(closed, axis=0), axis=1))])
    n = max(int(s[-1]), 8)
    t = np.arange(n) * (s[-1] / n)
    p = np.column_stack([np.interp(t, s, closed[:, 0]), np.interp(t, s, closed[:, 1])])
    k = max(int(round(step)), 1)
    u = p - np.roll(p, k, axis=0)
    v = np.roll(p, -k, axis=0) - p
    cos = (u * v).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-9)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def count_spikes(turning: np.ndarray, threshold: float) -> int:
    """Runs of consecutive outline points (cyclic) turning more than ``threshold`` degrees."""
    over = np.asarray(turning) > threshold
    if not over.any():
        return 0
    if over.all():
        return 1
    return int((over & ~np.roll(over, 1)).sum())


def spike_threshold(rest_turning: np.ndarray, q: float = 99.5, floor: float = 60.0) -> float:
    """Outlier threshold: the rest outline's ``q``-th percentile of turning, at least ``floor`` degrees."""
    return float(max(np.percentile(rest_turning, q), floor)) if len(rest_turning) else floor


# --------------------------------------------------------------------------- limb widths

def _segment_widths(mask: np.ndarray, p: np.ndarray, q: np.ndarray, reach: float) -> np.ndarray:
    """Width (px) of ``mask`` across the segment p→q at :data:`STATIONS`: the run through each station."""
    d = q - p
    L = float(np.linalg.norm(d))
    if L < 1e-6:
        return np.full(len(STATIONS), np.nan)
    n = np.array([-d[1], d[0]]) / L
    steps = np.arange(0.0, reach, 0.5)
    H, W = mask.shape
    out = np.empty(len(STATIONS))
    for k, f in enumerate(STATIONS):
        c = p + f * d
        ext = []
        for sgn in (1.0, -1.0):
            pts = np.rint(c + sgn * steps[:, None] * n).astype(int)
            ok = (pts[:, 0] >= 0) & (pts[:, 0] < W) & (pts[:, 1] >= 0) & (pts[:, 1] < H)
            inside = np.zeros(len(pts), bool)
            inside[ok] = mask[pts[ok, 1], pts[ok, 0]]
            ext.append(steps[np.argmin(inside)] if not inside.all() else steps[-1])
        out[k] = ext[0] + ext[1] if mask[int(np.clip(round(c[1]), 0, H - 1)), int(np.clip(round(c[0]), 0, W - 1))] \
            else np.nan
    return out


def limb_widths(vertices: np.ndarray, triangles: np.ndarray, parts: np.ndarray, keypoints: np.ndarray,
                shape: tuple[int, int], reach: float | None = None) -> np.ndarray:
    """Widths ``(4, 2 × len(STATIONS))`` px of the four limbs (:data:`LIMB_CHAINS`), NaN where unmeasurable.

    Each limb's triangles (both segments, with their joint caps) are
    rasterised alone at the frame's vertices ``(n, 2)``; the width is taken
    across each bone of ``keypoints`` ``(17, 2)`` (same pixel frame).
    """
    V = np.asarray(vertices, dtype=np.float64)
    kp = np.asarray(keypoints, dtype=np.float64)
    H, W = shape
    reach = reach if reach is not None else 0.25 * max(H, W)
    out = np.full((len(LIMB_CHAINS), 2 * len(STATIONS)), np.nan)
    for i, (_, (pu, pl), (j0, j1, j2)) in enumerate(LIMB_CHAINS):
        for seg, (part, ja, jb) in enumerate(((pu, j0, j1), (pl, j1, j2))):
            # Each segment alone: a folded limb's other segment would widen the cross-section.
            tri = np.asarray(triangles)[np.asarray(parts) == part]
            if not len(tri):
                continue
            pts = V[tri]
            lo = np.floor(np.minimum(pts.reshape(-1, 2).min(0), kp[[ja, jb]].min(0))) - 2
            hi = np.ceil(np.maximum(pts.reshape(-1, 2).max(0), kp[[ja, jb]].max(0))) + 2
            w, h = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
            if w <= 0 or h <= 0 or w * h > 4 * H * W:
                continue
            m = np.zeros((h, w), np.uint8)
            # One triangle at a time: cv2.fillPoly of a list fills overlaps (joint caps) even-odd, as holes.
            for tri_px in np.rint(pts - lo).astype(np.int32):
                cv2.fillConvexPoly(m, tri_px, 1)
            s = len(STATIONS)
            out[i, seg * s:(seg + 1) * s] = _segment_widths(m.astype(bool), kp[ja] - lo, kp[jb] - lo, reach)
    return out


def width_profile_stats(widths: np.ndarray, rest: np.ndarray) -> dict[str, float]:
    """Limb width profile against the rest pose, from widths ``(T, 4, s)`` and rest ``(4, s)`` px.

    * ``width_change``: mean of w/w₀ − 1 (negative: limbs drawn thinner);
    * ``width_error``: mean |w/w₀ − 1| (how far the width profile moves);
    * ``width_roughness``: mean |second difference of w along each segment|
      over the rest profile's mean width, minus the rest profile's own
      (positive: bumpier than drawn; the "smoothness" of the paper's Fig. 8);
    * ``width_jitter``: mean |w_t − w_{t−1}| / w₀ over consecutive measured frames.
    """
    w = np.asarray(widths, dtype=np.float64)
    r = np.asarray(rest, dtype=np.float64)
    ok = np.isfinite(r) & (r > 0.5)
    rel = np.where(ok, w / np.where(ok, r, 1.0), np.nan)
    s = len(STATIONS)

    def rough(x):  # x (..., 4, 2s): per segment second differences
        segs = [x[..., :s], x[..., s:]]
        return np.concatenate([np.abs(np.diff(g, 2, axis=-1)) for g in segs], axis=-1)

    scale = np.nanmean(np.where(ok, r, np.nan))
    rough_t = float(np.nanmean(rough(w))) / scale if np.isfinite(scale) else float("nan")
    rough_0 = float(np.nanmean(rough(r))) / scale if np.isfinite(scale) else float("nan")
    jit = np.abs(np.diff(w, axis=0)) / np.where(ok, r, np.nan) if len(w) > 1 else np.full((1,) + r.shape, np.nan)
    with np.errstate(all="ignore"):
        return {"width_change": float(np.nanmean(rel - 1)),
                "width_error": float(np.nanmean(np.abs(rel - 1))),
                "width_roughness": rough_t - rough_0,
                "width_jitter": float(np.nanmean(jit))}


# --------------------------------------------------------------------------- one clip

def part_image(triangle_ids: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Visible part per pixel ``(H, W)`` int (−1 background) from a triangle-id image."""
    ids = np.asarray(triangle_ids)
    out = np.full(ids.shape, -1, np.int64)
    on = ids >= 0
    out[on] = np.asarray(parts)[ids[on]]
    return out


def frame_tears(rgba: np.ndarray, labels: np.ndarray, by_pair: bool = False):
    """:func:`tear_pixels` of a frame, RGBA ``(H, W, 4)``, labels ``(H, W)``: seal-filled pixels are ink, not page."""
    cov = rgba[..., 3] >= 128
    return tear_pixels(np.where(cov, np.where(labels >= 0, labels, len(PARTS)), -1), background=~cov, by_pair=by_pair)


def frame_artefacts(rgba: np.ndarray, labels: np.ndarray, ink_thr: float, spike_thr: float,
                    joints=None, reach: int = 2) -> dict[str, float]:
    """Holes, tears, outline continuity, spikes and joint gaps of one rendered frame.

    RGBA ``(H, W, 4)``, labels ``(H, W)``; ``joints``: ``(centres (k, 2),
    radii (k,))`` for :func:`joint_gaps`; ``reach``: :func:`outline_continuity`'s.
    """
    cov = rgba[..., 3] >= 128
    hp, hn = holes(cov)
    seam, pose = hole_kinds(cov, np.where(cov, labels, -1))
    tp, pair_tears = frame_tears(rgba, labels, by_pair=True)
    out = {"hole_px": hp, "holes_gt4": hn, "seam_holes": seam, "pose_holes": pose,
           "tear_px": int(tp.sum()), "tear_pairs": pair_tears,
           "outline_ink": outline_continuity(cov, rgba[..., :3], ink_thr, reach),
           "spikes": count_spikes(outline_turning(cov), spike_thr), "detached": detached(cov)}
    if joints is not None:
        out["joint_gap_px"], out["joint_gap_each"] = joint_gaps(cov, *joints, per_joint=True)
    return out


def clip_artefacts(renderer, frames: np.ndarray, orders: np.ndarray, keypoints: np.ndarray,
                   rest_vertices: np.ndarray, rest_keypoints: np.ndarray, texture, mask,
                   every: int = 1, offset=None) -> dict[str, float]:
    """Artefact columns of one animation: means over every ``every``-th frame, against the rest pose.

    ``renderer``: a :class:`~nnsf.reshape.render.MeshRenderer` of the mesh;
    ``frames`` ``(T, n, 2)`` and ``keypoints`` ``(T, 17, 2)`` in the
    character's pixels (``offset`` ``(2,)`` is added for drawing on the
    renderer's canvas).  Columns: ``hole_px`` (mean per frame),
    ``holes_gt4`` (total over the measured frames), ``holes_gt4_rest`` (in
    the drawing's mask), ``extra_holes`` (total of each frame's holes beyond
    the drawing's: holes the artist did not draw), split into ``seam_holes``
    (defects) and ``pose_holes`` (background the pose encloses;
    :func:`hole_kinds`: per frame, the seam holes beyond the drawing's own
    seam-kind holes, at most that frame's extra holes; the rest of its extra
    holes are pose holes), ``frames_with_seam_holes``, ``frames_with_holes``,
    ``tear_px`` (mean), ``tear_px_max``, ``outline_ink`` and
    ``outline_ink_rest``, ``spikes`` (mean per frame) and ``spikes_rest``,
    the :func:`width_profile_stats`, ``joint_gap_px`` (mean), ``joint_gap_max``
    and ``joint_gap_rest`` (:func:`joint_gaps`, around the frame's key points),
    ``frames_with_joint_gaps`` (more than 4 px), ``frames_with_tears``;
    ``tear_beyond_rest`` (mean) and ``_max``: per frame, the tear pixels of
    each joined pair beyond that pair's in the rest pose, summed over the
    pairs; ``joint_gap_beyond_rest`` (mean), ``_max`` and
    ``frames_with_joint_gaps_beyond_rest`` (more than 4 px): likewise joint
    by joint (what the undeformed rig already shows is the drawing's);
    ``detached`` (:func:`detached`, total) and ``frames_with_detached``; and
    ``artefact_frames`` (how many frames were measured).  Key points are the
    ones that drove the mesh (``rig.drive``), in the same sense as
    ``rest_keypoints``.
    """
    off = np.zeros(2) if offset is None else np.asarray(offset, dtype=np.float64)
    thr = ink_threshold(texture, mask)
    reach = outline_reach(mask)
    parts = renderer.parts
    radii = joint_radii(mask, rest_keypoints)

    def draw(V, order):
        return renderer.render_labelled(V + off, order, labels=True)

    def joints_at(kp):
        return (np.asarray(kp, dtype=np.float64)[list(JOINTS_CHECKED)] + off, radii)

    rest_rgba, rest_lab = draw(np.asarray(rest_vertices, dtype=np.float64), orders[0])
    rest_cov = rest_rgba[..., 3] >= 128
    spike_thr = spike_threshold(outline_turning(rest_cov))
    rest_frame = frame_artefacts(rest_rgba, rest_lab, thr, spike_thr, joints_at(rest_keypoints), reach)
    shape = renderer.size
    rest_w = limb_widths(np.asarray(rest_vertices) + off, renderer.triangles, parts, np.asarray(rest_keypoints) + off,
                         shape)
    pick = np.arange(0, len(frames), max(int(every), 1))
    rows, widths = [], []
    for t in pick:
        rgba, lab = draw(frames[t], orders[t])
        rows.append(frame_artefacts(rgba, lab, thr, spike_thr, joints_at(keypoints[t]), reach))
        widths.append(limb_widths(frames[t] + off, renderer.triangles, parts, keypoints[t] + off, shape))
    hole = np.array([r["hole_px"] for r in rows], float)
    drawn_holes = holes(np.asarray(mask, dtype=bool))[1]  # the drawing's own (the robot's arm gaps)
    # Of the drawing's own holes, how many are seam-kind at rest (the robot's: between arm and body).
    drawn_seam = min(rest_frame["seam_holes"], drawn_holes)
    extra = [max(r["holes_gt4"] - drawn_holes, 0) for r in rows]
    tear_more = [int(np.maximum(r["tear_pairs"] - rest_frame["tear_pairs"], 0).sum()) for r in rows]
    gap_more = [int(np.maximum(r["joint_gap_each"] - rest_frame["joint_gap_each"], 0).sum()) for r in rows]
    seam = [min(max(r["seam_holes"] - drawn_seam, 0), e) for r, e in zip(rows, extra)]
    out = {"hole_px": float(hole.mean()), "holes_gt4": int(sum(r["holes_gt4"] for r in rows)),
           "holes_gt4_rest": drawn_holes,
           # holes the drawing does not have: per frame, beyond the drawing's own count
           "extra_holes": int(sum(extra)),
           # ... split: seam holes (defects) and pose holes (background the pose encloses)
           "seam_holes": int(sum(seam)), "pose_holes": int(sum(extra) - sum(seam)),
           "frames_with_seam_holes": int(sum(s_ > 0 for s_ in seam)),
           "frames_with_holes": int(sum(r["holes_gt4"] > 0 for r in rows)),
           "tear_px": float(np.mean([r["tear_px"] for r in rows])),
           "tear_px_max": int(max(r["tear_px"] for r in rows)),
           "tear_px_rest": int(rest_frame["tear_px"]),
           "outline_ink": float(np.nanmean([r["outline_ink"] for r in rows])),
           "outline_ink_rest": float(rest_frame["outline_ink"]),
           "spikes": float(np.mean([r["spikes"] for r in rows])),
           "spikes_rest": int(rest_frame["spikes"]),
           "joint_gap_px": float(np.mean([r["joint_gap_px"] for r in rows])),
           "joint_gap_max": int(max(r["joint_gap_px"] for r in rows)),
           "joint_gap_rest": int(rest_frame["joint_gap_px"]),
           "frames_with_joint_gaps": int(sum(r["joint_gap_px"] > 4 for r in rows)),
           # beyond the rest pose's, pair by pair and joint by joint (what the undeformed rig shows
           # already, a sprite's drawn gap between arm and body, is the drawing)
           "tear_beyond_rest": float(np.mean(tear_more)), "tear_beyond_rest_max": int(max(tear_more)),
           "joint_gap_beyond_rest": float(np.mean(gap_more)), "joint_gap_beyond_rest_max": int(max(gap_more)),
           "frames_with_joint_gaps_beyond_rest": int(sum(g > 4 for g in gap_more)),
           "frames_with_tears": int(sum(r["tear_px"] > 0 for r in rows)),
           "detached": int(sum(r["detached"] for r in rows)),
           "frames_with_detached": int(sum(r["detached"] > 0 for r in rows)), "artefact_frames": int(len(pick))}
    out.update(width_profile_stats(np.stack(widths), rest_w))
    return out
