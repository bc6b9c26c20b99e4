"""MLflow: the store, the experiment and the runs the flows log.

Everything goes through :class:`mlflow.MlflowClient` with explicit run ids
rather than MLflow's fluent ``start_run`` API: the fluent API keeps its
active-run stack per thread, and the sweep collects results from worker
threads.  All logging happens on the flow's main thread.
"""
from __future__ import annotations

import logging
import math
import numbers
import subprocess
import sys
import time
from pathlib import Path
from typing import Mapping

import pandas as pd

import mlflow
from mlflow.entities import Metric, Param
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient

from flows import project

# MLflow gives its logger a handler that writes to stderr ("Creating initial
# MLflow database tables..."); move it to stdout so stderr keeps only the one
# error line (see flows.console).
for _handler in logging.getLogger("mlflow").handlers:
    if isinstance(_handler, logging.StreamHandler):
        _handler.setStream(sys.stdout)

#: MLflow's per-request limits for ``log_batch``.
_MAX_PARAMS, _MAX_METRICS = 100, 1000
#: Longest parameter value MLflow stores.
_MAX_PARAM_CHARS = 6000


class ExperimentLog:
    """One MLflow experiment in the project's store.

    Parameters
    ----------
    experiment : str
        The experiment name (``mlflow.experiment`` in params.yaml).  It is
        created on first use with the artifact location
        ``<project root>/mlartifacts`` (fixed for the experiment's lifetime).
    root : Path, optional
        The project root; defaults to :func:`flows.project.root`.
    """

    def __init__(self, experiment: str, root: Path | None = None):
        self.root = root or project.root()
        self.uri = project.mlflow_uri(self.root)
        self.client = MlflowClient(tracking_uri=self.uri)
        self.experiment_id = self._ensure_experiment(experiment)

    def _ensure_experiment(self, name: str) -> str:
        exp = self.client.get_experiment_by_name(name)
        if exp is None:
            try:
                return self.client.create_experiment(
                    name, artifact_location=project.mlflow_artifacts(self.root))
            except MlflowException:
                # Another process created it between our lookup and create.
                exp = self.client.get_experiment_by_name(name)
                if exp is None:
                    raise
        if exp.lifecycle_stage == "deleted":
            # A deleted experiment keeps its name; logging into it would fail.
            self.client.restore_experiment(exp.experiment_id)
        return exp.experiment_id

    # -- runs ---------------------------------------------------------------

    def start_run(self, name: str, tags: Mapping[str, str] | None = None,
                  parent_id: str | None = None) -> str:
        """Create a run (nested under ``parent_id`` if given); return its id."""
        all_tags = {**context_tags(), **(tags or {})}
        if parent_id:
            all_tags["mlflow.parentRunId"] = parent_id
        run = self.client.create_run(self.experiment_id, run_name=name, tags=all_tags)
        return run.info.run_id

    def end_run(self, run_id: str, ok: bool = True) -> None:
        self.client.set_terminated(run_id, "FINISHED" if ok else "FAILED")

    def log(self, run_id: str, params: Mapping | None = None,
            metrics: Mapping | None = None, artifacts=()) -> None:
        """Log flat params, numeric metrics and files to a run.

        Metric values that are not real numbers are skipped (MLflow would
        reject the whole batch); artifact files keep their folder relative to
        the project (``reports/figures/…``) so the run mirrors the workspace.
        """
        now = int(time.time() * 1000)
        plist = [Param(str(k), _param_value(v)) for k, v in (params or {}).items()]
        mlist = [Metric(str(k), float(v), now, 0) for k, v in (metrics or {}).items()
                 if isinstance(v, numbers.Real)]
        for i in range(0, len(plist), _MAX_PARAMS):
            self.client.log_batch(run_id, params=plist[i:i + _MAX_PARAMS])
        for i in range(0, len(mlist), _MAX_METRICS):
            self.client.log_batch(run_id, metrics=mlist[i:i + _MAX_METRICS])
        for path in artifacts:
            path = Path(path)
            if path.is_file():
                self.client.log_artifact(run_id, str(path), self._artifact_dir(path))

    def _artifact_dir(self, path: Path) -> str | None:
        try:
            rel = path.resolve().relative_to(self.root)
        except ValueError:
            return "files"
        parent = rel.parent.as_posix()
        return None if parent == "." else parent

    def log_stage(self, stage: str, result, tags: Mapping[str, str] | None = None) -> str:
        """One finished run for a stage's :class:`~nnsf.stages.StageResult`."""
        run_id = self.start_run(stage, {"nnsf.stage": stage, **(tags or {})})
        try:
            self.log(run_id, result.params, result.metrics, result.artifacts)
        except BaseException:
            self.end_run(run_id, ok=False)
            raise
        self.end_run(run_id)
        return run_id

    def children(self, parent_id: str) -> pd.DataFrame:
        """The nested runs of ``parent_id``, read back with ``mlflow.search_runs``."""
        mlflow.set_tracking_uri(self.uri)
        return mlflow.search_runs(
            experiment_ids=[self.experiment_id],
            filter_string=f"tags.mlflow.parentRunId = '{parent_id}'",
            output_format="pandas",
        )


def _param_value(value) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        text = str(value)
    elif isinstance(value, (list, tuple)):
        text = ",".join(str(v) for v in value)
    else:
        text = str(value)
    return text[:_MAX_PARAM_CHARS]


def context_tags() -> dict[str, str]:
    """Tags that link a run to its code and its Prefect flow run."""
    tags: dict[str, str] = {}
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                                timeout=10, cwd=project.root())
        if commit.returncode == 0:
            tags["mlflow.source.git.commit"] = commit.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        pass
    try:
        from prefect.runtime import flow_run

        if flow_run.id:
            tags["prefect.flow_run_id"] = str(flow_run.id)
            tags["prefect.flow_run_name"] = str(flow_run.name)
            if flow_run.ui_url:
                tags["prefect.flow_run_url"] = str(flow_run.ui_url)
    except Exception:  # outside a flow run there is simply nothing to link
        pass
    return tags

