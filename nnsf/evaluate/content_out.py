"""Held-out style translation, the user's situation: leave one content out (docs/method.md §15.5).

A user brings a motion of an action the style library may not hold and asks
for a style.  For every content c (a fold):

* every clip of c is removed; the style model is fitted on the rest as
  ``nnsf styles`` fits it (:func:`nnsf.factor.style_model.unify_table`,
  :func:`~nnsf.factor.style_model.fit_model` to a file, read back), with
  the source style as its neutral style when one is named;
* each source clip of c (the ``source_style`` take, or every other style's
  clips) goes, as read (pixels), through :func:`nnsf.translate` into every
  other style s that performs c -- one cell (s, c) each;
* the independent judges (:mod:`nnsf.evaluate.judges`), fitted on every real
  clip except the cell's (as in leave one cell out), say whether the result
  is of style s and of content c; the real clips of the cell are the ceiling.

Methods (:data:`METHODS`): ``api`` (the default call), ``api_source`` (told
the source clip's style), ``api_offset_swing`` and ``api_recombine`` (the
same call with the model's other ``transfer`` settings), the baselines
``offset`` and ``spectral`` (:mod:`nnsf.evaluate.content_baselines`, on the
root-relative pose of the clip unified with its own proportions and mapped
back the same way), ``identity`` (the source clip) and ``real``.

Scores per (cell, method): the judges' style and content verdicts per family
(``lr``, ``nn1``, ``angles``, ``all``); ``dtw_error`` against the cell's real
clips (both unified with their own proportions, template units);
``jerk_ratio`` (mean |second difference| over that of the cell's real clips);
``lean_change_first`` (degrees between the first frame's lean -- the pelvis to
neck line against the image vertical -- and the source's).  Each fold also
records the seconds of the fit and of translating its cells with ``api``.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets.contract import features
from nnsf.errors import InputError
from nnsf.evaluate import content_baselines
from nnsf.evaluate.judges import FAMILIES as JUDGE_FAMILIES
from nnsf.evaluate.judges import Judges
from nnsf.evaluate.scores import compare_clips, jerk
from nnsf.factor.style_model import StyleModel, fit_model, translate_features, unify_clip, unify_table
from nnsf.params import CONTENT_OUT_METHODS as METHODS

__all__ = ["METHODS", "RESULT_COLUMNS", "content_folds", "evaluate_content", "leave_one_content_out",
           "summary_tables", "target_check", "lean_degrees", "relative_clips", "baseline_transfer"]

#: The public call and the variants it is scored with: method -> ``transfer`` setting (None: the model's).
_API: dict[str, str | None] = {"api": None, "api_source": None, "api_offset_swing": "offset_swing",
                               "api_recombine": "recombine"}

JUDGE_COLUMNS: tuple[str, ...] = tuple(f"{what}_{fam}" for fam in (*JUDGE_FAMILIES, "all")
                                       for what in ("style", "content"))
RESULT_COLUMNS: tuple[str, ...] = ("style", "content", "method", *JUDGE_COLUMNS, "dtw_error", "jerk_ratio",
                                   "lean_change_first", "n_sources", "n_hidden")
_METRICS: tuple[str, ...] = (*JUDGE_COLUMNS, "dtw_error", "jerk_ratio", "lean_change_first")

_PELVIS, _NECK = 0, 9


def lean_degrees(P) -> np.ndarray:
    """Lean of every frame of key points ``(n, 17, 2)`` (y down): the pelvis-to-neck line's angle
    from the image vertical, degrees, positive towards +x."""
    P = np.asarray(P, dtype=float)
    v = P[:, _NECK] - P[:, _PELVIS]
    return np.degrees(np.arctan2(v[:, 0], -v[:, 1]))


def _clips(table):
    out = []
    for name, g in table.groupby("clip", sort=True):
        out.append((str(name), str(g["character"].iloc[0]), str(g["motion"].iloc[0]),
                    features(g).reshape(len(g), 17, 2)))
    return out


def relative_clips(table) -> dict:
    """``{style: {content: [root-relative pose (n, 32), ...]}}`` of a unified contract table (template units)."""
    rel: dict = {}
    for _, g in table.groupby("clip", sort=True):
        Q = features(g).reshape(len(g), 17, 2)
        R = (Q[:, 1:] - Q[:, :1]).reshape(len(g), -1)
        rel.setdefault(str(g["character"].iloc[0]), {}).setdefault(str(g["motion"].iloc[0]), []).append(R)
    return rel


def baseline_transfer(name: str, P, unifier, rel: dict, source: str, target: str) -> np.ndarray:
    """The ``offset`` or ``spectral`` baseline on key points ``P`` ``(n, 17, 2)`` of style ``source``:
    the clip unified with its own proportions (as :func:`nnsf.translate` does), its root-relative pose
    transferred (:mod:`nnsf.evaluate.content_baselines`, training clips ``rel`` from
    :func:`relative_clips`), mapped back to the clip's coordinates."""
    X, u = unify_clip(P, unifier)
    Q = X.reshape(len(X), 17, 2)
    R = (Q[:, 1:] - Q[:, :1]).reshape(len(X), -1)
    fn = content_baselines.offset_transfer if name == "offset" else content_baselines.spectral_transfer
    R2 = fn(R, rel[target], rel[source]).reshape(len(X), 16, 2) + Q[:, :1]
    return u.inverse_transform(np.concatenate([Q[:, :1], R2], axis=1).reshape(len(X), 34), "__clip__")


