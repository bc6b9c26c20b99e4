"""One Prefect flow per DVC stage: call the ``nnsf.stages`` function, log to MLflow.

A flow never lets an :class:`~nnsf.errors.InputError` escape as an exception:
it returns a ``Failed`` state whose message is the error's one line (and whose
data is the error), so Prefect records a failed run without printing a
traceback, and ``python -m flows`` turns the state into ``error: …`` and exit
code 2.  Anything else that goes wrong is a bug; Prefect keeps its traceback
for the UI, and the console shows one line (see :mod:`flows.console`).
"""
from __future__ import annotations

import time
from typing import Callable

from prefect import flow, get_run_logger
from prefect.states import Failed

from nnsf import stages
from nnsf.errors import InputError
from nnsf.pipeline import StageResult

from flows.mlflow_runs import ExperimentLog
from flows.tracking import recorded


def run_stage(stage: str, fn: Callable[[dict], StageResult], params: dict):
    """Run ``fn(params)`` inside the current flow and log its result to MLflow.

    Returns a small summary (metrics and the MLflow run id), or a ``Failed``
    state carrying the :class:`InputError`.
    """
    logger = get_run_logger()
    started = time.perf_counter()
    try:
        result = fn(params)
    except InputError as err:
        logger.error("%s", err)
        return Failed(message=str(err), data=err)
    seconds = time.perf_counter() - started
    result.metrics.setdefault("stage_seconds", round(seconds, 3))
    with recorded(stage, result.artifacts):     # a store failing now: one line saying what was kept
        log = ExperimentLog(params["mlflow"]["experiment"])
        run_id = log.log_stage(stage, result)
        for name, child in result.runs.items():
            # One nested run per method/variant, so they line up in MLflow's
            # comparison view.
            child_id = log.start_run(name, {"nnsf.stage": f"{stage}-run", "nnsf.run": name},
                                     parent_id=run_id)
            log.log(child_id, child.params, child.metrics, child.artifacts, group=stage)
            log.end_run(child_id)
    shown = ", ".join(f"{k}={_short(v)}" for k, v in list(result.metrics.items())[:8])
    logger.info("%s done in %.1f s; MLflow run %s; %s", stage, seconds, run_id, shown)
    return {"metrics": result.metrics, "mlflow_run_id": run_id}


def _short(value) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


# The flows are spelled out one by one (rather than generated) so that each has
# a real module-level name, which Prefect deployments and the UI rely on.
_OPTIONS = dict(persist_result=False, validate_parameters=False, log_prints=False)


@flow(name="nnsf-data", **_OPTIONS)
def data(params: dict):
    """Produce the raw key-point table for ``dataset.name`` (data/raw/)."""
    return run_stage("data", stages.data, params)


@flow(name="nnsf-features", **_OPTIONS)
def features(params: dict):
    """Unify raw key points to the template (data/features/)."""
    return run_stage("features", stages.features, params)


@flow(name="nnsf-factorize", **_OPTIONS)
def factorize(params: dict):
    """Fit NNSF on all frames (models/nnsf.npz, reports/factorize.json)."""
    return run_stage("factorize", stages.factorize, params)


@flow(name="nnsf-evaluate", **_OPTIONS)
def evaluate(params: dict):
    """Grouped cross-validation, precision vs rank for every method; one task per fit."""
    return run_stage("evaluate", lambda p: stages.evaluate(p, mapper=_mapper("cv-fit")), params)


@flow(name="nnsf-isomap", **_OPTIONS)
def isomap(params: dict):
    """ISOMAP of the fitted weights V: residual variance and embedding."""
    return run_stage("isomap", stages.isomap, params)


def _mapper(task_name: str):
    from flows.runners import prefect_mapper

    return prefect_mapper(task_name)


@flow(name="nnsf-frames", **_OPTIONS)
def frames(params: dict):
    """Render cartoon clips with ground truth (data/frames/); one task per clip."""
    return run_stage("frames", lambda p: stages.frames(p, mapper=_mapper("render-clip")), params)


@flow(name="nnsf-roto", **_OPTIONS)
def roto(params: dict):
    """Track the clips' contours and derive key points (data/tracks, data/tracked); one task per clip."""
    return run_stage("roto", lambda p: stages.roto(p, mapper=_mapper("track-clip")), params)


@flow(name="nnsf-roto-eval", **_OPTIONS)
def roto_eval(params: dict):
    """Score three trackers against the rendered ground truth; one task per (clip, tracker)."""
    return run_stage("roto_eval", lambda p: stages.roto_eval(p, mapper=_mapper("score-tracker")), params)


@flow(name="nnsf-heldout", **_OPTIONS)
def heldout(params: dict):
    """Leave-one-cell-out style translation; one task per held-out cell."""
    return run_stage("heldout", lambda p: stages.heldout(p, mapper=_mapper("heldout-cell")), params)


@flow(name="nnsf-translate", **_OPTIONS)
def translate(params: dict):
    """One clip re-performed in another style (reports/translation)."""
    return run_stage("translate", stages.translate, params)


@flow(name="nnsf-reshape", **_OPTIONS)
def reshape(params: dict):
    """A drawn character performing the translated motion (reports/reshape)."""
    return run_stage("reshape", stages.reshape, params)


@flow(name="nnsf-styles", **_OPTIONS)
def styles(params: dict):
    """Fit the style translator on the configured dataset and save it (models/styles.npz, an MLflow artifact)."""
    return run_stage("styles", stages.styles, params)


@flow(name="nnsf-animate", **_OPTIONS)
def animate(params: dict):
    """The animate block: a character performing a motion in a style (reports/animate)."""
    return run_stage("animate", stages.animate, params)


@flow(name="nnsf-results", **_OPTIONS)
def results(params: dict):
    """The results document: docs/results.md from the reports (docs/results.yaml lists its tables)."""
    return run_stage("results", stages.results, params)


#: The stage flows by DVC stage name (the sweep lives in :mod:`flows.sweep`).
FLOWS = {f.fn.__name__: f for f in (data, features, factorize, evaluate, isomap, frames, roto, roto_eval,
                                    heldout, translate, reshape, styles, animate, results)}
#: Stages that fan out on the configured task runner (flows.runners).
FAN_OUT = {"evaluate", "frames", "roto", "roto_eval", "heldout"}
