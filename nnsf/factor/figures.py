"""Figures of a factorization: objective per iteration, the basis as poses, a sweep point's folds."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.plotting import new_figure, save_figure
from nnsf.skeleton import BONES, to_points


def objective_figure(objective, path) -> Path:
    """Objective C per iteration (log scale), ``objective`` of shape ``(n_iter + 1,)``.

    The value at the initialisation is given in the title but not drawn: the
    NNDSVD-type starts overshoot X by orders of magnitude, which would flatten
    the rest of the curve.
    """
    objective = np.asarray(objective, dtype=float)
    fig = new_figure(7, 4)
    ax = fig.add_subplot()
    start = 1 if len(objective) > 2 else 0
    ax.semilogy(np.arange(start, len(objective)), objective[start:], color="#d62728", linewidth=1.8)
    ax.set_xlabel("iteration", fontsize=11)
    ax.set_ylabel("objective C (log scale)", fontsize=11)
    ax.set_title(f"NNSF objective: {objective[0]:.3g} at init → {objective[-1]:.4g} "
                 f"after {len(objective) - 1} iterations", fontsize=12)
    ax.grid(True, which="both", alpha=0.3)
    return save_figure(fig, path)


def basis_figure(U, V, path, per_row: int = 8) -> Path:
    """Every basis row U_i drawn as a pose, scaled by a high weight it takes.

    A basis row lives in feature space (34 values = 17 points), so an atom
    times a large weight (the 95th percentile of its nonzero weights) is the
    part of a pose that atom contributes.  Joints below 5 % of the atom's
    largest entry are left out, and bones only join drawn joints.  Each panel
    is framed on its own atom, at one scale for all panels.
    """
    U = np.asarray(U, dtype=float)
    V = np.asarray(V, dtype=float)
    k = U.shape[0]
    scale = np.array([np.percentile(V[:, i][V[:, i] > 0], 95) if np.any(V[:, i] > 0) else 0.0
                      for i in range(k)])
    share = V.sum(axis=0) / max(V.sum(), 1e-300)
    cols = min(per_row, k)
    rows = int(np.ceil(k / cols))
    fig = new_figure(1.6 * cols + 0.4, 2.1 * rows + 0.6)
    pts = to_points(U * scale[:, None])
    strong = U.reshape(k, -1, 2).max(axis=2) > 0.05 * U.max(axis=1, keepdims=True)
    spans = [np.ptp(pts[i][strong[i]], axis=0).max() if strong[i].any() else 0.0 for i in range(k)]
    half = 0.55 * max(max(spans), 1e-9)
    for i in range(k):
        ax = fig.add_subplot(rows, cols, i + 1)
        P = pts[i]
        for p, c in BONES:
            if strong[i, p] and strong[i, c]:
                ax.plot(P[[p, c], 0], P[[p, c], 1], color="0.25", linewidth=1.5)
        ax.scatter(P[strong[i], 0], P[strong[i], 1], s=10, color="#d62728", zorder=3)
        shown = P[strong[i]] if strong[i].any() else np.zeros((1, 2))
        centre = (shown.min(axis=0) + shown.max(axis=0)) / 2
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] + half, centre[1] - half)  # image axes: y down
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"atom {i + 1}  ({100 * share[i]:.0f}% of ΣV)", fontsize=8)
    fig.suptitle("NNSF style basis U: each row as the pose it adds (× its 95th-percentile weight; "
                 "one scale for all panels)",
                 fontsize=11)
    return save_figure(fig, path)


def fold_figure(folds_table: pd.DataFrame, path, title: str) -> Path:
    """Held-out precision and reconstruction error per fold of one sweep point."""
    t = folds_table.sort_values("fold")
    fig = new_figure(7, 3.6)
    ax = fig.add_subplot(1, 2, 1)
    ax.bar(t["fold"] + 1, t["precision"], color="#d62728")
    ax.axhline(t["precision"].mean(), color="0.2", linestyle="--", linewidth=1,
               label=f"mean {t['precision'].mean():.3f}")
    ax.set_ylim(0, 1)
    ax.set_xlabel("fold")
    ax.set_ylabel("held-out macro precision")
    ax.legend(fontsize=8, loc="lower right")
    ax2 = fig.add_subplot(1, 2, 2)
    ax2.bar(t["fold"] + 1, t["recon_error"], color="#1f77b4")
    ax2.set_xlabel("fold")
    ax2.set_ylabel("held-out ‖X − VU‖ / ‖X‖")
    fig.suptitle(title, fontsize=11)
    return save_figure(fig, path)
