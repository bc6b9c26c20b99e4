"""A look at style carried onto actions the model never saw: one figure, front and side views.

``python -m nnsf.evaluate.style_figure --data FOLDER --source normal --out reports/figures/style_transfer_views.png``

For each view (``--views``) and each action (``--contents``, e.g. a walk and
an arm action), the style model is fitted as ``nnsf styles`` fits it on every
clip *but* that action's (leave one content out, the source style as the
neutral one), and the source style's take of the action goes through
:func:`nnsf.translate` into each of ``--styles``.  One row per (action,
view); the first column is the input, then one column per style, each the
same frames (same phase: the translation keeps the clip's timing) in colour
over the input in grey, root at the origin, with the lean -- the
pelvis-to-neck line's angle from the vertical, mean over the clip -- written
under it, beside the mean lean of that style's real clips of the action
(which the model never saw).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from nnsf.datasets import bvh_source
from nnsf.datasets.contract import features
from nnsf.datasets.stage import complete_grid
from nnsf.datasets.views import VIEWS
from nnsf.errors import InputError
from nnsf.evaluate.content_out import lean_degrees
from nnsf.factor.style_model import StyleModel, fit_translator, translate, translator_params, unify_table
from nnsf.params import load, require
from nnsf.plotting import categorical_colors, new_figure, save_figure
from nnsf.skeleton.layout import BONES

#: Where in the clip the drawn frames are, as fractions of its length.
PHASES = (0.35, 0.65)


def _draw(ax, P, color, lw, alpha=1.0, dx=0.0):
    for a, b in BONES:
        ax.plot([P[a, 0] + dx, P[b, 0] + dx], [P[a, 1], P[b, 1]], color=color, lw=lw, alpha=alpha,
                solid_capstyle="round")


def translations(table, content, source, styles, params, fps):
    """``({"input": (n, 17, 2), style: (n, 17, 2)}, {style: real lean})``: the source take of
    ``content``, its translations by a model fitted without ``content``, and the mean lean (degrees)
    of each style's real clips of ``content``."""
    train = table[table["motion"] != content].reset_index(drop=True)
    ft, unifier = unify_table(train, float(require(params, "unify.margin")))
    model = StyleModel(fit_translator(ft, {**translator_params(params), "neutral": source}, fps), unifier)
    take = table[(table["motion"] == content) & (table["character"] == source)]
    first = take[take["clip"] == sorted(set(take["clip"]))[0]]
    P = features(first).reshape(len(first), 17, 2)
    real = {}
    for s in ["input", *styles]:
        g = table[(table["motion"] == content) & (table["character"] == (source if s == "input" else s))]
        real[s] = float(np.mean([lean_degrees(features(c).reshape(len(c), 17, 2)).mean()
                                 for _, c in g.groupby("clip")]))
    return {"input": P, **{s: translate(P, s, model, fps=fps) for s in styles}}, real


def figure(rows, styles, path):
    """``rows``: ``[(label, {"input": P, style: P, ...}, {style: real lean}), ...]``; writes the grid."""
    cols = ["input", *styles]
    colors = dict(zip(styles, categorical_colors(len(styles))))
    fig = new_figure(2.3 * len(cols), 2.5 * len(rows) + 0.6)
    grid = fig.add_gridspec(len(rows), len(cols))
    for r, (label, clips, real) in enumerate(rows):
        P_in = clips["input"]
        n = len(P_in)
        picks = [int(round(f * (n - 1))) for f in PHASES]
        rel = {k: v - v[:, :1] for k, v in clips.items()}
        allp = np.concatenate([rel[k][picks] for k in cols])
        span = float(np.ptp(allp[..., 0])) + 1e-9
        height = float(np.ptp(allp[..., 1]))
        dx = 1.05 * span
        for c, k in enumerate(cols):
            ax = fig.add_subplot(grid[r, c])
            for i, f in enumerate(picks):
                if k != "input":
                    _draw(ax, rel["input"][f], "0.7", 3.0, 0.8, dx * i)
                _draw(ax, rel[k][f], "0.2" if k == "input" else colors[k], 1.6, 1.0, dx * i)
            lean = float(np.mean(lean_degrees(clips[k])))
            ax.set_title(f"{k}" if r == 0 else "", fontsize=9)
            ax.set_xlabel(f"lean {lean:+.1f}° (real clips {real[k]:+.1f}°)", fontsize=7.5)
            lo = allp[..., 1].min()
            ax.set_xlim(-0.6 * span, dx * (len(picks) - 1) + 0.6 * span)
            ax.set_ylim(lo + 1.08 * height, lo - 0.08 * height)      # y down
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            if c == 0:
                ax.set_ylabel(label, fontsize=9)
    fig.suptitle("A style carried onto an action the model never saw (leave one content out): "
                 f"frames at {', '.join(f'{int(100 * p)}%' for p in PHASES)} of the clip, input in grey",
                 fontsize=10)
    return save_figure(fig, path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nnsf.evaluate.style_figure", description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, help="folder of labelled .bvh clips")
    ap.add_argument("--source", required=True, help="the style of the clips translated (the neutral style)")
    ap.add_argument("--contents", default="walk,bye")
    ap.add_argument("--styles", default="old,proud,childish,sad")
    ap.add_argument("--views", default="front,side")
    ap.add_argument("--out", default="reports/figures/style_transfer_views.png")
    ap.add_argument("--params", default="params.yaml")
    a = ap.parse_args(argv)
    styles = [s for s in a.styles.split(",") if s]
    try:
        params = load(a.params)
        fps = float(require(params, "dataset.bvh.fps"))
        rows = []
        for view in [v for v in a.views.split(",") if v]:
            if view not in VIEWS:
                raise InputError("--views", "views", ", ".join(VIEWS), view)
            table, _ = bvh_source.read_folder(a.data, fps=fps, azimuth=VIEWS[view],
                                              facing=require(params, "dataset.bvh.facing"),
                                              center=bool(require(params, "dataset.bvh.center")))
            table, _ = complete_grid(table)
            for content in [c for c in a.contents.split(",") if c]:
                rows.append((f"{content}, {view}", *translations(table, content, a.source, styles, params, fps)))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    rows.sort(key=lambda r: r[0])
    print(figure(rows, styles, Path(a.out)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
