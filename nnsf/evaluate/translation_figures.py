"""Figures of the held-out translation evaluation (docs/method.md §15.5).

* :func:`per_style_figure` -- per target style, bars per method of the DTW
  error (% of torso length), the style accuracy and the content accuracy;
* :func:`strip_figure` -- stick-figure strips of real (grey) vs synthesised
  (colour) frames of a few held-out cells, paired along the DTW path.

Built on :class:`matplotlib.figure.Figure` (no ``pyplot``) and written
atomically through :mod:`nnsf.evaluate.figures`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.evaluate.translation import METHODS, per_style
from nnsf.skeleton import to_points
from nnsf.plotting import new_figure, save_figure
from nnsf.skeleton.layout import BONES

__all__ = ["TRANSLATION_STYLE", "per_style_figure", "strip_figure"]


#: Colour, hatch and label of every method in the translation figures (NNSF and
#: the bilinear model keep the colours of :data:`nnsf.evaluate.figures.METHOD_STYLE`).
TRANSLATION_STYLE: dict[str, dict] = {
    "nnsf": {"color": "#d62728", "label": "NNSF, V_content U_style (ours)"},
    "nnsf_swapped": {"color": "#ff9896", "label": "NNSF, swapped reading (V_style U_content)"},
    "nnsf_refit": {"color": "#aec7e8", "label": "NNSF, per-style refit of the source clip (method §8.1)"},
    "bilinear": {"color": "#9467bd", "label": "Bilinear (T&F), per-frame"},
    "bilinear_template": {"color": "#c5b0d5", "label": "Bilinear (T&F), cell template"},
    "nnsf_nosmooth": {"color": "#e377c2", "label": "NNSF without the smoothness term"},
    "nnsf_restore": {"color": "#f7b6d2", "label": "NNSF, content amplitude only"},
    "mgpm": {"color": "#ff7f0e", "label": "MGPM (Wang et al. 2007)"},
    "cbgpm": {"color": "#8c564b", "label": "CBGPM (after Ma et al. 2009)"},
    "offset": {"color": "#bcbd22", "label": "Source clip + the style's mean pose offset"},
    "identity": {"color": "#17becf", "label": "No translation (retarget only)"},
    "real": {"color": "#2ca02c", "label": "Real hidden clip (classifier ceiling)"},
}


def _tstyle(method, i):
    return TRANSLATION_STYLE.get(method, {"color": f"C{i % 10}", "label": method})


def per_style_figure(results: pd.DataFrame, path, methods=None,
                     title: str = "Held-out translation, per target style") -> "Path":
    """Bars per style and method: DTW error (% of torso), style and content accuracy.

    Parameters
    ----------
    results : :func:`leave_one_cell_out` output.
    path : PNG path (150 dpi), written atomically.
    methods : methods to draw, in order; default every method in ``results``
        except ``real`` in the error panel (its error is 0 by definition) --
        ``real`` is drawn in the accuracy panel as the ceiling.
    """
    table = per_style(results)
    if methods is None:
        methods = [m for m in METHODS if m in set(results["method"])] + \
            [m for m in dict.fromkeys(results["method"]) if m not in METHODS]
    styles = sorted(table["style"].unique())
    x = np.arange(len(styles))
    fig = new_figure(max(10.0, 0.75 * len(styles) + 3), 11.0)
    axes = fig.subplots(3, 1, sharex=True)
    panels = [("dtw_error", [m for m in methods if m != "real"], 100.0,
               "DTW joint error\n(% of torso length)", "lower is better"),
              ("style_acc", list(methods), 100.0, "style accuracy (%)", "higher is better"),
              ("content_acc", list(methods), 100.0, "content accuracy (%)", "higher is better")]
    for ax, (col, ms, scale, ylabel, note) in zip(axes, panels):
        width = 0.84 / max(len(ms), 1)
        for i, m in enumerate(ms):
            part = table[table["method"] == m].set_index("style").reindex(styles)
            st = _tstyle(m, i)
            ax.bar(x - 0.42 + width * (i + 0.5), part[col].to_numpy(float) * scale, width,
                   color=st["color"], label=st["label"], edgecolor="white", linewidth=0.4)
        ax.set_ylabel(ylabel, fontsize=11)
        ax.grid(True, axis="y", alpha=0.35)
        ax.set_axisbelow(True)
        ax.text(0.995, 0.98, note, transform=ax.transAxes, ha="right", va="top", fontsize=9,
                color="0.35")
        ax.tick_params(labelsize=9.5)
    for ax in axes[1:]:
        ax.set_ylim(0, 105)
    axes[-1].set_xticks(x)
    axes[-1].set_xticklabels(styles, rotation=35, ha="right", fontsize=10)
    axes[-1].set_xlabel("target style (held-out cells of that style, averaged over contents)", fontsize=11)
    handles, labels = axes[1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(3, len(labels)), fontsize=9.5,
               frameon=False)
    fig.suptitle(title, fontsize=13)
    return save_figure(fig, path)


def _draw_stick(ax, features_row, color, lw=2.0, alpha=1.0, zorder=2, ls="-"):
    p = to_points(np.asarray(features_row)[None])[0]
    for a, b in BONES:
        ax.plot([p[a, 0], p[b, 0]], [p[a, 1], p[b, 1]], color=color, linewidth=lw, alpha=alpha,
                zorder=zorder, linestyle=ls, solid_capstyle="round")


def strip_figure(examples: list, path, methods=("nnsf", "bilinear", "identity"), n_frames: int = 6,
                 title: str = "Held-out cells: real (grey) vs synthesised (colour), DTW-aligned"):
    """Stick-figure strips of real vs synthesised frames for a few held-out cells.

    Parameters
    ----------
    examples : list of ``((style, content), examples_dict)`` where the dict is
        :func:`evaluate_cell`'s second return value (``return_examples=True``).
    path : PNG path, written atomically.
    methods : one row per method and cell.
    n_frames : frames per row, spread evenly along the DTW path.
    """
    rows = [(cell, m, ex[m]) for cell, ex in examples for m in methods if m in ex]
    if not rows:
        raise ValueError("strip_figure: no examples of the requested methods")
    fig = new_figure(1.35 * n_frames + 1.6, 1.75 * len(rows) + 0.8)
    grid = fig.add_gridspec(len(rows), n_frames)
    for r, ((s, c), m, ex) in enumerate(rows):
        path_ = ex["path"]
        picks = path_[np.linspace(0, len(path_) - 1, n_frames).round().astype(int)]
        A, B = ex["synth"][picks[:, 0]], ex["real"][picks[:, 1]]
        pts = to_points(np.concatenate([A, B]))
        lo, hi = pts.reshape(-1, 2).min(0), pts.reshape(-1, 2).max(0)
        half = 0.55 * float(max(hi - lo))
        mid = (lo + hi) / 2
        st = _tstyle(m, r)
        for f in range(n_frames):
            ax = fig.add_subplot(grid[r, f])
            _draw_stick(ax, B[f], "0.55", lw=3.2, alpha=0.75, zorder=1)
            _draw_stick(ax, A[f], st["color"], lw=1.6, zorder=2)
            ax.set_xlim(mid[0] - half, mid[0] + half)
            ax.set_ylim(mid[1] + half, mid[1] - half)       # y down
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            for sp_ in ax.spines.values():
                sp_.set_color("0.85")
            if f == 0:
                ax.set_ylabel(f"{c} as {s}\n{st['label'].split(' (')[0]}\n"
                              f"err {100 * ex['dtw_error']:.0f}% torso", fontsize=7.5)
    fig.suptitle(title, fontsize=11.5)
    return save_figure(fig, path)
