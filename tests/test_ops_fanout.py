"""Fan-out on Prefect task runners: the mapper, a real Dask cluster, retries and failures.

Real Prefect (the session's ``prefect server start``), real MLflow (a sqlite
store), a real ``distributed.LocalCluster``; the sweep runs the real
``nnsf.stages.sweep_point`` on a small synthetic project.  Fault injection
uses point functions defined here that wrap the real one.
"""
from __future__ import annotations

import json
import os
import urllib.request
from pathlib import Path

# Imported at collection, not inside a test: distributed configures logging on
# import, which would swap the stream of the handler pytest captures a test's logs with.
import distributed  # noqa: F401
import numpy as np
import pandas as pd
import pytest

from flows import runners
from nnsf.errors import InputError
from test_ops_support import mlflow_db, small_project, sweep_table

pytestmark = pytest.mark.slow

#: Environment variable naming the folder where the fault-injecting point
#: functions count their attempts (one file per attempt).
ATTEMPTS_DIR = "NNSF_OPS_TEST_ATTEMPTS"


# -- module-level functions the workers import ------------------------------------------

def square_sum(item: tuple[int, int]) -> int:
    """A pure function of one picklable argument (oracle: the same computed here)."""
    a, b = item
    return int(np.sum(np.arange(a, b) ** 2))


def blas_threads_seen(item: tuple[str, float]) -> int:
    """As a fit does, limit BLAS to one thread for the item, after ``delay`` s; report the BLAS
    threads the item has at the end of its 0.3 s, while the other item starts or ends."""
    import time

    from threadpoolctl import threadpool_info, threadpool_limits

    _, delay = item
    time.sleep(delay)
    with threadpool_limits(1, user_api="blas"):
        time.sleep(0.3)
        return max(m["num_threads"] for m in threadpool_info() if m["user_api"] == "blas")


def _attempt(job: dict) -> int:
    """Record one attempt at this job's point; return how many there have been."""
    folder = Path(os.environ[ATTEMPTS_DIR])
    p = job["point"]
    stem = f"a{p['alpha']:g}_b{p['beta']:g}_k{p['rank']}"
    n = len(list(folder.glob(stem + ".*"))) + 1
    (folder / f"{stem}.{n}").touch()
    return n


def flaky_point(job: dict):
    """The real point, except that α=0, β=1, k=4 fails on its first attempt."""
    from flows.sweep import run_point

    n = _attempt(job)
    p = job["point"]
    if (p["alpha"], p["beta"], p["rank"]) == (0.0, 1.0, 4) and n == 1:
        raise ConnectionError("worker lost (injected, transient)")
    return run_point(job)


def broken_point(job: dict):
    """The real point, except two that always fail: one on bad input, one on a bug."""
    from flows.sweep import run_point

    _attempt(job)
    p = job["point"]
    if (p["alpha"], p["beta"], p["rank"]) == (0.01, 1.0, 6):
        raise RuntimeError("numerical blow-up (injected, permanent)")
    if (p["alpha"], p["beta"], p["rank"]) == (0.0, 0.0, 6):
        raise InputError("features.csv", "x3", "a finite number (injected)", "nan")
    return run_point(job)


# -- fixtures -----------------------------------------------------------------------------

@pytest.fixture
def prefect_here(prefect_api):
    """This process, its threads and the processes it starts talk to the session's Prefect server
    (flows.prefect_server.in_use: without it, the process runner's event-forwarding thread
    started a temporary server, whose database refused the task runs of a flow run it never saw)."""
    from prefect.settings import PREFECT_API_URL, temporary_settings

    from flows import prefect_server

    with prefect_server.in_use(prefect_api), temporary_settings(updates={PREFECT_API_URL: prefect_api}):
        yield prefect_api


@pytest.fixture
def project(tmp_path, mlflow_template, monkeypatch, prefect_here):
    """A small project as the working directory, with its own MLflow store."""
    root, params = small_project(tmp_path / "project")
    monkeypatch.chdir(root)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", mlflow_db(mlflow_template, tmp_path / "mlflow.db"))
    monkeypatch.setenv("NNSF_WORKERS", "2")
    attempts = tmp_path / "attempts"
    attempts.mkdir()
    monkeypatch.setenv(ATTEMPTS_DIR, str(attempts))
    return root, params, attempts


