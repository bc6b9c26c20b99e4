"""Cold and no-op ``python -m flows repro`` in a temporary clone, and where the time goes.

    .venv/bin/python benchmarks/bench_pipeline.py              # the default params.yaml
    .venv/bin/python benchmarks/bench_pipeline.py --small      # tiny params (tests' size), quick

The project is cloned from git HEAD into a temporary folder (committed code
only; committed results are removed so the run is cold, with new Prefect
and MLflow databases).  Then:

1. cold ``python -m flows repro``: it starts a local Prefect server, runs
   every stage as ``python -m flows <stage>`` and stops the server;
2. no-op ``python -m flows repro``: nothing to do, so no server starts.

Per stage it reports the wall time (from DVC's "Running stage" line to the
next), the stage's own work (``stage_seconds``/``sweep_seconds`` that the
flows log to MLflow) and the difference, which is the orchestration:
interpreter start-up and imports (nnsf, Prefect, MLflow), the Prefect flow
run against the server, the MLflow run and artifact logging, and DVC's
hashing of deps and outs.  Targets (issue 6): cold ≤ 3 min, no-op ≤ 5 s.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

PROJECT = Path(__file__).resolve().parents[1]
PYTHON = sys.executable


def timed_run(cmd, cwd, env) -> tuple[float, list[tuple[float, str]], int]:
    """Run ``cmd``; return (seconds, [(time since start, line)], exit code)."""
    started = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, stdin=subprocess.DEVNULL)
    lines = [(time.perf_counter() - started, line.rstrip()) for line in proc.stdout]
    code = proc.wait()
    return time.perf_counter() - started, lines, code


def stage_spans(lines, total) -> dict[str, float]:
    marks = [(t, m.group(1)) for t, line in lines if (m := re.search(r"Running stage '([^']+)'", line))]
    spans = {}
    for i, (t, stage) in enumerate(marks):
        end = marks[i + 1][0] if i + 1 < len(marks) else next(
            (t2 for t2, line in lines if t2 > t and "Prefect server" in line and "stop" in line.lower()),
            total)
        spans[stage] = end - t
    return spans


def stage_work(db: Path) -> dict[str, float]:
    """The stages' own seconds, from the MLflow runs the flows logged."""
    import mlflow

    mlflow.set_tracking_uri(f"sqlite:///{db}")
    runs = mlflow.search_runs(search_all_experiments=True)
    work = {}
    for _, row in runs.iterrows():
        stage = row.get("tags.nnsf.stage")
        if stage == "sweep":
            work[stage] = float(row.get("metrics.sweep/sweep_seconds", float("nan")))
        elif stage and stage != "sweep-point":
            work[stage] = float(row.get(f"metrics.{stage}/stage_seconds", float("nan")))
    return work


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--small", action="store_true", help="tiny params instead of params.yaml")
    parser.add_argument("--keep", action="store_true", help="keep the temporary clone")
    parser.add_argument("--worktree", action="store_true",
                        help="copy the working tree's sources (committed in a new repo) instead of "
                             "cloning HEAD, e.g. to measure uncommitted changes")
    opts = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="nnsf-bench-pipeline-"))
    root = work / "clone"
    try:
        if opts.worktree:
            sys.path.insert(0, str(PROJECT / "tests"))
            from conftest import copy_project

            root.mkdir()
            copy_project(root)
        else:
            subprocess.run(["git", "clone", "-q", "--no-hardlinks", str(PROJECT), str(root)], check=True)
        for generated in ("dvc.lock", "reports", "data", "models", "mlflow.db", "mlartifacts", ".prefect"):
            path = root / generated
            if path.is_dir():
                shutil.rmtree(path)
            elif path.exists():
                path.unlink()
        if opts.small:
            sys.path.insert(0, str(PROJECT / "tests"))
            from test_pipeline import SMALL_PARAMS

            (root / "params.yaml").write_text(SMALL_PARAMS)
        db = work / "mlflow.db"
        env = dict(os.environ, MLFLOW_TRACKING_URI=f"sqlite:///{db}", PYTHONDONTWRITEBYTECODE="1")
        env.pop("PREFECT_API_URL", None)
        env["PATH"] = str(Path(PYTHON).parent) + os.pathsep + env.get("PATH", "")

        cold, lines, code = timed_run([PYTHON, "-m", "flows", "repro"], root, env)
        if code != 0:
            print("\n".join(line for _, line in lines[-40:]))
            return 1
        server_up = next((t for t, line in lines if line.startswith("Prefect API")), float("nan"))
        spans = stage_spans(lines, cold)
        work_s = stage_work(db)
        noop, noop_lines, code = timed_run([PYTHON, "-m", "flows", "repro"], root, env)
        assert code == 0 and not any("Running stage" in line for _, line in noop_lines)

        print(f"cold `python -m flows repro` ({'small' if opts.small else 'default'} params): {cold:.1f} s")
        print(f"  Prefect server start until healthy: {server_up:.1f} s")
        print(f"  {'stage':10} {'wall s':>8} {'work s':>8} {'orchestration s':>16}")
        for stage, wall in spans.items():
            w = work_s.get(stage, float("nan"))
            print(f"  {stage:10} {wall:8.1f} {w:8.1f} {wall - w:16.1f}")
        total_work = sum(v for k, v in work_s.items() if k in spans)
        print(f"  stages' own work {total_work:.1f} s; orchestration {cold - total_work:.1f} s "
              f"({(cold - total_work) / max(len(spans), 1):.1f} s per stage incl. the server start)")
        print(f"no-op `python -m flows repro`: {noop:.1f} s (no server started)")
        return 0
    finally:
        if opts.keep:
            print("kept", work)
        else:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
