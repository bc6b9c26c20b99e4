"""The α/β/rank sweep: one parent MLflow run, one nested run per point.

The points (``nnsf.stages.sweep_grid``) are cross-validated in parallel as
Prefect tasks on the runner from :mod:`flows.runners`.  Results come back to
the flow's main thread, which does all MLflow logging with explicit run ids.
Afterwards the nested runs are read back with ``mlflow.search_runs`` and
written as the comparison table ``reports/sweep.csv`` plus the metrics file
``reports/sweep.json`` (the best point).
"""
from __future__ import annotations

import contextlib
import time
from pathlib import Path

import pandas as pd
from prefect import flow, get_run_logger, task
from prefect.cache_policies import NO_CACHE
from prefect.futures import as_completed
from prefect.states import Failed

from nnsf import stages
from nnsf.errors import InputError
from nnsf.io import write_csv, write_json

from flows import project, runners
from flows.mlflow_runs import ExperimentLog

SWEEP_CSV = stages.REPORTS / "sweep.csv"
SWEEP_JSON = stages.REPORTS / "sweep.json"
FIGURE_DIR = stages.REPORTS / "figures" / "sweep"
#: The metric that ranks sweep points, best first if higher; the first one a
#: point reports is used.
SCORES = ("precision_mean", "precision", "accuracy_mean", "accuracy")
#: Columns that identify a point in the table.
POINT = ("alpha", "beta", "rank")


# No caching: the task reads files, and Prefect's INPUTS policy would hash the
# path string, not the file's contents.
@task(name="sweep-point", cache_policy=NO_CACHE, persist_result=False,
      task_run_name="sweep-point α={point[alpha]} β={point[beta]} k={point[rank]}")
def cross_validate_point(params: dict, point: dict, features_csv: str, figure_dir: str):
    """Cross-validate NNSF at one point (runs on a task-runner worker)."""
    return stages.sweep_point(params, point, features_csv=Path(features_csv),
                              figure_dir=Path(figure_dir))


def point_name(point: dict) -> str:
    return f"α={point['alpha']:g} β={point['beta']:g} k={point['rank']}"


@flow(name="nnsf-sweep", persist_result=False, validate_parameters=False)
def sweep(params: dict):
    """Run every sweep point and log parent + nested MLflow runs."""
    logger = get_run_logger()
    try:
        points = stages.sweep_grid(params)
    except InputError as err:
        logger.error("%s", err)
        return Failed(message=str(err), data=err)
    root = project.root()
    log = ExperimentLog(params["mlflow"]["experiment"], root)
    parent = log.start_run("sweep", {"nnsf.stage": "sweep"})
    log.log(parent, params={f"sweep.{k}": v for k, v in params.get("sweep", {}).items()}
            | {"points": len(points), "task_runner": runners.kind(),
               "workers": runners.workers()})
    started = time.perf_counter()
    try:
        failure = _fan_out(params, points, log, parent, root, logger)
        if failure is not None:
            log.end_run(parent, ok=False)
            return failure
        table = _comparison_table(log.children(parent), len(points))
        best = _best(table)
        write_csv(root / SWEEP_CSV, table)
        write_json(root / SWEEP_JSON, best)
        log.log(parent, metrics={**best, "sweep_seconds": time.perf_counter() - started},
                artifacts=[root / SWEEP_CSV, root / SWEEP_JSON])
    except BaseException:
        log.end_run(parent, ok=False)
        raise
    log.end_run(parent)
    logger.info("sweep: %d points in %.1f s; best %s; MLflow parent run %s",
                len(points), time.perf_counter() - started, best, parent)
    return {"best": best, "mlflow_run_id": parent}


def _fan_out(params, points, log, parent, root, logger):
    """Submit all points; log each nested run as its result arrives.

    Returns ``None`` on success or a ``Failed`` state for the first bad input.
    """
    features_csv = str(root / stages.FEATURES_DIR / "features.csv")
    figure_dir = root / FIGURE_DIR
    figure_dir.mkdir(parents=True, exist_ok=True)
    with _one_blas_thread_per_worker():
        futures = {cross_validate_point.submit(params, p, features_csv, str(figure_dir)): p
                   for p in points}
        for future in as_completed(list(futures)):
            point = futures[future]
            try:
                result = future.result()
            except InputError as err:
                logger.error("%s", err)
                _cancel(futures)
                return Failed(message=str(err), data=err)
            child = log.start_run(point_name(point), {"nnsf.stage": "sweep-point"},
                                  parent_id=parent)
            log.log(child, params={**result.params, **point}, metrics=result.metrics,
                    artifacts=result.artifacts)
            log.end_run(child)
            logger.info("sweep point %s: %s", point_name(point),
                        ", ".join(f"{k}={v:.4g}" for k, v in result.metrics.items()
                                  if isinstance(v, float)))
    return None


def _cancel(futures) -> None:
    for future in futures:
        with contextlib.suppress(Exception):
            future.cancel()


@contextlib.contextmanager
def _one_blas_thread_per_worker():
    """With worker threads, one BLAS thread each: otherwise they oversubscribe the cores."""
    if runners.kind() != "threads" or runners.workers() < 2:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield


#: Metrics that vary from run to run with the same inputs.
VOLATILE_METRICS = ("metrics.seconds", "metrics.stage_seconds")


def _comparison_table(runs: pd.DataFrame, expected: int) -> pd.DataFrame:
    """One row per point: α, β, rank and every metric; sorted by the point.

    Run ids and wall times are left out: the table is a versioned output whose
    hash must depend on the inputs only (the MLflow runs keep both).
    """
    if len(runs) != expected:
        raise RuntimeError(f"MLflow returned {len(runs)} nested sweep runs, expected {expected}")
    table = pd.DataFrame({
        "alpha": runs["params.alpha"].astype(float),
        "beta": runs["params.beta"].astype(float),
        "rank": runs["params.rank"].astype(int),
    })
    metric_cols = sorted(c for c in runs.columns
                         if c.startswith("metrics.") and c not in VOLATILE_METRICS)
    for col in metric_cols:
        table[col.removeprefix("metrics.")] = runs[col].astype(float)
    return table.sort_values(list(POINT), kind="stable").reset_index(drop=True)


def score_column(table: pd.DataFrame) -> str:
    """The metric that ranks points (see :data:`SCORES`)."""
    for name in SCORES:
        if name in table:
            return name
    raise RuntimeError(f"no score metric among {list(table.columns)}; expected one of {SCORES}")


def _best(table: pd.DataFrame) -> dict:
    """The best point and its score, as a flat metrics dict."""
    score = score_column(table)
    row = table.loc[table[score].idxmax()]
    return {"points": int(len(table)), "best_alpha": float(row["alpha"]),
            "best_beta": float(row["beta"]), "best_rank": int(row["rank"]),
            f"best_{score}": float(row[score])}
