"""The command line: ``python -m flows <command>``.

Commands::

    python -m flows frames|roto|roto_eval|data|features|factorize|evaluate|isomap|sweep|
                    heldout|translate|reshape|styles|animate [--params FILE]
        run one DVC stage as a Prefect flow and log it to MLflow (dvc.yaml's cmd)
    python -m flows repro [dvc repro arguments]
        `dvc repro` with one short-lived local Prefect server shared by all stages
    python -m flows pipeline [dvc repro arguments]
        the scheduled pipeline flow, run once now (same server handling as repro)
    python -m flows serve [--cron "0 3 * * *"] [--name nnsf-pipeline]
        serve the pipeline flow as a deployment on a cron schedule
    python -m flows ui [--port 5000]
        MLflow's UI on the project's store; prints the URL of the experiment's runs

Exit codes: 0 success, 2 bad input (one ``error: …`` line on stderr, never a
traceback), 1 any other failure (also one line; set ``NNSF_DEBUG=1`` to get
the traceback), 130 interrupted.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import flows  # noqa: F401  (telemetry switches, before any heavy import)
from flows import project
from flows.console import error_line
from nnsf.errors import exception_line
from nnsf.params import STAGE_NAMES

# nnsf's stages are imported only by the commands that run them: they pull in
# scikit-learn (about 2 s), which a no-op `python -m flows repro` does not need
# (nnsf.errors and nnsf.params are light).

STAGES = STAGE_NAMES
USAGE = __doc__.split("Commands::", 1)[1].split("Exit codes", 1)[0].rstrip()


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help", "help"):
        print("usage:" + USAGE)
        return 0 if argv else 2
    command, rest = argv[0], argv[1:]
    try:
        _settle_publications()
        if command in STAGES and os.environ.get("NNSF_STAGE_SERVER"):
            # Under `python -m flows repro`: the long-lived process that has Prefect and
            # MLflow imported runs this stage in a child of its own (flows.stage_server).
            from flows import stage_server

            code = stage_server.delegate(argv)
            if code is not None:
                return code
        if command in STAGES:
            return run_stage_command(command, rest)
        if command == "repro":
            from flows import repro

            return repro.main(rest)
        if command == "pipeline":
            from flows import pipeline

            return pipeline.main(rest)
        if command == "serve":
            from flows import pipeline

            return pipeline.serve_main(rest)
        if command == "ui":
            from flows import mlflow_ui

            return mlflow_ui.main(rest)
        error_line(f"command line: {command!r}: expected one of "
                   f"{', '.join(STAGES + ('repro', 'pipeline', 'serve', 'ui'))}")
        return 2
    except KeyboardInterrupt:
        error_line("interrupted")
        return 130
    except Exception as err:
        if _is_input_error(err):
            error_line(str(err))
            return 2
        # A bug or an environment problem: one line unless debugging.
        if os.environ.get("NNSF_DEBUG"):
            raise
        error_line(f"{command}: {exception_line(err)} (set NNSF_DEBUG=1 for the traceback)")
        return 1


def _settle_publications() -> None:
    """Finish or drop the output sets a killed stage left half-published (nnsf/publish.py).

    Every command does this first, in the project root, so a set interrupted by
    a kill is the old or the new one again before any stage or reader runs.
    Only a staging folder present costs an import: the listing alone is what
    the stages' recorded imports (and so their dvc.yaml deps) see.
    """
    reports = project.root() / "reports"
    try:
        pending = any(e.name.startswith(".") and ".staging" in e.name for e in os.scandir(reports))
    except OSError:
        return
    if pending:
        from nnsf.publish import recover_all

        for note in recover_all(reports):
            print(f"nnsf: note: {note}", file=sys.stderr)


def _is_input_error(err: BaseException) -> bool:
    # Only code that imported nnsf.errors can have raised an InputError.
    errors = sys.modules.get("nnsf.errors")
    return errors is not None and isinstance(err, errors.InputError)


def run_stage_command(stage: str, args: list[str]) -> int:
    """Validate params, then run the stage's flow; map its final state to an exit code."""
    parser = argparse.ArgumentParser(prog=f"python -m flows {stage}")
    parser.add_argument("--params", default="params.yaml", help="the params file")
    opts = parser.parse_args(args)
    root = project.root()
    os.chdir(root)  # nnsf.pipeline's default paths are relative to the project root

    # Cheap checks first: a wrong params.yaml costs no Prefect start-up.
    from nnsf.params import load, require

    params = load(opts.params)
    require(params, "mlflow.experiment")
    from nnsf.pipeline import check_outputs

    check_outputs(stage)  # an unwritable output folder: one line now, not after the work
    from flows.tracking import preflight

    preflight()  # MLflow's store and Prefect's API reached now, within NNSF_TRACKING_TIMEOUT

    from flows.console import quiet_prefect_console

    if stage == "sweep":
        from flows import runners
        from flows.sweep import sweep

        configured = runners.configured(sweep, stage)  # validates NNSF_TASK_RUNNER before the flow starts
        quiet_prefect_console()
        state = configured(params, return_state=True)
    else:
        from flows.stage_flows import FAN_OUT, FLOWS

        stage_flow = FLOWS[stage]
        if stage in FAN_OUT:
            from flows import runners

            stage_flow = runners.configured(stage_flow, stage)  # validates NNSF_TASK_RUNNER first
        quiet_prefect_console()
        state = stage_flow(params, return_state=True)

    if state.is_completed():
        _record_imports(stage, root)
        return 0
    exc = state.result(raise_on_failure=False)
    if _is_input_error(exc):
        error_line(str(exc))
        return 2
    if isinstance(exc, BaseException):
        if os.environ.get("NNSF_DEBUG"):
            raise exc
        error_line(f"{stage}: {exception_line(exc)} (the Prefect UI has the traceback; "
                   "NNSF_DEBUG=1 prints it)")
    else:
        error_line(f"{stage}: flow run ended in state {state.type.value}: {state.message}")
    return 1


def _record_imports(stage: str, root: Path) -> None:
    """If ``NNSF_RECORD_IMPORTS`` names a folder, write the project files this stage ran.

    One line per module file under the project root, to ``<folder>/<stage>.txt``,
    after a completed run only (a run stopped by bad input imports less).  The
    pipeline test compares them with the stage's deps in dvc.yaml, which keeps
    DVC's view of "what this stage depends on" exact.
    """
    folder = os.environ.get("NNSF_RECORD_IMPORTS")
    if not folder:
        return
    files = project.loaded_files(root)
    # What the fan-out's items loaded in worker processes (the held-out cells' process pool).
    runners = sys.modules.get("flows.runners")        # loaded by the stages that fan out
    files |= {f for f in getattr(runners, "WORKER_FILES", ()) if (root / f).is_file()}
    # The stage server only forks the stage's process: orchestration like DVC itself.
    files.discard("flows/stage_server.py")
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{stage}.txt").write_text("".join(f"{f}\n" for f in sorted(files)))


if __name__ == "__main__":
    sys.exit(main())
