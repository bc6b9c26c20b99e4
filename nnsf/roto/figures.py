"""The tracking overlay figure (like the paper's Fig. 5).

One row per tracker, one column per chosen frame: the frame (cropped to the
character), the tracker's side curves in its colour, the true curves as thin
dashed black lines, and every spline sample more than ``fail_px`` from the
truth marked with a magenta cross.  Each panel's title gives the frame and
the tracker's mean error there.
"""
from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.lines import Line2D

from nnsf.plotting import new_figure, save_figure
from nnsf.roto import curves
from nnsf.roto.curves import project_to_polyline

TRACKER_STYLE: dict[str, dict] = {
    "ours": {"color": "#d62728", "label": "ours (sketch + colour)"},
    "agarwala": {"color": "#1f77b4", "label": "Agarwala (no sketch/colour)"},
    "lk": {"color": "#ff7f0e", "label": "pyramidal LK"},
}
FAIL_COLOUR = "#e600e6"
MIN_WIDTH = 6.4      # in: room for the title line and a legend of two columns


def _samples(control: np.ndarray, n: int) -> np.ndarray:
    """(N, P, 2) NaN-padded control points -> (N, n, 2) samples (NaN rows stay NaN)."""
    out = np.full((control.shape[0], n, 2), np.nan)
    for i, c in enumerate(control):
        ok = np.isfinite(c).all(-1)
        if ok.sum() >= 2:
            out[i] = curves.sample(c[: int(ok.sum())], n)
    return out


def roto_overlay(frames: np.ndarray, tracked: dict[str, np.ndarray], truth: np.ndarray,
                     show: list[int], path, fail_px: float = 3.0, n_samples: int = 32,
                     title: str | None = None, crop_margin: int = 16) -> Path:
    """Draw the overlay figure and save it (atomically) to ``path``.

    frames  : (T, H, W, 3) uint8 RGB.
    tracked : tracker name -> (T, N, P, 2) control points (same curve order as ``truth``).
    truth   : (T, N, S, 2) dense true curves, or None (then no failures are marked).
    show    : frame indices to draw (columns).
    """
    methods = [m for m in TRACKER_STYLE if m in tracked] + \
        [m for m in tracked if m not in TRACKER_STYLE]
    T, H, W, _ = frames.shape
    # crop: bounding box of all curves in the shown frames (+ margin), square-ish
    pts = np.concatenate([tracked[m][show].reshape(-1, 2) for m in methods]
                         + ([truth[show].reshape(-1, 2)] if truth is not None else []))
    pts = pts[np.isfinite(pts).all(1)]
    x0, y0 = np.maximum(np.floor(pts.min(0)) - crop_margin, 0).astype(int)
    x1, y1 = np.minimum(np.ceil(pts.max(0)) + crop_margin, [W - 1, H - 1]).astype(int)
    aspect = (y1 - y0 + 1) / max(x1 - x0 + 1, 1)
    ncol, nrow = len(show), len(methods)
    pw = 2.6
    # the title and the legend need about MIN_WIDTH in: with one or two columns of panels
    # the figure is widened (the panels keep their size) instead of cutting them at both edges
    width = max(pw * ncol + 0.2, MIN_WIDTH)
    fig = new_figure(width, pw * aspect * nrow + 1.3)
    axes = fig.subplots(nrow, ncol, squeeze=False)
    for r, m in enumerate(methods):
        style = TRACKER_STYLE.get(m, {"color": f"C{r}", "label": m})
        for c, t in enumerate(show):
            ax = axes[r, c]
            ax.imshow(frames[t], interpolation="nearest")
            S = _samples(tracked[m][t], n_samples)                       # (N, n, 2)
            if truth is not None:
                for tr in truth[t]:
                    ax.plot(tr[:, 0], tr[:, 1], color="black", lw=0.6, ls=(0, (2, 2)))
            for s in S:
                ax.plot(s[:, 0], s[:, 1], color=style["color"], lw=1.4)
            err_txt = ""
            if truth is not None:
                ok = np.isfinite(S).all(axis=(1, 2))
                d, _ = project_to_polyline(S[ok], truth[t][ok])
                bad = S[ok][d > fail_px]
                if len(bad):
                    ax.plot(bad[:, 0], bad[:, 1], ls="none", marker="x", ms=2.5, mew=0.7,
                            color=FAIL_COLOUR)
                err_txt = f", mean {d.mean():.1f} px" if d.size else ""
            ax.set_xlim(x0 - 0.5, x1 + 0.5)
            ax.set_ylim(y1 + 0.5, y0 - 0.5)
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"frame {t}{err_txt}", fontsize=8)
            if c == 0:
                ax.set_ylabel(style["label"], fontsize=8, color=style["color"])
    handles = [Line2D([], [], color=TRACKER_STYLE.get(m, {"color": f"C{i}"})["color"], lw=2,
                      label=TRACKER_STYLE.get(m, {"label": m})["label"])
               for i, m in enumerate(methods)]
    if truth is not None:
        handles += [Line2D([], [], color="black", lw=0.8, ls=(0, (2, 2)), label="true contour"),
                    Line2D([], [], color=FAIL_COLOUR, ls="none", marker="x",
                           label=f"failure (> {fail_px:g} px from truth)")]
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 3 if ncol > 1 else 2),
               fontsize=8, frameon=False)
    if title:
        # about 13 characters of 10-pt text per inch of figure
        fig.suptitle(textwrap.fill(title, max(int(width * 13), 30)), fontsize=10)
    return save_figure(fig, path)
