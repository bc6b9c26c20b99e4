"""End to end: ``python -m flows repro`` on a small params.yaml in a copy of the project.

Real DVC, real Prefect flows against the session's Prefect server, a real
sqlite MLflow store.  The tests of this module share one reproduced project
(``conftest.small_pipeline``, made once per session for this module and
test_ops_repro) and run in file order; the last ones change ``nnsf.alpha``
and ``animate.style``.
"""
from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path

import pandas as pd
import pytest
import yaml

from conftest import run

pytestmark = pytest.mark.slow

FLOWS = [sys.executable, "-m", "flows"]
DVC = [sys.executable, "-m", "dvc"]
ALL_STAGES = {"frames", "roto", "roto_eval", "data", "features", "factorize", "evaluate", "isomap", "sweep",
              "heldout", "translate", "reshape", "styles", "animate", "results"}
EXPERIMENT = "nnsf-e2e"

#: Small enough for seconds per stage, big enough for 3 grouped folds.
SMALL_PARAMS = f"""\
seed: 0
dataset:
  name: synthetic
  path: nnsf/datasets
  synthetic:
    characters: 3
    clips_per_cell: 2
    frames: 12
    noise_px: 0.4
  bvh:
    fps: 30
    azimuth: 0.0
    view: null
    elevation: 0.0
    facing: normalise
    center: true
    complete_grid: true
    joint_map: null
frames:
  characters: 1
  motions: [walk, wave]
  clips_per_cell: 1
  frames: 6
  size: 128
  keyframe_every: 0
  control_points: 4
roto:
  method: ours
  w_velocity: 3.0
  w_length: 1.0
  w_length_anchor: 4.0
  w_curvature: 1.0
  w_edge: 1.0
  w_sketch: 100.0
  w_colour: 100.0
  w_slide: 10.0
  edge_gate: 1.0
  velocity_trust: false
  snap: 3.0
  snap_to: auto
  window: 3
  samples: 8
  levels: 1
  max_iter: 5
  init: linear
  lk_end: blend
  eval_clips: 1
  edit_tol_px: 2.0
  max_edits: 2
unify:
  margin: 0.5
nnsf:
  label: motion
  rank: 4
  alpha: 0.01
  beta: 1.0
  class_in_loop: true
  max_iter: 30
  tol: 1.0e-4
  init: nndsvda
evaluate:
  folds: 3
  ranks: [2, 4]
  methods: [nnsf, nnsc, nmf, bilinear, mgpm, cbgpm]
  max_iter: 20
  gp:
    phase_bins: 2
    max_iter: 10
isomap:
  samples: 60
  neighbors: 6
  max_dim: 4
sweep:
  folds: 3
  alpha: [0.0, 0.01]
  beta: [0.0, 1.0]
  rank: [4]
  max_iter: 20
translation:
  rank: 4
  alpha: 0.01
  beta: 0.0
  label: motion
  basis: aligned
  synthesis: consensus
  amplitude: restore
  tempo: true
  ridge: 0.5
  smooth: 0.0
  transfer: recombine_swing
  neutral: null
  max_iter: 20
  align_iter: 20
  bilinear_rank: 1
  gp_rank: 2
  gp_phase_bins: 2
  gp_max_iter: 10
  max_sources: 0
  max_cells: 2
  examples: 1
  methods: [nnsf, bilinear, mgpm, cbgpm, identity]
  content_methods: [api, offset, spectral]
  max_contents: 1
  content_clip: auto
  style: auto
reshape:
  clip: null
  character: bruno
  character_size: 256
  n_vertices: 300
  subkeys_per_limb: 2
  method: ours
  propagation: limb-frame
  fps: 12
  max_frames: 6
  formats: [png, gif, mp4]
  depth_overrides: []
animate:
  character: pip
  motion: synthetic:max/walk/6
  style: bruno
  view: auto
  fps: 24
  n_vertices: 300
  max_frames: 6
  output: [mp4, gif, sheet]
mlflow:
  experiment: {EXPERIMENT}
"""


def stages_run(output: str) -> set[str]:
    return set(re.findall(r"Running stage '([^']+)'", output))


@pytest.fixture(scope="module")
def pipeline(small_pipeline):
    """A copy of the project with SMALL_PARAMS, reproduced once from scratch (conftest.small_pipeline,
    shared with test_ops_repro, which only reads its reference hashes)."""
    return small_pipeline


def dvc_yaml(root: Path) -> dict:
    return yaml.safe_load((root / "dvc.yaml").read_text())


def declared(entries) -> list[str]:
    """Paths of a dvc.yaml outs/metrics/deps list (entries may carry options)."""
    return [next(iter(e)) if isinstance(e, dict) else e for e in entries or []]


