"""Bad input through the real command line, and the flows' small building blocks.

Every bad-input case runs ``python -m flows <stage>`` in a copy of the project
and expects: exit code 2, exactly one ``error: …`` line on stderr naming the
file or field, no traceback anywhere, and no output file that looks finished.
"""
from __future__ import annotations

import io
import logging
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from conftest import PROJECT, committed_reports, run
from flows import project, runners
from flows.console import NoTracebackFormatter
from flows.pipeline import report
from nnsf.datasets.contract import COLUMNS
from nnsf.errors import InputError

FLOWS = [sys.executable, "-m", "flows"]


def set_params(root: Path, **changes) -> None:
    """Change dotted keys of the copy's params.yaml, e.g. ``set_params(root, **{"nnsf.rank": 3})``."""
    path = root / "params.yaml"
    params = yaml.safe_load(path.read_text())
    for key, value in changes.items():
        node = params
        *parents, last = key.split(".")
        for part in parents:
            node = node[part]
        node[last] = value
    path.write_text(yaml.safe_dump(params, sort_keys=False))


def write_features(root: Path, bad: str | None = None) -> Path:
    """A small valid unified feature table (2 characters x 2 motions x 2 clips x 6 frames).

    ``bad="nan"`` or ``bad="negative"`` spoils one value in column x5, row 4.
    """
    rng = np.random.default_rng(0)
    rows = []
    for c in ("hero", "sidekick"):
        for m in ("walk", "jump"):
            for k in range(2):
                for f in range(6):
                    rows.append([f"{c}-{m}-{k}", f, c, m, *rng.uniform(0.5, 3.0, 34)])
    table = pd.DataFrame(rows, columns=list(COLUMNS))
    if bad == "nan":
        table.loc[3, "x5"] = np.nan
    elif bad == "negative":
        table.loc[3, "x5"] = -0.25
    path = root / "data" / "features" / "features.csv"
    path.parent.mkdir(parents=True, exist_ok=True)
    table.to_csv(path, index=False)
    return path


def assert_clean_failure(result, *needles: str) -> str:
    """Exit 2, one ``error:`` line on stderr containing every needle, no traceback."""
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, (result.returncode, result.stdout[-2000:], result.stderr)
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("error: "), lines[0]
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    assert "Traceback" not in result.stderr + result.stdout
    return lines[0]


def assert_nothing_finished(root: Path) -> None:
    """No model, report or figure was left behind (not even a temporary file); the committed
    reports of runs on outside data, which the project copy starts with, are untouched."""
    committed = {root / name for name in committed_reports()}
    for folder in ("models", "reports"):
        left = [p for p in (root / folder).rglob("*") if p.is_file() and p not in committed]
        assert left == [], left
    for path in committed:
        assert path.read_bytes() == (PROJECT / path.relative_to(root)).read_bytes(), path


# -- bad input, caught before any flow starts (no Prefect server needed) -------------

@pytest.mark.slow  # runs `python -m flows`
def test_wrong_type_in_params_fails_before_prefect(make_project):
    root, env = make_project(prefect=False)
    set_params(root, **{"nnsf.rank": "ten"})
    result = run(FLOWS + ["factorize"], root, env)
    line = assert_clean_failure(result, "params.yaml", "nnsf.rank")
    assert "'ten'" in line
    assert "flow run" not in result.stdout.lower()  # validated before Prefect started
    assert_nothing_finished(root)


@pytest.mark.slow  # runs `python -m flows`
def test_unknown_dataset_name(make_project):
    root, env = make_project(prefect=False)
    set_params(root, **{"dataset.name": "mocap-2000"})
    result = run(FLOWS + ["data"], root, env)
    assert_clean_failure(result, "params.yaml", "dataset.name")
    assert "flow run" not in result.stdout.lower()
    assert not (root / "data" / "raw").exists()


@pytest.mark.slow  # runs `python -m flows`
def test_unknown_command(make_project):
    root, env = make_project(prefect=False)
    result = run(FLOWS + ["factorise"], root, env)
    assert_clean_failure(result, "factorise")


# -- bad input found inside a flow (real Prefect server) ------------------------------

