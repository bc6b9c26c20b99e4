"""The α/β/rank sweep on the default dataset: local runner vs a 2-worker Dask LocalCluster.

    .venv/bin/python benchmarks/bench_sweep.py                      # 5 x 5 x 4 = 100 points x 10 folds (long)
    .venv/bin/python benchmarks/bench_sweep.py --grid 2 2 2 --folds 3   # 8 points x 3 folds (a minute or two)

Both runs use the real sweep flow (:func:`flows.sweep.sweep`, no reuse of
earlier points) against one ``prefect server start`` on 127.0.0.1, a fresh
sqlite MLflow store each, and the default params.yaml's dataset, ``seed``,
``nnsf`` settings and ``sweep.max_iter``.  The grid is α in
``[0, 0.001, 0.01, 0.1, 1]``, β in ``[0, 1, 10, 100, 1000]`` and rank in
``[4, 8, 16, 24]`` (the first ``A``, ``B``, ``R`` of each).

- local: ``NNSF_TASK_RUNNER=threads`` with ``NNSF_WORKERS`` threads
  (default 2), one BLAS thread each;
- dask: ``distributed.LocalCluster(n_workers=2, processes=True,
  threads_per_worker=1)``, reached through ``NNSF_DASK_ADDRESS``.

Prints the wall time of each sweep flow (cluster start-up excluded), the
speed-up, and checks the two tables are equal.
"""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

ALPHAS = [0.0, 0.001, 0.01, 0.1, 1.0]
BETAS = [0.0, 1.0, 10.0, 100.0, 1000.0]
RANKS = [4, 8, 16, 24]
PROJECT = Path(__file__).resolve().parents[1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--grid", nargs=3, type=int, default=[5, 5, 4], metavar=("A", "B", "R"),
                        help="how many α, β and rank values (default 5 5 4 = 100 points)")
    parser.add_argument("--folds", type=int, default=10)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--runners", nargs="+", default=["threads", "dask"],
                        choices=["threads", "processes", "dask"])
    opts = parser.parse_args(argv)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[name] = "1"  # inherited by the Dask worker processes
    os.environ["NNSF_WORKERS"] = str(opts.workers)

    import flows  # noqa: F401  (telemetry off)
    import yaml

    from flows import prefect_server, runners
    from nnsf import pipeline, stages

    work = Path(tempfile.mkdtemp(prefix="nnsf-bench-sweep-"))
    try:
        params = yaml.safe_load((PROJECT / "params.yaml").read_text())
        a, b, r = opts.grid
        params["sweep"].update(alpha=ALPHAS[:a], beta=BETAS[:b], rank=RANKS[:r], folds=opts.folds)
        root = work / "project"
        root.mkdir()
        (root / "dvc.yaml").write_text("stages: {}\n")
        stages.data(params, out_dir=root / pipeline.RAW_DIR)
        stages.features(params, raw_dir=root / pipeline.RAW_DIR, out_dir=root / pipeline.FEATURES_DIR)
        os.chdir(root)
        n_points = a * b * r
        print(f"sweep: {n_points} points x {opts.folds} folds, default dataset "
              f"({sum(1 for _ in open(root / pipeline.FEATURES_DIR / 'features.csv')) - 1} frames), "
              f"max_iter {params['sweep']['max_iter']}", flush=True)

        with prefect_server.running(work / "prefect", ui=False) as api, prefect_server.in_use(api):
            from prefect.settings import PREFECT_API_URL, temporary_settings
            from flows.sweep import sweep

            seconds, tables = {}, {}
            for kind in opts.runners:
                os.environ["NNSF_TASK_RUNNER"] = kind
                os.environ["MLFLOW_TRACKING_URI"] = f"sqlite:///{work / (kind + '.db')}"
                run_params = dict(params, mlflow={"experiment": f"bench-{kind}"})
                cluster = None
                if kind == "dask":
                    from distributed import LocalCluster

                    cluster = LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                           dashboard_address=None, host="127.0.0.1")
                    os.environ["NNSF_DASK_ADDRESS"] = cluster.scheduler_address
                try:
                    with temporary_settings(updates={PREFECT_API_URL: api}):
                        started = time.perf_counter()
                        state = runners.configured(sweep)(run_params, reuse=False, return_state=True)
                        seconds[kind] = time.perf_counter() - started
                finally:
                    if cluster is not None:
                        cluster.close()
                        os.environ.pop("NNSF_DASK_ADDRESS", None)
                if not state.is_completed():
                    print(f"{kind}: sweep failed: {state.message}")
                    return 1
                tables[kind] = (root / "reports" / "sweep.csv").read_bytes()
                print(f"{kind:9} {seconds[kind]:8.1f} s  ({seconds[kind] / n_points:.2f} s per point)",
                      flush=True)
        if "threads" in seconds and "dask" in seconds:
            print(f"speed-up of Dask (2 workers) over threads ({opts.workers} workers): "
                  f"{seconds['threads'] / seconds['dask']:.2f}x")
        same = len(set(tables.values())) == 1
        print("tables identical across runners:", same)
        return 0 if same else 1
    finally:
        os.chdir(PROJECT)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
