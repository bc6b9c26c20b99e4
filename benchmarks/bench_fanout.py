"""The held-out translation fan-out on each task runner: threads, processes, Dask; 1 and 2 workers.

Builds the Bandai-Namco features as the pipeline would (``bench_translation``'s
``build_features``), then runs the held-out stage on ``--cells`` cells inside a
real Prefect flow whose fan-out goes through :mod:`flows.runners`, once per
runner set-up, and prints the wall time of the stage, the speed-up over the
first set-up and whether ``heldout.csv`` is identical to the first set-up's.

    .venv/bin/python benchmarks/bench_fanout.py [--data ../shared/data/bandai-namco-1]
        [--cells 20] [--setups threads:1,dask:1,dask:2,processes:2,threads:2]
    .venv/bin/python benchmarks/bench_fanout.py --dataset default [--setups ...]

``--dataset default`` measures the default pipeline's own held-out stage instead:
params.yaml as it is (the embedded synthetic set, ``translation.max_cells``
cells), on the raw key points the ``data`` stage writes, which is what the
stage reads.

A temporary Prefect server on 127.0.0.1 is started unless ``PREFECT_API_URL`` is set.
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import os
import sys
import tempfile
import time
from pathlib import Path

import pandas as pd
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

import flows  # noqa: E402,F401  (telemetry off before Prefect is imported)
from bench_translation import DEFAULT, TRANSLATION, build_features  # noqa: E402


def run_setup(params: dict, features: Path, out: Path, runner: str, workers: int) -> float:
    """One held-out stage on ``runner`` with ``workers`` workers; returns the stage's wall time."""
    os.environ["NNSF_TASK_RUNNER"], os.environ["NNSF_WORKERS"] = runner, str(workers)
    from prefect import flow

    from flows.runners import configured, prefect_mapper
    from nnsf.evaluate.heldout_report import write_heldout as heldout

    @flow(name="bench-fanout", persist_result=False, validate_parameters=False)
    def stage():
        t0 = time.perf_counter()
        heldout(params, features, out, mapper=prefect_mapper("heldout-cell"))
        return time.perf_counter() - t0

    return configured(stage)()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT)
    ap.add_argument("--fps", type=float, default=15.0)
    ap.add_argument("--cells", type=int, default=20)
    ap.add_argument("--setups", default="threads:1,dask:1,dask:2,processes:2,threads:2")
    ap.add_argument("--out", type=Path, default=Path(tempfile.gettempdir()) / "bench-fanout")
    ap.add_argument("--dataset", choices=["bandai", "default"], default="bandai")
    args = ap.parse_args(argv)

    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    if args.dataset == "default":
        from nnsf import stages
        from nnsf.params import Params

        params = Params(params)
        stages.data(params, out_dir=args.out / "features")   # raw key points, as the stage reads
        feats = pd.read_csv(args.out / "features" / "keypoints.csv")
        (args.out / "features" / "keypoints.csv").replace(args.out / "features" / "features.csv")
        cells = params["translation"]["max_cells"]
        print(f"default params: {len(feats)} frames, {feats['clip'].nunique()} clips; {cells} cells; "
              f"methods {', '.join(params['translation']['methods'])}", flush=True)
    else:
        params["translation"] = {**TRANSLATION, **params.get("translation", {}),
                                 "max_cells": args.cells, "examples": 0}
        params["dataset"] = {**params.get("dataset", {}), "name": "bvh"}
        feats = build_features(args, args.out / "features")
        print(f"bandai: {len(feats)} frames, {feats['clip'].nunique()} clips; {args.cells} cells",
              flush=True)

    with contextlib.ExitStack() as stack:
        if not os.environ.get("PREFECT_API_URL"):
            from flows import prefect_server
            os.environ["PREFECT_API_URL"] = stack.enter_context(
                prefect_server.running(args.out / "prefect-home", ui=False))
        first_time = first_hash = None
        for setup in args.setups.split(","):
            runner, n = setup.split(":")
            out = args.out / f"reports-{runner}-{n}"
            cpu0, wall0 = _cpu_seconds(), time.perf_counter()
            seconds = run_setup(params, args.out / "features" / "features.csv", out, runner, int(n))
            wall, cpu = time.perf_counter() - wall0, _cpu_seconds() - cpu0
            digest = hashlib.md5((out / "heldout.csv").read_bytes()).hexdigest()
            first_time = first_time or seconds
            first_hash = first_hash or digest
            # CPU of this process and of the workers it has reaped (process pools and Dask
            # clusters are shut down with the flow): on a shared machine, "cores" is what the
            # set-up got, which caps its speed-up.
            print(f"{runner:>9} x {n}: {seconds:7.1f} s  speed-up {first_time / seconds:4.2f}x  "
                  f"heldout.csv {'identical' if digest == first_hash else 'DIFFERS'} ({digest[:8]}); "
                  f"flow with runner start/stop {wall:.1f} s, CPU {cpu:.1f} s, cores {cpu / wall:.2f}",
                  flush=True)


def _cpu_seconds() -> float:
    import resource

    return sum(r.ru_utime + r.ru_stime for r in (resource.getrusage(resource.RUSAGE_SELF),
                                                 resource.getrusage(resource.RUSAGE_CHILDREN)))


if __name__ == "__main__":
    main()
