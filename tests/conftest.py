"""Shared fixtures for the end-to-end tests: a real Prefect server, an MLflow store,
and a throw-away copy of the project.

Everything is real (no mocks): one ``prefect server start`` per test session on
127.0.0.1 and a free port, sqlite MLflow stores copied from a migrated template
(creating a database runs migrations, 1-6 s; copying one takes milliseconds).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
from pathlib import Path

import pytest

import flows  # noqa: F401  (telemetry switches before anything else is imported)

PROJECT = Path(__file__).resolve().parents[1]

# --------------------------------------------------------------------------- spawn guard
#: Audit events (PEP 578) of starting a process: a command, a fork, a spawn.
_SPAWN_EVENTS = {"subprocess.Popen", "os.fork", "os.forkpty", "os.posix_spawn", "os.system",
                 "os.exec", "os.spawn", "_posixsubprocess.fork_exec"}
_GUARDED: dict = {"test": None, "thread": None, "started": []}


def _spawn_audit(event: str, args) -> None:
    test = _GUARDED["test"]
    if test is None or event not in _SPAWN_EVENTS or threading.get_ident() != _GUARDED["thread"]:
        return
    what = event
    if event in ("subprocess.Popen", "_posixsubprocess.fork_exec") and args[1]:
        what = " ".join(str(a) for a in list(args[1])[:3])
    _GUARDED["started"].append(what)
    raise RuntimeError(f"{test} starts a process ({what}) but is not marked slow: mark it "
                       "@pytest.mark.slow (docs/operations.md, Tests), or run the code in this process")


# Three libraries ask the system by running a command: joblib counts the physical cores
# (`lscpu`) and the platform module the processor (`uname -p`, for Prefect and Dask), once
# per process; matplotlib lists the fonts (`fc-list`) once per machine, when it builds its font
# cache (a fresh home has none).  Done here, before any test, so that a quick test using them
# starts no process.
import platform  # noqa: E402

import matplotlib.font_manager  # noqa: E402,F401
from joblib.externals.loky.backend.context import cpu_count  # noqa: E402

cpu_count(only_physical_cores=True)
platform.processor()
sys.addaudithook(_spawn_audit)


def _watch_fork_exec() -> None:
    """Also watch ``_posixsubprocess.fork_exec``, which multiprocessing's spawn and
    joblib's loky workers call directly (it raises no audit event of its own)."""
    import _posixsubprocess

    real = _posixsubprocess.fork_exec

    def fork_exec(*args, **kwargs):
        _spawn_audit("_posixsubprocess.fork_exec", (None, args[0] if args else ()))
        return real(*args, **kwargs)

    _posixsubprocess.fork_exec = fork_exec


_watch_fork_exec()


@pytest.fixture(autouse=True)
def _quick_tests_start_no_process(request):
    """Every test that starts a process is marked slow, so ``-m "not slow"`` starts none.

    A test without the marker fails as soon as it starts one (from its own thread:
    ``subprocess``, ``os.fork``, ``os.system``, ``os.posix_spawn``).  Module and
    session fixtures are not watched: a test that needs a server is marked slow.
    """
    if request.node.get_closest_marker("slow") is not None:
        yield
        return
    _GUARDED.update(test=request.node.nodeid, thread=threading.get_ident(), started=[])
    try:
        yield
    finally:
        started = list(_GUARDED["started"])
        _GUARDED.update(test=None, thread=None, started=[])
    if started:
        pytest.fail(f"{request.node.nodeid} started a process ({started[0]}) but is not marked slow",
                    pytrace=False)


# --------------------------------------------------------------------------- projects and servers
#: What a fresh clone holds that the pipeline needs (no data, models, reports,
#: stores or environments).
SOURCES = ("nnsf", "flows", "dvc.yaml", "params.yaml", "pyproject.toml", ".dvcignore",
           ".gitignore", ".dvc/config", ".dvc/.gitignore", "docs/results.yaml")


