"""What makes a style recognisable, and how much of it carries to an action it was not seen in (docs/method.md §8.4).

For every real clip, five cues of its key points (root-relative, divided by
the clip's body length -- the median summed bone length --, so any unit):

* ``lean``: the mean angle of the pelvis-to-neck line from the image
  vertical (1 number);
* ``posture``: the mean root-relative pose (32), i.e. the pose offsets;
* ``swing``: every coordinate's standard deviation over the clip (32);
* ``tempo``: the log of the motion's effective frequency, Σ mean |velocity|
  over Σ standard deviation, per second (1);
* ``bands``: the log root-mean-square amplitude of every coordinate in each
  band (below 0.5 Hz, the four octaves 0.5-8 Hz, above 8 Hz;
  :func:`nnsf.factor.style_transfer.band_amplitudes`, 6 × 32).

Two measures per cue, with every content held out in turn:

* ``accuracy``: a style classifier (standardised logistic regression) on the
  cue alone, trained on the other contents' clips, tested on the held-out
  content's -- how recognisable the style is from that cue on an action the
  classifier never saw (chance: 1 / styles);
* ``r2_mean`` / ``r2_near``: how much of a style's effect on the held-out
  content -- cue(style, c) − cue(source, c) -- is predicted by its effect on
  the other contents: their plain mean, or their mean weighted by how alike
  each content's source-style motion is to c's
  (:func:`nnsf.factor.style_transfer.content_weights` on the band
  descriptor).  1 − Σ(effect − prediction)² / Σ effect².

``python -m nnsf.evaluate.style_cues --data FOLDER --source normal --out reports/style_cues_FOLDER``
writes ``OUT.json``; ``--params`` gives the ``dataset.bvh`` view and rate.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from nnsf.datasets import bvh_source
from nnsf.datasets.contract import features
from nnsf.datasets.stage import complete_grid
from nnsf.datasets.views import VIEWS
from nnsf.errors import InputError
from nnsf.factor import style_transfer as st
from nnsf.io import write_json
from nnsf.params import load, require
from nnsf.skeleton.layout import BONES

CUES: tuple[str, ...] = ("lean", "posture", "swing", "tempo", "bands")


def clip_cues(P, fps: float) -> dict[str, np.ndarray]:
    """The five cues of one clip of key points ``(n, 17, 2)`` (y down), module docstring."""
    P = np.asarray(P, dtype=float)
    B = np.array([P[:, c] - P[:, p] for p, c in BONES])
    size = float(np.median(np.linalg.norm(B, axis=-1).sum(axis=0)))
    R = ((P[:, 1:] - P[:, :1]) / size).reshape(len(P), -1)
    v = P[:, 9] - P[:, 0]
    sd = R.std(axis=0)
    speed = np.abs(np.diff(R, axis=0)).mean(axis=0) if len(R) > 1 else np.zeros_like(sd)
    return {"lean": np.array([np.degrees(np.arctan2(v[:, 0], -v[:, 1])).mean()]),
            "posture": R.mean(axis=0), "swing": sd,
            "tempo": np.array([np.log(max(speed.sum() * fps, 1e-12) / max(sd.sum(), 1e-12))]),
            "bands": st.describe(st.band_amplitudes(R, fps))}


def analyse(table: pd.DataFrame, source_style: str, fps: float, seed: int = 0) -> dict:
    """``{cue: {"accuracy", "r2_mean", "r2_near"}}`` over every content held out in turn, and ``chance``."""
    rows = []
    for _, g in table.groupby("clip", sort=True):
        rows.append((str(g["character"].iloc[0]), str(g["motion"].iloc[0]),
                     clip_cues(features(g).reshape(len(g), 17, 2), fps)))
    style = np.array([r[0] for r in rows])
    content = np.array([r[1] for r in rows])
    contents = sorted(set(content))
    if source_style not in set(style):
        raise InputError("table", "character", f"the source style {source_style!r} among the styles",
                         sorted(set(style)))
    cells = {}
    for s, c, cue in rows:
        cells.setdefault((s, c), []).append(cue)
    cell = {k: {q: np.mean([x[q] for x in v], axis=0) for q in CUES} for k, v in cells.items()}
    out = {}
    for q in CUES:
        F = np.stack([r[2][q] for r in rows])
        hits = n = 0
        for c in contents:
            test = content == c
            if len(set(style[~test])) < 2 or not test.any():
                continue
            clf = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000)).fit(F[~test], style[~test])
            hits += int((clf.predict(F[test]) == style[test]).sum())
            n += int(test.sum())
        num_m = num_n = den = 0.0
        for c in contents:
            others = [c2 for c2 in contents if c2 != c and (source_style, c2) in cell]
            if (source_style, c) not in cell or not others:
                continue
            w = st.content_weights(cell[(source_style, c)]["bands"],
                                   np.stack([cell[(source_style, c2)]["bands"] for c2 in others]))
            for s in sorted(set(style) - {source_style}):
                have = [i for i, c2 in enumerate(others) if (s, c2) in cell]
                if (s, c) not in cell or not have:
                    continue
                eff = cell[(s, c)][q] - cell[(source_style, c)][q]
                effs = np.stack([cell[(s, others[i])][q] - cell[(source_style, others[i])][q] for i in have])
                wi = w[have] / w[have].sum()
                num_m += float(((eff - effs.mean(axis=0)) ** 2).sum())
                num_n += float(((eff - wi @ effs) ** 2).sum())
                den += float((eff ** 2).sum())
        out[q] = {"accuracy": round(hits / max(n, 1), 4), "dims": int(F.shape[1]),
                  "r2_mean": round(1 - num_m / den, 4) if den else None,
                  "r2_near": round(1 - num_n / den, 4) if den else None}
    return {"cues": out, "chance": round(1 / len(set(style)), 4), "styles": len(set(style)),
            "contents": len(contents), "clips": len(rows), "source_style": source_style, "fps": fps}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nnsf.evaluate.style_cues", description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True, help="folder of labelled .bvh clips")
    ap.add_argument("--source", required=True, help="the style the effects are measured from (e.g. normal)")
    ap.add_argument("--out", required=True, help="output path without suffix (.json is written)")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--view", choices=("front", "side", "three-quarter"), default=None,
                    help="project the clips in this view (default: dataset.bvh.azimuth)")
    a = ap.parse_args(argv)
    try:
        params = load(a.params)
        bvh = {"fps": float(require(params, "dataset.bvh.fps")),
               "azimuth": VIEWS[a.view] if a.view else float(require(params, "dataset.bvh.azimuth")),
               "elevation": float(require(params, "dataset.bvh.elevation")),
               "facing": require(params, "dataset.bvh.facing"), "center": bool(require(params, "dataset.bvh.center"))}
        table, _ = bvh_source.read_folder(a.data, **bvh)
        table, _ = complete_grid(table)
        result = analyse(table, a.source, bvh["fps"], seed=int(require(params, "seed")))
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    write_json(Path(a.out).with_suffix(".json"), {"data": Path(a.data).name, "bvh": bvh, **result})
    return 0


if __name__ == "__main__":
    sys.exit(main())
