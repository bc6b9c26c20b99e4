"""Figure: a wrist and an ankle over time in held-out Bandai-Namco-1 cells, real vs three smoothness settings.

    .venv/bin/python scripts/smoothness_figure.py --data ../shared/data/bandai-namco-1 \\
        --out reports/figures/translation_smoothness.png

For each cell (hidden as in the held-out evaluation), the default synthesis (params.yaml) and
the same with ``smooth: 0`` and with a weaker ``smooth: 5`` are drawn in the target character's
pixels, beside the hidden real clip: the vertical position of the right wrist and of the left
ankle, frame by frame (each curve on its own time axis, normalised to [0, 1]).  It shows what
the jerk ratio measures: the row-to-row jitter of an unsmoothed consensus, and the
second-order term's smooth curve at full amplitude.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

CELLS = (("tired", "walk"), ("happy", "byebye"), ("old", "run"))
SETTINGS = {"smooth 0": {"smooth": 0.0}, "smooth 5": {"smooth": 5.0}, "default": {}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    a = ap.parse_args(argv)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nnsf.datasets import bvh_source
    from nnsf.datasets.contract import features
    from nnsf.evaluate import translation as ev
    from nnsf.factor.style_model import translator_params
    from nnsf.factor.translate import StyleTranslator
    from nnsf.io import atomic_path
    from nnsf.params import load, require
    from nnsf.skeleton import JOINT_INDEX, Unifier, to_points
    from nnsf.datasets.stage import complete_grid

    params = load("params.yaml")
    table, _ = bvh_source.read_folder(a.data, fps=float(require(params, "dataset.bvh.fps")),
                                      azimuth=float(require(params, "dataset.bvh.azimuth")),
                                      elevation=float(require(params, "dataset.bvh.elevation")),
                                      facing=require(params, "dataset.bvh.facing"),
                                      center=bool(require(params, "dataset.bvh.center")))
    table, _ = complete_grid(table)
    tp = translator_params(params)
    joints = (("r_wrist", "right wrist"), ("l_ankle", "left ankle"))
    fig, axes = plt.subplots(len(joints), len(CELLS), figsize=(5 * len(CELLS), 6.4), squeeze=False)
    for col, (style, content) in enumerate(CELLS):
        hidden = ev._check_cell(table, style, content)
        train = table.loc[~hidden].reset_index(drop=True)
        P = to_points(features(train))
        ch, mo, cl = (train[k].astype(str).to_numpy() for k in ("character", "motion", "clip"))
        u = Unifier(margin=float(require(params, "unify.margin"))).fit(P, ch)
        X = u.transform(P, ch)
        real = to_points(features(table.loc[hidden]))
        real = real[table.loc[hidden, "clip"].to_numpy() == table.loc[hidden, "clip"].iloc[0]]
        curves = {"real (hidden)": real}
        for name, over in SETTINGS.items():
            tr = StyleTranslator(**{**tp, **over}).fit(X, mo, ch, cl)
            curves[name] = u.inverse_transform(tr.synthesize_cell(content, style), style)
        for row, (j, label) in enumerate(joints):
            ax = axes[row, col]
            for name, Q in curves.items():
                y = Q[:, JOINT_INDEX[j], 1] - Q[:, 0, 1]          # relative to the pelvis, px (y down)
                ax.plot(np.linspace(0, 1, len(y)), y, lw=2.2 if name.startswith("real") else 1.3,
                        color="0.55" if name.startswith("real") else None, label=name)
            ax.invert_yaxis()
            ax.set_title(f"{content} as {style}: {label}", fontsize=10)
            ax.set_xlabel("normalised time")
            ax.set_ylabel("height below the pelvis, px")
    axes[0, 0].legend(fontsize=8)
    fig.tight_layout()
    with atomic_path(Path(a.out)) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
