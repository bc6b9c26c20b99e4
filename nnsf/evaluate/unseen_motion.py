"""Held-out check: a style library's styles carried onto motion capture from elsewhere (docs/method.md §15.5).

The tuning set's leave-one-content-out protocol hides one of its own
actions; this check takes motions from *other* captures -- other performers,
skeletons and actions (a folder of ``.bvh`` files, never tuned on) -- reads
each as the library's neutral (``--source``) style and translates it into
every other style with :func:`nnsf.translate`, the model fitted on the whole
library (one view, the ``dataset.bvh`` settings).  Judged by classifiers
trained on the library's real clips only (:mod:`nnsf.evaluate.judges` and
its statistics):

* ``style_<f>``: the library's style judges, as in the other protocols.
  A motion from another capture is unlike every library clip, so these
  mostly name the same style whatever the translation (``identity`` shows
  the floor);
* ``change_<f>`` (``lr``, ``angles``): is the *change* a translation makes --
  the judge statistics of the result minus those of the input -- the change
  the style makes to the source style's take of an action?  The classifier
  is trained on the library's real pairs: each styled clip's statistics
  minus the mean of the source style's clips of the same action.  The mean
  pose offset dominates these statistics, so the ``offset`` baseline, which
  adds exactly the library's mean offset, has an edge here by construction;
* ``content_kept``: is the result still nearest its own input among all the
  inputs (1-NN on the judges' pose statistics, standardised over the inputs)?
* ``dtw_error`` to the input (template units), ``jerk_ratio`` (result over
  input) and ``lean_change_first`` (degrees).

``python -m nnsf.evaluate.unseen_motion --styles LIBRARY --motions FOLDER [FOLDER …] --source normal
--out reports/heldout_unseen_motion`` writes ``OUT.json`` (per method, per style and per motion means;
motions that could not be read, with why) and ``OUT.csv``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd
from sklearn.linear_model import LogisticRegression
from sklearn.neighbors import KNeighborsClassifier
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from nnsf.datasets import bvh_source
from nnsf.datasets.contract import features
from nnsf.datasets.stage import complete_grid
from nnsf.datasets.views import VIEWS
from nnsf.errors import InputError
from nnsf.evaluate import judges as J
from nnsf.evaluate.content_out import baseline_transfer, lean_degrees, relative_clips
from nnsf.evaluate.scores import compare_clips, jerk
from nnsf.factor.style_model import (
    StyleModel, fit_translator, translate_features, translator_params, unify_clip, unify_table,
)
from nnsf.io import write_csv, write_json
from nnsf.params import load, require

METHODS: tuple[str, ...] = ("api", "offset", "spectral", "identity")
_CHANGE = {"lr": J.pose_statistics, "angles": J.angle_statistics}


def _change_judges(clips, source):
    """Classifiers of the change a style makes: trained on (styled clip − mean of the source style's
    clips of its action) of the library's real clips, per family."""
    style = np.array([s for s, _, _ in clips])
    content = np.array([c for _, c, _ in clips])
    out = {}
    for fam, stat in _CHANGE.items():
        F = np.stack([stat(P) for _, _, P in clips])
        base = {c: F[(style == source) & (content == c)].mean(axis=0) for c in set(content)
                if ((style == source) & (content == c)).any()}
        keep = np.array([s != source and c in base for s, c in zip(style, content)])
        D = np.stack([F[i] - base[content[i]] for i in np.flatnonzero(keep)])
        model = make_pipeline(StandardScaler(), LogisticRegression(max_iter=2000) if fam == "lr" else
                              SVC(kernel="rbf", C=10.0, gamma="scale", random_state=0))
        out[fam] = model.fit(D, style[keep])
    return out


