"""Time the public translation path against another checkout of nnsf, in the same run.

Two timings, each for this checkout and for ``--peer`` (a second checkout of
the project, e.g. ``git worktree add /tmp/base <commit>``; it runs in a
subprocess with that checkout first on ``sys.path``), one BLAS thread:

* ``translate_300``: :func:`nnsf.translate` of a 300-frame clip (a
  Bandai-Namco-1 walk, repeated) into one style, the fastest of ``--repeat``;
* ``fold``: one leave-one-content-out fold -- the style model fitted on every
  clip but one content's (as ``nnsf styles`` fits it, without the file), then
  the source style's take of that content translated into every other style.

Prints one JSON line per checkout and the ratios, with the load average
(the machine may be shared: compare the ratio, not the seconds)::

    .venv/bin/python benchmarks/bench_style_transfer.py --data ../shared/data/bandai-namco-1 \\
        --peer /tmp/base --content walk --source normal
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

CHILD = r'''
import json, sys, time
import numpy as np
from threadpoolctl import threadpool_limits
from nnsf.datasets import bvh_source, contract
from nnsf.factor.style_model import StyleModel, translate, translator_params, unify_table
from nnsf.factor.translate import StyleTranslator
from nnsf.params import load

data, content, source, repeat, params_path = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
params = load(params_path)
tp = translator_params(params)
if "neutral" in StyleTranslator().get_params():
    tp["neutral"] = source
table, _ = bvh_source.read_folder(data, fps=30, facing="first")
fit_kw = {"fps": 30.0} if "fps" in StyleTranslator.fit.__code__.co_varnames else {}
with threadpool_limits(1):
    t0 = time.perf_counter()
    train = table[table["motion"] != content].reset_index(drop=True)
    ft, u = unify_table(train, 0.5)
    tr = StyleTranslator(**tp).fit(contract.features(ft), ft["motion"].to_numpy(str),
                                   ft["character"].to_numpy(str), ft["clip"].to_numpy(str), **fit_kw)
    fit = time.perf_counter() - t0
    model = StyleModel(tr, u)
    src = table[(table["motion"] == content) & (table["character"] == source)]
    P = contract.features(src[src["clip"] == src["clip"].iloc[0]]).reshape(-1, 17, 2)
    styles = sorted(set(table.loc[table["motion"] == content, "character"]) - {source})
    t1 = time.perf_counter()
    for s in styles:
        translate(P, s, model)
    cells = time.perf_counter() - t1
    P300 = np.concatenate([P] * (300 // len(P) + 1))[:300]
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        translate(P300, styles[0], model)
        best = min(best, time.perf_counter() - t)
print(json.dumps({"nnsf": __import__("nnsf").__file__, "fold_fit": fit, "fold_translate": cells,
                  "fold": fit + cells, "cells": len(styles), "translate_300": best}))
'''


def run(checkout: Path, args) -> dict:
    env = dict(os.environ, PYTHONPATH=str(checkout), OMP_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-c", CHILD, str(args.data), args.content, args.source,
                           str(args.repeat), str(checkout / "params.yaml")],
                          env=env, capture_output=True, text=True, cwd=checkout, timeout=3600)
    if done.returncode != 0:
        raise SystemExit(f"{checkout}: {done.stderr.strip().splitlines()[-1]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, help="a folder of labelled .bvh clips")
    ap.add_argument("--peer", type=Path, required=True, help="another checkout of the project")
    ap.add_argument("--content", default="walk", help="the content held out (default walk)")
    ap.add_argument("--source", default="normal", help="the style of the clip translated")
    ap.add_argument("--repeat", type=int, default=5)
    args = ap.parse_args(argv)
    here = Path(__file__).resolve().parents[1]
    load_before = os.getloadavg()[0]
    t = time.perf_counter()
    ours = run(here, args)
    peer = run(args.peer.resolve(), args)
    out = {"ours": ours, "peer": peer,
           "ratio_translate_300": ours["translate_300"] / peer["translate_300"],
           "ratio_fold": ours["fold"] / peer["fold"],
           "load_average": [round(load_before, 2), round(os.getloadavg()[0], 2)],
           "wall_seconds": round(time.perf_counter() - t, 1)}
    print(json.dumps(out, indent=1, default=lambda x: round(float(x), 4) if isinstance(x, np.floating) else x))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
