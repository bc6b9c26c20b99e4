"""Crash safety and determinism of ``dvc repro`` in real clones of the project.

- A stage SIGKILLed while it writes its outputs (``evaluate``, reproduced with
  what it needs) leaves nothing that looks finished, and the next repro gives
  outputs identical (same hashes in dvc.lock) to a run that was never
  interrupted.
- Two cold repros of the small pipeline (test_pipeline.SMALL_PARAMS, every
  stage) in separate git clones of HEAD give identical dvc.lock output hashes,
  the first with one OpenBLAS thread, the second with two: on one machine the
  outputs are the same bytes whatever the thread count (what other machines
  reproduce, and to what tolerance: test_determinism).

Every project here is a clone of HEAD with the small params committed; the
uninterrupted cold repro is made once per session (conftest.small_pipeline, a
committed copy of the sources, shared with test_pipeline) and is the reference
of both tests.  Slow (minutes): they run the real pipeline several times.
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

from conftest import PROJECT, committed_reports, git, lock_hashes, project_env, run
from test_ops_support import process_group, wait_for

pytestmark = pytest.mark.slow

FLOWS = [sys.executable, "-m", "flows"]
DVC = [sys.executable, "-m", "dvc"]


def small_params() -> str:
    from test_pipeline import SMALL_PARAMS

    return SMALL_PARAMS


def _small_clone(base: Path, name: str, mlflow_template: Path, prefect_api: str,
                 extra_env: dict | None = None):
    """A git clone of HEAD without generated files, SMALL_PARAMS committed; (root, env)."""
    root = _clone_head(base / name)
    (root / "params.yaml").write_text(small_params())
    git(root, "commit", "-q", "-am", "small params")
    db = base / f"{name}-mlflow.db"
    shutil.copy2(mlflow_template, db)
    env = project_env(root, prefect_api, db)
    env.update(extra_env or {})
    return root, env


def test_this_module_runs_on_the_worker_of_test_pipeline(request):
    """Under ``--dist loadgroup`` (the README's test command) this module and test_pipeline are
    one group (conftest.GROUPS), so one worker makes conftest.small_pipeline, once.

    pytest-xdist 3.8 puts a test in its group by adding ``@group`` to its node id.  pytest 9.2
    drops that suffix (pytest-xdist issue 1386): the tests were then handed out one by one and
    both workers made the small pipeline, 100 s each.  pyproject.toml pins pytest 9.1.1.
    """
    if not getattr(request.config.option, "loadgroup", False):
        pytest.skip("not run by pytest-xdist with --dist loadgroup")
    assert request.node.nodeid.endswith("@small-pipeline"), request.node.nodeid


@pytest.fixture(scope="module")
def reference(small_pipeline):
    """dvc.lock output hashes of one uninterrupted cold repro of the small pipeline (one OpenBLAS
    thread): conftest.small_pipeline, the cold repro test_pipeline inspects."""
    return small_pipeline.reference


def test_a_stage_killed_while_writing_leaves_nothing_finished_and_repro_recovers(
        tmp_path, mlflow_template, prefect_api, reference):
    root, env = _small_clone(tmp_path, "killed", mlflow_template, prefect_api)
    # evaluate writes its set into a staging folder and publishes it as a whole (nnsf/publish.py):
    # the first staged file appearing means the writing has begun, and nothing is published yet.
    first_output = root / "reports" / ".evaluate.staging" / "cv_folds.csv"
    last_output = root / "reports" / "metrics.json"       # published with the rest of the set
    log = tmp_path / "killed.log"
    # `repro evaluate`: the killed stage and what it needs (data, features); the other stages
    # neither feed it nor read it, and their repro against the same reference is the next test.
    with process_group(FLOWS + ["repro", "evaluate"], env, root, log) as proc:
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

    again = run(FLOWS + ["repro", "evaluate"], root, env, timeout=1800)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    reproduced = lock_hashes(root)
    assert set(reproduced) == {"data", "features", "evaluate"}
    assert reproduced == {stage: reference[stage] for stage in reproduced}
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
    kept = {dest / name: (dest / name).read_bytes() for name in committed_reports()}
    for generated in ("dvc.lock", "reports", "data", "models"):
        # Drop committed results so the run below is cold, as on a fresh machine.
        path = dest / generated
        if path.is_dir():
            shutil.rmtree(path)
        elif path.exists():
            path.unlink()
    for path, data in kept.items():  # the runs on outside data: inputs of the results stage
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
    return dest


def test_two_cold_repros_with_one_and_two_blas_threads_give_identical_hashes(
        tmp_path, mlflow_template, prefect_api, small_pipeline, reference):
    root, env = _small_clone(tmp_path, "second", mlflow_template, prefect_api,
                             {"OPENBLAS_NUM_THREADS": "2"})
    result = run(FLOWS + ["repro"], root, env, timeout=1800)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    hashes = lock_hashes(root)
    # Every output byte for byte, the H.264 MP4s too (docs/operations.md, Reproducibility).
    assert hashes == reference
    assert set(reference) >= {"frames", "roto", "roto_eval", "data", "features", "factorize",
                              "evaluate", "isomap", "sweep", "heldout", "translate", "reshape"}
