"""Held-out translation on a motion-capture folder, outside the DVC pipeline (docs/method.md §15.5).

``python -m nnsf.evaluate.heldout_bvh --data FOLDER --out reports/heldout_<name>``
reads every labelled ``.bvh`` clip of ``FOLDER`` with the ``dataset.bvh``
settings of ``params.yaml`` (keeping the motions every style performs),
holds out every (style, content) cell (or ``--cells N`` of them, spread
evenly over the sorted grid) and scores every method of ``--methods`` with
:func:`nnsf.evaluate.translation.evaluate_cell` -- the same function the
``heldout`` stage runs, judges included.  The table is the raw key points in
pixels: every cell's unifier, models and judges see its remaining clips only.

``--protocol content`` runs leave one content out instead
(:mod:`nnsf.evaluate.content_out`): ``--source STYLE`` names the style of the
clips translated (default ``translation.neutral``; none: every other
style's), ``--methods`` are then of :data:`nnsf.evaluate.content_out.METHODS`.

Writes ``OUT.csv`` (one row per cell × method) and ``OUT.json`` (per method,
per style and per content means; seconds per cell or fold, with the load
average), after every finished cell or fold, so an interrupted run keeps
what it has.  ``--jobs`` processes (one BLAS thread each).
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets import bvh_source
from nnsf.datasets.stage import complete_grid as _complete_grid
from nnsf.datasets.views import VIEWS
from nnsf.errors import InputError
from nnsf.evaluate import content_out
from nnsf.evaluate.gp_translation import GP_TRANSLATION_METHODS, translation_gp_params
from nnsf.evaluate.heldout_report import _target_check
from nnsf.evaluate.translation import DEFAULT_VARIANTS, STAGE_METHODS, _pick, evaluate_cell, grid_cells
from nnsf.factor.style_model import translator_params
from nnsf.io import read_json, write_csv, write_json
from nnsf.params import load, require

__all__ = ["main", "summary_tables", "markdown", "target_check"]

METRICS = ("dtw_error", "style_lr", "content_lr", "style_nn1", "content_nn1", "style_angles",
           "content_angles", "style_all", "content_all", "style_acc", "content_acc", "jerk_ratio")


def _round(x):
    return None if pd.isna(x) else round(float(x), 4)


def summary_tables(results: pd.DataFrame) -> dict:
    """Per method, per (style, method) and per (content, method) means of :data:`METRICS`, 4 decimals."""
    out = {}
    for key, by in (("methods", ["method"]), ("per_style", ["style", "method"]),
                    ("per_content", ["content", "method"])):
        g = results.groupby(by, sort=False)[list(METRICS)].mean()
        g["cells"] = results.groupby(by, sort=False).size()
        rows = {}
        for idx, row in g.iterrows():
            name = idx if isinstance(idx, str) else "/".join(idx)
            rows[name] = {k: _round(v) for k, v in row.items() if k != "cells"} | {"cells": int(row["cells"])}
        out[key] = rows
    return out


def markdown(summary: dict, key: str = "methods", only=None) -> str:
    """A Markdown table of one section of a written ``OUT.json`` (``methods``, ``per_style`` or
    ``per_content``): DTW error in % of the torso, then every judge's style/content accuracy.
    ``only``: the methods to show (all by default), in the JSON's order."""
    fams = ("lr", "nn1", "angles", "all")
    head = "| " + ("method" if key == "methods" else "cell group / method") + " | DTW % torso | " + \
        " | ".join(f"style {f} | content {f}" for f in fams) + " | jerk ratio | cells |"
    lines = [head, "|---" + "|---:" * (3 + 2 * len(fams)) + "|"]
    rank = {m: i for i, m in enumerate(STAGE_METHODS)}

    def order(name):            # the JSON's keys are sorted: back to the methods' table order
        *group, method = name.split("/")
        return (group, rank.get(method, len(rank)), method)

    for name, v in sorted(summary[key].items(), key=lambda kv: order(kv[0])):
        if only and name.split("/")[-1] not in only:
            continue
        cells = [f"{100 * v['dtw_error']:.1f}" if v["dtw_error"] else "0"]
        for f in fams:
            cells += [f"{v[f'style_{f}']:.2f}", f"{v[f'content_{f}']:.2f}"]
        cells += [f"{v['jerk_ratio']:.2f}", str(v["cells"])]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def target_check(results: pd.DataFrame, method: str = "nnsf") -> dict:
    """The translation targets for ``method`` on these results
    (:func:`nnsf.evaluate.translation._target_check`)."""
    cols = ["dtw_error", *[c for c in results.columns if c.startswith(("style_", "content_"))]]
    means = results.groupby("method")[cols].mean()
    per_method = {m: {k: (None if pd.isna(v) else float(v)) for k, v in row.items()} for m, row in means.iterrows()}
    return _target_check(per_method, method)


