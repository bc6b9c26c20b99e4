"""``python -m flows ui``: MLflow's UI on the project's store, opened on the experiment's runs.

MLflow 3.17's UI chooses an experiment's pages from its own workflow switch ("GenAI" or "Model
training", GenAI in a browser that has not chosen), not from the experiment's
``mlflow.experimentKind`` tag, which the flows set all the same (:mod:`flows.mlflow_runs`).
The URLs made here carry ``workflowType=machine_learning``, so they open on the runs table and
its charts, and on the comparison of runs.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import urllib.parse

from flows import project

#: The UI's query parameter and value for its "Model training" pages.
WORKFLOW = {"workflowType": "machine_learning"}
#: The server's environment: job execution and telemetry off.
QUIET = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", "MLFLOW_DISABLE_TELEMETRY": "true", "DO_NOT_TRACK": "1"}


def runs_url(base: str, experiment_id: str | None) -> str:
    """The experiment's runs view (the experiments list when there is no experiment yet)."""
    page = f"experiments/{experiment_id}" if experiment_id is not None else "experiments"
    return f"{base.rstrip('/')}/#/{page}?{urllib.parse.urlencode(WORKFLOW)}"


def compare_url(base: str, experiment_id: str, run_ids: list[str]) -> str:
    """The comparison page of ``run_ids`` (parallel coordinates, scatter, the runs' tables)."""
    query = urllib.parse.urlencode({"runs": json.dumps(list(run_ids)),
                                    "experiments": json.dumps([experiment_id]), **WORKFLOW})
    return f"{base.rstrip('/')}/#/compare-runs?{query}"


def experiment_id(uri: str, name: str) -> str | None:
    """The id of experiment ``name`` in the store at ``uri``, or None if it does not exist."""
    from mlflow.tracking import MlflowClient

    found = MlflowClient(tracking_uri=uri).get_experiment_by_name(name)
    return None if found is None else found.experiment_id


def command(uri: str, port: int) -> list[str]:
    """``mlflow ui`` on the store at ``uri``, bound to loopback, one worker."""
    return [sys.executable, "-m", "mlflow", "ui", "--backend-store-uri", uri, "--host", "127.0.0.1",
            "--port", str(port), "--workers", "1"]


def main(argv: list[str] | None = None) -> int:
    from nnsf.params import load, require

    parser = argparse.ArgumentParser(prog="python -m flows ui", description=__doc__.split("\n\n")[0])
    parser.add_argument("--port", type=int, default=5000)
    parser.add_argument("--params", default="params.yaml", help="names the experiment (mlflow.experiment)")
    opts = parser.parse_args(argv)
    root = project.root()
    name = require(load(root / opts.params), "mlflow.experiment")
    uri = project.mlflow_uri(root)
    if uri.startswith(("http://", "https://")):  # a tracking server is already serving the UI
        print(f"mlflow ui: open {runs_url(uri, experiment_id(uri, name))}")
        return 0
    print(f"mlflow ui: open {runs_url(f'http://127.0.0.1:{opts.port}', experiment_id(uri, name))}",
          flush=True)
    os.execve(sys.executable, command(uri, opts.port), dict(os.environ, **QUIET))
    return 0  # not reached