@pytest.mark.slow
def test_features_with_nan(make_project):
    root, env = make_project()
    csv = write_features(root, bad="nan")
    result = run(FLOWS + ["factorize"], root, env)
    assert_clean_failure(result, str(csv.relative_to(root)), "x5")
    assert "Finished in state Failed" in result.stdout  # Prefect recorded the failure
    assert_nothing_finished(root)


@pytest.mark.slow
def test_features_with_negative_value(make_project):
    root, env = make_project()
    csv = write_features(root, bad="negative")
    result = run(FLOWS + ["factorize"], root, env)
    assert_clean_failure(result, str(csv.relative_to(root)), "x5")
    assert_nothing_finished(root)


@pytest.mark.slow
def test_rank_larger_than_feature_count(make_project):
    root, env = make_project()
    write_features(root)
    set_params(root, **{"nnsf.rank": 40})
    result = run(FLOWS + ["factorize"], root, env)
    assert_clean_failure(result, "nnsf.rank")
    assert_nothing_finished(root)


@pytest.mark.slow
def test_sweep_rank_larger_than_feature_count(make_project):
    root, env = make_project()
    write_features(root)
    set_params(root, **{"sweep.rank": [4, 40], "sweep.alpha": [0.0], "sweep.beta": [0.0]})
    result = run(FLOWS + ["sweep"], root, env)
    assert_clean_failure(result, "sweep.rank")
    assert not (root / "reports" / "sweep.csv").exists()
    assert not (root / "reports" / "sweep.json").exists()


# -- the stage server ----------------------------------------------------------------

@pytest.mark.slow  # runs `python -m flows factorize` twice and a stage server
def test_a_stage_run_through_the_stage_server_is_the_same_stage(make_project, tmp_path):
    """flows/stage_server.py: the stage a server's child runs writes the same bytes as the
    stage run on its own, is still its own Prefect flow run and its own MLflow run, and takes
    its Prefect settings from its command's environment, not the server's."""
    import hashlib
    import shutil

    from flows import stage_server

    root, env = make_project()
    write_features(root)
    set_params(root, **{"nnsf.rank": 3, "nnsf.max_iter": 20})
    outputs = ("models/nnsf.npz", "reports/factorize.json", "reports/factorize.manifest.json",
               "reports/figures/objective.png", "reports/figures/basis.png")

    def digests():
        return {f: hashlib.sha256((root / f).read_bytes()).hexdigest() for f in outputs}

    env.pop(stage_server.ENV, None)
    alone = run(FLOWS + ["factorize"], root, env)
    assert alone.returncode == 0, alone.stderr[-2000:]
    first = digests()
    shutil.rmtree(root / "models")
    shutil.rmtree(root / "reports")

    # The server starts with a Prefect API where nothing listens: the stage must use its
    # command's environment (the session's server), as it would on its own.
    server_env = dict(env, PREFECT_API_URL="http://127.0.0.1:9/api")
    with stage_server.running(server_env, root, tmp_path / "stage-server.log") as served:
        assert stage_server.ENV in served, (tmp_path / "stage-server.log").read_text()[-2000:]
        served = dict(served, PREFECT_API_URL=env["PREFECT_API_URL"])
        # What `python -m flows factorize` does under repro, spelled out: delegate() returns
        # the stage's exit code when the server ran it, None when it would run locally.
        code = ("import sys; from flows import stage_server; "
                "code = stage_server.delegate(['factorize']); print('delegated:', code); "
                "sys.exit(3 if code is None else code)")
        through = run([sys.executable, "-c", code], root, served)
    assert through.returncode == 0, through.stdout[-2000:] + through.stderr[-2000:]
    assert "delegated: 0" in through.stdout
    assert digests() == first

    import mlflow

    mlflow.set_tracking_uri(env["MLFLOW_TRACKING_URI"])
    runs = mlflow.search_runs(search_all_experiments=True)
    stage_runs = runs[runs["tags.nnsf.stage"] == "factorize"]
    assert len(stage_runs) == 2 and (stage_runs["status"] == "FINISHED").all()
    assert stage_runs["tags.prefect.flow_run_id"].nunique() == 2


# -- building blocks -------------------------------------------------------------------

