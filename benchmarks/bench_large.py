"""NNSF on a large input: seconds per iteration against the floor, and peak memory.

    .venv/bin/python benchmarks/bench_large.py                 # 1,000,000 x 34, k = 20, both dtypes
    .venv/bin/python benchmarks/bench_large.py --rows 200000 --dtypes float32

For each dtype a fresh Python process builds X (non-negative, low rank plus
noise), then measures:

- the floor: the two n-sized matrix products one iteration cannot avoid,
  X Uᵀ (the weight update's numerator) and VᵀX (the basis gradient), timed
  in the same process on the same arrays (best of ``--repeats``);
- seconds per iteration of ``NNSF.fit`` (no labels): (time of a fit with
  1 + m iterations − time of a fit with 1 iteration) / m, tol = 0 so every
  iteration runs, best of ``--repeats``;
- peak memory of one fit: the largest amount tracemalloc saw allocated
  during ``fit`` (numpy reports its buffers to it), over the input's size;
  and the process's resident high-water mark during the fit (``VmHWM``,
  reset just before it through ``/proc/self/clear_refs``) above its
  resident size before the fit (X and the interpreter).

Targets (issue 6): peak ≤ 3 × the input; per-iteration ≤ 2 × the floor.
Figures are printed, not asserted.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

CHILD_FLAG = "--child"


def child(rows: int, cols: int, k: int, dtype: str, iters: int, repeats: int, seed: int) -> dict:
    import time
    import tracemalloc

    import numpy as np

    from nnsf import NNSF

    def rss_mb(field):
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith(field):
                    return int(line.split()[1]) / 1024
        return float("nan")

    rng = np.random.default_rng(seed)
    # Low rank plus noise, non-negative: the shape of real key-point features.
    X = (rng.random((rows, 8)) @ rng.random((8, cols))).astype(dtype)
    X += rng.random((rows, cols), dtype=np.float64).astype(dtype) * 0.05
    input_mb = X.nbytes / 2**20

    # The floor: X Uᵀ and VᵀX on arrays of the fit's shapes and type.
    U = rng.random((k, cols)).astype(dtype)
    V = rng.random((rows, k)).astype(dtype)
    out_v, out_g = np.empty((rows, k), dtype), np.empty((k, cols), dtype)
    xut, vtx = [], []
    for _ in range(repeats):
        t = time.perf_counter()
        np.matmul(X, U.T, out=out_v)
        xut.append(time.perf_counter() - t)
        t = time.perf_counter()
        np.matmul(V.T, X, out=out_g)
        vtx.append(time.perf_counter() - t)
    del U, V, out_v, out_g
    floor = min(xut) + min(vtx)

    def fit_seconds(max_iter):
        model = NNSF(k, max_iter=max_iter, tol=0.0, init="nndsvda", random_state=0, dtype=dtype)
        t = time.perf_counter()
        model.fit(X)
        seconds = time.perf_counter() - t
        assert model.n_iter_ == max_iter and model.components_.dtype == np.dtype(dtype)
        return seconds

    base = min(fit_seconds(1) for _ in range(repeats))
    more = min(fit_seconds(1 + iters) for _ in range(repeats))
    per_iter = (more - base) / iters

    import gc

    gc.collect()
    rss_before = rss_mb("VmRSS:")
    # Reset the kernel's high-water mark (VmHWM) so it covers the fit only.
    with open("/proc/self/clear_refs", "w") as fh:
        fh.write("5")
    tracemalloc.start()
    NNSF(k, max_iter=3, tol=0.0, init="nndsvda", random_state=0, dtype=dtype).fit(X)
    _, traced_peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    peak_rss = rss_mb("VmHWM:")
    return {
        "dtype": dtype, "rows": rows, "cols": cols, "k": k, "input_mb": input_mb,
        "floor_s": floor, "xut_s": min(xut), "vtx_s": min(vtx),
        "init_plus_one_iter_s": base, "per_iter_s": per_iter, "per_iter_over_floor": per_iter / floor,
        "fit_peak_mb": traced_peak / 2**20, "fit_peak_over_input": traced_peak / X.nbytes,
        "rss_before_fit_mb": rss_before, "peak_rss_mb": peak_rss,
        "rss_growth_over_input": (peak_rss - rss_before) / input_mb,
        "peak_rss_over_input_incl_x": (peak_rss - rss_before + input_mb) / input_mb,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--cols", type=int, default=34)
    parser.add_argument("--rank", type=int, default=20)
    parser.add_argument("--dtypes", nargs="+", default=["float64", "float32"],
                        choices=["float64", "float32"])
    parser.add_argument("--iters", type=int, default=5, help="iterations timed per fit")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--blas-threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(CHILD_FLAG, action="store_true", help=argparse.SUPPRESS)
    opts = parser.parse_args(argv)
    if opts.child:
        result = child(opts.rows, opts.cols, opts.rank, opts.dtypes[0], opts.iters, opts.repeats,
                       opts.seed)
        print(json.dumps(result))
        return 0
    env = dict(os.environ)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env[name] = str(opts.blas_threads)
    print(f"NNSF fit, {opts.rows:,} x {opts.cols}, k = {opts.rank}, {opts.blas_threads} BLAS thread(s)")
    print(f"{'dtype':8} {'input MB':>9} {'floor s':>8} {'s/iter':>8} {'× floor':>8} "
          f"{'fit peak MB':>12} {'× input':>8} {'RSS peak MB':>12} {'RSS growth × input':>19}")
    print("(fit peak: tracemalloc during fit; RSS growth: VmHWM during fit minus VmRSS before it)")
    for dtype in opts.dtypes:
        cmd = [sys.executable, __file__, CHILD_FLAG, "--rows", str(opts.rows), "--cols", str(opts.cols),
               "--rank", str(opts.rank), "--dtypes", dtype, "--iters", str(opts.iters),
               "--repeats", str(opts.repeats), "--seed", str(opts.seed)]
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"{dtype:8} {r['input_mb']:9.0f} {r['floor_s']:8.3f} {r['per_iter_s']:8.3f} "
              f"{r['per_iter_over_floor']:8.2f} {r['fit_peak_mb']:12.0f} {r['fit_peak_over_input']:8.2f} "
              f"{r['peak_rss_mb']:12.0f} {r['rss_growth_over_input']:19.2f}", flush=True)
        print("  " + json.dumps({k: round(v, 4) if isinstance(v, float) else v for k, v in r.items()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