def test_cold_repro_runs_every_stage_and_writes_every_output(pipeline):
    assert stages_run(pipeline.cold.stdout) == ALL_STAGES
    assert "Traceback" not in pipeline.cold.stdout + pipeline.cold.stderr
    for name, stage in dvc_yaml(pipeline.root)["stages"].items():
        for path in declared(stage.get("outs")) + declared(stage.get("metrics")):
            assert (pipeline.root / path).exists(), (name, path)
        for path in declared(stage.get("metrics")):
            metrics = json.loads((pipeline.root / path).read_text())
            assert isinstance(metrics, dict) and metrics, path


def test_each_multi_file_report_stage_published_exactly_its_outputs(pipeline):
    """factorize, evaluate, isomap, heldout and tracking publish their files as one set
    (nnsf/publish.py): each manifest verifies and lists every other declared output."""
    from nnsf.publish import verify

    reports = pipeline.root / "reports"
    for name, stage in dvc_yaml(pipeline.root)["stages"].items():
        outputs = set(declared(stage.get("outs")) + declared(stage.get("metrics")))
        manifest = f"reports/{name}.manifest.json"
        if manifest not in outputs:
            continue
        published = {p.resolve().relative_to(pipeline.root.resolve()).as_posix()
                     for p in verify(reports, name).values()}
        assert published == outputs - {manifest}, name
    assert {p.name for p in reports.glob("*.manifest.json")} == {
        f"{s}.manifest.json" for s in ("factorize", "evaluate", "isomap", "heldout", "roto_eval")}
    # nothing staged left (reports/.gitignore is DVC's list of the cached outputs under reports/)
    assert not [p for p in reports.iterdir() if p.name.endswith(".staging")]
    assert not [p for p in reports.iterdir() if p.name.startswith(".") and p.name != ".gitignore"]


def test_plot_data_has_the_declared_columns(pipeline):
    precision = pd.read_csv(pipeline.root / "reports/plots/precision_vs_rank.csv")
    assert {"rank", "nnsf", "nnsc", "nmf", "bilinear"} <= set(precision.columns)
    assert sorted(precision["rank"]) == [2, 4]
    residual = pd.read_csv(pipeline.root / "reports/plots/isomap_residual.csv")
    assert {"dim", "residual_variance"} <= set(residual.columns)
    shown = run(DVC + ["plots", "show", "--json"], pipeline.root, pipeline.env)
    assert shown.returncode == 0, shown.stderr
    rendered = json.loads(shown.stdout)
    assert not rendered.get("errors"), rendered.get("errors")
    plots = rendered["data"]
    assert {"precision_vs_rank", "recon_error_vs_rank", "isomap_residual", "sweep"} <= set(plots)
    for name in ("precision_vs_rank", "isomap_residual", "sweep"):
        values = plots[name][0]["content"]["data"]["values"]
        assert values, name


def test_second_repro_is_a_noop_and_starts_no_server(pipeline):
    env = dict(pipeline.env)
    env.pop("PREFECT_API_URL")  # `python -m flows repro` would have to start its own server
    started = time.perf_counter()
    again = run(FLOWS + ["repro"], pipeline.root, env)
    seconds = time.perf_counter() - started
    print(f"no-op repro: {seconds:.1f} s")
    assert again.returncode == 0, again.stderr
    assert stages_run(again.stdout) == set()
    assert "Data and pipelines are up to date" in again.stdout + again.stderr
    assert not (pipeline.root / ".prefect" / "server.log").exists()  # no server was started
    status = run(DVC + ["status", "--json"], pipeline.root, pipeline.env)
    assert json.loads(status.stdout) == {}


def test_pipeline_command_records_its_run_in_the_server_it_starts(pipeline):
    """`python -m flows pipeline` without PREFECT_API_URL starts a server on the project's
    PREFECT_HOME; its flow run (and report) goes there, not to a temporary server of Prefect's
    own that vanishes with the command."""
    import sqlite3

    env = dict(pipeline.env)
    env.pop("PREFECT_API_URL")
    out = run(FLOWS + ["pipeline"], pipeline.root, env)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert "temporary server" not in out.stdout + out.stderr
    assert "Error logging to API" not in out.stdout + out.stderr  # logs sent before the server stops
    db = Path(env["PREFECT_HOME"]) / "prefect.db"
    with sqlite3.connect(db) as con:
        states = con.execute("SELECT flow_run.state_type FROM flow_run JOIN flow "
                             "ON flow.id = flow_run.flow_id WHERE flow.name = 'nnsf-pipeline'").fetchall()
    assert states == [("COMPLETED",)]


