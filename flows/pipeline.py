"""The scheduled pipeline: ``dvc repro`` in the project, then a report of what changed.

Run it once with ``python -m flows pipeline``, or serve it as a deployment on
a cron schedule with ``python -m flows serve`` (needs a running Prefect
server: ``PREFECT_API_URL``).  Each DVC stage shows up in the Prefect UI as
its own flow run (``nnsf-data`` … ``nnsf-sweep``), next to the pipeline run
that started them; the pipeline run carries a Markdown report (stages re-run,
metrics that changed against the last commit).
"""
from __future__ import annotations

import json
import os
import re
import subprocess
from pathlib import Path

from prefect import flow, get_run_logger, task
from prefect.artifacts import create_markdown_artifact
from prefect.cache_policies import NO_CACHE

from nnsf.errors import InputError, OneLineParser

from flows import project
from flows.repro import dvc, stage_env
from flows.runners import retry_unless_bad_input

DEFAULT_CRON = "0 3 * * *"  # every night at 03:00 (the server's time zone is UTC by default)
DEPLOYMENT = "nnsf-pipeline"
#: Prefect's own console lines from the stage processes; the stage flow runs
#: already send those to the API, so the pipeline does not log them twice.
_PREFECT_LINE = re.compile(r"^\d\d:\d\d:\d\d\.\d{3} \| ")


class StageInputError(InputError):
    """A stage rejected its input; re-running it cannot help.

    Its message is the stage's own one-line error, unchanged.
    """

    def __init__(self, stage: str, message: str):
        ValueError.__init__(self, message)
        self.source, self.field, self.expected, self.got = "dvc repro", stage, message, None