def content_folds(table: pd.DataFrame, source_style: str | None = None) -> list[str]:
    """Contents that can be held out: performed by a source (``source_style``, or any style) and another
    style, with at least two styles left in the other contents.  Sorted."""
    pairs = table[["character", "motion"]].drop_duplicates().astype(str)
    out = []
    for c, g in pairs.groupby("motion"):
        styles = set(g["character"])
        if source_style is not None and source_style not in styles:
            continue
        if len(styles - ({source_style} if source_style else set())) < (1 if source_style else 2):
            continue
        if pairs.loc[pairs["motion"] != c, "character"].nunique() < 2:
            continue
        out.append(str(c))
    return sorted(out)


def evaluate_content(table: pd.DataFrame, content: str, *, translator_params: dict, methods=METHODS,
                     source_style: str | None = None, margin: float = 0.5, fps: float | None = None,
                     seed: int = 0, max_sources: int | None = None, model_dir=None):
    """Hold out every clip of ``content``, fit the style model on the rest, score every cell of the content.

    Parameters
    ----------
    table : a contract table in pixels; ``character`` is the style, ``motion`` the content.
    content : the content to hold out.
    translator_params : StyleTranslator parameters (``translation.*``); ``neutral`` is
        replaced by ``source_style`` when that is given.
    methods : names from :data:`METHODS`.
    source_style : the style of the source clips (e.g. ``normal``); None: every other style's clips.
    margin : the unifier's margin (``unify.margin``).
    fps : the clips' frame rate.
    max_sources : at most this many source clips per cell (evenly spread), all by default.
    model_dir : a folder for the fold's model file ``styles.npz`` (kept there); a temporary one by default.

    Returns
    -------
    ``(rows, info)``: a DataFrame with :data:`RESULT_COLUMNS` (one row per cell and method, means
    over sources × hidden clips), and ``{"fit_seconds", "translate_seconds", "cells",
    "model_contents", "model"}`` (the model file's contents, and the loaded model).
    """
    content = str(content)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"unknown method(s) {bad}; choose from {list(METHODS)}")
    mo = table["motion"].astype(str).to_numpy()
    if content not in set(mo):
        raise InputError("table", "motion", "a content of the table", content)
    train = table.loc[mo != content].reset_index(drop=True)
    clips = _clips(table)
    tp = dict(translator_params)
    if source_style is not None:
        tp["neutral"] = source_style

    t0 = time.perf_counter()
    ft, unifier = unify_table(train, margin)
    with tempfile.TemporaryDirectory(prefix="nnsf-content-out-") as tmp:
        path = Path(model_dir or tmp) / "styles.npz"
        fit_model([(None, ft, unifier)], tp, path, fps=fps, source=f"all contents but {content}")
        model = StyleModel.load(path)
    fit_seconds = time.perf_counter() - t0
    tr = model.translator
    transfer = tr.transfer

    rel = relative_clips(ft)
    styles = sorted({s for _, s, c, _ in clips if c == content})
    targets = [s for s in styles if s != source_style and s in rel]
    rows, translate_seconds = [], 0.0
    c_style = np.array([s for _, s, _, _ in clips])
    c_content = np.array([c for _, _, c, _ in clips])
    for s in targets:
        keep = ~((c_style == s) & (c_content == content))
        judges = Judges(seed=seed).fit([P for (_, _, _, P), k in zip(clips, keep) if k], c_style[keep],
                                       c_content[keep])
        hidden = [P for _, s2, c2, P in clips if s2 == s and c2 == content]
        hidden_X = [unify_clip(P, unifier)[0] for P in hidden]
        jerk_real = float(np.mean([jerk(X) for X in hidden_X]))
        sources = [(P, s2) for _, s2, c2, P in clips
                   if c2 == content and (s2 == source_style if source_style is not None else s2 != s)]
        if max_sources is not None and len(sources) > max_sources:
            pick = np.unique(np.linspace(0, len(sources) - 1, max_sources).round().astype(int))
            sources = [sources[i] for i in pick]
        outs: dict[str, list] = {m: [] for m in methods}
        for P, src in sources:
            for m in methods:
                if m in _API:
                    tr.set_params(transfer=_API[m] or transfer)
                    t = time.perf_counter()
                    out = translate_features(P, s, model, source_style=src if m == "api_source" else None)[0]
                    if m == "api":
                        translate_seconds += time.perf_counter() - t
                elif m in ("offset", "spectral"):
                    out = baseline_transfer(m, P, unifier, rel, src, s)
                elif m == "identity":
                    out = P
                else:
                    continue
                outs[m].append((out, P))
        tr.set_params(transfer=transfer)
        if "real" in methods:
            outs["real"] = [(P, P) for P in hidden]
        for m in methods:
            pairs = outs[m]
            if not pairs:
                continue
            verdict = judges.score([o for o, _ in pairs], s, content)
            X_out = [unify_clip(o, unifier)[0] for o, _ in pairs]
            dtw = [np.mean([compare_clips({"x": X}, Xh)["x"][0] for Xh in hidden_X]) for X in X_out]
            rows.append({
                "style": s, "content": content, "method": m,
                **{f"{w}_{fam}": float(np.mean(v[i])) for fam, v in verdict.items()
                   for i, w in enumerate(("style", "content"))},
                "dtw_error": float(np.mean(dtw)),
                "jerk_ratio": float(np.mean([jerk(X) for X in X_out])) / max(jerk_real, 1e-12),
                "lean_change_first": float(np.mean([abs(lean_degrees(o[:1])[0] - lean_degrees(p[:1])[0])
                                                    for o, p in pairs])),
                "n_sources": len(sources) if m != "real" else 0, "n_hidden": len(hidden),
            })
    info = {"fit_seconds": fit_seconds, "translate_seconds": translate_seconds, "cells": len(targets),
            "model_contents": list(model.meta.get("contents", [])), "model": model}
    return pd.DataFrame(rows, columns=list(RESULT_COLUMNS)), info