def test_mlflow_has_stage_runs_and_nested_sweep_runs(pipeline):
    import mlflow
    from mlflow.tracking import MlflowClient

    mlflow.set_tracking_uri(pipeline.mlflow_uri)
    runs = mlflow.search_runs(experiment_names=[EXPERIMENT])
    assert (runs["status"] == "FINISHED").all()
    by_stage = runs.groupby("tags.nnsf.stage").size().to_dict()
    assert by_stage == {"frames": 1, "roto": 1, "roto_eval": 1, "data": 1, "features": 1, "factorize": 1,
                        "evaluate": 1, "isomap": 1, "sweep": 1, "sweep-point": 4, "heldout": 1,
                        "heldout-run": 5, "translate": 1, "reshape": 1, "styles": 1, "animate": 1,
                        "results": 1}
    experiment = mlflow.get_experiment_by_name(EXPERIMENT)
    assert experiment.artifact_location == (pipeline.root / "mlartifacts").as_uri()
    # MLflow 3's UI opens an experiment of this kind on its runs (not on the GenAI pages)
    assert experiment.tags["mlflow.experimentKind"] == "custom_model_development"

    client = MlflowClient(pipeline.mlflow_uri)
    for stage in ("factorize", "evaluate"):
        row = runs[runs["tags.nnsf.stage"] == stage].iloc[0]
        assert row.filter(like="params.").notna().any(), stage
        metrics = row.filter(like="metrics.").dropna().index
        assert len(metrics) and all(m.startswith(f"metrics.{stage}/") for m in metrics), stage
        assert row["tags.prefect.flow_run_id"], stage
    evaluate_id = runs.loc[runs["tags.nnsf.stage"] == "evaluate", "run_id"].iloc[0]
    assert _artifact_files(client, evaluate_id, ".png"), "evaluate logged no figure"

    styles_id = runs.loc[runs["tags.nnsf.stage"] == "styles", "run_id"].iloc[0]
    assert _artifact_files(client, styles_id, "styles.npz"), "styles logged no model file"

    parent = runs.loc[runs["tags.nnsf.stage"] == "sweep", "run_id"].iloc[0]
    children = mlflow.search_runs(experiment_names=[EXPERIMENT],
                                  filter_string=f"tags.mlflow.parentRunId = '{parent}'")
    assert len(children) == 4
    points = {(float(a), float(b), int(k)) for a, b, k in
              children[["params.alpha", "params.beta", "params.rank"]].itertuples(index=False)}
    assert points == {(a, b, 4) for a in (0.0, 0.01) for b in (0.0, 1.0)}
    for child in children["run_id"]:
        assert _artifact_files(client, child, ".png"), f"sweep point {child} logged no figure"
    assert _artifact_files(client, parent, "precision_vs_alpha_beta_rank.png"), "the sweep run has no chart"

    # The comparison table is what MLflow holds for the nested runs (without
    # run ids or wall times, which would make the versioned file vary).
    table = pd.read_csv(pipeline.root / "reports/sweep.csv")
    assert "run_id" not in table and "seconds" not in table
    from_runs = {(float(a), float(b), int(k)): float(p) for a, b, k, p in children[
        ["params.alpha", "params.beta", "params.rank", "metrics.sweep/precision_mean"]].itertuples(index=False)}
    from_table = {(float(a), float(b), int(k)): float(p) for a, b, k, p in table[
        ["alpha", "beta", "rank", "precision_mean"]].itertuples(index=False)}
    assert from_table == pytest.approx(from_runs, rel=5.1e-6)  # the CSV keeps 6 significant digits
    best = json.loads((pipeline.root / "reports/sweep.json").read_text())
    assert best["points"] == 4 and best["best_rank"] == 4


def _artifact_files(client, run_id: str, suffix: str, path: str | None = None) -> list[str]:
    found = []
    for item in client.list_artifacts(run_id, path):
        if item.is_dir:
            found += _artifact_files(client, run_id, suffix, item.path)
        elif item.path.endswith(suffix):
            found.append(item.path)
    return found


def test_deps_are_exactly_the_code_each_stage_runs(pipeline):
    """Every project file a stage imported is a dep, and every code dep was imported."""
    for name, stage in dvc_yaml(pipeline.root)["stages"].items():
        executed = set((pipeline.imports / f"{name}.txt").read_text().split())
        deps = [d for d in declared(stage["deps"]) if d.split("/")[0] in ("nnsf", "flows")]
        covered = set()
        for dep in deps:
            path = pipeline.root / dep
            files = ({p.relative_to(pipeline.root).as_posix() for p in path.rglob("*.py")}
                     if path.is_dir() else {dep})
            assert files & executed, f"{name}: dep {dep} is never executed"
            covered |= files
        assert executed <= covered, f"{name}: executed but not in deps: {executed - covered}"