def run_sweep(params: dict, **kwargs):
    from flows.sweep import sweep

    return runners.configured(sweep)(params, return_state=True, **kwargs)


def task_runs(api: str, flow_run_id) -> dict[str, dict]:
    """The flow run's task runs by name, from Prefect's REST API."""
    body = json.dumps({"flow_runs": {"id": {"any_": [str(flow_run_id)]}}}).encode()
    request = urllib.request.Request(api + "/task_runs/filter", data=body,
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return {run["name"]: run for run in json.loads(response.read())}


def nested_runs(parent_id: str) -> pd.DataFrame:
    import mlflow

    mlflow.set_tracking_uri(os.environ["MLFLOW_TRACKING_URI"])
    return mlflow.search_runs(search_all_experiments=True,
                              filter_string=f"tags.mlflow.parentRunId = '{parent_id}'")


# -- the mapper ---------------------------------------------------------------------------

def test_prefect_mapper_returns_results_in_order(prefect_here, monkeypatch):
    from prefect import flow

    monkeypatch.setenv("NNSF_WORKERS", "2")
    items = [(i, i + 7 * (i % 3) + 1) for i in range(12)]

    @flow(persist_result=False)
    def fan_out():
        return runners.prefect_mapper("square-sum")(square_sum, items)

    assert runners.configured(fan_out)() == runners.local_mapper(square_sum, items)


def test_items_on_threads_keep_one_blas_thread_when_another_item_ends(prefect_here, monkeypatch):
    """A limit set and restored per item races on the thread runner (the BLAS pool is the
    process's): an item ending restores what it found, two threads, under one still running,
    whose sums then round differently (a CV fit's iteration count differed between a cold run
    and the committed one).  The mapper holds one BLAS thread for the whole fan-out (without it: [2, 1])."""
    from prefect import flow
    from threadpoolctl import threadpool_info, threadpool_limits

    monkeypatch.setenv("NNSF_TASK_RUNNER", "threads")
    monkeypatch.setenv("NNSF_WORKERS", "2")
    items = [("short", 0.0), ("long", 0.15)]

    @flow(persist_result=False)
    def fan_out():
        return runners.prefect_mapper("blas-threads")(blas_threads_seen, items)

    with threadpool_limits(2, user_api="blas"):   # the default on a 2-core machine
        if max(m["num_threads"] for m in threadpool_info() if m["user_api"] == "blas") < 2:
            pytest.skip("this BLAS cannot run two threads here (capped by its environment)")
        seen = runners.configured(fan_out)()
    assert seen == [1, 1]


def test_worker_processes_report_the_project_files_they_ran(prefect_here, monkeypatch, tmp_path):
    """Under NNSF_RECORD_IMPORTS, items run in a process pool send back the project files their
    worker loaded (flows.__main__ adds them to the stage's record, checked against its deps)."""
    from prefect import flow

    monkeypatch.setenv("NNSF_TASK_RUNNER", "processes")
    monkeypatch.setenv("NNSF_WORKERS", "2")
    monkeypatch.setenv("NNSF_RECORD_IMPORTS", str(tmp_path))
    runners.WORKER_FILES.clear()
    items = [(i, i + 5) for i in range(4)]

    @flow(persist_result=False)
    def fan_out():
        return runners.prefect_mapper("square-sum")(square_sum, items)

    assert runners.configured(fan_out)() == runners.local_mapper(square_sum, items)
    # the worker unpickled the recording wrapper from flows.runners, so loaded it and its package
    assert {"flows/__init__.py", "flows/runners.py"} <= runners.WORKER_FILES
    assert all(f.split("/")[0] in ("nnsf", "flows") for f in runners.WORKER_FILES)
    runners.WORKER_FILES.clear()


def test_configured_runner_follows_the_environment(monkeypatch):
    from prefect import flow
    from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner
    from prefect_dask import DaskTaskRunner

    @flow
    def noop():
        return None

    monkeypatch.setenv("NNSF_WORKERS", "3")
    monkeypatch.setenv("NNSF_TASK_RUNNER", "processes")
    assert isinstance(runners.configured(noop).task_runner, ProcessPoolTaskRunner)
    monkeypatch.setenv("NNSF_TASK_RUNNER", "threads")
    runner = runners.configured(noop).task_runner
    assert isinstance(runner, ThreadPoolTaskRunner) and runner._max_workers == 3
    monkeypatch.setenv("NNSF_TASK_RUNNER", "dask")
    monkeypatch.setenv("NNSF_DASK_ADDRESS", "tcp://127.0.0.1:8786")
    runner = runners.configured(noop).task_runner
    assert isinstance(runner, DaskTaskRunner) and runner.address == "tcp://127.0.0.1:8786"
    assert noop.task_runner is not runner  # the flow object itself is unchanged


# -- a real Dask cluster --------------------------------------------------------------------

def test_sweep_on_a_dask_local_cluster_equals_the_local_runner(project, tmp_path, monkeypatch):
    from distributed import Client, LocalCluster, get_task_stream

    root, params, _ = project
    local = run_sweep(params)
    assert local.is_completed(), local.message
    expected = sweep_table(root)
    (root / "reports" / "sweep.csv").unlink()

    params = dict(params, mlflow={"experiment": "ops-dask"})  # nothing to reuse there
    monkeypatch.setenv("NNSF_TASK_RUNNER", "dask")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")  # inherited by the worker processes
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                      dashboard_address=None, host="127.0.0.1") as cluster, \
            Client(cluster) as client:
        monkeypatch.setenv("NNSF_DASK_ADDRESS", cluster.scheduler_address)
        with get_task_stream(client) as stream:
            state = run_sweep(params)
        workers_used = {entry["worker"] for entry in stream.data}
    assert state.is_completed(), state.message
    assert len(stream.data) >= 8 and len(workers_used) == 2  # both workers ran points
    pd.testing.assert_frame_equal(sweep_table(root), expected, check_exact=True)
    assert state.result()["points_computed"] == 8


