"""``python -m flows ui``: MLflow's UI on the project's store, opened on the experiment's runs.

The installed MLflow's UI bundle is read to check the two names the URL and the experiment tag
rely on, so an MLflow upgrade that renames them fails here rather than in a browser.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from flows import mlflow_runs, mlflow_ui
from flows.prefect_server import stop


def test_urls_open_the_model_training_pages():
    url = mlflow_ui.runs_url("http://127.0.0.1:5000/", "7")
    assert url == "http://127.0.0.1:5000/#/experiments/7?workflowType=machine_learning"
    assert mlflow_ui.runs_url("http://h:1", None) == "http://h:1/#/experiments?workflowType=machine_learning"
    compare = urllib.parse.urlsplit(mlflow_ui.compare_url("http://h:1", "7", ["a1", "b2"]))
    assert compare.fragment.startswith("/compare-runs?")
    query = urllib.parse.parse_qs(compare.fragment.partition("?")[2])
    assert json.loads(query["runs"][0]) == ["a1", "b2"] and json.loads(query["experiments"][0]) == ["7"]
    assert query["workflowType"] == ["machine_learning"]


def test_the_ui_binds_to_loopback_with_one_worker():
    cmd = mlflow_ui.command("sqlite:////tmp/x.db", 5123)
    assert cmd[cmd.index("--host") + 1] == "127.0.0.1" and cmd[cmd.index("--workers") + 1] == "1"
    assert cmd[cmd.index("--port") + 1] == "5123" and cmd[1:4] == ["-m", "mlflow", "ui"]


def test_the_installed_ui_knows_the_workflow_and_the_experiment_kind():
    import mlflow

    bundle = Path(mlflow.__file__).parent / "server" / "js" / "build" / "static" / "js"
    text = "".join(p.read_text(errors="ignore") for p in bundle.glob("main.*.js"))
    text += "".join(p.read_text(errors="ignore") for p in bundle.glob("*.chunk.js")
                    if "experimentKind" in p.read_text(errors="ignore"))
    assert 'MACHINE_LEARNING="machine_learning"' in text            # the workflowType value
    assert '"workflowType"' in text                                  # read from the URL
    assert mlflow_runs.EXPERIMENT_KIND_TAG in text                  # the tag the flows set
    assert f'CUSTOM_MODEL_DEVELOPMENT="{mlflow_runs.EXPERIMENT_KIND}"' in text


@pytest.mark.slow  # starts mlflow ui
def test_the_command_serves_the_store_and_prints_the_runs_url(tmp_path):
    from mlflow.tracking import MlflowClient

    from conftest import PROJECT
    from test_ops_support import free_port

    (tmp_path / "params.yaml").write_text((PROJECT / "params.yaml").read_text())
    (tmp_path / "dvc.yaml").write_text("stages: {}\n")
    db = tmp_path / "mlflow.db"
    experiment = MlflowClient(f"sqlite:///{db}").create_experiment("nnsf")
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(PROJECT), MLFLOW_TRACKING_URI=f"sqlite:///{db}")
    proc = subprocess.Popen([sys.executable, "-m", "flows", "ui", "--port", str(port)], cwd=tmp_path, env=env,
                            stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, start_new_session=True)
    try:
        line = proc.stdout.readline()
        assert line.strip() == (f"mlflow ui: open http://127.0.0.1:{port}/#/experiments/{experiment}"
                                "?workflowType=machine_learning"), line
        deadline = time.monotonic() + 120
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/health", timeout=2) as response:
                    assert response.status == 200
                    break
            except OSError:
                assert proc.poll() is None and time.monotonic() < deadline, "mlflow ui did not come up"
                time.sleep(0.5)
    finally:
        stop(proc, grace=20)
