"""Time one NNSF iteration against one scikit-learn NMF ``mu`` iteration.

Both run in this process on the same 100,000 × 34 non-negative matrix, for
k = 10 and k = 34.  The time per iteration is the slope between a short and a
long run, (t(T2) − t(T1)) / (T2 − T1), so initialisation, validation and the
fixed-length encoding NNSF does after fitting (to fit its class map) drop
out; each run is repeated and the fastest kept.  NNSF is timed without the
class term (β = 0, no labels) and with it (β = 1, 15 classes).

    .venv/bin/python benchmarks/bench_nnsf.py [--rows 100000] [--repeat 2] [--blas-threads 1]
"""
from __future__ import annotations

import argparse
import time
import warnings

import numpy as np
from sklearn.decomposition import NMF
from sklearn.exceptions import ConvergenceWarning

from nnsf import NNSF


def best_time(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def per_iteration(make, X, y, repeat, t1=5, t2=25):
    def run(T):
        return best_time(lambda: make(T).fit(X, y), repeat)
    return (run(t2) - run(t1)) / (t2 - t1)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=100_000)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--blas-threads", type=int, default=None,
                    help="limit BLAS threads for both (default: the library's own)")
    args = ap.parse_args(argv)
    if args.blas_threads:
        from threadpoolctl import threadpool_limits
        threadpool_limits(args.blas_threads, user_api="blas")
    rng = np.random.default_rng(0)
    X = rng.random((args.rows, 34)) * rng.random((1, 34)) * 4
    y = rng.integers(0, 15, args.rows)
    warnings.simplefilter("ignore", ConvergenceWarning)
    from threadpoolctl import threadpool_info
    threads = {i["internal_api"]: i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}
    print(f"X: {X.shape[0]:,} x {X.shape[1]} float64; BLAS threads {threads}; "
          f"time per iteration, best of {args.repeat}")
    print(f"{'k':>3} {'sklearn mu':>12} {'NNSF b=0':>12} {'NNSF b=1':>12} {'ratio b=0':>10} {'ratio b=1':>10}")
    for k in (10, 34):
        sk = per_iteration(lambda T: NMF(k, solver="mu", init="nndsvda", tol=0, max_iter=T), X, None, args.repeat)
        n0 = per_iteration(lambda T: NNSF(k, alpha=0.01, beta=0.0, tol=0, max_iter=T, transform_max_iter=10), X, None, args.repeat)
        n1 = per_iteration(lambda T: NNSF(k, alpha=0.01, beta=1.0, tol=0, max_iter=T, transform_max_iter=10), X, y, args.repeat)
        print(f"{k:>3} {sk * 1e3:>10.2f}ms {n0 * 1e3:>10.2f}ms {n1 * 1e3:>10.2f}ms "
              f"{n0 / sk:>10.2f} {n1 / sk:>10.2f}")


if __name__ == "__main__":
    main()
