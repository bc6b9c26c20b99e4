"""A short-lived local Prefect server.

Without ``PREFECT_API_URL`` every Prefect process starts its own temporary
server (10-18 s each).  One ``prefect server start`` shared by all stages of a
``dvc repro`` costs that once; each stage's flow then takes about 3 s.
"""
from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from pathlib import Path
from typing import Iterator

#: How long a cold start (new database, migrations) may take on a slow machine.
START_TIMEOUT_S = 180.0


class ServerError(RuntimeError):
    """The Prefect server did not come up."""


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port that is free right now on ``host``."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind((host, 0))
        return sock.getsockname()[1]


def healthy(api_url: str, timeout: float = 2.0) -> bool:
    """True when ``<api_url>/health`` answers 200."""
    try:
        with urllib.request.urlopen(api_url.rstrip("/") + "/health", timeout=timeout) as resp:
            return resp.status == 200
    except (urllib.error.URLError, OSError, ValueError):
        return False


def _prefect_command() -> list[str]:
    # The `prefect` script beside this interpreter; `python -m prefect` is
    # the same CLI when the script is missing (e.g. a bare interpreter).
    script = Path(sys.executable).with_name("prefect")
    return [str(script)] if script.exists() else [sys.executable, "-m", "prefect"]


@contextlib.contextmanager
def running(home: Path, host: str = "127.0.0.1", port: int | None = None,
            ui: bool = True, log_file: Path | None = None) -> Iterator[str]:
    """Start ``prefect server start``; yield its API URL; always stop it.

    Parameters
    ----------
    home : Path
        ``PREFECT_HOME`` of the server (its sqlite database lives there).
        Reusing one folder keeps the run history and skips migrations
        (about 8 s to healthy instead of about 18 s).
    port : int, optional
        Defaults to a free port.
    ui : bool
        Serve the dashboard too (about 1.5 s more to start).
    log_file : Path, optional
        Where the server's own output goes; default ``<home>/server.log``.
    """
    home.mkdir(parents=True, exist_ok=True)
    port = port or free_port(host)
    api_url = f"http://{host}:{port}/api"
    env = dict(os.environ, PREFECT_HOME=str(home), PREFECT_SERVER_ANALYTICS_ENABLED="false",
               PREFECT_UI_ENABLED="true" if ui else "false")
    env.pop("PREFECT_API_URL", None)  # the server must not try to talk to another one
    log_file = log_file or home / "server.log"
    cmd = _prefect_command() + ["server", "start", "--host", host, "--port", str(port),
                                "--analytics-off"] + ([] if ui else ["--no-ui"])
    with open(log_file, "ab") as log:
        # The server and anything it spawns form one process group of their
        # own (setsid), so stop() can end them all and nothing else.
        proc = subprocess.Popen(cmd, env=env, stdin=subprocess.DEVNULL, stdout=log,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        _wait_until_healthy(proc, api_url, log_file)
        yield api_url
    finally:
        stop(proc)


@contextlib.contextmanager
def in_use(api_url: str) -> Iterator[str]:
    """This process, its threads and the processes it starts use the Prefect server at ``api_url``.

    Prefect reads the environment into global settings once, at import: a URL set later in
    ``os.environ`` alone reaches child processes but not this one, whose flows (and threads,
    such as the process runner's event forwarder) then start a temporary server of their own
    and lose their runs with it.  On leaving, Prefect's queued logs and events are sent while
    the server still runs (left to the interpreter's exit, they end the output with "Error
    logging to API"), and the environment is restored.
    """
    # Imported here: `python -m flows repro` uses this module without loading Prefect.
    from prefect.context import refresh_global_settings_context
    from prefect.events.worker import EventsWorker
    from prefect.logging.handlers import APILogWorker

    before = os.environ.get("PREFECT_API_URL")
    os.environ["PREFECT_API_URL"] = api_url
    refresh_global_settings_context()
    try:
        yield api_url
    finally:
        EventsWorker.drain_all(at_exit=False)
        APILogWorker.drain_all(at_exit=False)
        if before is None:
            os.environ.pop("PREFECT_API_URL", None)
        else:
            os.environ["PREFECT_API_URL"] = before
        refresh_global_settings_context()


def _wait_until_healthy(proc: subprocess.Popen, api_url: str, log_file: Path) -> None:
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise ServerError(f"prefect server exited with code {proc.returncode} "
                              f"before it was healthy; see {log_file}")
        if healthy(api_url, timeout=1.0):
            return
        time.sleep(0.2)
    raise ServerError(f"prefect server not healthy after {START_TIMEOUT_S:.0f} s; see {log_file}")


def stop(proc: subprocess.Popen, grace: float = 15.0) -> None:
    """SIGTERM the server's process group, then SIGKILL what is left after ``grace`` s."""
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=grace)
    except subprocess.TimeoutExpired:
        pass
    # Whatever of the group outlived the server (worker processes) goes too.
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
