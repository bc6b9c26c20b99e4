"""Faults: processes that die. An MLflow run whose process is SIGKILLed ends KILLED, not
RUNNING forever; a sweep killed halfway resumes without recomputing its finished points.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pandas as pd
import pytest
import yaml

from test_ops_support import mlflow_db, process_group, small_project, wait_for

FLOWS = [sys.executable, "-m", "flows"]


def _client(uri: str):
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=uri)


@pytest.mark.slow  # spawns a process and SIGKILLs it
def test_a_run_whose_process_was_killed_is_marked_killed_on_the_next_start(tmp_path, mlflow_template,
                                                                             monkeypatch):
    from flows.mlflow_runs import ExperimentLog

    uri = mlflow_db(mlflow_template, tmp_path / "mlflow.db")
    monkeypatch.setenv("MLFLOW_TRACKING_URI", uri)
    (tmp_path / "ready").unlink(missing_ok=True)
    script = textwrap.dedent(f"""
        import time
        from pathlib import Path
        from flows.mlflow_runs import ExperimentLog
        log = ExperimentLog("faults", Path({str(tmp_path)!r}))
        run = log.start_run("doomed", {{"nnsf.stage": "factorize"}})
        Path({str(tmp_path / 'ready')!r}).write_text(run)
        time.sleep(600)
    """)
    proc = subprocess.Popen([sys.executable, "-c", script], env=dict(os.environ),
                            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        run_id = wait_for(lambda: (tmp_path / "ready").exists() and (tmp_path / "ready").read_text(),
                          120, "the doomed run", proc)
        # A run of a live process (this one) must be left alone.
        mine = ExperimentLog("faults", tmp_path)
        alive = mine.start_run("alive")
        assert mine.close_dead_runs() == []
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    client = _client(uri)
    assert client.get_run(run_id).info.status == "RUNNING"  # nobody could end it
    reopened = ExperimentLog("faults", tmp_path)  # what the next stage or sweep does
    assert reopened.closed_stale == [run_id]
    assert client.get_run(run_id).info.status == "KILLED"
    assert str(proc.pid) in client.get_run(run_id).data.tags["nnsf.killed_reason"]
    assert client.get_run(alive).info.status == "RUNNING"
    mine.end_run(alive)


@pytest.mark.slow
def test_a_sweep_killed_halfway_resumes_without_recomputing_finished_points(
        tmp_path, mlflow_template, prefect_api):
    params = yaml.safe_load(yaml.safe_dump(__import__("test_ops_support").SMALL))
    params["sweep"].update(alpha=[0.0, 0.01, 0.1], beta=[0.0, 1.0, 10.0, 100.0], rank=[4, 6])
    total = 24
    root, params = small_project(tmp_path / "project", params)
    uri = mlflow_db(mlflow_template, tmp_path / "mlflow.db")
    env = dict(os.environ, MLFLOW_TRACKING_URI=uri, PREFECT_API_URL=prefect_api,
               NNSF_WORKERS="1", NNSF_TASK_RUNNER="threads", OMP_NUM_THREADS="1",
               PYTHONDONTWRITEBYTECODE="1")
    env.pop("NNSF_DEBUG", None)
    client = _client(uri)

    def finished_points():
        exp = client.get_experiment_by_name("ops")
        if exp is None:
            return 0
        runs = client.search_runs([exp.experiment_id],
                                  "tags.`nnsf.stage` = 'sweep-point' and attributes.status = 'FINISHED'")
        return len(runs)

    log = tmp_path / "first.log"
    with process_group(FLOWS + ["sweep"], env, root, log) as proc:
        done = wait_for(lambda: finished_points() >= 4 and finished_points(), 300,
                        "four finished points", proc, log, every=0.05)
        os.killpg(proc.pid, signal.SIGKILL)  # the whole stage, mid-sweep
        proc.wait()
    finished_before = finished_points()
    assert done <= finished_before < total, "the sweep was not interrupted halfway"
    assert not (root / "reports" / "sweep.csv").exists()

    second = subprocess.run(FLOWS + ["sweep"], cwd=root, env=env, capture_output=True, text=True,
                            stdin=subprocess.DEVNULL, timeout=600)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]

    exp = client.get_experiment_by_name("ops")
    sweeps = client.search_runs([exp.experiment_id], "tags.`nnsf.stage` = 'sweep'",
                                order_by=["attributes.start_time ASC"])
    killed, resumed = sweeps
    assert killed.info.status == "KILLED"  # marked when the second run opened the store
    assert resumed.info.status == "FINISHED"
    # The counter: every point that had finished was copied, only the rest computed.
    assert resumed.data.metrics["sweep/points_reused"] == finished_before
    assert resumed.data.metrics["sweep/points_computed"] == total - finished_before
    children = client.search_runs([exp.experiment_id],
                                  f"tags.mlflow.parentRunId = '{resumed.info.run_id}'")
    reused = [c for c in children if "nnsf.reused_from" in c.data.tags]
    assert len(children) == total and len(reused) == finished_before
    assert not [r for r in client.search_runs([exp.experiment_id], "attributes.status = 'RUNNING'")]

    # The resumed table is what the points give when computed from scratch.
    from nnsf import pipeline, stages

    table = pd.read_csv(root / "reports" / "sweep.csv")
    assert len(table) == total
    for row in table.itertuples():
        if row.Index % 5:  # a fifth of the points, reused and computed ones alike
            continue
        fresh = stages.sweep_point(params, {"alpha": row.alpha, "beta": row.beta, "rank": int(row.rank)},
                                   features_csv=root / pipeline.FEATURES_DIR / "features.csv")
        assert row.precision_mean == pytest.approx(fresh.metrics["precision_mean"],
                                                    rel=5.1e-6)  # the CSV keeps 6 digits
    figures = sorted(p.name for p in (root / "reports" / "figures" / "sweep").iterdir())
    assert len(figures) == total + 1  # reused points got their figures back from MLflow; the chart
    assert "precision_vs_alpha_beta_rank.png" in figures
    assert not [f for f in figures if f.startswith(".")]  # the killed run's temporary files are gone