def leave_one_content_out(table: pd.DataFrame, contents=None, *, progress=None, **kwargs):
    """:func:`evaluate_content` for every fold (``contents``, default :func:`content_folds`).

    Returns ``(rows, folds)``: every fold's rows, and per content its seconds
    (``fit_seconds``, ``translate_seconds``) and number of cells.
    ``progress(i, n, content, seconds)`` is called after each fold.
    """
    folds = content_folds(table, kwargs.get("source_style")) if contents is None else [str(c) for c in contents]
    if not folds:
        raise InputError("table", "motion", "a content performed by the source style and another style",
                         "none")
    parts, info = [], {}
    for i, c in enumerate(folds):
        t = time.perf_counter()
        rows, fold = evaluate_content(table, c, **kwargs)
        parts.append(rows)
        info[c] = {k: fold[k] for k in ("fit_seconds", "translate_seconds", "cells")}
        if progress is not None:
            progress(i, len(folds), c, time.perf_counter() - t)
    return pd.concat(parts, ignore_index=True), info


def summary_tables(results: pd.DataFrame, digits: int = 4) -> dict:
    """Means of every metric per method, per (style, method) and per (content, method); each cell weighs
    the same.  ``{"methods": {m: {...}}, "per_style": {"s/m": {...}}, "per_content": {"c/m": {...}}}``."""
    order = {m: i for i, m in enumerate(METHODS)}
    out = {}
    for key, by in (("methods", ["method"]), ("per_style", ["style", "method"]),
                    ("per_content", ["content", "method"])):
        g = results.groupby(by, sort=True)[list(_METRICS)].mean()
        n = results.groupby(by, sort=True).size()
        rows = {}
        for idx in sorted(g.index, key=lambda i: ((i,) if isinstance(i, str) else i)[:-1]
                          + (order.get(i if isinstance(i, str) else i[-1], len(order)),)):
            name = idx if isinstance(idx, str) else "/".join(idx)
            rows[name] = {k: (None if pd.isna(v) else round(float(v), digits)) for k, v in g.loc[idx].items()}
            rows[name]["cells"] = int(n.loc[idx])
        out[key] = rows
    return out


