"""One long-lived process per repro that has imported Prefect and MLflow; one forked child per stage.

Every DVC stage is ``python -m flows <stage>``, and importing Prefect and MLflow
costs a stage about 6 s before it does anything (``python -X importtime``:
Prefect 2.2 s, MLflow 1.7 s of which ``mlflow.genai`` 1.0 s; more when the
machine is busy).  ``python -m flows repro`` therefore starts this server
once, after the imports, and exports its socket as ``NNSF_STAGE_SERVER``.
DVC still decides which stages run and runs each one's command; the command
finds the socket, hands over its arguments, working folder, environment and
its stdin/stdout/stderr (file descriptors over the Unix socket), and waits.
The server forks a child that runs exactly what the command would have run
(:func:`flows.__main__.main`): each stage is still its own process, its own
Prefect flow run and its own MLflow run; only the imports are shared.

Nothing of the project (``nnsf``, the flows) is imported before the fork, so
each stage imports its own code fresh, and ``NNSF_RECORD_IMPORTS`` still sees
exactly what that stage ran.  No socket, or one that does not answer: the
command runs in its own process as before.

Lifetime: the child dies with its command (the command's end of the socket
closes: the child kills its process group) and with the server
(``PR_SET_PDEATHSIG``); the server dies with ``repro`` (it stops it, and
``PR_SET_PDEATHSIG`` covers a SIGKILLed ``repro``).
"""
from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

ENV = "NNSF_STAGE_SERVER"
#: The third-party modules a stage needs, imported once by the server.
PRELOAD = ("prefect", "prefect.flows", "prefect.task_runners", "prefect.futures", "prefect.states",
           "prefect.cache_policies", "prefect.runtime", "mlflow", "mlflow.tracking", "mlflow.entities",
           "pandas", "scipy.sparse.linalg", "sklearn.base", "sklearn.decomposition",
           "sklearn.linear_model", "sklearn.model_selection", "matplotlib")
_CODE = struct.Struct("!i")


def _die_with_parent() -> None:
    """Ask Linux to SIGKILL this process when its parent dies (no-op elsewhere)."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


# -- the command's side ------------------------------------------------------------

def delegate(argv: list[str]) -> int | None:
    """Run ``python -m flows <argv>`` in the server; its exit code, or None without a server."""
    path = os.environ.get(ENV)
    if not path:
        return None
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        sock.connect(path)
    except OSError:
        sock.close()
        return None
    request = json.dumps({"argv": argv, "cwd": os.getcwd(),
                          "env": {k: v for k, v in os.environ.items() if k != ENV}}).encode()
    with sock:
        sys.stdout.flush()
        sys.stderr.flush()
        socket.send_fds(sock, [_CODE.pack(len(request)) + request], [0, 1, 2])
        reply = b""
        while len(reply) < _CODE.size:
            chunk = sock.recv(_CODE.size - len(reply))
            if not chunk:
                return 1  # the server died under the stage; it has said nothing we can add
            reply += chunk
    return _CODE.unpack(reply)[0]


# -- the server's side -------------------------------------------------------------

def serve(path: str) -> None:
    """Import :data:`PRELOAD`, listen on ``path``, fork one child per request, forever."""
    import flows  # noqa: F401  (telemetry off before the tools are imported)

    _die_with_parent()
    os.environ.setdefault("MPLBACKEND", "Agg")
    for name in PRELOAD:
        __import__(name)
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # children are reaped by the kernel
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path + ".tmp")
    listener.listen(8)
    os.replace(path + ".tmp", path)  # the socket appears once it is ready
    while True:
        conn, _ = listener.accept()
        try:
            message, fds, _, _ = socket.recv_fds(conn, 1 << 20, 3)
            size = _CODE.unpack(message[:_CODE.size])[0]
            while len(message) < _CODE.size + size:
                message += conn.recv(_CODE.size + size - len(message))
            request = json.loads(message[_CODE.size:])
        except (OSError, ValueError, struct.error):
            conn.close()
            continue
        if os.fork() == 0:
            listener.close()
            _child(conn, fds, request)  # never returns
        conn.close()
        for fd in fds:
            os.close(fd)


def _child(conn: socket.socket, fds: list[int], request: dict) -> None:
    """Become the stage's process: its descriptors, folder and environment; run; report; exit."""
    code = 1
    try:
        os.setpgid(0, 0)  # its own group, so that it can end itself and what it started
        _die_with_parent()
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        for target, fd in enumerate(fds):
            os.dup2(fd, target)
            os.close(fd)
        os.chdir(request["cwd"])
        os.environ.clear()
        os.environ.update(request["env"])
        # Prefect, imported before the fork, holds the server's environment in its global
        # settings (PREFECT_API_URL among them): the command's environment must win.
        from prefect.context import refresh_global_settings_context

        refresh_global_settings_context()
        sys.argv = [sys.argv[0], *request["argv"]]
        import threading

        def watch():  # the command went away (killed, interrupted): so does the stage
            try:
                while conn.recv(1):
                    pass
            except OSError:
                pass
            os.killpg(0, signal.SIGKILL)

        threading.Thread(target=watch, daemon=True).start()
        from flows.__main__ import main

        try:
            code = main(list(request["argv"]))
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:  # noqa: BLE001  (the stage's own handler already printed its line)
        code = 1
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        with contextlib.suppress(Exception):
            conn.sendall(_CODE.pack(int(code)))
        os._exit(int(code))


@contextlib.contextmanager
def running(env: dict, root: Path, log_file: Path, timeout: float = 120.0) -> Iterator[dict]:
    """Start the server with ``env`` in the project ``root``; yield ``env`` plus ``NNSF_STAGE_SERVER``.

    The server is stopped when the block ends.

    If it is not ready within ``timeout`` seconds (or ``NNSF_STAGE_SERVER=off``),
    ``env`` is yielded unchanged and every stage imports for itself.
    """
    if env.get(ENV) == "off":
        yield {k: v for k, v in env.items() if k != ENV}
        return
    folder = Path(tempfile.mkdtemp(prefix="nnsf-stages-"))  # short: socket paths are <= 107 bytes
    path = str(folder / "socket")
    log_file.parent.mkdir(parents=True, exist_ok=True)
    with open(log_file, "ab") as log:
        proc = subprocess.Popen([sys.executable, "-m", "flows.stage_server", path], env=env, cwd=root,
                                stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + timeout
        while not os.path.exists(path) and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        ready = os.path.exists(path) and proc.poll() is None
        yield {**env, ENV: path} if ready else env
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    serve(sys.argv[1])
