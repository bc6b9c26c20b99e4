"""What a viewer sees in a rendered frame: detached pieces, cracks, notches at joints, spikes, limb widths.

Independent of the renderer it measures: this module imports nothing from the reshaping code.
It reads only rendered RGBA frames, the key points that drove them (the motion put on the
drawing) and the drawing itself, which is the reference ("at rest").  Coverage is alpha ≥ 128.

* :func:`detached`: drawn components (8-connected, 3 px² or more) apart from the largest: bits
  of the character not joined to the body.
* :func:`cracks`: enclosed background (components of the background that do not touch the image's
  border) no wider than 3 px (the largest disc it holds is at most 3 px across) and at least two
  drawn pixels from any other background: a thin gap opening inside the drawing; ``joint_cracks``
  those within 1.5 joint radii of a joint (where parts are joined: a seam splitting), the rest
  being thin gaps between parts pressed together in the pose.  ``specks`` count
  every thin enclosed bit of background, joined through pixel edges only, pinched ends of wider
  gaps included.  A drawing may have such slits of its own;
  they are counted on the drawing too.
* :func:`joint_notches`: undrawn pixels in a disc about each joint (shoulders, elbows, hips,
  knees, neck) of radius 0.8 × the drawing's distance to its edge at the joint, centred where
  the frame's key point is: a notch, wedge or crack where two parts meet, whatever caused it.
* :func:`outline_turning` and :func:`count_spikes`: a spike is a run of outer-outline points
  turning more than the drawing's own outline ever does (its 99.5th percentile, at least 60°)
  over ±4 px of arc.
* :func:`limb_widths`: the width of the coverage across each limb bone at :data:`STATIONS`,
  against the drawing's (the paper's Fig. 8 claim); :func:`width_stats` summarises.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.skeleton import JOINT_INDEX, LIMBS

#: Joints whose discs :func:`joint_notches` checks.
JOINTS_CHECKED = tuple(JOINT_INDEX[j] for j in ("l_shoulder", "r_shoulder", "l_elbow", "r_elbow", "l_hip",
                                                 "r_hip", "l_knee", "r_knee", "neck"))
#: Fractions along each limb bone where its width is measured.
STATIONS = np.array([0.3, 0.4, 0.5, 0.6, 0.7])
#: The widest enclosed background a crack may be, pixels.
CRACK_WIDTH = 3.0


def coverage(rgba: np.ndarray) -> np.ndarray:
    """Drawn pixels ``(H, W)`` bool of an RGBA frame: alpha ≥ 128."""
    return np.asarray(rgba)[..., 3] >= 128


def detached(cov: np.ndarray, min_area: int = 3) -> int:
    """Drawn components (8-connected) of ``cov`` apart from the largest, of at least ``min_area`` px."""
    _, _, st, _ = cv2.connectedComponentsWithStats(np.asarray(cov, np.uint8), connectivity=8)
    return int((np.sort(st[1:, cv2.CC_STAT_AREA])[::-1][1:] >= min_area).sum())


def cracks(cov: np.ndarray, width: float = CRACK_WIDTH, connectivity: int = 8, isolated: bool = True,
           near: np.ndarray | None = None, labels: np.ndarray | None = None) -> tuple[int, int]:
    """``(count, pixels)`` of enclosed background components no wider than ``width`` px.

    A component's width is the diameter of the largest disc it holds, measured on the image at twice
    its resolution (a band w pixels wide is 2w half-pixels, whose middle lies w half-pixels from its
    edge).  Background is joined through edges and corners (``connectivity`` 8), as drawn pixels are
    for :func:`detached`.  With ``isolated`` a crack lies at least two drawn pixels from any other
    background: a thin gap opening inside the drawing.  Background one drawn pixel from other
    background is the pinched end of a wider gap (or of the outside) where two edges meet at a
    shallow angle; ``isolated=False, connectivity=4`` counts those too (the "specks").  ``near``
    ``(H, W)`` bool: count only the cracks that touch it (the discs about the joints).  ``labels``
    ``(H, W)`` int, optional: each counted crack's pixels are set to its number (1, 2, ...) there."""
    bg = (~np.asarray(cov, dtype=bool)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bg, connectivity=connectivity)
    if n <= 1:
        return 0, 0
    border = set(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])).tolist())
    H, W = bg.shape
    count = pixels = 0
    for c in range(1, n):
        if c in border:
            continue
        x, y, w, h, area = stats[c]
        crop = np.pad((lab[y:y + h, x:x + w] == c).astype(np.uint8), 1)
        fine = cv2.resize(crop, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
        if cv2.distanceTransform(fine, cv2.DIST_L2, cv2.DIST_MASK_PRECISE).max() > width:
            continue
        if near is not None and not near[y:y + h, x:x + w][lab[y:y + h, x:x + w] == c].any():
            continue
        if isolated:
            # The pinched end of a wider gap, or of the outside, lies one drawn pixel from it.
            y0, y1, x0, x1 = max(y - 2, 0), min(y + h + 2, H), max(x - 2, 0), min(x + w + 2, W)
            ring = cv2.dilate((lab[y0:y1, x0:x1] == c).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
            if (ring & (bg[y0:y1, x0:x1] > 0) & (lab[y0:y1, x0:x1] != c)).any():
                continue
        count, pixels = count + 1, pixels + int(area)
        if labels is not None:
            labels[y:y + h, x:x + w][lab[y:y + h, x:x + w] == c] = count
    return count, pixels


#: The key point each checked joint's child bone runs to (the limb or head that turns there).
CHILD_OF = tuple(JOINT_INDEX[j] for j in ("l_elbow", "r_elbow", "l_wrist", "r_wrist", "l_knee", "r_knee",
                                          "l_ankle", "r_ankle", "head_top"))


def joint_radii(mask: np.ndarray, keypoints: np.ndarray, share: float = 0.8) -> np.ndarray:
    """Radius (px) of each joint disc, :data:`JOINTS_CHECKED` order: ``share`` × the drawing's half-width
    there, the smaller of its distance to the edge at the joint and along the first half of the bone
    that turns there (a joint drawn inside a wide body gets the limb's width, not the body's)."""
    m = np.asarray(mask, dtype=np.uint8)
    dist = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    H, W = m.shape
    kp = np.asarray(keypoints, float)
    lam = np.linspace(0.15, 0.5, 8)[:, None, None]
    a, b = kp[list(JOINTS_CHECKED)], kp[list(CHILD_OF)]
    pts = np.clip(np.rint(np.concatenate([a[None], a + lam * (b - a)])).astype(int), 0, [W - 1, H - 1])
    along = dist[pts[..., 1], pts[..., 0]]                           # (9, joints)
    return share * np.minimum(along[0], np.median(along[1:], axis=0))


def joint_notches(cov: np.ndarray, keypoints: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """Undrawn pixels ``(9,)`` in each joint's disc (centre: the key point in ``keypoints`` ``(17, 2)``)."""
    cov = np.asarray(cov, dtype=bool)
    H, W = cov.shape
    out = np.zeros(len(radii), np.int64)
    for k, (j, r) in enumerate(zip(JOINTS_CHECKED, radii)):
        x, y = keypoints[j]
        if r < 0.5 or not np.isfinite([x, y]).all():
            continue
        x0, y0 = int(max(np.floor(x - r) - 1, 0)), int(max(np.floor(y - r) - 1, 0))
        x1, y1 = int(min(np.ceil(x + r) + 2, W)), int(min(np.ceil(y + r) + 2, H))
        if x1 <= x0 or y1 <= y0:
            out[k] = int(np.pi * r * r)
            continue
        disc = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.circle(disc, (int(round((x - x0) * 8)), int(round((y - y0) * 8))), int(round(r * 8)), 1, -1, cv2.LINE_8, 3)
        out[k] = int((disc.astype(bool) & ~cov[y0:y1, x0:x1]).sum())
    return out


def outline_turning(cov: np.ndarray, step: float = 4.0) -> np.ndarray:
    """Turning angle (degrees) at every pixel of arc along the largest outer outline: the angle between
    the chords to the points ``step`` px of arc before and after."""
    cs, _ = cv2.findContours(np.asarray(cov, np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
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
    u, v = p - np.roll(p, k, axis=0), np.roll(p, -k, axis=0) - p
    cos = (u * v).sum(1) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-9)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def count_spikes(turning: np.ndarray, threshold: float) -> int:
    """Runs of consecutive outline points (cyclic) turning more than ``threshold`` degrees."""
    over = np.asarray(turning) > threshold
    if not over.any():
        return 0
    return 1 if over.all() else int((over & ~np.roll(over, 1)).sum())


def spike_threshold(rest_turning: np.ndarray, q: float = 99.5, floor: float = 60.0) -> float:
    """The rest outline's ``q``-th percentile of turning, at least ``floor`` degrees."""
    return float(max(np.percentile(rest_turning, q), floor)) if len(rest_turning) else floor


def limb_widths(cov: np.ndarray, keypoints: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Widths ``(8, len(STATIONS))`` px of the coverage across each limb bone (``nnsf.skeleton.LIMBS``)
    at :data:`STATIONS`; NaN where the station is not drawn or the run exceeds ``reach`` ``(8,)`` px on
    a side (the limb lies against something else there)."""
    cov = np.asarray(cov, dtype=bool)
    H, W = cov.shape
    kp = np.asarray(keypoints, dtype=np.float64)
    out = np.full((len(LIMBS), len(STATIONS)), np.nan)
    for i, (a, b) in enumerate(LIMBS.values()):
        d = kp[b] - kp[a]
        L = float(np.linalg.norm(d))
        if L < 1e-6 or not np.isfinite(reach[i]):
            continue
        n = np.array([-d[1], d[0]]) / L
        steps = np.arange(0.0, reach[i] + 0.5, 0.5)
        centres = kp[a] + STATIONS[:, None] * d                         # (s, 2)
        pts = centres[:, None, None] + np.array([1.0, -1.0])[None, :, None, None] * steps[None, None, :, None] * n
        ij = np.rint(pts).astype(int)                                   # (s, 2, k, 2)
        ok = (ij[..., 0] >= 0) & (ij[..., 0] < W) & (ij[..., 1] >= 0) & (ij[..., 1] < H)
        inside = np.zeros(ok.shape, bool)
        inside[ok] = cov[ij[..., 1][ok], ij[..., 0][ok]]
        ext = np.where(inside.all(axis=2), np.nan, steps[np.argmin(inside, axis=2)])   # (s, 2)
        out[i] = np.where(inside[:, 0, 0], ext.sum(axis=1), np.nan)
    return out


def width_stats(widths: np.ndarray, rest: np.ndarray) -> dict[str, float]:
    """Limb widths ``(T, 8, s)`` against the drawing's ``(8, s)``: ``width_change`` (mean w/w₀ − 1, < 0
    thinner), ``width_error`` (mean |w/w₀ − 1|), ``width_roughness`` (mean |second difference along the
    limb| / mean rest width, minus the drawing's own: bumpier than drawn) and ``width_jitter``
    (mean |w_t − w_{t−1}| / w₀)."""
    w, r = np.asarray(widths, float), np.asarray(rest, float)
    ok = np.isfinite(r) & (r > 0.5)
    r = np.where(ok, r, np.nan)
    with np.errstate(all="ignore"):
        rel = w / r
        scale = np.nanmean(r)
        rough = np.nanmean(np.abs(np.diff(w, 2, axis=-1))) / scale - np.nanmean(np.abs(np.diff(r, 2, axis=-1))) / scale
        jit = np.nanmean(np.abs(np.diff(w, axis=0)) / r) if len(w) > 1 else np.nan
        return {"width_change": float(np.nanmean(rel - 1)), "width_error": float(np.nanmean(np.abs(rel - 1))),
                "width_roughness": float(rough), "width_jitter": float(jit)}


class FrameMeasures:
    """Every measure of one clip's frames against the drawing (module docstring).

    ``texture`` ``(H, W, 4)``, ``mask`` ``(H, W)`` and ``keypoints`` ``(17, 2)``: the drawing, which
    is the reference; :meth:`__call__` measures one RGBA frame with the key points that drove it
    (same pixel frame as the image).
    """

    def __init__(self, texture: np.ndarray, mask: np.ndarray, keypoints: np.ndarray):
        drawn = np.asarray(mask, bool) & (np.asarray(texture)[..., 3] >= 128)
        self.radii = joint_radii(mask, keypoints)
        self.rest_notches = joint_notches(drawn, keypoints, self.radii)
        self.rest_cracks = cracks(drawn)[0]
        self.rest_specks = cracks(drawn, connectivity=4, isolated=False)[0]
        self.rest_detached = detached(drawn)
        turning = outline_turning(drawn)
        self.spike_threshold = spike_threshold(turning)
        self.rest_spikes = count_spikes(turning, self.spike_threshold)
        self.rest_roughness = float(np.mean(turning)) if len(turning) else float("nan")
        dist = cv2.distanceTransform(np.pad(drawn.astype(np.uint8), 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
        H, W = drawn.shape
        reach = []
        for a, b in LIMBS.values():
            mid = np.clip(np.rint(keypoints[a] + 0.5 * (keypoints[b] - keypoints[a])).astype(int), 0, [W - 1, H - 1])
            reach.append(2.0 * max(float(dist[mid[1], mid[0]]), 1.0) + 2.0)
        self.reach = np.array(reach)
        self.rest_widths = limb_widths(drawn, keypoints, self.reach)

    def __call__(self, rgba: np.ndarray, keypoints: np.ndarray) -> dict:
        cov = coverage(rgba)
        n_cracks, crack_px = cracks(cov)
        discs = np.zeros(cov.shape, np.uint8)
        for j, r in zip(JOINTS_CHECKED, self.radii):
            if np.isfinite(keypoints[j]).all():
                cv2.circle(discs, tuple(int(v) for v in np.rint(keypoints[j])), int(round(1.5 * r)) + 1, 1, -1)
        notch = joint_notches(cov, keypoints, self.radii)
        turning = outline_turning(cov)
        return {"detached": detached(cov), "cracks": n_cracks, "crack_px": crack_px,
                "joint_cracks": cracks(cov, near=discs > 0)[0] if n_cracks else 0,
                "specks": cracks(cov, connectivity=4, isolated=False)[0], "notch_px": int(notch.sum()),
                "notch_beyond_rest": int(np.maximum(notch - self.rest_notches, 0).sum()),
                "spikes": count_spikes(turning, self.spike_threshold),
                "outline_roughness": float(np.mean(turning)) if len(turning) else float("nan"),
                "widths": limb_widths(cov, keypoints, self.reach)}

    def rest(self) -> dict:
        """The drawing's own numbers (the rows of a frame that changes nothing)."""
        return {"detached": self.rest_detached, "cracks": self.rest_cracks, "specks": self.rest_specks,
                "notch_px": int(self.rest_notches.sum()), "spikes": self.rest_spikes,
                "outline_roughness": self.rest_roughness}