def committed_reports() -> list[str]:
    """Reports a stage reads that no stage writes: the committed runs on data outside the
    repository, which the ``results`` stage puts in the results document.  A fresh clone has them."""
    import yaml

    stages = yaml.safe_load((PROJECT / "dvc.yaml").read_text())["stages"].values()
    name = lambda entry: next(iter(entry)) if isinstance(entry, dict) else entry  # noqa: E731
    written = {name(e) for s in stages for key in ("outs", "metrics", "plots") for e in s.get(key) or []}
    inside = lambda path: any(path == w or path.startswith(w.rstrip("/") + "/") for w in written)  # noqa: E731
    return sorted({name(d) for s in stages for d in s.get("deps") or []
                   if name(d).startswith("reports/") and not inside(name(d))})


@pytest.fixture(scope="session")
def prefect_api(tmp_path_factory) -> str:
    """The API URL of a real Prefect server that lives for the whole session."""
    from flows import prefect_server

    home = tmp_path_factory.mktemp("prefect-home")
    with prefect_server.running(home, ui=False) as api_url:
        yield api_url


@pytest.fixture(scope="session")
def mlflow_template(tmp_path_factory) -> Path:
    """An empty, fully migrated MLflow sqlite database to copy from."""
    from mlflow.tracking import MlflowClient

    db = tmp_path_factory.mktemp("mlflow-template") / "mlflow.db"
    MlflowClient(tracking_uri=f"sqlite:///{db}").search_experiments()
    return db


def copy_project(dest: Path) -> Path:
    """Copy the project's sources to ``dest`` and commit them in a new git repo."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in SOURCES + tuple(committed_reports()):
        src = PROJECT / name
        if src.is_dir():
            shutil.copytree(src, dest / name, ignore=ignore)
        elif src.is_file():
            (dest / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, dest / name)
    git(dest, "init", "-q")
    git(dest, "add", "-A")
    git(dest, "commit", "-q", "-m", "project copy")
    return dest



def moving_box_frames(T: int = 24, H: int = 61, W: int = 87):
    """``(T, H, W, 3)`` uint8 frames: a red box moving 3 px a frame across white (a small clip to encode)."""
    import numpy as np

    imgs = np.full((T, H, W, 3), 255, np.uint8)
    for t in range(T):
        imgs[t, 10:50, 3 * t: 3 * t + 12] = (200, 40, 20)
    return imgs


def git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", "-c", "user.name=nnsf-tests", "-c", "user.email=tests@nnsf",
                           "-c", "init.defaultBranch=main", *args], cwd=cwd, check=True,
                          capture_output=True, text=True).stdout


def project_env(root: Path, prefect_api: str, mlflow_db: Path) -> dict[str, str]:
    """Environment for commands run in a copied project: its own stores, the session server."""
    env = dict(os.environ)
    env.update(PREFECT_API_URL=prefect_api, PREFECT_HOME=str(root / ".prefect"),
               MLFLOW_TRACKING_URI=f"sqlite:///{mlflow_db}", PYTHONDONTWRITEBYTECODE="1")
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    env.pop("NNSF_DEBUG", None)
    return env


def run(cmd: list[str], root: Path, env: dict, timeout: float = 600) -> subprocess.CompletedProcess:
    """Run a command in the copied project, no stdin, output captured as text."""
    return subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True,
                          stdin=subprocess.DEVNULL, timeout=timeout)


def new_project(dest: Path, mlflow_template: Path, prefect_api: str | None) -> tuple[Path, dict]:
    """A committed copy of the project with its own MLflow store; returns (root, env).

    Without ``prefect_api`` the environment has no ``PREFECT_API_URL``: enough
    for commands that must fail before any flow starts.
    """
    root = copy_project(dest)
    db = dest.parent / f"{dest.name}-mlflow.db"
    shutil.copy2(mlflow_template, db)
    env = project_env(root, prefect_api or "", db)
    if not prefect_api:
        env.pop("PREFECT_API_URL")
    return root, env


@pytest.fixture
def make_project(tmp_path, mlflow_template, request):
    """Factory ``make_project(prefect=True)`` -> (root, env) for one test."""
    def make(name: str = "project", prefect: bool = True):
        api = request.getfixturevalue("prefect_api") if prefect else None
        return new_project(tmp_path / name, mlflow_template, api)
    return make


# --------------------------------------------------------------------------- the small pipeline, once

def lock_hashes(root: Path) -> dict[str, dict[str, str]]:
    """Stage -> {output path: md5} from a project's dvc.lock."""
    import yaml

    lock = yaml.safe_load((root / "dvc.lock").read_text())
    return {stage: {o["path"]: o["md5"] for o in body.get("outs", [])}
            for stage, body in lock["stages"].items()}


