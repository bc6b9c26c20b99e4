"""A screenshot of MLflow's run comparison of the last α/β/rank sweep, taken with headless Chromium.

    .venv/bin/python scripts/mlflow_screenshot.py                       # the project's mlflow.db
    .venv/bin/python scripts/mlflow_screenshot.py --db other.db --out /tmp/sweep.png

Finds the newest finished ``sweep`` run of the experiment (``mlflow.experiment`` of
params.yaml) in the store, starts ``mlflow server`` on the store (127.0.0.1, a free
port, job execution off, telemetry off), opens the comparison page of the sweep's
nested runs (one per point: parallel coordinates of α, β, rank and the score, and
the table of their parameters and metrics) in headless Chromium with a fresh
profile, and writes the page as a PNG (default ``docs/figures/mlflow_sweep_compare.png``).
The server is stopped afterwards.  Needs Chromium (Debian: ``apt-get install chromium``).
"""
from __future__ import annotations

import argparse
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
from flows.mlflow_ui import QUIET, compare_url  # noqa: E402
from flows.prefect_server import stop  # noqa: E402
CHROMIUM_FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--hide-scrollbars"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def sweep_runs(db: Path, experiment: str) -> tuple[str, str, list[str]]:
    """(experiment id, sweep run id, its nested run ids) of the newest finished sweep."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=f"sqlite:///{db}")
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        sys.exit(f"error: {db}: no experiment {experiment!r} (run the pipeline first)")
    sweeps = client.search_runs([exp.experiment_id], "tags.`nnsf.stage` = 'sweep' and attributes.status = 'FINISHED'",
                                order_by=["attributes.start_time DESC"], max_results=1)
    if not sweeps:
        sys.exit(f"error: {db}: experiment {experiment!r} has no finished sweep run")
    parent = sweeps[0].info.run_id
    children = client.search_runs([exp.experiment_id], f"tags.mlflow.parentRunId = '{parent}'",
                                  max_results=1000)
    return exp.experiment_id, parent, [c.info.run_id for c in children]


def _wait_healthy(url: str, proc: subprocess.Popen, seconds: float = 120) -> None:
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            sys.exit(f"error: mlflow server exited with {proc.returncode}")
        try:
            with urllib.request.urlopen(url + "/health", timeout=2) as response:
                if response.status == 200:
                    return
        except OSError:
            pass
        time.sleep(0.5)
    sys.exit(f"error: mlflow server not healthy after {seconds:.0f} s")


def screenshot(url: str, out: Path, size: tuple[int, int], budget_ms: int) -> None:
    """Render ``url`` in headless Chromium with a fresh profile; write the PNG to ``out``."""
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        sys.exit("error: chromium not found (Debian: apt-get install -y chromium)")
    with tempfile.TemporaryDirectory(prefix="nnsf-chromium-") as profile:
        tmp = Path(profile) / "shot.png"
        cmd = [chromium, *CHROMIUM_FLAGS, f"--user-data-dir={profile}", f"--window-size={size[0]},{size[1]}",
               f"--virtual-time-budget={budget_ms}", f"--screenshot={tmp}", url]
        done = subprocess.run(cmd, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL)
        if done.returncode != 0 or not tmp.is_file():
            sys.exit(f"error: chromium failed ({done.returncode}): {done.stderr.strip()[-500:]}")
        out.parent.mkdir(parents=True, exist_ok=True)
        shutil.move(tmp, out)


def main(argv=None) -> int:
    import yaml

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--db", type=Path, default=ROOT / "mlflow.db", help="the MLflow sqlite store")
    ap.add_argument("--experiment", default=None, help="default: mlflow.experiment of params.yaml")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "mlflow_sweep_compare.png")
    ap.add_argument("--size", type=int, nargs=2, default=(1600, 1500), metavar=("W", "H"))
    ap.add_argument("--budget", type=int, default=30000, help="Chromium's virtual time budget, ms")
    a = ap.parse_args(argv)
    experiment = a.experiment or yaml.safe_load((ROOT / "params.yaml").read_text())["mlflow"]["experiment"]
    exp_id, parent, children = sweep_runs(a.db.resolve(), experiment)
    print(f"sweep run {parent}: {len(children)} nested runs")
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    env = dict(os.environ, **QUIET)
    server = subprocess.Popen([sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1", "--port", str(port),
                               "--workers", "1", "--backend-store-uri", f"sqlite:///{a.db.resolve()}"],
                              env=env, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        _wait_healthy(base, server)
        screenshot(compare_url(base, exp_id, children), a.out, tuple(a.size), a.budget)
    finally:
        stop(server, grace=20)
    print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