def test_scheduled_deployment_runs_the_pipeline(pipeline):
    """`python -m flows serve` registers a cron deployment; a run of it completes."""
    env = dict(pipeline.env, PREFECT_RUNNER_POLL_FREQUENCY="2")
    api = env["PREFECT_API_URL"]
    serve = subprocess.Popen(FLOWS + ["serve", "--cron", "*/30 * * * *", "--name", "e2e"],
                             cwd=pipeline.root, env=env, stdin=subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                             start_new_session=True)
    try:
        deployment = _wait_for(lambda: _deployment(api, "e2e"), 90, serve)
        assert deployment["schedules"][0]["schedule"]["cron"] == "*/30 * * * *"
        flow_run = _wait_for(
            lambda: _post(api, f"/deployments/{deployment['id']}/create_flow_run", {}), 60, serve)
        final = _wait_for(lambda: _final_state(api, flow_run["id"]), 240, serve)
        assert final == "COMPLETED", final
    finally:
        os.killpg(serve.pid, signal.SIGTERM)
        try:
            serve.wait(timeout=20)
        except subprocess.TimeoutExpired:
            os.killpg(serve.pid, signal.SIGKILL)
            serve.wait()


def _post(api: str, path: str, body: dict):
    request = urllib.request.Request(api + path, data=json.dumps(body).encode(),
                                     headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=10) as response:
        return json.loads(response.read())


def _deployment(api: str, name: str):
    found = _post(api, "/deployments/filter", {"deployments": {"name": {"any_": [name]}}})
    return found[0] if found else None


def _final_state(api: str, flow_run_id: str):
    with urllib.request.urlopen(f"{api}/flow_runs/{flow_run_id}", timeout=10) as response:
        state = json.loads(response.read())["state"]
    return state["type"] if state and state["type"] in (
        "COMPLETED", "FAILED", "CRASHED", "CANCELLED") else None


def _wait_for(probe, seconds: float, proc: subprocess.Popen):
    """Call ``probe`` until it returns something truthy; a busy server (503) means "not yet"."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        try:
            value = probe()
        except (urllib.error.URLError, ConnectionError):  # HTTPError is a URLError
            value = None
        if value:
            return value
        if proc.poll() is not None:
            pytest.fail(f"serve exited early:\n{proc.stdout.read()[-3000:]}")
        time.sleep(1)
    pytest.fail(f"timed out after {seconds} s")


def test_changing_animate_style_reruns_only_animate(pipeline):
    import cv2

    params = yaml.safe_load((pipeline.root / "params.yaml").read_text())
    params["animate"]["style"] = "olga"
    (pipeline.root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    status = run(DVC + ["status", "--json"], pipeline.root, pipeline.env)
    assert set(json.loads(status.stdout)) == {"animate"}
    rerun = run(FLOWS + ["repro"], pipeline.root, pipeline.env, timeout=600)
    assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
    assert stages_run(rerun.stdout) == {"animate"}
    made = json.loads((pipeline.root / "reports/animate/animate.json").read_text())
    assert made["style"] == "olga" and made["frames"] == 6
    cap = cv2.VideoCapture(str(pipeline.root / "reports/animate/animation.mp4"))
    assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 6
    cap.release()


def test_changing_alpha_reruns_only_its_dependents(pipeline):
    params = yaml.safe_load((pipeline.root / "params.yaml").read_text())
    params["nnsf"]["alpha"] = 0.05
    (pipeline.root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    # Directly out of date: the stages that read nnsf.alpha.  isomap follows
    # because the model it reads changes, and results because their reports do;
    # data, features and sweep stay.
    status = run(DVC + ["status", "--json"], pipeline.root, pipeline.env)
    assert set(json.loads(status.stdout)) == {"factorize", "evaluate"}
    rerun = run(FLOWS + ["repro"], pipeline.root, pipeline.env, timeout=600)
    assert rerun.returncode == 0, rerun.stdout[-3000:] + rerun.stderr[-3000:]
    assert stages_run(rerun.stdout) == {"factorize", "evaluate", "isomap", "results"}


def test_pipeline_flow_fails_cleanly_on_bad_input_without_retrying(pipeline):
    """The scheduled flow on a bad params.yaml: one error line, exit 2, no retry."""
    params = yaml.safe_load((pipeline.root / "params.yaml").read_text())
    params["nnsf"]["rank"] = 40
    (pipeline.root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    result = run(FLOWS + ["pipeline"], pipeline.root, pipeline.env)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stdout[-3000:] + result.stderr
    assert len(lines) == 1 and lines[0].startswith("error: params.yaml: nnsf.rank: "), lines
    assert "40" in lines[0]
    assert result.stdout.count("Running stage 'factorize'") == 1  # bad input is not retried
    assert "Traceback" not in result.stdout + result.stderr
