"""The drawing's outline: its style, and its redraw along edges a deformation makes new.

:func:`outline_style` reads the outline's colour, line width and paper margin
from a drawing; :func:`redraw_outline` strokes that outline along the
silhouette edges of a rendered frame whose texels lay inside the drawing
(a cut, a joint tab, a body side a limb left).  :class:`nnsf.reshape.render.MeshRenderer`
calls it on pieced meshes (docs/method.md §13).
"""
from __future__ import annotations

import cv2
import numpy as np


def outline_style(texture: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, float, float] | None:
    """The drawing's outline: its colour ``(3,)``, line width and paper margin (px), or None without one.

    Dark: pixels of the band just inside the silhouette (up to 6 % of the
    drawing's height deep) darker than the midpoint between the band's 5th
    percentile and the inside's median luminance.  At each depth d (px from
    the mask's edge) the share of dark pixels is taken; the outline is the
    first run of depths where most are dark (it must start within 6 px:
    scanned masks keep a little paper around the line, the paper margin).
    Width: the depths of that run where nearly all (85 %) pixels are dark,
    plus one; colour: the median of the run's dark pixels.
    """
    m = np.asarray(mask, dtype=bool)
    if m.sum() < 16:
        return None
    ys = np.flatnonzero(m.any(axis=1))
    height = float(ys[-1] - ys[0] + 1)
    inner = cv2.distanceTransform(np.pad(m.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    band = m & (inner <= max(0.06 * height, 2.0))
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    dark_thr = 0.5 * (np.percentile(lum[band], 5) + np.median(lum[m & ~band] if (m & ~band).any() else lum[m]))
    dark = band & (lum < dark_thr)
    # The dark share at each depth inside the outline: a drawn outline is a run of depths where
    # most pixels are dark, after a margin of paper the mask may keep around the line.
    depths = np.arange(1, int(max(0.06 * height, 4.0)) + 1)
    frac = np.array([dark[m & (np.abs(inner - d) < 0.5)].mean() if (m & (np.abs(inner - d) < 0.5)).any() else 0.0
                     for d in depths])
    on = frac >= 0.5
    if not on[:6].any():  # no outline along the edge: nothing to redraw
        return None
    first = int(np.argmax(on))
    off = np.flatnonzero(~on[first:])
    last = first + (int(off[0]) if len(off) else len(on) - first)
    # The line's solid core (depths where nearly all pixels are dark) and a pixel of soft edge.
    width = float(max(int((frac[first:last] >= 0.85).sum()) + 1, 1))
    paper = float(depths[first] - 1)
    ink = dark & (inner <= paper + width + 0.5)
    rgb = np.median(np.asarray(texture)[..., :3][ink], axis=0)
    return rgb.astype(np.float32), width, paper


def redraw_outline(crop: np.ndarray, depth: np.ndarray, style) -> np.ndarray:
    """Redraw the outline along silhouette edges the drawing had no outline on.

    ``crop``: premultiplied RGBA ``(h, w, 4)`` uint8 frame, with a margin of
    at least the line width around the drawn pixels; ``depth``: ``(h, w)``
    float, each pixel's texel's distance (px) inside the drawing's outline
    (large for a tab's texels: every edge of a tab is new); ``style``:
    :func:`outline_style`'s ``(rgb, width, paper)``.  Returns the inked crop.

    An edge pixel of the silhouette (outer outline and holes,
    ``cv2.findContours``) is new when its texel lies deeper inside the
    drawing than the paper margin, half the line width and 2 px (a cut, a
    tab, a body side a limb left).  Each run of new edge points is smoothed
    (a moving average of 5 points, so the stroke does not follow the pixel
    staircase) and stroked with the drawing's outline colour, its line width
    plus a pixel wide, anti-aliased (``cv2.polylines``, LINE_AA, 1/8 px),
    inside the silhouette along the edge (:func:`inward`), where the drawn
    outline lies too; outside it only in pockets narrower than the stroke
    (the closing of the silhouette by a disc and by a square of the
    stroke's width on either side: a gap between two pieces at a joint),
    where the stroke centred on the edge closes the outline.  (Centred on
    every edge, its outer half was a bump beside the drawn line:
    ``benchmarks/bench_seal.py`` counts the ink it adds outside the pieces.)
    A run shorter than
    three times the line width is the outline's own wiggle and is left
    alone, unless its texels lie a line width beyond that depth: then it is
    a notch (a tab's edge where a bent knee opens, between two drawn outline
    ends), stroked inside the silhouette only, so it joins those ends
    without a bump outside.  Edges the drawing outlined keep their own ink.
    """
    rgb, width, paper = style
    cov = crop[..., 3] >= 128
    if not cov.any():
        return crop
    contours, _ = cv2.findContours(cov.astype(np.uint8), cv2.RETR_CCOMP, cv2.CHAIN_APPROX_NONE)
    thr = paper + 0.5 * width + 2.0
    min_run = max(3.0 * width, 8.0)
    runs, notches = [], []
    for c in contours:
        c = c[:, 0, :]
        if len(c) < 8:
            continue
        d = depth[c[:, 1], c[:, 0]]
        new = d > thr
        if not new.any():
            continue
        # Close one- and two-point gaps, then grow each run by two points into the old ink.
        k = np.ones(5)
        new = np.convolve(np.r_[new[-2:], new, new[:2]].astype(float), k, "same")[2:-2] > 0
        sm = np.stack([np.convolve(np.r_[c[-2:, i], c[:, i], c[:2, i]].astype(float), k / 5, "same")[2:-2]
                       for i in range(2)], axis=1)
        if new.all():
            runs.append(np.vstack([sm, sm[:1]]))
            continue
        start = np.flatnonzero(new & ~np.roll(new, 1))
        for s0 in start:
            idx = [s0]
            i = (s0 + 1) % len(c)
            while new[i] and i != s0:
                idx.append(i)
                i = (i + 1) % len(c)
            if len(idx) >= min_run:
                runs.append(sm[idx])
            elif len(idx) >= 5 and np.median(d[idx]) > thr + width:
                # A few stray points just past the threshold are the outline's own wiggle; a
                # short run well inside the drawing is new (a tab's edge in the notch of a
                # bent knee, between two drawn outline ends): inked inside the silhouette
                # only, so it joins those ends without a bump outside.
                notches.append(sm[idx])
    if not runs and not notches:
        return crop
    shift = 3
    thick = max(int(round(width)) + 1, 1)
    # Work in the box around the strokes: the closing below sees the silhouette up to three
    # stroke widths from them, which is all it needs there (and most of the frame is untouched).
    pts = np.vstack(runs + notches)
    pad = 3 * thick + 2
    x0, y0 = np.maximum(np.floor(pts.min(axis=0)).astype(int) - pad, 0)
    x1, y1 = np.minimum(np.ceil(pts.max(axis=0)).astype(int) + pad + 1, [cov.shape[1], cov.shape[0]])
    box = (slice(y0, y1), slice(x0, x1))
    cov_b = cov[box]
    at = np.array([x0, y0], np.float64)

    def stroke(lines, thickness):
        canvas = np.zeros(cov_b.shape, np.uint8)
        cv2.polylines(canvas, [np.rint((r - at) * (1 << shift)).astype(np.int32).reshape(-1, 1, 2)
                               for r in lines], False, 255, thickness, cv2.LINE_AA, shift)
        return canvas.astype(np.float32) / 255.0

    alpha = crop[box][..., 3].astype(np.float32) / 255.0
    # The drawn outline lies inside the silhouette, a line width deep: a new edge is inked the
    # same way, along the run moved inward by half the stroke.  Outside the silhouette the stroke
    # is laid only where the silhouette is concave by less than a line width (a gap between two
    # pieces at a joint): there it closes the outline; elsewhere its outer half would be a bump
    # beside the drawn line.
    a = np.zeros(cov_b.shape, np.float32)
    if runs:
        a = stroke([inward(r, cov, 0.5 * thick) for r in runs], thick) * alpha
        # The pockets: a closing by a disc rounds concave corners, one by a square also closes
        # the mouth of a narrow gap (the disc's narrow top misses its outermost row).
        size = (2 * thick + 1, 2 * thick + 1)
        c8 = cov_b.astype(np.uint8)
        pocket = (cv2.morphologyEx(c8, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, size))
                  | cv2.morphologyEx(c8, cv2.MORPH_CLOSE, np.ones(size, np.uint8))).astype(np.float32)
        a = np.maximum(a, stroke(runs, thick) * (1.0 - alpha) * pocket)
    if notches:
        a = np.maximum(a, stroke(notches, thick) * alpha)
    hit = a > 0
    a = a[hit][:, None]
    out = crop.copy()
    px = out[box][hit].astype(np.float32)
    ink = np.asarray(rgb, np.float32)[None, :]
    # Premultiplied "over": the stroke (opaque ink, coverage a) over the frame, where it lies.
    px[:, :3] = ink * a + px[:, :3] * (1 - a)
    px[:, 3:4] = 255.0 * a + px[:, 3:4] * (1 - a)
    view = out[box]
    view[hit] = np.clip(np.rint(px), 0, 255).astype(np.uint8)
    return out


def inward(run: np.ndarray, cov: np.ndarray, by: float) -> np.ndarray:
    """The polyline ``run`` ``(n, 2)`` (x, y px, along a silhouette edge) moved ``by`` px along its
    normal, to the side of ``cov`` ``(h, w)`` bool (the silhouette) for most of its points."""
    run = np.asarray(run, dtype=np.float64)
    if len(run) < 2:
        return run
    t = np.gradient(run, axis=0)
    t /= np.maximum(np.linalg.norm(t, axis=1, keepdims=True), 1e-9)
    n = np.stack([-t[:, 1], t[:, 0]], axis=1)
    h, w = cov.shape
    probe = np.rint(run + 2.0 * n).astype(int)
    probe[:, 0] = np.clip(probe[:, 0], 0, w - 1)
    probe[:, 1] = np.clip(probe[:, 1], 0, h - 1)
    side = 1.0 if cov[probe[:, 1], probe[:, 0]].mean() >= 0.5 else -1.0
    return run + side * by * n
