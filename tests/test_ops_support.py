"""Shared pieces of the operations tests (``tests/test_ops_*.py``); holds no tests.

A *small project* is a folder with a ``dvc.yaml`` marker, a tiny
``params.yaml`` and the real ``data`` and ``features`` stage outputs
(computed by :mod:`nnsf.stages`, no orchestration), so a sweep can run in it
within seconds.
"""
from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import yaml

from conftest import PROJECT

#: Tiny but real: 3 characters x 15 motions x 2 clips x 12 frames; 2 x 2 x 2 sweep points.
SMALL = {
    "seed": 0,
    "dataset": {"name": "synthetic", "path": "nnsf/datasets",
                "synthetic": {"characters": 3, "clips_per_cell": 2, "frames": 12, "noise_px": 0.4}},
    "unify": {"margin": 0.5},
    "nnsf": {"label": "motion", "rank": 4, "alpha": 0.01, "beta": 1.0, "class_in_loop": True,
             "max_iter": 30, "tol": 1.0e-4, "init": "nndsvda"},
    "sweep": {"folds": 2, "alpha": [0.0, 0.01], "beta": [0.0, 1.0], "rank": [4, 6],
              "max_iter": 20},
    "mlflow": {"experiment": "ops"},
}


def small_project(root: Path, params: dict | None = None) -> tuple[Path, dict]:
    """Create a small project at ``root`` with features computed; return (root, params)."""
    from nnsf import pipeline, stages

    params = yaml.safe_load(yaml.safe_dump(params or SMALL))
    root.mkdir(parents=True, exist_ok=True)
    (root / "dvc.yaml").write_text("stages: {}\n")
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    stages.data(params, out_dir=root / pipeline.RAW_DIR)
    stages.features(params, raw_dir=root / pipeline.RAW_DIR, out_dir=root / pipeline.FEATURES_DIR)
    return root, params


def sweep_table(root: Path) -> pd.DataFrame:
    return pd.read_csv(root / "reports" / "sweep.csv")


def mlflow_db(template: Path, dest: Path) -> str:
    """A fresh sqlite store copied from the migrated template; returns its URI."""
    shutil.copy2(template, dest)
    return f"sqlite:///{dest}"


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def group_pids(pgid: int) -> list[int]:
    """Live (non-zombie) processes of process group ``pgid`` (Linux /proc)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
            found.append(int(entry.name))
    return found


@contextlib.contextmanager
def process_group(cmd: list[str], env: dict, cwd: Path, log: Path):
    """Start ``cmd`` in its own session; yield the Popen; kill the whole group afterwards."""
    with open(log, "ab") as out:
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        yield proc
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGTERM)
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            pass
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()


def wait_for(probe, seconds: float, what: str, proc: subprocess.Popen | None = None,
             log: Path | None = None, every: float = 0.2):
    """Call ``probe`` until it returns something truthy, or fail after ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        value = probe()
        if value:
            return value
        if proc is not None and proc.poll() is not None:
            tail = log.read_text()[-3000:] if log else ""
            raise AssertionError(f"{what}: process exited with {proc.returncode}\n{tail}")
        time.sleep(every)
    tail = log.read_text()[-3000:] if log else ""
    raise AssertionError(f"{what}: not after {seconds} s\n{tail}")


PYTHON = sys.executable
VENV_BIN = Path(sys.executable).parent
__all__ = ["SMALL", "PROJECT", "small_project", "sweep_table", "mlflow_db", "free_port",
           "group_pids", "process_group", "wait_for", "PYTHON", "VENV_BIN"]
