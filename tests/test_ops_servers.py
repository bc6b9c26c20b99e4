"""Against real servers: a sweep logged over HTTP to ``mlflow server``, and the cron
deployment of the pipeline served by a real ``prefect server start``.

Both servers are started here on 127.0.0.1 and a free port, checked to listen
on loopback only, and stopped at the end; no process of theirs may survive.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import urllib.error
import urllib.request


import psutil
import pytest
import yaml

from conftest import new_project, run
from test_ops_support import (VENV_BIN, free_port, group_pids, process_group, small_project,
                              sweep_table, wait_for)

pytestmark = pytest.mark.slow

FLOWS = [sys.executable, "-m", "flows"]


def _get(url: str, timeout: float = 5.0):
    try:
        with urllib.request.urlopen(url, timeout=timeout) as response:
            return response.status == 200 and (response.read() or b"ok")
    except (urllib.error.URLError, OSError):
        return None


def _post(api: str, path: str, body: dict):
    request = urllib.request.Request(api + path, data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read())


def _try_post(api: str, path: str, body: dict):
    """``_post``, or None while the server is busy (503) or unreachable."""
    try:
        return _post(api, path, body)
    except (urllib.error.URLError, ConnectionError):  # HTTPError is a URLError
        return None


def _listens_on_loopback_only(port: int) -> bool:
    found = [c for c in psutil.net_connections(kind="inet")
             if c.status == psutil.CONN_LISTEN and c.laddr.port == port]
    return bool(found) and {c.laddr.ip for c in found} <= {"127.0.0.1", "::1"}


def _stop_group(proc: subprocess.Popen, grace: float = 20.0) -> None:
    """SIGTERM the server's process group and wait for the leader, as a user's Ctrl-C would."""
    os.killpg(proc.pid, signal.SIGTERM)
    proc.wait(timeout=grace)


# -- MLflow ---------------------------------------------------------------------------------

def test_sweep_against_a_real_mlflow_server(tmp_path, prefect_api, monkeypatch):
    from mlflow.tracking import MlflowClient
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows import runners
    from flows.sweep import sweep

    port = free_port()
    store = tmp_path / "server"
    store.mkdir()
    cmd = [str(VENV_BIN / "mlflow"), "server", "--host", "127.0.0.1", "--port", str(port),
           "--backend-store-uri", f"sqlite:///{store / 'mlflow.db'}",
           "--artifacts-destination", (store / "artifacts").as_uri(), "--workers", "1"]
    env = dict(os.environ, MLFLOW_SERVER_ENABLE_JOB_EXECUTION="false",
               MLFLOW_DISABLE_TELEMETRY="true")
    env.pop("MLFLOW_TRACKING_URI", None)
    log = tmp_path / "mlflow-server.log"
    url = f"http://127.0.0.1:{port}"
    with open(log, "ab") as out:
        server = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                  stderr=subprocess.STDOUT, start_new_session=True)
    try:
        wait_for(lambda: _get(url + "/health"), 180, "mlflow server health", server, log)
        assert _listens_on_loopback_only(port)

        root, params = small_project(tmp_path / "project")
        params["mlflow"]["experiment"] = "ops-http"
        monkeypatch.chdir(root)
        monkeypatch.setenv("MLFLOW_TRACKING_URI", url)
        monkeypatch.setenv("NNSF_WORKERS", "2")
        with temporary_settings(updates={PREFECT_API_URL: prefect_api}):
            state = runners.configured(sweep)(params, return_state=True)
        assert state.is_completed(), state.message

        # Read everything back through the REST API.
        client = MlflowClient(tracking_uri=url)
        experiment = client.get_experiment_by_name("ops-http")
        assert experiment.artifact_location.startswith("mlflow-artifacts:")  # served by the server
        parent = state.result()["mlflow_run_id"]
        children = client.search_runs([experiment.experiment_id],
                                      f"tags.mlflow.parentRunId = '{parent}'")
        assert len(children) == 8 and all(c.info.status == "FINISHED" for c in children)
        table = sweep_table(root)
        from_server = {(float(c.data.params["alpha"]), float(c.data.params["beta"]),
                        int(c.data.params["rank"])): c.data.metrics["sweep/precision_mean"] for c in children}
        from_table = {(r.alpha, r.beta, int(r.rank)): r.precision_mean for r in table.itertuples()}
        assert from_table == pytest.approx(from_server, rel=5.1e-6)  # 6 significant digits
        figure = client.list_artifacts(children[0].info.run_id, "reports/figures/sweep")
        assert len(figure) == 1 and figure[0].path.endswith(".png")
        stored = list((store / "artifacts").rglob("*.png"))
        assert len(stored) == 8 + 1  # the points' and the parent's chart, proxied to the server
        assert not (root / "mlflow.db").exists()  # nothing was logged locally
    finally:
        pgid = server.pid
        if server.poll() is None:
            _stop_group(server)
    # The server and its workers are gone.
    wait_for(lambda: not group_pids(pgid), 30, "mlflow server processes to exit")
    assert _get(url + "/health", timeout=1) is None


# -- Prefect ----------------------------------------------------------------------------------

#: Two real stages of the pipeline (data, features) on tiny params: enough for
#: the scheduled flow's `dvc repro` to do real work in seconds.
TINY = {"seed": 0,
        "dataset": {"name": "synthetic", "path": "nnsf/datasets",
                    "synthetic": {"characters": 2, "clips_per_cell": 2, "frames": 6, "noise_px": 0.4}},
        "unify": {"margin": 0.5}, "mlflow": {"experiment": "ops-deploy"}}


def test_cron_deployment_on_a_real_prefect_server(tmp_path, mlflow_template):
    from flows import prefect_server

    home = tmp_path / "prefect-home"
    with prefect_server.running(home, ui=False) as api:
        port = int(api.rsplit(":", 1)[1].split("/")[0])
        assert _listens_on_loopback_only(port)
        server_pids = group_pids(os.getpgid(_server_pid(port)))
        assert server_pids

        root, env = new_project(tmp_path / "project", mlflow_template, api)
        stages = yaml.safe_load((root / "dvc.yaml").read_text())
        stages["stages"] = {k: stages["stages"][k] for k in ("data", "features")}
        (root / "dvc.yaml").write_text(yaml.safe_dump(stages, sort_keys=False))
        (root / "params.yaml").write_text(yaml.safe_dump(TINY, sort_keys=False))
        run(["git", "-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qam", "tiny"], root, env)
        env["PREFECT_RUNNER_POLL_FREQUENCY"] = "1"

        log = tmp_path / "serve.log"
        with process_group(FLOWS + ["serve", "--cron", "0 3 * * *", "--name", "ops"], env, root,
                           log) as serve:
            deployment = wait_for(lambda: _deployment(api, "ops"), 120, "the deployment", serve, log,
                                  every=1)
            schedule = deployment["schedules"][0]["schedule"]
            assert schedule["cron"] == "0 3 * * *" and deployment["schedules"][0]["active"]
            flow_run = wait_for(lambda: _try_post(api, f"/deployments/{deployment['id']}/create_flow_run",
                                                  {}), 60, "a triggered run", serve, log, every=1)
            final = wait_for(lambda: _final_state(api, flow_run["id"]), 300, "the triggered run",
                             serve, log, every=1)
            assert final == "COMPLETED", log.read_text()[-3000:]
        assert (root / "data" / "features" / "features.csv").is_file()
        stage_runs = _try_post(api, "/flow_runs/filter", {"flows": {"name": {"any_": ["nnsf-data",
                                                                                  "nnsf-features"]}}})
        assert {r["state"]["type"] for r in stage_runs} == {"COMPLETED"} and len(stage_runs) == 2
    assert not [p for p in server_pids if psutil.pid_exists(p)
                and psutil.Process(p).status() != psutil.STATUS_ZOMBIE]


def _server_pid(port: int) -> int:
    for conn in psutil.net_connections(kind="inet"):
        if conn.status == psutil.CONN_LISTEN and conn.laddr.port == port and conn.pid:
            return conn.pid
    raise AssertionError(f"nothing listens on {port}")


def _deployment(api: str, name: str):
    try:
        found = _try_post(api, "/deployments/filter", {"deployments": {"name": {"any_": [name]}}})
    except (urllib.error.URLError, ConnectionError):
        return None
    return found[0] if found else None


def _final_state(api: str, flow_run_id: str):
    try:
        with urllib.request.urlopen(f"{api}/flow_runs/{flow_run_id}", timeout=10) as response:
            state = json.loads(response.read())["state"]
    except (urllib.error.URLError, ConnectionError):
        return None
    return state["type"] if state and state["type"] in (
        "COMPLETED", "FAILED", "CRASHED", "CANCELLED") else None
