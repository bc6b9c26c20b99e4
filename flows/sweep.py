"""The α/β/rank sweep: one parent MLflow run, one nested run per point.

The points (``nnsf.stages.sweep_grid``) are cross-validated in parallel, one
Prefect task each, on the runner of :mod:`flows.runners` (threads, processes
or a Dask cluster).  Each result comes back to the flow's main thread, which
logs its nested run at once (explicit run ids, no fluent API), so a sweep
that is interrupted keeps every point that finished.

A point is identified by its *sweep key*: a hash of the feature file's
contents, the library's source, the parameters a point reads and the point
itself.  A point whose key already has a FINISHED nested run in the
experiment is not recomputed: its metrics and figure are copied from that run
into the new sweep (tag ``nnsf.reused_from``).  That is what lets an
interrupted sweep resume, and an unchanged point survive a grid that grew.

Afterwards the nested runs are read back with ``mlflow.search_runs`` and
written as the comparison table ``reports/sweep.csv`` plus the metrics file
``reports/sweep.json`` (the best point); the parent run carries the table and
a chart of the score against α, β and rank (:data:`CHART`).  Metrics are
logged as ``sweep/<name>`` (:func:`flows.mlflow_runs.metric_name`).
"""
from __future__ import annotations

import contextlib
import hashlib
import importlib
import json
import shutil
import time
from pathlib import Path

import pandas as pd
from prefect import flow, get_run_logger
from prefect.states import Failed

from nnsf import pipeline, stages
from nnsf.errors import InputError
from nnsf.evaluate.figures import sweep_figure
from nnsf.io import write_csv, write_json

from flows import project, runners
from flows.mlflow_runs import ExperimentLog, metric_name

SWEEP_CSV = pipeline.REPORTS / "sweep.csv"
SWEEP_JSON = pipeline.REPORTS / "sweep.json"
FIGURE_DIR = pipeline.REPORTS / "figures" / "sweep"
#: The parent run's chart: the score of every point against α, β and rank.
CHART = FIGURE_DIR / "precision_vs_alpha_beta_rank.png"
#: The chart section of the sweep's metrics in MLflow.
GROUP = "sweep"
#: The metric that ranks sweep points, best first if higher; the first one a
#: point reports is used.
SCORES = ("precision_mean", "precision", "accuracy_mean", "accuracy")
#: Columns that identify a point in the table.
POINT = ("alpha", "beta", "rank")
#: The parameters one point's result depends on, besides the point itself
#: (the sweep's deps in dvc.yaml; α, β and rank come from the point).
POINT_PARAMS = ("seed", "nnsf.label", "nnsf.init", "nnsf.tol", "nnsf.class_in_loop",
                "sweep.folds", "sweep.max_iter")
TAG_KEY, TAG_REUSED = "nnsf.sweep_key", "nnsf.reused_from"


def run_point(job: dict):
    """Cross-validate NNSF at one point (runs on a task-runner worker).

    ``job`` holds ``params``, ``point``, ``features_csv`` and ``figure_dir``
    (plain data, so it travels to process and Dask workers).
    """
    return stages.sweep_point(job["params"], job["point"], features_csv=Path(job["features_csv"]),
                              figure_dir=Path(job["figure_dir"]))


def point_name(point: dict) -> str:
    return f"α={point['alpha']:g} β={point['beta']:g} k={point['rank']}"


def _job_name(job: dict) -> str:
    return point_name(job["point"])


# -- sweep identity -----------------------------------------------------------------

def _dotted(params: dict, key: str):
    node = params
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()


