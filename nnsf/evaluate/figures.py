"""Figures of the evaluation: precision and reconstruction vs rank, ISOMAP.

Drawn with :mod:`nnsf.plotting` (Agg canvas, no ``pyplot``, atomic files).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.lines import Line2D
from matplotlib.ticker import FuncFormatter

from nnsf.plotting import categorical_colors, new_figure, save_figure

#: One fixed colour and marker per method, the same in every figure.
METHOD_STYLE: dict[str, dict] = {
    "nnsf": {"color": "#d62728", "marker": "o", "label": "NNSF (ours)"},
    "nnsc": {"color": "#1f77b4", "marker": "s", "label": "NNSC (NNSF, β = 0)"},
    "nmf": {"color": "#2ca02c", "marker": "^", "label": "NMF"},
    "bilinear": {"color": "#9467bd", "marker": "D", "label": "Bilinear (Tenenbaum & Freeman)"},
    "mgpm": {"color": "#ff7f0e", "marker": "v", "label": "MGPM (Wang et al.)"},
    "cbgpm": {"color": "#8c564b", "marker": "P", "label": "CBGPM (after Ma et al.)"},
}


def _style(method, i):
    default = {"color": f"C{i % 10}", "marker": "o", "label": method}
    return METHOD_STYLE.get(method, default)


def _per_rank_figure(summary, value, path, title, ylabel, ylim=None, log=False, chance=None,
                     band_range=None):
    need = ["method", "rank", f"{value}_mean"]
    missing = [c for c in need if c not in summary]
    if missing:
        raise ValueError(f"summary lacks column(s) {missing}; build it with crossval.summarise()")
    fig = new_figure(8, 5)
    ax = fig.add_subplot()
    methods = list(dict.fromkeys(summary["method"]))
    clipped_any = False
    for i, method in enumerate(methods):
        part = summary[summary["method"] == method].sort_values("rank")
        x = part["rank"].to_numpy(float)
        m = part[f"{value}_mean"].to_numpy(float)
        sd = part[f"{value}_sd"].to_numpy(float) if f"{value}_sd" in part else np.zeros_like(m)
        st = _style(method, i)
        lo, hi = m - sd, m + sd
        if log:
            lo = np.maximum(lo, m * 0.1)      # a band below 0 cannot be drawn on a log axis
        if band_range is not None:            # e.g. precision cannot leave [0, 1]
            lo, hi = np.clip(lo, *band_range), np.clip(hi, *band_range)
        ax.fill_between(x, lo, hi, color=st["color"], alpha=0.15, linewidth=0)
        ax.plot(x, m, color=st["color"], marker=st["marker"], markersize=5, linewidth=1.8,
                label=st["label"])
        if "rank_used" in part:
            clipped = part["rank_used"].to_numpy() < part["rank"].to_numpy()
            if clipped.any():
                clipped_any = True
                # Open markers: the method cannot use this rank and ran at its maximum.
                ax.plot(x[clipped], m[clipped], linestyle="none", marker=st["marker"],
                        markersize=7, markerfacecolor="white", markeredgecolor=st["color"],
                        markeredgewidth=1.5)
    handles, labels = ax.get_legend_handles_labels()
    if chance is not None:
        handles.append(ax.axhline(chance, color="0.4", linestyle=":", linewidth=1.2))
        labels.append(f"chance ({chance:.2f})")
    if clipped_any:
        handles.append(Line2D([], [], linestyle="none", marker="o", markerfacecolor="white",
                              markeredgecolor="0.3", markersize=7))
        labels.append("rank clipped to method's maximum")
    handles.append(Line2D([], [], color="0.5", alpha=0.3, linewidth=8))
    labels.append("± 1 sd over folds")
    ranks = np.unique(summary["rank"].to_numpy())
    ax.set_xticks(ranks)
    ax.set_xlim(ranks.min() - 0.5, ranks.max() + 0.5)
    if log:
        ax.set_yscale("log")
        # Plain decimals (0.02, 0.1) read better than 2×10⁻² on a relative error.
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        ax.yaxis.set_major_formatter(plain)
        ax.yaxis.set_minor_formatter(plain)
        ax.tick_params(axis="y", which="minor", labelsize=8)
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.set_xlabel("rank k (number of basis rows)", fontsize=12)
    ax.set_ylabel(ylabel, fontsize=12)
    ax.set_title(title, fontsize=13)
    ax.tick_params(labelsize=10)
    ax.grid(True, which="major", alpha=0.35)
    # Below the axes, so it never hides a curve and the plot keeps the full width.
    fig.legend(handles, labels, loc="outside lower center", ncols=3, fontsize=9.5, frameon=False)
    return save_figure(fig, path)


def precision_vs_rank_figure(summary: pd.DataFrame, path, title: str = "Held-out precision vs rank",
                             chance: float | None = None) -> Path:
    """The paper's Fig. 7: held-out macro precision (mean ± sd over folds) vs rank.

    Parameters
    ----------
    summary : DataFrame
        :func:`nnsf.evaluate.crossval.summarise` output (``method, rank,
        precision_mean, precision_sd`` and optionally ``rank_used``; ranks a
        method had to clip are drawn with open markers).
    path : path of the image (PNG at 150 dpi, 8 × 5 inches).
    chance : float, optional
        Precision of guessing (e.g. ``1 / r``), drawn as a dotted line.
    """
    return _per_rank_figure(summary, "precision", path, title,
                            "held-out macro precision (fraction)", ylim=(0, 1.02), chance=chance,
                            band_range=(0.0, 1.0))


def reconstruction_figure(summary: pd.DataFrame, path,
                          title: str = "Held-out reconstruction error vs rank") -> Path:
    """Held-out relative reconstruction error ‖X − X̂‖_F / ‖X‖_F vs rank, per method.

    The y axis is logarithmic when the errors span more than a factor of 10.
    For the bilinear model X̂ is the nearest cell mean, so its error keeps the
    within-cell variation and levels off.
    """
    m = summary["recon_error_mean"].to_numpy(float) if "recon_error_mean" in summary else np.array([])
    pos = m[m > 0]
    log = pos.size > 0 and pos.max() / pos.min() > 10
    return _per_rank_figure(summary, "recon_error", path, title,
                            "held-out relative error ‖X − X̂‖ / ‖X‖ (fraction)", log=log,
                            ylim=None if log else (0, None))


def isomap_figure(embedding3d, labels, dims, rv, intrinsic_dim: int, path,
                  title: str = "ISOMAP of the style weights V", label_name: str = "character") -> Path:
    """The paper's Fig. 6: 3D ISOMAP embedding and residual-variance curve.

    Parameters
    ----------
    embedding3d : array, shape (n, ≥1)
        Embedding; the first three columns are drawn (missing ones as 0).
    labels : array, shape (n,)
        Category of each point (e.g. character), one colour each.
    dims, rv : arrays, shape (D,)
        Residual-variance curve from :func:`nnsf.evaluate.isomap.residual_variance`.
    intrinsic_dim : int
        Dimension to mark on the curve.
    path : path of the image (PNG, 150 dpi, 12 × 5.5 inches).
    label_name : str
        What the labels are, for the legend title.
    """
    E = np.asarray(embedding3d, dtype=float)
    labels = np.asarray(labels)
    if E.ndim != 2 or E.shape[0] != labels.shape[0]:
        raise ValueError(f"embedding3d (n, 3) and labels (n,) disagree: {E.shape} vs {labels.shape}")
    if E.shape[1] < 3:
        E = np.hstack([E, np.zeros((E.shape[0], 3 - E.shape[1]))])
    dims = np.asarray(dims)
    rv = np.asarray(rv, dtype=float)
    if dims.shape != rv.shape:
        raise ValueError(f"dims and rv must have the same shape, got {dims.shape} and {rv.shape}")

    fig = new_figure(12, 5.5)
    grid = fig.add_gridspec(1, 2, width_ratios=[1.15, 1])
    ax3 = fig.add_subplot(grid[0, 0], projection="3d")
    names = list(dict.fromkeys(sorted(labels.tolist())))
    cmap = categorical_colors(len(names))
    index = {name: i for i, name in enumerate(names)}
    colors = np.array([cmap[index[v]] for v in labels.tolist()])
    # One scatter in a fixed shuffled order: drawn label by label, the last
    # label would hide the others wherever points overlap.
    order = np.random.default_rng(0).permutation(len(labels))
    ax3.scatter(E[order, 0], E[order, 1], E[order, 2], s=7, c=colors[order], alpha=0.75,
                depthshade=False)
    for i, name in enumerate(names):
        ax3.scatter([], [], [], s=7, color=cmap[i], label=str(name))
    ax3.set_xlabel("ISOMAP 1", fontsize=10)
    ax3.set_ylabel("ISOMAP 2", fontsize=10)
    ax3.set_zlabel("ISOMAP 3", fontsize=10)
    ax3.tick_params(labelsize=8)
    ax3.set_title(f"3D embedding (coloured by {label_name})", fontsize=12)
    ax3.legend(loc="upper left", bbox_to_anchor=(-0.12, 1.0), fontsize=8.5, markerscale=2.5,
               frameon=False, ncols=1 if len(names) <= 12 else 2, title=label_name,
               title_fontsize=9.5)

    ax = fig.add_subplot(grid[0, 1])
    ax.plot(dims, rv, color="#1f77b4", marker="o", markersize=4, linewidth=1.8,
            label="residual variance")
    if intrinsic_dim in set(dims.tolist()):
        y = rv[list(dims).index(intrinsic_dim)]
        ax.axvline(intrinsic_dim, color="#d62728", linestyle="--", linewidth=1.2)
        ax.plot([intrinsic_dim], [y], marker="o", markersize=11, markerfacecolor="none",
                markeredgecolor="#d62728", markeredgewidth=2,
                label=f"intrinsic dimension = {intrinsic_dim}")
    ax.set_xlabel("embedding dimension d", fontsize=12)
    ax.set_ylabel("residual variance 1 − R² (fraction)", fontsize=12)
    ax.set_title("Residual variance vs dimension", fontsize=12)
    ax.set_ylim(0, max(1e-3, float(np.nanmax(rv)) * 1.08))
    ax.set_xlim(0.5, dims.max() + 0.5 if dims.size else 1.5)
    ax.grid(True, alpha=0.35)
    ax.legend(loc="upper right", fontsize=10)
    fig.suptitle(title, fontsize=13)
    return save_figure(fig, path)


def sweep_figure(table: pd.DataFrame, score: str, path) -> Path:
    """Precision against α, β and rank: one panel per parameter, every sweep point a dot.

    ``table`` has one row per point with columns ``alpha``, ``beta``, ``rank``
    and ``score``; in each panel a point is drawn at its value of that
    parameter (coloured by rank in the α and β panels, by β in the rank panel),
    and the line joins the best score at each value, so the panel shows how
    far the parameter alone can move the score.
    """
    fig = new_figure(12, 4)
    axes = fig.subplots(1, 3, sharey=True)
    ranks = sorted(table["rank"].unique())
    betas = sorted(table["beta"].unique())
    for ax, param, label in zip(axes, ("alpha", "beta", "rank"), ("α (sparsity)", "β (class term)", "rank k")):
        by, groups = ("beta", betas) if param == "rank" else ("rank", ranks)
        colors = categorical_colors(len(groups))
        for color, value in zip(colors, groups):
            part = table[table[by] == value]
            ax.scatter(part[param], part[score], s=28, color=color, alpha=0.85,
                       label=f"{'β' if by == 'beta' else 'k'} = {value:g}")
        best = table.groupby(param)[score].max()
        ax.plot(best.index, best.to_numpy(), color="black", linewidth=1.2, label="best at this value")
        if param != "rank" and (table[param] > 0).any():
            positive = table.loc[table[param] > 0, param]
            ax.set_xscale("symlog", linthresh=float(positive.min()))
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    axes[0].set_ylabel(score.replace("_", " "))
    fig.suptitle(f"Sweep: {score.replace('_', ' ')} of {len(table)} points against α, β and rank")
    return save_figure(fig, path)
