"""Driver of the kill test (tests/test_hardening_publish.py): SIGKILL ``evaluate`` at its k-th write.

Usage: ``python tests/kill_evaluate.py FEATURES_CSV REPORTS_DIR OUT_JSON``

Runs the real ``nnsf.stages.evaluate`` in forked child processes.  An audit
hook (:func:`sys.addaudithook`) in the child counts every file-system write
under ``REPORTS_DIR`` (opening a file for writing, rename/replace, remove,
rmdir, rmtree, truncate) and sends the child SIGKILL just
before the k-th one, for k = 1, 2, ... until a run finishes.  Before each
run ``REPORTS_DIR`` is reset to the previous run's complete output (params A,
``seed: 0``); the killed run writes params B (``seed: 1``).  For every k the
driver records the published files (``relative path -> SHA-256``) right
after the kill (and whether the staging folder held a commit journal), then
runs what the user would run next, a real command of the project
(``nnsf check``, through :func:`nnsf.cli.main` in the reports' parent
folder, as any ``nnsf`` or ``python -m flows`` command settles interrupted
publications first), records the files again, and what
:func:`nnsf.publish.verify` says.  The test judges them.
"""
from __future__ import annotations

import copy
import hashlib
import json
import os
import shutil
import signal
import sys
from pathlib import Path

import yaml

from nnsf import stages
from nnsf.errors import InputError
# Imported once here, not in every forked child (evaluate imports them lazily).
import matplotlib.pyplot  # noqa: E402,F401
import nnsf.evaluate.crossval  # noqa: E402,F401
import nnsf.evaluate.figures  # noqa: E402,F401
from nnsf.params import Params

try:
    from nnsf.publish import JOURNAL, staging_path, verify
except ImportError:  # a checkout without the publication protocol: kill on the files alone
    JOURNAL = ".commit.json"

    def staging_path(root, stage):
        return Path(root) / f".{stage}.staging"

    def verify(root, stage):
        raise InputError(root, "manifest", "a publication manifest (not implemented)")

PROJECT = Path(__file__).resolve().parents[1]
#: Events that change what a reader finds: creating or writing a file, renaming
#: (os.replace), removing.  (mkdir and chmod only precede one of these.)
EVENTS = {"open", "os.rename", "os.remove", "os.rmdir", "shutil.rmtree", "os.truncate"}
WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_TRUNC | os.O_APPEND


def params_for(seed: int) -> Params:
    p = yaml.safe_load((PROJECT / "params.yaml").read_text())
    p = copy.deepcopy(p)
    p["seed"] = seed
    p["evaluate"].update(ranks=[2], methods=["nnsf"], folds=2, max_iter=5)
    p["nnsf"]["rank"] = 2
    return Params(p)


def snapshot(reports: Path) -> dict[str, str]:
    """Visible files under ``reports`` (no hidden staging or temporaries) and their SHA-256."""
    out = {}
    if reports.exists():
        for p in sorted(reports.rglob("*")):
            rel = p.relative_to(reports)
            if p.is_file() and not any(part.startswith(".") for part in rel.parts):
                out[rel.as_posix()] = hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def _is_write(event: str, args) -> list:
    """The paths a write event touches (empty if it is not a write)."""
    if event == "open":
        path, mode, flags = args
        if isinstance(mode, str):
            writes = any(c in mode for c in "wax+")
        else:
            writes = bool(flags & WRITE_FLAGS)
        return [path] if writes else []
    if event == "os.rename":
        return [args[0], args[1]]
    return [args[0]]


def run_child(features: Path, reports: Path, params: Params, kill_at: int | None) -> int:
    """Run evaluate in a forked child; its wait status (killed children: SIGKILL)."""
    root = os.path.abspath(reports)
    pid = os.fork()
    if pid == 0:
        if kill_at is not None:
            count = [0]

            def hook(event, args):
                if event not in EVENTS:
                    return
                for p in _is_write(event, args):
                    if isinstance(p, int):
                        continue
                    full = os.path.abspath(os.fsdecode(p))
                    if full == root or full.startswith(root + os.sep):
                        count[0] += 1
                        if count[0] == kill_at:
                            os.kill(os.getpid(), signal.SIGKILL)
                        return
            sys.addaudithook(hook)
        code = 0
        try:
            stages.evaluate(params, features_csv=features, reports=reports,
                            mapper=lambda fn, jobs: [fn(j) for j in jobs])
        except BaseException as exc:  # reported through the exit code
            print(f"child: {type(exc).__name__}: {exc}", file=sys.stderr)
            code = 1
        os._exit(code)
    _, status = os.waitpid(pid, 0)
    return status


def next_command(reports: Path) -> str:
    """``nnsf check`` in the reports' parent folder (the project), in this process; its stderr."""
    import contextlib
    import io

    from nnsf import cli

    params = reports.parent / "params.yaml"
    params.write_text((PROJECT / "params.yaml").read_text())
    err, here = io.StringIO(), os.getcwd()
    os.chdir(reports.parent)
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            assert cli.main(["check", "--params", "params.yaml"]) == 0
    finally:
        os.chdir(here)
        params.unlink()
    return err.getvalue()


def reset(reports: Path, saved: Path) -> None:
    shutil.rmtree(reports, ignore_errors=True)
    shutil.copytree(saved, reports)


def main(features: str, reports: str, out: str) -> None:
    features, reports = Path(features), Path(reports)
    a, b = params_for(0), params_for(1)
    assert run_child(features, reports, a, None) == 0
    old = snapshot(reports)
    saved = reports.parent / "saved-old"
    shutil.copytree(reports, saved)
    assert run_child(features, reports, b, None) == 0
    new = snapshot(reports)
    runs = []
    k = 0
    while True:
        k += 1
        reset(reports, saved)
        status = run_child(features, reports, b, k)
        killed = os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
        if not killed:
            assert os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0, status
            runs.append({"k": k, "killed": False, "after_kill": snapshot(reports)})
            break
        entry = {"k": k, "killed": True, "after_kill": snapshot(reports)}
        staging = staging_path(reports, "evaluate")
        entry["recovery"] = ("completed" if (staging / JOURNAL).is_file() else
                             "discarded" if staging.exists() else "none")
        entry["notes"] = next_command(reports)
        entry["after_recovery"] = snapshot(reports)
        entry["hidden_left"] = sorted(p.name for p in reports.iterdir() if p.name.startswith("."))
        try:
            entry["verified"] = sorted(verify(reports, "evaluate"))
        except InputError as exc:
            entry["verified"] = None
            entry["verify_error"] = str(exc)
        runs.append(entry)
        if k == 3:  # a rerun after a kill gives the uninterrupted run's files
            assert run_child(features, reports, b, None) == 0
            entry["rerun"] = snapshot(reports)
    Path(out).write_text(json.dumps({"old": old, "new": new, "runs": runs}, indent=1))


if __name__ == "__main__":
    main(*sys.argv[1:4])