@pytest.fixture(scope="session")
def small_pipeline(tmp_path_factory, prefect_api, mlflow_template):
    """One cold ``python -m flows repro`` of ``test_pipeline.SMALL_PARAMS`` (every stage) in a
    committed copy of the project, shared by the modules of the xdist group ``small-pipeline``.

    test_pipeline inspects (and then changes) the project; test_ops_repro compares its
    own repros with ``reference``, the dvc.lock output hashes taken right after this run.
    One OpenBLAS thread: test_ops_repro repeats it with two.
    """
    import time
    from types import SimpleNamespace

    from test_pipeline import SMALL_PARAMS

    base = tmp_path_factory.mktemp("e2e")
    root, env = new_project(base / "project", mlflow_template, prefect_api)
    (root / "params.yaml").write_text(SMALL_PARAMS)
    git(root, "commit", "-q", "-am", "small params")
    env["NNSF_RECORD_IMPORTS"] = str(base / "imports")
    env["OPENBLAS_NUM_THREADS"] = "1"
    started = time.perf_counter()
    cold = run([sys.executable, "-m", "flows", "repro"], root, env, timeout=1800)
    seconds = time.perf_counter() - started
    assert cold.returncode == 0, cold.stdout[-4000:] + cold.stderr[-4000:]
    print(f"cold repro of the small pipeline: {seconds:.1f} s")
    # The reports as the cold run left them (test_pipeline changes the project later).
    reports = base / "reports-after-cold-repro"
    for path in (root / "reports").rglob("*"):
        if path.suffix in (".json", ".csv") and path.is_file():
            (reports / path.relative_to(root / "reports")).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(path, reports / path.relative_to(root / "reports"))
    # The animate stage's files as the cold run left them (test_pipeline re-runs the stage later).
    animate = base / "animate-after-cold-repro"
    shutil.copytree(root / "reports" / "animate", animate)
    return SimpleNamespace(root=root, env=env, cold=cold, seconds=seconds, imports=base / "imports",
                           mlflow_uri=env["MLFLOW_TRACKING_URI"], reference=lock_hashes(root),
                           reports=reports, animate=animate)


# --------------------------------------------------------------------------- scheduling on xdist workers

#: Modules that share a session fixture, so they must run on one xdist worker (``--dist
#: loadgroup``); every other module is a group of its own, as with ``--dist loadfile``.
GROUPS = {"test_pipeline.py": "small-pipeline", "test_ops_repro.py": "small-pipeline",
          "test_determinism.py": "small-pipeline"}
#: The modules that take minutes (the ``--durations`` table of .ci/run), longest first: they are
#: handed out first (``--no-loadscope-reorder`` keeps this order), so the many short modules fill
#: in around them instead of leaving one worker running a long module alone at the end.
LONGEST_FIRST = ("small-pipeline", "test_ops_faults.py", "test_ops_servers.py",
                 "test_hardening_publish.py", "test_track_stage.py", "test_flows.py",
                 "test_ops_fanout.py", "test_animate.py", "test_translation_eval.py", "test_hardening.py")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    rank = {name: i for i, name in enumerate(LONGEST_FIRST)}
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(GROUPS.get(item.path.name, item.path.name)))
    group = {id(item): GROUPS.get(item.path.name, item.path.name) for item in items}
    items.sort(key=lambda item: rank.get(group[id(item)], len(rank)))  # stable: file order otherwise