def code_digest() -> str:
    """SHA-256 over the ``nnsf`` package's source files (names and contents)."""
    package = Path(pipeline.__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def sweep_keys(params: dict, points: list[dict], features_csv: Path) -> list[str]:
    """One key per point: same key ⇔ same inputs, code, settings and point."""
    base = {"features": _file_digest(features_csv), "code": code_digest(),
            "params": {k: _dotted(params, k) for k in POINT_PARAMS}}
    keys = []
    for point in points:
        text = json.dumps({**base, "point": {k: point[k] for k in POINT}}, sort_keys=True,
                          default=str)
        keys.append(hashlib.sha256(text.encode()).hexdigest()[:32])
    return keys


# -- the flow -----------------------------------------------------------------------

@flow(name="nnsf-sweep", persist_result=False, validate_parameters=False)
def sweep(params: dict, point_fn: str | None = None, reuse: bool = True):
    """Run every sweep point and log parent + nested MLflow runs.

    Parameters
    ----------
    params : dict
        The parsed params.yaml.
    point_fn : str, optional
        ``"module:function"`` computing one point from a job dict (default
        :func:`run_point`); another function, e.g. one that injects faults,
        must be importable on the workers.
    reuse : bool
        Copy points whose sweep key has a FINISHED run instead of recomputing.
    """
    logger = get_run_logger()
    try:
        points = stages.sweep_grid(params)
    except InputError as err:
        logger.error("%s", err)
        return Failed(message=str(err), data=err)
    fn = _resolve(point_fn) if point_fn else run_point
    root = project.root()
    features_csv = root / pipeline.FEATURES_DIR / "features.csv"
    if not features_csv.is_file():
        err = InputError(features_csv, "file", "the features stage's output (run it first)")
        logger.error("%s", err)
        return Failed(message=str(err), data=err)
    log = ExperimentLog(params["mlflow"]["experiment"], root)
    keys = sweep_keys(params, points, features_csv)
    parent = log.start_run("sweep", {"nnsf.stage": "sweep"})
    log.log(parent, params={f"sweep.{k}": v for k, v in params.get("sweep", {}).items()}
            | {"points": len(points), "task_runner": runners.kind("sweep"),
               "workers": runners.workers()})
    started = time.perf_counter()
    try:
        figure_dir = root / FIGURE_DIR
        figure_dir.mkdir(parents=True, exist_ok=True)
        _remove_leftovers(figure_dir)
        done = _reuse_finished(log, parent, points, keys, figure_dir, logger) if reuse else {}
        todo = [i for i in range(len(points)) if i not in done]
        jobs = [{"params": params, "point": points[i], "features_csv": str(features_csv),
                 "figure_dir": str(figure_dir), "key": keys[i]} for i in todo]
        failure = _fan_out(fn, jobs, log, parent, logger)
        counts = {"points_reused": len(done), "points_computed": len(todo) - _failed_count(failure)}
        log.log(parent, metrics=counts, group=GROUP)
        if failure is not None:
            log.end_run(parent, ok=False)
            return failure
        table = _comparison_table(log.children(parent), len(points))
        best = _best(table)
        write_csv(root / SWEEP_CSV, table)
        write_json(root / SWEEP_JSON, best)
        chart = sweep_figure(table, score_column(table), root / CHART)
        log.log(parent, metrics={**best, "sweep_seconds": time.perf_counter() - started},
                artifacts=[root / SWEEP_CSV, root / SWEEP_JSON, chart], group=GROUP)
    except BaseException:
        log.end_run(parent, ok=False)
        raise
    log.end_run(parent)
    logger.info("sweep: %d points (%d reused, %d computed) in %.1f s; best %s; MLflow parent run %s",
                len(points), counts["points_reused"], counts["points_computed"],
                time.perf_counter() - started, best, parent)
    return {"best": best, "mlflow_run_id": parent, **counts}


def _remove_leftovers(folder: Path) -> None:
    """Delete temporary files a killed run left (``nnsf.io.atomic_path`` names them ``.<name>.*``).

    They never look finished, but inside a DVC output folder they would
    change its hash.
    """
    for path in folder.glob(".*"):
        if path.is_dir():
            shutil.rmtree(path, ignore_errors=True)
        else:
            path.unlink(missing_ok=True)


def _resolve(spec: str):
    module, _, name = spec.partition(":")
    if not module or not name:
        raise InputError("sweep flow", "point_fn", "'module:function'", spec)
    return getattr(importlib.import_module(module), name)


def _failed_count(failure) -> int:
    err = getattr(failure, "data", None)
    return len(getattr(err, "failed", {})) if err is not None else 0


def _fan_out(fn, jobs, log: ExperimentLog, parent: str, logger):
    """Run the jobs as Prefect tasks; log each nested run as its result arrives.

    Returns ``None`` when every point finished, else a ``Failed`` state whose
    data names the failed points (an :class:`InputError` if all of them
    failed on bad input).  The finished points stay logged either way.
    """
    def record(job, result):
        point = job["point"]
        child = log.start_run(point_name(point), {"nnsf.stage": "sweep-point", TAG_KEY: job["key"]},
                              parent_id=parent)
        log.log(child, params={**result.params, **point}, metrics=result.metrics,
                artifacts=result.artifacts, group=GROUP)
        log.end_run(child)
        logger.info("sweep point %s: %s", point_name(point),
                    ", ".join(f"{k}={v:.4g}" for k, v in result.metrics.items()
                              if isinstance(v, float)))

    if not jobs:
        return None
    mapper = runners.prefect_mapper("sweep-point", name=_job_name, on_result=record)
    try:
        with _one_blas_thread_per_worker():
            mapper(fn, jobs)
    except runners.FanOutError as err:
        logger.error("%s", err)
        return Failed(message=str(err), data=err)
    return None


def _reuse_finished(log: ExperimentLog, parent: str, points, keys, figure_dir: Path,
                    logger) -> dict[int, str]:
    """Copy points whose key already has a FINISHED nested run; return {index: old run id}."""
    found = log.finished_by_tag(TAG_KEY, set(keys), {"nnsf.stage": "sweep-point"})
    done: dict[int, str] = {}
    for i, (point, key) in enumerate(zip(points, keys)):
        old = found.get(key)
        if old is None:
            continue
        files = log.download_artifacts(old.info.run_id, FIGURE_DIR.as_posix(), figure_dir)
        child = log.start_run(point_name(point), {"nnsf.stage": "sweep-point", TAG_KEY: key,
                                                  TAG_REUSED: old.info.run_id}, parent_id=parent)
        log.log(child, params=dict(old.data.params), metrics=dict(old.data.metrics),
                artifacts=files)
        log.end_run(child)
        done[i] = old.info.run_id
        logger.info("sweep point %s: reused MLflow run %s", point_name(point), old.info.run_id)
    return done


@contextlib.contextmanager
def _one_blas_thread_per_worker():
    """With worker threads, one BLAS thread each: otherwise they oversubscribe the cores."""
    if runners.kind("sweep") != "threads" or runners.workers() < 2:
        yield
        return
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):
        yield


#: Metrics that vary from run to run with the same inputs.
VOLATILE_METRICS = ("seconds", "stage_seconds")


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
    prefix = "metrics." + metric_name(GROUP, "")
    names = sorted(c.removeprefix(prefix) for c in runs.columns if c.startswith(prefix))
    for name in names:
        if name not in VOLATILE_METRICS:
            table[name] = runs[prefix + name].astype(float)
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