#: The targets of the default public call under leave one content out.
TARGET_STYLE = {"lr": 0.45, "angles": 0.35}
TARGET_CONTENT_LR = 0.70
TARGET_JERK = (0.7, 1.5)
TARGET_STYLE_FLOOR_LR = 0.25
TARGET_BASELINES = ("offset", "spectral")


def target_check(results: pd.DataFrame, method: str = "api") -> dict:
    """The leave-one-content-out targets for ``method``, each recorded as passed or not.

    ``style_<f> >= x`` for lr (0.45) and angles (0.35), ``content_lr >= 0.70``, the jerk ratio within
    [0.7, 1.5], every style's ``style_lr >= 0.25``, and, per baseline run (offset, spectral), style
    above it for both judges.  nn1 is reported, with no target.  ``met``: all passed (None when
    ``method`` was not run).
    """
    if method not in set(results["method"]):
        return {"method": method, "met": None, "checks": {}}
    means = results.groupby("method")[list(_METRICS)].mean()
    v = means.loc[method]
    checks = {}
    for fam, goal in TARGET_STYLE.items():
        checks[f"style_{fam} >= {goal:.2f}"] = {"value": float(v[f"style_{fam}"]), "target": goal,
                                                "met": bool(v[f"style_{fam}"] >= goal)}
    checks[f"content_lr >= {TARGET_CONTENT_LR:.2f}"] = {"value": float(v["content_lr"]),
                                                         "target": TARGET_CONTENT_LR,
                                                         "met": bool(v["content_lr"] >= TARGET_CONTENT_LR)}
    lo, hi = TARGET_JERK
    checks[f"jerk_ratio in [{lo}, {hi}]"] = {"value": float(v["jerk_ratio"]), "target": [lo, hi],
                                            "met": bool(lo <= v["jerk_ratio"] <= hi)}
    per_style = results[results["method"] == method].groupby("style")["style_lr"].mean()
    worst = per_style.idxmin()
    checks[f"every style's style_lr >= {TARGET_STYLE_FLOOR_LR:.2f}"] = {
        "value": float(per_style.min()), "style": str(worst), "target": TARGET_STYLE_FLOOR_LR,
        "met": bool(per_style.min() >= TARGET_STYLE_FLOOR_LR)}
    for b in TARGET_BASELINES:
        if b in means.index:
            for fam in TARGET_STYLE:
                checks[f"style_{fam} > {b}"] = {"value": float(v[f"style_{fam}"]),
                                                "target": float(means.loc[b, f"style_{fam}"]),
                                                "met": bool(v[f"style_{fam}"] > means.loc[b, f"style_{fam}"])}
    return {"method": method, "met": all(c["met"] for c in checks.values()), "checks": checks,
            "passed": sum(c["met"] for c in checks.values()), "of": len(checks)}