def test_console_formatter_shows_one_line_but_keeps_the_traceback_for_others():
    console, api = io.StringIO(), io.StringIO()
    logger = logging.getLogger("nnsf-test-console")
    logger.propagate = False
    first = logging.StreamHandler(console)
    first.setFormatter(NoTracebackFormatter(logging.Formatter("%(levelname)s %(message)s")))
    second = logging.StreamHandler(api)  # stands in for Prefect's API handler
    logger.handlers = [first, second]
    try:
        raise RuntimeError("boom\nsecond line")
    except RuntimeError:
        logger.exception("stage failed")
    assert console.getvalue() == "ERROR stage failed (RuntimeError: boom)\n"
    assert "Traceback" in api.getvalue()


def test_root_of_a_dvc_experiment_workspace_is_the_real_project(tmp_path):
    (tmp_path / "dvc.yaml").write_text("stages: {}\n")
    workspace = tmp_path / ".dvc" / "tmp" / "exps" / "tmpabc123"
    workspace.mkdir(parents=True)
    (workspace / "dvc.yaml").write_text("stages: {}\n")
    assert project.root(workspace) == tmp_path
    assert project.root(tmp_path / "nested" / "deeper") == tmp_path


def test_mlflow_store_is_absolute_and_overridable(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    assert project.mlflow_uri(tmp_path) == f"sqlite:///{tmp_path}/mlflow.db"
    assert project.mlflow_artifacts(tmp_path) == (tmp_path / "mlartifacts").as_uri()
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "sqlite:////elsewhere/x.db")
    assert project.mlflow_uri(tmp_path) == "sqlite:////elsewhere/x.db"


def test_task_runner_is_chosen_in_one_place(monkeypatch):
    from prefect.task_runners import ThreadPoolTaskRunner

    monkeypatch.setenv("NNSF_WORKERS", "3")
    monkeypatch.delenv("NNSF_TASK_RUNNER", raising=False)
    runner = runners.task_runner()
    assert isinstance(runner, ThreadPoolTaskRunner) and runner._max_workers == 3
    monkeypatch.setenv("NNSF_TASK_RUNNER", "spark")
    with pytest.raises(InputError, match="NNSF_TASK_RUNNER"):
        runners.task_runner()


def test_each_fan_out_gets_its_runner_and_the_environment_overrides_the_rule(monkeypatch):
    """The rule (flows/runners.py, docs/operations.md): processes for the held-out cells (few, large items),
    threads for every other fan-out; NNSF_TASK_RUNNER, when set, decides for all of them."""
    from prefect.task_runners import ProcessPoolTaskRunner, ThreadPoolTaskRunner

    from flows.stage_flows import FAN_OUT, FLOWS

    monkeypatch.delenv("NNSF_TASK_RUNNER", raising=False)
    monkeypatch.setenv("NNSF_WORKERS", "2")
    chosen = {stage: runners.kind(stage) for stage in (*FAN_OUT, "sweep")}
    assert chosen == {"evaluate": "threads", "frames": "threads", "roto": "threads",
                      "roto_eval": "threads", "heldout": "processes", "sweep": "threads"}
    heldout = runners.configured(FLOWS["heldout"], "heldout")
    assert isinstance(heldout.task_runner, ProcessPoolTaskRunner)
    assert isinstance(runners.configured(FLOWS["evaluate"], "evaluate").task_runner, ThreadPoolTaskRunner)
    for name, cls in (("threads", ThreadPoolTaskRunner), ("processes", ProcessPoolTaskRunner)):
        monkeypatch.setenv("NNSF_TASK_RUNNER", name)
        assert {runners.kind(stage) for stage in chosen} == {name}
        assert isinstance(runners.configured(FLOWS["heldout"], "heldout").task_runner, cls)


def test_pipeline_report_names_stages_and_changed_metrics():
    status = {"factorize": [{"changed deps": {"params.yaml": {"nnsf.alpha": 0.1}}}]}
    diff = {"reports/metrics.json": {"nnsf_precision": {"old": 0.5, "new": 0.6, "diff": 0.1},
                                     "same": {"old": 1, "new": 1, "diff": 0}}}
    text = report(status, ["factorize"], diff)
    assert "`factorize` (changed deps: params.yaml)" in text
    assert "| reports/metrics.json | nnsf_precision | 0.5 | 0.6 |" in text
    assert "same" not in text
    assert "Nothing to reproduce" in report({}, [], {})