def _one(args):
    table, s, c, kw = args
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        t0, c0 = time.perf_counter(), time.process_time()
        r = evaluate_cell(table, s, c, **kw)
        r["seconds"] = time.perf_counter() - t0
        r["cpu_seconds"] = time.process_time() - c0
    return r


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m nnsf.evaluate.heldout_bvh", description=__doc__.split("\n")[0])
    ap.add_argument("--data", help="folder of labelled .bvh clips")
    ap.add_argument("--out", required=True, help="output path without suffix (.csv and .json are written)")
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--view", choices=("front", "side", "three-quarter"), default=None,
                    help="project the clips in this view (default: dataset.bvh.azimuth)")
    ap.add_argument("--cells", type=int, default=0, help="cells to hold out, spread evenly (0: all)")
    ap.add_argument("--methods", default=",".join(STAGE_METHODS),
                    help="comma-separated methods of nnsf.evaluate.translation (default: every method "
                         "of the heldout stage)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--protocol", choices=("cell", "content"), default="cell",
                    help="leave one cell out (default) or leave one content out")
    ap.add_argument("--source", default=None,
                    help="--protocol content: the style of the clips translated (default: translation.neutral)")
    ap.add_argument("--markdown", choices=("methods", "per_style", "per_content"),
                    help="print that table of an existing OUT.json and exit")
    ap.add_argument("--only", default="", help="with --markdown: comma-separated methods to show")
    a = ap.parse_args(argv)
    if a.markdown:
        print(markdown(read_json(Path(a.out).with_suffix(".json")), a.markdown,
                       only=[m for m in a.only.split(",") if m] or None))
        return 0
    if not a.data:
        print("error: --data: expected a folder of labelled .bvh clips, got nothing", file=sys.stderr)
        return 2
    try:
        params = load(a.params)
        kw = {"fps": float(require(params, "dataset.bvh.fps")),
              "azimuth": VIEWS[a.view] if a.view else float(require(params, "dataset.bvh.azimuth")),
              "elevation": float(require(params, "dataset.bvh.elevation")),
              "facing": require(params, "dataset.bvh.facing"),
              "center": bool(require(params, "dataset.bvh.center"))}
        table, _ = bvh_source.read_folder(a.data, **kw)
        table, _ = _complete_grid(table)
        tp = translator_params(params)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.protocol == "content":
        return _content_out(a, params, table, tp, kw)
    methods = tuple(m for m in a.methods.split(",") if m)
    bad = [m for m in methods if m not in STAGE_METHODS]
    if bad or not methods:
        print(f"error: --methods: expected a comma-separated list of {', '.join(STAGE_METHODS)}, got "
              f"{a.methods!r}", file=sys.stderr)
        return 2
    gp = [m for m in methods if m in GP_TRANSLATION_METHODS]
    try:
        gp_params = translation_gp_params(params, table, gp) if gp else None
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    cells = _pick(grid_cells(table), a.cells)
    ev = dict(methods=methods, translator_params=tp, variants=dict(DEFAULT_VARIANTS), gp_params=gp_params,
              bilinear_rank=int(require(params, "translation.bilinear_rank")),
              margin=float(require(params, "unify.margin")), seed=int(require(params, "seed")))
    out = Path(a.out)
    jobs = [(table, s, c, ev) for s, c in cells]
    parts = []

    def flush():
        res = pd.concat(parts, ignore_index=True)
        write_csv(out.with_suffix(".csv"), res.round(4))
        per_cell = res.groupby(["style", "content"])[["seconds", "cpu_seconds"]].first()
        write_json(out.with_suffix(".json"), {
            "data": Path(a.data).name, "bvh": kw, "translation": {k: v for k, v in tp.items()},
            "cells": len(per_cell), "cells_planned": len(cells), "methods_run": list(methods),
            "seconds_per_cell": {"wall_mean": _round(per_cell["seconds"].mean()),
                                 "wall_max": _round(per_cell["seconds"].max()),
                                 "cpu_mean": _round(per_cell["cpu_seconds"].mean()),
                                 "cpu_max": _round(per_cell["cpu_seconds"].max())},
            "target": target_check(res),
            **summary_tables(res)})

    if a.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        with ProcessPoolExecutor(a.jobs) as pool:
            for i, r in enumerate(pool.map(_one, jobs)):
                parts.append(r)
                flush()
                print(f"{i + 1}/{len(jobs)} {r['style'].iloc[0]}/{r['content'].iloc[0]} "
                      f"{r['cpu_seconds'].iloc[0]:.1f} s cpu", flush=True)
    else:
        for i, j in enumerate(jobs):
            parts.append(_one(j))
            flush()
            print(f"{i + 1}/{len(jobs)} {j[1]}/{j[2]} {parts[-1]['cpu_seconds'].iloc[0]:.1f} s cpu", flush=True)
    return 0