# -- faults ---------------------------------------------------------------------------------

def test_a_transient_point_failure_is_retried_and_the_sweep_completes(project, prefect_here):
    root, params, attempts = project
    state = run_sweep(params, point_fn=f"{__name__}:flaky_point")
    assert state.is_completed(), state.message
    assert sorted(p.name for p in attempts.glob("a0_b1_k4.*")) == ["a0_b1_k4.1", "a0_b1_k4.2"]
    runs = task_runs(prefect_here, state.state_details.flow_run_id)
    flaky = runs["sweep-point α=0 β=1 k=4"]
    assert flaky["state"]["type"] == "COMPLETED" and flaky["run_count"] == 2  # Prefect retried it
    assert all(r["run_count"] == 1 for name, r in runs.items() if name != flaky["name"])
    table = sweep_table(root)
    assert len(table) == 8 and table["precision_mean"].notna().all()


def test_a_point_that_always_fails_is_named_and_the_others_are_kept(project, prefect_here):
    root, params, attempts = project
    state = run_sweep(params, point_fn=f"{__name__}:broken_point")
    assert state.is_failed()
    assert "α=0.01 β=1 k=6" in state.message and "α=0 β=0 k=6" in state.message
    error = state.result(raise_on_failure=False)
    assert isinstance(error, runners.FanOutError) and not isinstance(error, InputError)
    assert set(error.failed) == {"α=0.01 β=1 k=6", "α=0 β=0 k=6"}
    runs = task_runs(prefect_here, state.state_details.flow_run_id)
    assert runs["sweep-point α=0.01 β=1 k=6"]["run_count"] == 1 + runners.RETRIES  # a bug: retried
    assert runs["sweep-point α=0 β=0 k=6"]["run_count"] == 1  # bad input: not retried
    assert len(list(attempts.glob("a0_b0_k6.*"))) == 1

    # The six good points are logged and finished; the sweep itself is marked failed
    # and wrote no table that could look finished.
    import mlflow

    mlflow.set_tracking_uri(os.environ["MLFLOW_TRACKING_URI"])
    parent = mlflow.search_runs(experiment_names=["ops"], filter_string="tags.`nnsf.stage` = 'sweep'")
    assert list(parent["status"]) == ["FAILED"]
    children = nested_runs(parent["run_id"].iloc[0])
    assert len(children) == 6 and (children["status"] == "FINISHED").all()
    assert children["metrics.sweep/precision_mean"].notna().all()
    assert not (root / "reports" / "sweep.csv").exists()

    # Once the broken points are fixed, only they are computed: the six are reused.
    again = run_sweep(params)
    assert again.is_completed(), again.message
    assert {k: again.result()[k] for k in ("points_reused", "points_computed")} == {
        "points_reused": 6, "points_computed": 2}
