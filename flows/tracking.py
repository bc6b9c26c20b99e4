"""The tracking servers, reached before a stage works: MLflow's store and Prefect's API, each within a timeout.

A stage that cannot record its run should say so in a second, not after its
work (and not after MLflow's own retries, about four minutes against a closed
port).  :func:`preflight` runs before the flow starts:

* **Prefect**: when ``PREFECT_API_URL`` is set (a server you run, or the one
  ``python -m flows repro`` starts), ``<url>/health`` must answer within the
  timeout.  Without it Prefect starts a temporary server of its own: nothing
  to reach.
* **MLflow**: an ``http(s)://`` ``MLFLOW_TRACKING_URI`` must answer
  ``<uri>/health``; a ``sqlite:///`` store (the project's ``mlflow.db`` by
  default) must open as a database and take a write lock (``BEGIN
  IMMEDIATE``), so a locked or corrupt file is named now.

The timeout is ``NNSF_TRACKING_TIMEOUT`` seconds (default
:data:`DEFAULT_TIMEOUT`).  MLflow's own HTTP retries are capped too
(:data:`MLFLOW_HTTP_DEFAULTS`, unless set): a server that goes away while
the stage works fails its logging in seconds.  Every failure is one
:class:`~nnsf.errors.InputError` line naming the setting (``PREFECT_API_URL``,
``MLFLOW_TRACKING_URI``) or the file (``mlflow.db``).

:func:`recorded` wraps the logging after the work: a store that fails then
is named, with the outputs the stage wrote and kept (DVC does not record a
failed stage; rerunning it logs the run).
"""
from __future__ import annotations

import contextlib
import math
import os
import sqlite3
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path
from typing import Iterator

from nnsf.errors import InputError, exception_line
from nnsf.pipeline import OUTPUT_FOLDERS

from flows import project

#: The setting that bounds every check (seconds).
TIMEOUT_ENV = "NNSF_TRACKING_TIMEOUT"
DEFAULT_TIMEOUT = 5.0
#: MLflow's HTTP retry settings used unless set: 2 retries 1 s and 2 s apart, 30 s per request
#: (MLflow's own defaults, 7 retries with a doubling backoff, wait about four minutes).
MLFLOW_HTTP_DEFAULTS = {"MLFLOW_HTTP_REQUEST_MAX_RETRIES": "2", "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR": "1",
                        "MLFLOW_HTTP_REQUEST_TIMEOUT": "30"}


def timeout() -> float:
    """``NNSF_TRACKING_TIMEOUT`` in seconds (default :data:`DEFAULT_TIMEOUT`); InputError if not in (0, 600]."""
    text = os.environ.get(TIMEOUT_ENV, "").strip()
    if not text:
        return DEFAULT_TIMEOUT
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value <= 600:
        raise InputError("environment", TIMEOUT_ENV, "a number of seconds in (0, 600]", text)
    return value


def _health(url: str, seconds: float) -> str | None:
    """None when ``url`` answers 200 within ``seconds``, else why not (one line)."""
    try:
        with urllib.request.urlopen(url, timeout=seconds) as resp:
            return None if resp.status == 200 else f"HTTP {resp.status}"
    except urllib.error.HTTPError as exc:
        return f"HTTP {exc.code} {exc.reason}"
    except urllib.error.URLError as exc:
        return str(exc.reason)
    except (OSError, ValueError) as exc:   # a timeout, a malformed URL
        return exception_line(exc)


def check_prefect(seconds: float) -> None:
    """``PREFECT_API_URL``'s ``/health`` answers within ``seconds`` (nothing to check when it is unset)."""
    url = os.environ.get("PREFECT_API_URL", "").strip()
    if not url:
        from prefect.settings import PREFECT_API_URL   # a profile may set it instead of the environment

        url = (PREFECT_API_URL.value() or "").strip()
    if not url:
        return
    why = _health(url.rstrip("/") + "/health", seconds)
    if why is not None:
        raise InputError("PREFECT_API_URL", url, f"a Prefect server answering {url.rstrip('/')}/health within "
                         f"{seconds:g} s (start it, unset PREFECT_API_URL for a temporary one, or raise "
                         f"{TIMEOUT_ENV})", reason=why)


def store_name(uri: str) -> str:
    """How a message names the MLflow store: the sqlite file, else ``MLFLOW_TRACKING_URI (<uri>)``."""
    path = sqlite_path(uri)
    return str(path) if path is not None else f"MLFLOW_TRACKING_URI ({uri})"


def sqlite_path(uri: str) -> Path | None:
    """The file of a ``sqlite:///`` URI, else None."""
    if not uri.startswith("sqlite:///"):
        return None
    return Path(urllib.parse.unquote(uri[len("sqlite:///"):].split("?", 1)[0]))


def check_mlflow(uri: str, seconds: float) -> None:
    """The MLflow store at ``uri`` can be reached (server) or opened and written (sqlite) within ``seconds``."""
    if uri.startswith(("http://", "https://")):
        why = _health(uri.rstrip("/") + "/health", seconds)
        if why is not None:
            raise InputError("MLFLOW_TRACKING_URI", uri, f"an MLflow tracking server answering "
                             f"{uri.rstrip('/')}/health within {seconds:g} s (start it, or raise {TIMEOUT_ENV})",
                             reason=why)
        return
    path = sqlite_path(uri)
    if path is None:
        return                              # another kind of store: MLflow reports its own errors
    expected = (f"an MLflow sqlite store that opens and takes a write lock within {seconds:g} s "
                f"(another process holds it, or it is not a database; {TIMEOUT_ENV} sets the wait)")
    if not path.exists():
        if not path.parent.is_dir() or not os.access(path.parent, os.W_OK):
            raise InputError(path, "file", "an MLflow sqlite store it can create (a writable folder)")
        return                              # MLflow creates it
    try:
        con = sqlite3.connect(f"file:{path}?mode=rw", uri=True, timeout=seconds)
    except sqlite3.Error as exc:
        raise InputError(path, "file", expected, reason=str(exc)) from None
    try:
        con.execute("SELECT count(*) FROM sqlite_master").fetchone()
        con.execute("BEGIN IMMEDIATE")
        con.execute("ROLLBACK")
    except sqlite3.Error as exc:
        raise InputError(path, "file", expected, reason=str(exc)) from None
    finally:
        con.close()


def preflight() -> None:
    """Reach Prefect's API and MLflow's store before the stage works (module docstring)."""
    for name, value in MLFLOW_HTTP_DEFAULTS.items():
        os.environ.setdefault(name, value)
    seconds = timeout()
    check_mlflow(project.mlflow_uri(), seconds)
    check_prefect(seconds)


@contextlib.contextmanager
def recorded(stage: str, artifacts=()) -> Iterator[None]:
    """Run the block that logs ``stage``'s MLflow run; a failing store is one line that says what was kept."""
    try:
        yield
    except (InputError, KeyboardInterrupt):
        raise
    except Exception as exc:
        files = [str(a) for a in artifacts] or [str(f) for f in OUTPUT_FOLDERS.get(stage, ())]
        kept = ", ".join(files[:4]) + (", ..." if len(files) > 4 else "")
        raise InputError(store_name(project.mlflow_uri()), "run", f"the {stage} stage's MLflow run recorded; "
                         f"its outputs were written and are kept ({kept}), rerun the stage to record it",
                         reason=exception_line(exc)) from None
