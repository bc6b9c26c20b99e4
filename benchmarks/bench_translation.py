"""Time the held-out translation stage (docs/method.md §15.5): one cell, and the whole grid.

Builds the features the pipeline would (Bandai-Namco BVH -> key points at
``--fps`` -> template unification, or the embedded synthetic set), then

* times one held-out cell with every method of the stage
  (:func:`nnsf.evaluate.translation.run_cell`, one BLAS thread), ``--repeat``
  times, the fastest kept;
* with ``--full``, runs the whole stage (:func:`nnsf.evaluate.heldout_report.write_heldout`)
  with its cells fanned out over ``--workers`` processes (joblib) and writes
  its reports under ``--out``; without, it prints the estimate
  cells × one cell / workers.

    .venv/bin/python benchmarks/bench_translation.py bandai [--data ../shared/data/bandai-namco-1]
        [--fps 15] [--workers 2] [--full] [--out /tmp/heldout-bandai]
    .venv/bin/python benchmarks/bench_translation.py synthetic [--full] [--max-cells 0]

Parameters are ``params.yaml``'s, with the ``translation`` section below
filling in whatever the file does not have yet.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from nnsf.datasets import contract
from nnsf.evaluate.heldout_report import write_heldout as heldout
from nnsf.evaluate.translation import CellJob, STAGE_METHODS, grid_cells, run_cell
from nnsf.factor.style_model import translator_params
from nnsf.io import write_json
from nnsf.skeleton import Unifier, to_points

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = ROOT.parent / "shared" / "data" / "bandai-namco-1"

#: The translation section proposed for params.yaml (used where the file has none).
TRANSLATION = {
    "rank": 16, "alpha": 0.01, "beta": 10.0, "label": "motion", "basis": "aligned",
    "synthesis": "consensus", "amplitude": "restore", "tempo": True, "ridge": 0.5,
    "max_iter": 150, "align_iter": 150, "bilinear_rank": 1, "max_sources": 0, "max_cells": 0,
    "examples": 3, "methods": list(STAGE_METHODS),
}


def build_features(args, out: Path):
    """Write ``features.csv`` and ``unifier.json`` into ``out`` like the features stage."""
    if args.dataset == "bandai":
        from nnsf.datasets.bvh_source import read_folder
        table, report = read_folder(args.data, fps=args.fps)
        for line in report:
            print("  report:", line)
    else:
        from nnsf.datasets.synthetic import generate
        table = generate(characters=args.characters, clips_per_cell=3, frames=24, noise_px=0.4, seed=0)
    P = to_points(contract.features(table))
    ch = table["character"].astype(str).to_numpy()
    u = Unifier(margin=0.5).fit(P, ch)
    feats = table.copy()
    feats.loc[:, list(contract.COLUMNS[4:])] = u.transform(P, ch)
    out.mkdir(parents=True, exist_ok=True)
    contract.write_table(out / "features.csv", feats)
    write_json(out / "unifier.json", u.to_dict())
    return feats


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset", choices=["bandai", "synthetic"])
    ap.add_argument("--data", type=Path, default=DEFAULT)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--characters", type=int, default=9)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--full", action="store_true", help="run the whole stage")
    ap.add_argument("--max-cells", type=int, default=None, help="translation.max_cells (0 = all)")
    ap.add_argument("--set", type=json.loads, default={},
                    help="JSON overrides of the translation section, e.g. '{\"tempo\": false}'")
    ap.add_argument("--out", type=Path, default=Path("/tmp/heldout"))
    args = ap.parse_args(argv)

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["translation"] = {**TRANSLATION, **params.get("translation", {}), **args.set}
    params["dataset"] = {**params.get("dataset", {}),
                         "name": "bvh" if args.dataset == "bandai" else "synthetic"}
    if args.max_cells is not None:
        params["translation"]["max_cells"] = args.max_cells
    t0 = time.perf_counter()
    feats = build_features(args, args.out / "features")
    print(f"{args.dataset}: {len(feats)} frames, {feats['clip'].nunique()} clips, "
          f"{len(grid_cells(feats))} cells; features in {time.perf_counter() - t0:.1f} s", flush=True)

    # One cell, every method of the stage.
    from threadpoolctl import threadpool_limits
    cells = grid_cells(feats)
    s, c = cells[len(cells) // 2]
    tp = translator_params(params)
    kw = dict(methods=tuple(params["translation"]["methods"]), translator_params=tp,
              bilinear_rank=params["translation"]["bilinear_rank"], seed=0)
    best = np.inf
    for _ in range(args.repeat):
        with threadpool_limits(1):
            t1 = time.perf_counter()
            run_cell(CellJob(feats, s, c, kw))
            best = min(best, time.perf_counter() - t1)
    n = params["translation"]["max_cells"] or len(cells)
    print(f"one held-out cell ({s}/{c}, {len(kw['methods'])} methods): {best:.2f} s; "
          f"estimate for {n} cells on {args.workers} worker(s): {best * n / args.workers:.0f} s", flush=True)

    if args.full:
        from joblib import Parallel, delayed

        def mapper(fn, items):
            return Parallel(n_jobs=args.workers)(delayed(fn)(x) for x in items)

        t2 = time.perf_counter()
        heldout(params, args.out / "features" / "features.csv", args.out / "reports", mapper=mapper)
        wall = time.perf_counter() - t2
        summary = json.loads((args.out / "reports" / "heldout.json").read_text())
        pd.set_option("display.width", 200)
        print(pd.DataFrame(summary["methods"]).T.round(4).to_string())
        print("target:", summary["target"])
        print(f"full stage: {summary['cells']} cells in {wall:.0f} s on {args.workers} worker(s)")


if __name__ == "__main__":
    main()
