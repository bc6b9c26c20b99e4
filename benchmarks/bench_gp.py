"""Fit time per method and rank of the evaluate stage, the GP baselines beside the others.

On the default embedded dataset (9 characters × 15 motions × 3 clips × 24
frames, unified), for the first training fold of the stage's 10-fold split,
every method of the evaluate stage is fitted at every rank of
``evaluate.ranks`` (clipped to the method's maximum, as the stage does) with
one BLAS thread, then scores the held-out fold.  Printed per (method, rank):
wall and CPU seconds of fit + scoring (CPU time is the better figure on a
shared machine), and for the GPs the training points and L-BFGS iterations.
The last lines estimate the evaluate stage's extra cost: the per-fit CPU time
of each GP summed over the stage's distinct (rank, fold) fits, divided by the
two cores.

    .venv/bin/python benchmarks/bench_gp.py [--methods mgpm,cbgpm,bilinear,nnsf] [--params params.yaml]
"""
from __future__ import annotations

import argparse
import os
import time
import warnings

import numpy as np


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--methods", default="nnsf,nnsc,nmf,bilinear,mgpm,cbgpm")
    args = ap.parse_args(argv)
    from sklearn.exceptions import ConvergenceWarning

    from nnsf.datasets import contract, synthetic
    from nnsf.evaluate.crossval import _score_fold, folds, max_rank
    from nnsf.factor.gp_data import phase_bins
    from nnsf.params import load
    from nnsf.skeleton import Unifier, to_points
    from nnsf.evaluate.stage import clip_phase
    from nnsf.pipeline import nnsf_params as _nnsf_params

    warnings.simplefilter("ignore", ConvergenceWarning)
    p = load(args.params)
    syn = p["dataset"]["synthetic"]
    raw = synthetic.generate(characters=syn["characters"], clips_per_cell=syn["clips_per_cell"],
                             frames=syn["frames"], noise_px=syn["noise_px"], seed=p["seed"])
    raw = contract.validate(raw, "synthetic")
    unifier = Unifier(margin=p["unify"]["margin"]).fit(to_points(contract.features(raw)),
                                                       raw["character"].to_numpy())
    X = unifier.transform(to_points(contract.features(raw)), raw["character"].to_numpy())
    y, styles = raw["motion"].to_numpy(), raw["character"].to_numpy()
    groups = raw["clip"].to_numpy()
    phase = clip_phase(raw)
    ev = p["evaluate"]
    gp = dict(ev["gp"])
    splits = folds(y, groups, ev["folds"], p["seed"])
    train, test = splits[0]
    S, C, d = len(np.unique(styles)), len(np.unique(y)), X.shape[1]
    load1 = os.getloadavg()[0]
    print(f"{len(X):,} frames x {d}; fold 0: {len(train):,} train / {len(test):,} test; "
          f"GP: {gp['phase_bins']} phase bins per cell, {gp['max_iter']} L-BFGS iterations; "
          f"1 BLAS thread; load average {load1:.1f} on {os.cpu_count()} cores")
    print(f"{'method':>8} {'rank':>4} {'used':>4} {'wall s':>7} {'cpu s':>7} {'points':>6} {'iter':>5} "
          f"{'precision':>9}")
    cpu_per_fit = {}
    for method in args.methods.split(","):
        top = max_rank(method, d, S, C)
        used_ranks = sorted({min(r, top) for r in ev["ranks"]})
        for r in used_ranks:
            w0, c0 = time.perf_counter(), time.process_time()
            res = _score_fold(method, r, ev["max_iter"], p["seed"], _nnsf_params(p), X, y, styles, train,
                              test, 1, phase, gp)
            wall, cpu = time.perf_counter() - w0, time.process_time() - c0
            points = ""
            if method in ("mgpm", "cbgpm"):
                observed = phase_bins(X[train], styles[train], y[train], phase[train], gp["phase_bins"])[3]
                points = str(int(observed.sum()))
            cpu_per_fit.setdefault(method, []).append(cpu)
            print(f"{method:>8} {r:>4} {res['rank_used']:>4} {wall:7.2f} {cpu:7.2f} {points:>6} "
                  f"{res['n_iter']:>5} {res['precision']:9.3f}")
    folds_n = ev["folds"]
    print("\nevaluate stage, CPU seconds of fits per method (distinct ranks x folds):")
    for method, cpus in cpu_per_fit.items():
        total = sum(cpus) * folds_n
        print(f"  {method:>8}: {len(cpus)} ranks x {folds_n} folds, {total:6.1f} CPU s "
              f"(~{total / 2:5.1f} s wall on 2 cores)")


if __name__ == "__main__":
    main()