def _content_out(a, params, table, tp, bvh) -> int:
    """``--protocol content``: every fold in turn (or over ``--jobs`` processes), written after each."""
    methods = content_out.METHODS if a.methods == ",".join(STAGE_METHODS) else \
        tuple(m for m in a.methods.split(",") if m)
    bad = [m for m in methods if m not in content_out.METHODS]
    if bad or not methods:
        print(f"error: --methods: expected a comma-separated list of {', '.join(content_out.METHODS)}, got "
              f"{a.methods!r}", file=sys.stderr)
        return 2
    source = a.source if a.source is not None else tp.get("neutral")
    styles = set(table["character"].astype(str))
    if source is not None and source not in styles:
        print(f"error: --source: expected a style of {a.data} ({', '.join(sorted(styles))}), got {source!r}",
              file=sys.stderr)
        return 2
    folds = content_out.content_folds(table, source)
    if a.cells:
        folds = _pick(folds, a.cells)
    kw = dict(translator_params=tp, methods=methods, source_style=source, fps=float(bvh["fps"]),
              margin=float(require(params, "unify.margin")), seed=int(require(params, "seed")))
    out = Path(a.out)
    parts, seconds = [], {}

    def flush():
        res = pd.concat(parts, ignore_index=True)
        write_csv(out.with_suffix(".csv"), res.round(4))
        fit = [v["fit_seconds"] for v in seconds.values()]
        tr = [v["translate_seconds"] for v in seconds.values()]
        write_json(out.with_suffix(".json"), {
            "data": Path(a.data).name, "bvh": bvh, "protocol": "leave one content out",
            "source_style": source, "translation": dict(tp), "folds": len(seconds), "folds_planned": len(folds),
            "methods_run": list(methods),
            "seconds_per_fold": {"fit_mean": _round(np.mean(fit)), "fit_max": _round(np.max(fit)),
                                 "translate_mean": _round(np.mean(tr)), "translate_max": _round(np.max(tr)),
                                 "fit_plus_translate_max": _round(max(f + t for f, t in zip(fit, tr))),
                                 "jobs": a.jobs, "load_average": _round(os.getloadavg()[0])},
            "target": content_out.target_check(res),
            **content_out.summary_tables(res)})

    jobs = [(table, c, kw) for c in folds]
    if a.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        with ProcessPoolExecutor(a.jobs) as pool:
            for c, (rows, info) in zip(folds, pool.map(_fold, jobs)):
                parts.append(rows)
                seconds[c] = info
                flush()
                print(f"{len(seconds)}/{len(folds)} {c} fit {info['fit_seconds']:.1f} s", flush=True)
    else:
        for job in jobs:
            c = job[1]
            rows, info = _fold(job)
            parts.append(rows)
            seconds[c] = info
            flush()
            print(f"{len(seconds)}/{len(folds)} {c} fit {info['fit_seconds']:.1f} s, translate "
                  f"{info['translate_seconds']:.2f} s", flush=True)
    return 0


def _fold(args):
    """One leave-one-content-out fold (one BLAS thread): its rows and seconds."""
    from threadpoolctl import threadpool_limits

    table, content, kw = args
    with threadpool_limits(1):
        rows, info = content_out.evaluate_content(table, content, **kw)
    return rows, {k: info[k] for k in ("fit_seconds", "translate_seconds", "cells")}


if __name__ == "__main__":
    sys.exit(main())
