"""``python -m flows repro``: ``dvc repro`` with one shared Prefect server.

Each stage's ``python -m flows <stage>`` talks to the server through
``PREFECT_API_URL``; without it every stage would start its own temporary
server.  When ``PREFECT_API_URL`` is already set (a server you run yourself),
that one is used.  When nothing needs to run, no server is started at all, so
a no-op repro stays as fast as ``dvc repro`` itself.
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
from pathlib import Path

from flows import prefect_server, project, stage_server
from flows.console import error_line
from nnsf.errors import terminate_as_interrupt


def dvc(*args: str) -> list[str]:
    """The DVC command line of this interpreter's environment."""
    return [sys.executable, "-m", "dvc", *args]


def stage_env(root: Path) -> dict[str, str]:
    """The environment for ``dvc repro`` and its stages.

    This interpreter's ``bin`` folder goes first on ``PATH``, so the ``python``
    in dvc.yaml's commands is the one that has the project installed, even
    when the virtual environment is not activated.
    """
    env = dict(os.environ)
    bindir = str(Path(sys.executable).parent)
    env["PATH"] = bindir + os.pathsep + env.get("PATH", "")
    env.setdefault("PREFECT_HOME", str(project.prefect_home(root)))
    return env


def stages_to_run(root: Path, args: list[str], env: dict[str, str]) -> list[str] | None:
    """The stages ``dvc repro <args>`` would run (a dry run), or ``None`` if unsure."""
    dry = subprocess.run(dvc("repro", "--dry", *args), cwd=root, env=env,
                         capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if dry.returncode != 0:
        return None  # the real run will show DVC's own error message
    return re.findall(r"Running stage '([^']+)'", dry.stdout)


def main(args: list[str]) -> int:
    """Run ``dvc repro <args>``; start and stop a Prefect server if stages will run."""
    root = project.root()
    if not (root / "dvc.yaml").is_file():
        error_line(f"{root}: dvc.yaml: expected the project root (run from inside the project)")
        return 2
    env = stage_env(root)
    repro = dvc("repro", *args)
    if env.get("PREFECT_API_URL"):
        if stages_to_run(root, args, env) == []:
            return subprocess.call(repro, cwd=root, env=env)
        with stage_server.running(env, root, Path(env["PREFECT_HOME"]) / "stage-server.log") as env:
            return subprocess.call(repro, cwd=root, env=env)
    todo = stages_to_run(root, args, env)
    if todo == []:
        return subprocess.call(repro, cwd=root, env=env)  # a no-op: DVC says so itself
    signal.signal(signal.SIGTERM, terminate_as_interrupt)  # a CI timeout must still stop the server
    home = Path(env["PREFECT_HOME"])
    what = f"stages {', '.join(todo)}" if todo else "the stages to run"
    print(f"Starting a local Prefect server (PREFECT_HOME={home}) for {what}", flush=True)
    try:
        with prefect_server.running(home) as api_url:
            print(f"Prefect API {api_url}; dashboard {api_url.removesuffix('/api')} "
                  "(stops when the run ends)", flush=True)
            env["PREFECT_API_URL"] = api_url
            with stage_server.running(env, root, home / "stage-server.log") as env:
                return subprocess.call(repro, cwd=root, env=env)
    except prefect_server.ServerError as err:
        error_line(str(err))
        return 1