@task(name="dvc-status", cache_policy=NO_CACHE, persist_result=False)
def dvc_status(root: str) -> dict:
    """``dvc status --json``: which stages are out of date, and why."""
    out = subprocess.run(dvc("status", "--json"), cwd=root, env=stage_env(Path(root)),
                         capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if out.returncode != 0:
        raise RuntimeError(f"dvc status failed: {out.stderr.strip().splitlines()[-1:]}")
    return json.loads(out.stdout or "{}")


@task(name="dvc-repro", cache_policy=NO_CACHE, persist_result=False, retries=1,
      retry_delay_seconds=30, retry_condition_fn=retry_unless_bad_input)
def dvc_repro(root: str, args: list[str]) -> list[str]:
    """Run ``dvc repro``, streaming its output to the run log; return the stages it ran.

    DVC keeps the stages that finished, so a retry re-runs only what failed.
    """
    logger = get_run_logger()
    proc = subprocess.Popen(dvc("repro", *args), cwd=root, env=stage_env(Path(root)),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            stdin=subprocess.DEVNULL)
    ran, errors, bad_input = [], [], False
    for line in proc.stdout:
        line = line.rstrip()
        if m := re.match(r"Running stage '([^']+)'", line):
            ran.append(m.group(1))
        if line.startswith("error: "):  # a stage's one-line error (flows.console)
            errors.append(line.removeprefix("error: "))
        # DVC: "ERROR: failed to reproduce 'x': failed to run: ..., exited with 2";
        # exit code 2 is this project's "bad input".
        bad_input |= line.startswith("ERROR:") and line.endswith("exited with 2")
        if line and not _PREFECT_LINE.match(line):
            logger.info("%s", line)
    if proc.wait() != 0:
        message = "; ".join(errors) or "see the log above"
        if bad_input:
            raise StageInputError(ran[-1] if ran else "dvc repro", message)
        raise RuntimeError(f"dvc repro failed: {message}")
    return ran


@task(name="dvc-metrics-diff", cache_policy=NO_CACHE, persist_result=False)
def metrics_diff(root: str) -> dict:
    """``dvc metrics diff --json``: the workspace's metrics against the last commit."""
    out = subprocess.run(dvc("metrics", "diff", "--json"), cwd=root,
                         env=stage_env(Path(root)), capture_output=True, text=True,
                         stdin=subprocess.DEVNULL)
    if out.returncode != 0:
        return {}
    return json.loads(out.stdout or "{}")


def report(status: dict, ran: list[str], diff: dict) -> str:
    """Markdown: stages that were out of date and re-ran, metrics that changed."""
    lines = ["# nnsf pipeline", ""]
    if not ran:
        lines.append("Nothing to reproduce: every stage was up to date.")
    else:
        lines.append("## Stages re-run")
        for stage in ran:
            why = []
            for entry in status.get(stage, []):
                if isinstance(entry, dict):
                    for kind, what in entry.items():
                        names = ", ".join(what) if isinstance(what, dict) else str(what)
                        why.append(f"{kind}: {names}")
                else:
                    why.append(str(entry))
            lines.append(f"- `{stage}`" + (f" ({'; '.join(why)})" if why else ""))
    changed = [(path, key, v) for path, metrics in diff.items()
               for key, v in metrics.items() if v.get("old") != v.get("new")]
    if changed:
        lines += ["", "## Metrics changed since the last commit", "",
                  "| file | metric | old | new |", "|---|---|---|---|"]
        lines += [f"| {p} | {k} | {v.get('old')} | {v.get('new')} |" for p, k, v in changed]
    return "\n".join(lines) + "\n"


@flow(name="nnsf-pipeline", persist_result=False)
def pipeline(project_dir: str | None = None, dvc_args: list[str] | None = None) -> dict:
    """Re-run what is out of date (``dvc repro``) and report what changed."""
    root = str(Path(project_dir).resolve() if project_dir else project.root())
    status = dvc_status(root)
    ran = dvc_repro(root, list(dvc_args or []))
    diff = metrics_diff(root)
    text = report(status, ran, diff)
    create_markdown_artifact(markdown=text, key="nnsf-pipeline-report",
                             description="Stages re-run and metrics changed")
    get_run_logger().info("stages re-run: %s", ", ".join(ran) or "none")
    return {"stages_run": ran, "metrics_diff": diff}


def main(args: list[str]) -> int:
    """``python -m flows pipeline [dvc repro args]``: one run now."""
    root = project.root()
    env = stage_env(root)
    if env.get("PREFECT_API_URL"):
        return _run_once(root, args)
    from flows import prefect_server

    with prefect_server.running(Path(env["PREFECT_HOME"])) as api_url, prefect_server.in_use(api_url):
        return _run_once(root, args)


def _run_once(root: Path, args: list[str]) -> int:
    from flows.console import error_line, quiet_prefect_console

    quiet_prefect_console()
    state = pipeline(str(root), args, return_state=True)
    if state.is_completed():
        return 0
    exc = state.result(raise_on_failure=False)
    error_line(str(exc) if isinstance(exc, InputError) else f"pipeline: {state.message}")
    return 2 if isinstance(exc, InputError) else 1


def serve_main(args: list[str]) -> int:
    """``python -m flows serve``: serve the pipeline deployment on a cron schedule."""
    parser = OneLineParser(prog="python -m flows serve")
    parser.add_argument("--cron", default=DEFAULT_CRON, help=f"schedule (default {DEFAULT_CRON!r})")
    parser.add_argument("--name", default=DEPLOYMENT, help="deployment name")
    opts = parser.parse_args(args)
    if not os.environ.get("PREFECT_API_URL"):
        raise InputError("environment", "PREFECT_API_URL",
                         "the API URL of a running Prefect server, e.g. "
                         "http://127.0.0.1:4200/api (start one with `prefect server start`)")
    root = project.root()
    os.chdir(root)
    pipeline.serve(name=opts.name, cron=opts.cron, parameters={"project_dir": str(root)},
                   description="dvc repro of the nnsf project, then a report of what changed")
    return 0