def evaluate(library: pd.DataFrame, motions: dict, *, translator_params: dict, source: str, fps: float,
             margin: float = 0.5, seed: int = 0, methods=METHODS) -> pd.DataFrame:
    """One row per (motion, style, method) (module docstring); ``motions``: name -> key points ``(n, 17, 2)``."""
    clips = [(str(g["character"].iloc[0]), str(g["motion"].iloc[0]), features(g).reshape(len(g), 17, 2))
             for _, g in library.groupby("clip", sort=True)]
    styles = sorted({s for s, _, _ in clips})
    if source not in styles:
        raise InputError("--source", "source", "a style of the library: " + ", ".join(styles), source)
    ft, unifier = unify_table(library, margin)
    model = StyleModel(fit_translator(ft, {**translator_params, "neutral": source}, fps), unifier)
    rel = relative_clips(ft)
    judges = J.Judges(seed=seed).fit([P for _, _, P in clips], [s for s, _, _ in clips], [c for _, c, _ in clips])
    change = _change_judges(clips, source)
    names = sorted(motions)
    stats_in = np.stack([J.pose_statistics(motions[k]) for k in names])
    scaler = StandardScaler().fit(stats_in)
    nearest = KNeighborsClassifier(n_neighbors=1).fit(scaler.transform(stats_in), names)
    rows = []
    for k in names:
        P = motions[k]
        X_in = unify_clip(P, unifier)[0]
        base = {fam: stat(P) for fam, stat in _CHANGE.items()}
        for s in styles:
            if s == source:
                continue
            for m in methods:
                if m == "api":
                    out = translate_features(P, s, model, fps=fps)[0]
                elif m == "identity":
                    out = P
                else:
                    out = baseline_transfer(m, P, unifier, rel, source, s)
                verdict = judges.score([out], s, "none")
                X_out = unify_clip(out, unifier)[0]
                rows.append({
                    "motion": k, "style": s, "method": m,
                    **{f"style_{fam}": int(v[0][0]) for fam, v in verdict.items()},
                    **{f"change_{fam}": int(change[fam].predict((stat(out) - base[fam])[None])[0] == s)
                       for fam, stat in _CHANGE.items()},
                    "content_kept": int(nearest.predict(scaler.transform(J.pose_statistics(out)[None]))[0] == k),
                    "dtw_error": compare_clips({"x": X_out}, X_in)["x"][0],
                    "jerk_ratio": jerk(X_out) / max(jerk(X_in), 1e-12),
                    "lean_change_first": float(abs(lean_degrees(out[:1])[0] - lean_degrees(P[:1])[0])),
                })
    return pd.DataFrame(rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nnsf.evaluate.unseen_motion", description=__doc__.split("\n")[0])
    ap.add_argument("--styles", required=True, help="the style library: a folder of labelled .bvh clips")
    ap.add_argument("--motions", required=True, nargs="+", help="folders (searched recursively) or .bvh files")
    ap.add_argument("--source", required=True, help="the library's neutral style the motions are read as")
    ap.add_argument("--out", required=True, help="output path without suffix (.csv and .json are written)")
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
        library, _ = bvh_source.read_folder(a.styles, **bvh)
        library, _ = complete_grid(library)
        tp = translator_params(params)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    files = sorted({f for m in a.motions for f in ([Path(m)] if Path(m).is_file() else Path(m).rglob("*.bvh"))})
    motions, skipped = {}, {}
    for f in files:
        name = f"{f.parent.name}/{f.stem}"
        try:
            P = bvh_source.load_clip(f, **bvh).points
            unify_clip(P, None)                      # a skeleton with a zero-length bone cannot be unified
            motions[name] = P
        except (InputError, ValueError) as exc:
            skipped[name] = str(exc).splitlines()[0]
    if len(motions) < 2:
        print(f"error: --motions: expected at least two readable .bvh motions, got {len(motions)}", file=sys.stderr)
        return 2
    res = evaluate(library, motions, translator_params=tp, source=a.source, fps=bvh["fps"],
                   margin=float(require(params, "unify.margin")), seed=int(require(params, "seed")))
    out = Path(a.out)
    write_csv(out.with_suffix(".csv"), res.round(4))
    cols = [c for c in res.columns if c not in ("motion", "style", "method")]
    tables = {}
    for key, by in (("methods", ["method"]), ("per_style", ["style", "method"]), ("per_motion", ["motion", "method"])):
        g = res.groupby(by, sort=True)[cols].mean().round(4)
        tables[key] = {(i if isinstance(i, str) else "/".join(i)): row.to_dict() for i, row in g.iterrows()}
    write_json(out.with_suffix(".json"), {
        "styles_from": Path(a.styles).name, "bvh": bvh, "source_style": a.source, "translation": tp,
        "motions": sorted(motions), "skipped": skipped, "chance": round(1 / library["character"].nunique(), 4),
        **tables})
    return 0


if __name__ == "__main__":
    sys.exit(main())
