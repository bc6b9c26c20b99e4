"""Outputs are the same bytes on another machine: two BLAS and CPU set-ups, one set of hashes.

Every stage of the small pipeline runs as its plain ``nnsf`` command (no
orchestration; all of them in one fresh process per set-up) twice, in two
folders, under two set-ups that stand for two different machines:

- this machine's defaults pinned to one OpenBLAS thread;
- two OpenBLAS threads, OpenBLAS's Haswell kernels instead of the ones it picks
  for this CPU (``OPENBLAS_CORETYPE``), and numpy's AVX-512 loops switched off
  (``NPY_DISABLE_CPU_FEATURES``): what an AVX2 machine would run.

Sums come out differently in their last bits under the two (the numbers in
the files did, before every writer rounded to ``nnsf.io.DIGITS`` significant
digits); every output file must now hash the same.  Slow: it spawns the stages.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import PROJECT

pytestmark = pytest.mark.slow

STAGES = ("frames", "roto", "roto_eval", "data", "features", "factorize", "evaluate", "isomap", "heldout",
          "translate", "reshape")

#: Two machines' worth of BLAS and SIMD choices (see the module docstring).
SETUPS = {
    "one-thread": {"OPENBLAS_NUM_THREADS": "1"},
    "avx2-two-threads": {"OPENBLAS_NUM_THREADS": "2", "OPENBLAS_CORETYPE": "Haswell",
                         "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR"},
}


#: Runs ``nnsf <stage>`` for each stage named on its command line, stops at the first failure.
RUN_STAGES = """
import sys
from nnsf import cli
for stage in sys.argv[1:]:
    code = cli.main([stage])
    if code != 0:
        sys.exit(f"nnsf {stage} exited {code}")
"""


def _run_stages(root: Path, extra: dict[str, str]) -> dict[str, str]:
    """Run every stage in ``root``; return {relative path: md5} of everything they wrote."""
    from test_pipeline import SMALL_PARAMS

    root.mkdir(parents=True)
    (root / "params.yaml").write_text(SMALL_PARAMS)
    env = dict(os.environ, PYTHONPATH=str(PROJECT), **extra)
    for name in ("OPENBLAS_CORETYPE", "NPY_DISABLE_CPU_FEATURES"):
        if name not in extra:
            env.pop(name, None)
    # Every stage's `nnsf <stage>` (nnsf.cli.main) in one fresh process per set-up: the BLAS
    # and SIMD set-up is read once, when numpy loads, and one start-up instead of eleven.
    done = subprocess.run([sys.executable, "-c", RUN_STAGES, *STAGES], cwd=root, env=env,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL, timeout=1800)
    assert done.returncode == 0, (done.stdout[-2000:], done.stderr[-2000:])
    return {p.relative_to(root).as_posix(): hashlib.md5(p.read_bytes()).hexdigest()
            for d in ("data", "models", "reports") for p in sorted((root / d).rglob("*")) if p.is_file()}


def test_every_output_hashes_the_same_under_two_blas_and_cpu_setups(tmp_path):
    first, second = (_run_stages(tmp_path / name, extra) for name, extra in SETUPS.items())
    differ = sorted(path for path in first if first[path] != second.get(path))
    assert len(first) > 40 and {"models/nnsf.npz", "reports/metrics.json", "reports/heldout.csv",
                                "reports/roto_eval.json", "data/features/features.csv"} <= set(first)
    assert differ == []
    assert set(first) == set(second)
