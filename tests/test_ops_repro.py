"""Crash safety and determinism of ``dvc repro`` in real clones of the project.

- A stage SIGKILLed while it writes its outputs leaves nothing that looks
  finished, and the next repro gives outputs identical (same hashes in
  dvc.lock) to a run that was never interrupted.
- Two cold repros of the default pipeline in separate git clones of HEAD give
  identical dvc.lock output hashes.

Slow (minutes): they run the real pipeline several times.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import sys
from pathlib import Path

import pytest
import yaml

from conftest import PROJECT, git, new_project, project_env, run
from test_ops_support import process_group, wait_for

pytestmark = pytest.mark.slow

FLOWS = [sys.executable, "-m", "flows"]
DVC = [sys.executable, "-m", "dvc"]


def lock_hashes(root: Path) -> dict[str, dict[str, str]]:
    """Stage -> {output path: md5} from dvc.lock."""
    lock = yaml.safe_load((root / "dvc.lock").read_text())
    return {stage: {o["path"]: o["md5"] for o in body.get("outs", [])}
            for stage, body in lock["stages"].items()}


def small_params() -> str:
    from test_pipeline import SMALL_PARAMS

    return SMALL_PARAMS


def _small_project(base: Path, name: str, mlflow_template: Path, prefect_api: str):
    root, env = new_project(base / name, mlflow_template, prefect_api)
    (root / "params.yaml").write_text(small_params())
    git(root, "commit", "-q", "-am", "small params")
    return root, env


def test_a_stage_killed_while_writing_leaves_nothing_finished_and_repro_recovers(
        tmp_path, mlflow_template, prefect_api):
    reference, env_ref = _small_project(tmp_path, "reference", mlflow_template, prefect_api)
    done = run(FLOWS + ["repro"], reference, env_ref, timeout=900)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    root, env = _small_project(tmp_path, "killed", mlflow_template, prefect_api)
    first_output = root / "reports" / "cv_folds.csv"      # evaluate writes this first ...
    last_output = root / "reports" / "metrics.json"       # ... and this last
    log = tmp_path / "killed.log"
    with process_group(FLOWS + ["repro"], env, root, log) as proc:
        wait_for(lambda: first_output.exists(), 600, "evaluate to start writing", proc, log,
                 every=0.005)
        os.killpg(proc.pid, signal.SIGKILL)  # dvc, the stage and everything they started
        proc.wait()
    assert not last_output.exists(), "the kill came too late to interrupt the writing"

    # Nothing looks finished: DVC does not record evaluate, and says it must run.
    lock = yaml.safe_load((root / "dvc.lock").read_text()) if (root / "dvc.lock").exists() else {}
    assert "evaluate" not in (lock or {}).get("stages", {})
    # (DVC first notices that the killed repro's read/write lock is stale and drops it.)
    status = wait_for(lambda: _status(root, env), 60, "dvc status after the kill")
    assert "evaluate" in status

    again = run(FLOWS + ["repro"], root, env, timeout=900)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert lock_hashes(root) == lock_hashes(reference)
    leftovers = [p for d in ("data", "models", "reports") for p in (root / d).rglob(".*")
                 if p.name != ".gitignore"]  # DVC's own
    assert leftovers == []  # no temporary file survived in an output


def _status(root: Path, env: dict):
    out = run(DVC + ["status", "--json"], root, env)
    try:
        return json.loads(out.stdout) if out.returncode == 0 else None
    except json.JSONDecodeError:
        return None


def _clone_head(dest: Path) -> Path:
    """``git clone`` of the project's HEAD (committed code only)."""
    out = run(["git", "clone", "-q", "--no-hardlinks", str(PROJECT), str(dest)], PROJECT.parent,
              dict(os.environ))
    assert out.returncode == 0, out.stderr
    for generated in ("dvc.lock", "reports", "data", "models"):
        # Drop committed results so the run below is cold, as on a fresh machine.
        path = dest / generated
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    return dest


def test_two_cold_repros_of_the_default_pipeline_give_identical_hashes(
        tmp_path, mlflow_template, prefect_api):
    hashes = []
    for name in ("first", "second"):
        root = _clone_head(tmp_path / name)
        db = tmp_path / f"{name}-mlflow.db"
        shutil.copy2(mlflow_template, db)
        env = project_env(root, prefect_api, db)
        result = run(FLOWS + ["repro"], root, env, timeout=1800)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
        hashes.append(lock_hashes(root))
    assert hashes[0] == hashes[1]
    assert set(hashes[0]) >= {"data", "features", "factorize", "evaluate", "isomap", "sweep"}
