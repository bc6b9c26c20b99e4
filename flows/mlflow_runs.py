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
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Mapping

import pandas as pd

import mlflow
from mlflow.entities import Metric, Param
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from mlflow.utils.logging_utils import MLFLOW_LOGGING_STREAM

from flows import project

# MLflow gives its logger a handler that writes to stderr ("Creating initial
# MLflow database tables..."); move it to stdout so stderr keeps only the one
# error line (see flows.console).
# Only MLflow's own stderr handler: others on that logger (a test runner's
# capture handler) keep their streams.
# MLflow's handler writes to its own wrapper of sys.stderr (MLFLOW_LOGGING_STREAM), so that is
# what is looked for, besides stderr itself.
for _handler in logging.getLogger("mlflow").handlers:
    if type(_handler) is logging.StreamHandler and _handler.stream in (sys.stderr, sys.__stderr__,
                                                                      MLFLOW_LOGGING_STREAM):
        _handler.setStream(sys.stdout)

#: The experiment tag MLflow 3's UI reads to choose an experiment's pages, and the kind that
#: opens on the runs table and charts (without it the UI may open the GenAI pages: traces,
#: prompts).  The value is one of the UI's ``ExperimentKind`` names.
EXPERIMENT_KIND_TAG, EXPERIMENT_KIND = "mlflow.experimentKind", "custom_model_development"
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
        self.closed_stale = self.close_dead_runs()

    def _ensure_experiment(self, name: str) -> str:
        exp = self.client.get_experiment_by_name(name)
        if exp is None:
            # A tracking server chooses its own artifact store (--artifacts-destination
            # or --default-artifact-root); a local store keeps them in the project.
            location = None if _is_remote(self.uri) else project.mlflow_artifacts(self.root)
            try:
                return self.client.create_experiment(name, artifact_location=location,
                                                     tags={EXPERIMENT_KIND_TAG: EXPERIMENT_KIND})
            except MlflowException:
                # Another process created it between our lookup and create.
                exp = self.client.get_experiment_by_name(name)
                if exp is None:
                    raise
        if exp.lifecycle_stage == "deleted":
            # A deleted experiment keeps its name; logging into it would fail.
            self.client.restore_experiment(exp.experiment_id)
        if EXPERIMENT_KIND_TAG not in exp.tags:  # made by another tool, or by an older nnsf
            self.client.set_experiment_tag(exp.experiment_id, EXPERIMENT_KIND_TAG, EXPERIMENT_KIND)
        return exp.experiment_id

    # -- runs ---------------------------------------------------------------

    def start_run(self, name: str, tags: Mapping[str, str] | None = None,
                  parent_id: str | None = None) -> str:
        """Create a run (nested under ``parent_id`` if given); return its id."""
        all_tags = {**context_tags(), **process_tags(), **(tags or {})}
        if parent_id:
            all_tags["mlflow.parentRunId"] = parent_id
        run = self.client.create_run(self.experiment_id, run_name=name, tags=all_tags)
        return run.info.run_id

    def end_run(self, run_id: str, ok: bool = True) -> None:
        self.client.set_terminated(run_id, "FINISHED" if ok else "FAILED")

    def log(self, run_id: str, params: Mapping | None = None,
            metrics: Mapping | None = None, artifacts=(), group: str | None = None) -> None:
        """Log flat params, numeric metrics and files to a run.

        Metric values that are not real numbers are skipped (MLflow would
        reject the whole batch); artifact files keep their folder relative to
        the project (``reports/figures/…``) so the run mirrors the workspace.
        With ``group`` (the stage), each metric is named ``<group>/<name>``:
        MLflow's charts gather the metrics of one prefix in one section, so the
        runs view shows one section per stage instead of one grid of all.
        """
        now = int(time.time() * 1000)
        plist = [Param(str(k), _param_value(v)) for k, v in (params or {}).items()]
        mlist = [Metric(metric_name(group, k), float(v), now, 0) for k, v in (metrics or {}).items()
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
        """One finished run for a stage's :class:`~nnsf.pipeline.StageResult`."""
        run_id = self.start_run(stage, {"nnsf.stage": stage, **(tags or {})})
        try:
            self.log(run_id, result.params, result.metrics, result.artifacts, group=stage)
        except BaseException:
            self.end_run(run_id, ok=False)
            raise
        self.end_run(run_id)
        return run_id

    def close_dead_runs(self) -> list[str]:
        """Mark RUNNING runs whose process has died as KILLED; return their ids.

        Every run records the host, pid and the pid's start time that created
        it (:func:`process_tags`).  A run still RUNNING whose process is gone
        (or whose pid now belongs to another process) was killed before it
        could end itself: SIGKILL, out of memory, a power cut.  Runs created on
        other hosts are left alone (their processes cannot be checked here).
        Called whenever an :class:`ExperimentLog` is opened, so a dead run is
        marked on the next start at the latest.
        """
        host = socket.gethostname()
        closed = []
        for run in self._search(f"attributes.status = 'RUNNING' and tags.`{TAG_HOST}` = '{host}'"):
            tags = run.data.tags
            if process_alive(tags.get(TAG_PID), tags.get(TAG_PID_START)):
                continue
            self.client.set_terminated(run.info.run_id, "KILLED")
            self.client.set_tag(run.info.run_id, "nnsf.killed_reason",
                                f"process {tags.get(TAG_PID)} on {host} ended without ending the run")
            closed.append(run.info.run_id)
        return closed

    def _search(self, filter_string: str):
        """Every run of the experiment matching ``filter_string`` (all pages)."""
        token = None
        while True:
            page = self.client.search_runs([self.experiment_id], filter_string=filter_string,
                                           max_results=1000, page_token=token)
            yield from page
            token = page.token
            if not token:
                return

    def finished_by_tag(self, tag: str, values: set[str], tags: Mapping[str, str] | None = None) -> dict:
        """FINISHED runs whose ``tag`` is one of ``values``: ``{value: newest run}``.

        ``tags`` narrows the search to runs with those exact tag values.
        """
        clauses = ["attributes.status = 'FINISHED'"]
        clauses += [f"tags.`{k}` = '{v}'" for k, v in (tags or {}).items()]
        found: dict = {}
        for run in self._search(" and ".join(clauses)):
            value = run.data.tags.get(tag)
            if value in values:
                best = found.get(value)
                if best is None or run.info.start_time > best.info.start_time:
                    found[value] = run
        return found

    def download_artifacts(self, run_id: str, folder: str, dest: Path) -> list[Path]:
        """Copy the files of a run's artifact ``folder`` into ``dest``; return the new paths.

        Each file is moved into place whole (rename), so ``dest`` never holds
        a half-copied file.
        """
        dest = Path(dest)
        dest.mkdir(parents=True, exist_ok=True)
        names = [Path(a.path).name for a in self.client.list_artifacts(run_id, folder)
                 if not a.is_dir]
        if not names:
            return []
        copied = []
        with tempfile.TemporaryDirectory(dir=dest, prefix=".download.") as tmp:
            local = Path(self.client.download_artifacts(run_id, folder, tmp))
            for name in names:
                os.replace(local / name, dest / name)
                copied.append(dest / name)
        return copied

    def children(self, parent_id: str) -> pd.DataFrame:
        """The nested runs of ``parent_id``, read back with ``mlflow.search_runs``."""
        mlflow.set_tracking_uri(self.uri)
        return mlflow.search_runs(
            experiment_ids=[self.experiment_id],
            filter_string=f"tags.mlflow.parentRunId = '{parent_id}'",
            output_format="pandas",
        )


def metric_name(group: str | None, name) -> str:
    """A metric's MLflow name: ``<group>/<name>`` (the stage's chart section), or ``name``."""
    return f"{group}/{name}" if group else str(name)


def _param_value(value) -> str:
    if isinstance(value, float) and not math.isfinite(value):
        text = str(value)
    elif isinstance(value, (list, tuple)):
        text = ",".join(str(v) for v in value)
    else:
        text = str(value)
    return text[:_MAX_PARAM_CHARS]


#: Tags that let a later process tell whether a run's creator is still alive.
TAG_HOST, TAG_PID, TAG_PID_START = "nnsf.host", "nnsf.pid", "nnsf.pid_start"


def _is_remote(uri: str) -> bool:
    return uri.startswith(("http://", "https://", "databricks"))


def _pid_start(pid: int) -> str | None:
    """The start time of process ``pid`` (clock ticks since boot, Linux), or None."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    # The command name (field 2) may contain spaces; fields after it are plain.
    return stat.rsplit(")", 1)[1].split()[19]


def process_tags() -> dict[str, str]:
    """Host, pid and pid start time of this process (see :meth:`ExperimentLog.close_dead_runs`)."""
    pid = os.getpid()
    tags = {TAG_HOST: socket.gethostname(), TAG_PID: str(pid)}
    start = _pid_start(pid)
    if start is not None:
        tags[TAG_PID_START] = start
    return tags


def process_alive(pid: str | None, start: str | None) -> bool:
    """True if process ``pid`` exists and (where known) started at ``start``.

    An unparsable pid counts as alive: such a run was not created by us, and
    marking it KILLED could be wrong.
    """
    try:
        number = int(pid)
    except (TypeError, ValueError):
        return True
    try:
        os.kill(number, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, owned by someone else
    if start is not None:
        now = _pid_start(number)
        if now is not None and now != start:
            return False  # the pid was reused by a newer process
    if Path(f"/proc/{number}/stat").exists():
        # A zombie has exited; only its parent has not collected it yet.
        state = Path(f"/proc/{number}/stat").read_text().rsplit(")", 1)[1].split()[0]
        if state in ("Z", "X"):
            return False
    return True


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

