"""Question answered: at which step does the default style translation lose style and content?

The steps of the synthesis (per-clip weights, the content's consensus weights with and without
the temporal term, the amplitude restore, the tempo) scored one by one against the hidden real
clips on 30 held-out Bandai-Namco-1 cells, for the first-order smoothness then in use.  Answer
(``experiments/translation_diagnosis.{json,png}``): the consensus loses the amplitude (its swing
is about half the real clips') and the first-order term damps motion with the jitter; it led to
the second-order temporal term and to scaling the swing to the target style
(``translation.smooth_order: 2``, ``amplitude: style``; method §8).  Ran against the code of its
time; it is kept as a record and is not maintained with the library.

For held-out cells of a labelled BVH folder (Bandai-Namco-1), this replays
the default NNSF synthesis of :func:`nnsf.evaluate.translation.evaluate_cell`
one step at a time and measures every intermediate clip against the hidden
real clip and with the independent judges:

* ``source``           -- per-clip weights: every remaining clip of the content, encoded
                          under its own style's basis, rendered with the target's (the
                          reading without the consensus);
* ``consensus_nosmooth`` -- the content's shared (consensus) weights V_c U_t + b_t of a fit
                          without the temporal term (``smooth: 0``);
* ``consensus``        -- the same with the default temporal term (``smooth`` of params.yaml);
* ``+amplitude``       -- ``consensus`` with the amplitude restore;
* ``+tempo``           -- ``+amplitude`` resampled to the target style's tempo: the default
                          ``nnsf`` output;
* ``identity``, ``real`` -- the source clip unchanged and the hidden clip, for reference;

plus any candidate steps named in :data:`CANDIDATES` (ways to fix what the
diagnosis shows; they are measured here before one becomes a default).

Per step: DTW error (% torso), per-joint error over the hidden clip's
normalised time (10 bins), the jerk ratio (mean |second difference| over the
target style's real training clips), the amplitude ratio (sd of every
coordinate over the hidden clip's), each judge family's verdict, and how far
the judges' own statistics of the synthesis sit from those of the hidden clip
(RMS of the standardised difference, per statistic group, standardised as the
judges do: on the real training clips).  The judges see pixels: every step is
mapped to the target character with the cell's inverse unification.

    .venv/bin/python experiments/diagnose_translation.py --data ../shared/data/bandai-namco-1 \\
        --cells 30 --jobs 2 --out experiments/translation_diagnosis --set smooth=5.0 --set smooth_order=1 \\
        --candidates "smooth_order=2+smooth=20,smooth_order=2+smooth=20+amplitude=style"

(the diagnosis of the previous default, first-order smoothness 5, and the two candidate fixes;
``experiments/translation_diagnosis.{json,png}`` hold that run's output; ``--redraw`` prints and
redraws them without recomputing).

Writes ``OUT.json`` (means per step, per-joint error over time of every step)
and ``OUT.png`` (per-joint error over time of the default; statistic-group
distances per step), and prints the tables.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

STEPS = ("source", "consensus_nosmooth", "consensus", "+amplitude", "+tempo", "identity", "real")
#: Candidate fixes, measured beside the diagnosis (name -> what it is); see candidate().
CANDIDATES: dict[str, str] = {}
BINS = 10


def _groups():
    # Statistic groups of the judges' features (nnsf.evaluate.judges): pose (96 = 3 x 32) and
    # angles (64 = cos 16, sin 16, spread 16, speed 16).
    return {"pose mean": slice(0, 32), "pose sd": slice(32, 64), "pose |velocity|": slice(64, 96),
            "bone direction": slice(96, 128), "bone spread": slice(128, 144), "bone speed": slice(144, 160)}


def diagnose_cell(args):
    table, style, content, tp, margin, seed, candidates = args
    from sklearn.preprocessing import StandardScaler
    from threadpoolctl import threadpool_limits

    from nnsf.datasets.contract import features
    from nnsf.evaluate import translation as ev
    from nnsf.evaluate.judges import Judges, angle_statistics, pose_statistics
    from nnsf.factor.timewarp import dtw_accumulate, dtw_path, joint_distance_matrix, resample_clip
    from nnsf.factor.translate import StyleTranslator
    from nnsf.skeleton import Unifier, to_points

    t0 = time.perf_counter()
    with threadpool_limits(1):
        hidden = ev._check_cell(table, style, content)
        train = table.loc[~hidden].reset_index(drop=True)
        test = table.loc[hidden].reset_index(drop=True)
        P = to_points(features(train))
        ch = train["character"].astype(str).to_numpy()
        mo = train["motion"].astype(str).to_numpy()
        cl = train["clip"].astype(str).to_numpy()
        unifier = Unifier(margin=margin).fit(P, ch)
        X = unifier.transform(P, ch)
        names, rows = ev._clip_index(train)
        cs = np.array([ch[r[0]] for r in rows])
        cc = np.array([mo[r[0]] for r in rows])
        _, h_rows = ev._clip_index(test)
        Pt = to_points(features(test))
        hidden_P = Pt[h_rows[0]]
        hidden_X = ev._unify(unifier, hidden_P, style)
        judges = Judges(seed=seed).fit([P[r] for r in rows], cs, cc)
        stats = lambda Q: np.concatenate([pose_statistics(Q), angle_statistics(Q)])  # noqa: E731
        scaler = StandardScaler().fit(np.stack([stats(P[r]) for r in rows]))
        jerk_real = float(np.mean([ev.jerk(X[rows[i]]) for i in np.flatnonzero(cs == style)]))

        base = {**tp, "random_state": seed}
        tr = StyleTranslator(**base).fit(X, mo, ch, cl)
        tr0 = StyleTranslator(**{**base, "smooth": 0.0}).fit(X, mo, ch, cl)
        src = np.flatnonzero(cc == content)

        def synth(t, amplitude, tempo):
            t.set_params(amplitude=amplitude, tempo=tempo)
            try:
                return t.synthesize(content, style)
            finally:
                t.set_params(amplitude=base["amplitude"], tempo=base["tempo"])

        clips = {
            "source": [tr.translate(X[rows[q]], cs[q], style) for q in src],
            "consensus_nosmooth": [synth(tr0, "none", False)],
            "consensus": [synth(tr, "none", False)],
            "+amplitude": [synth(tr, "restore", False)],
            "+tempo": [synth(tr, base["amplitude"], base["tempo"])],
            "identity": [X[rows[q]] for q in src],
            "real": [hidden_X],
        }
        for name in candidates:
            clips[name] = candidate(name, X, mo, ch, cl, content, style, base)

        out = {}
        z_real = scaler.transform(stats(hidden_P)[None])[0]
        for step, lst in clips.items():
            acc = {k: [] for k in ("dtw", "jerk", "amp", "joint_time", *[f"z {g}" for g in _groups()])}
            pix = []
            for Xh in lst:
                C = joint_distance_matrix(Xh, hidden_X)
                D = dtw_accumulate(C)
                p = dtw_path(D)
                acc["dtw"].append(D[-1, -1] / len(p))
                A, B = Xh[p[:, 0]].reshape(-1, 17, 2), hidden_X[p[:, 1]].reshape(-1, 17, 2)
                err = np.linalg.norm(A - B, axis=-1)                                   # (L, 17)
                b = np.minimum((p[:, 1] * BINS) // len(hidden_X), BINS - 1)
                jt = np.stack([err[b == i].mean(axis=0) if (b == i).any() else np.full(17, np.nan)
                               for i in range(BINS)])                                 # (BINS, 17)
                acc["joint_time"].append(jt)
                acc["jerk"].append(ev.jerk(Xh) / max(jerk_real, 1e-12))
                acc["amp"].append(float(np.mean(Xh.std(axis=0)) / max(np.mean(hidden_X.std(axis=0)), 1e-12)))
                Q = hidden_P if step == "real" else unifier.inverse_transform(Xh, style)
                pix.append(Q)
                dz = scaler.transform(stats(Q)[None])[0] - z_real
                for g, sl in _groups().items():
                    acc[f"z {g}"].append(float(np.sqrt(np.mean(dz[sl] ** 2))))
            verdict = judges.score(pix, style, content)
            row = {k: float(np.mean(v)) for k, v in acc.items() if k != "joint_time"}
            row["joint_time"] = np.nanmean(np.stack(acc["joint_time"]), axis=0)
            for fam, (ok_s, ok_c) in verdict.items():
                row[f"style_{fam}"] = float(ok_s.mean())
                row[f"content_{fam}"] = float(ok_c.mean())
            out[step] = row
    return style, content, out, time.perf_counter() - t0


def candidate(name, X, mo, ch, cl, content, style, base):
    """Clips of a candidate fix: ``name`` is ``key=value`` StyleTranslator settings joined by
    ``+`` (e.g. ``smooth_order=2+smooth=20``), fitted on the cell's training clips and used like
    the default (consensus, amplitude restore, tempo)."""
    import ast

    from nnsf.factor.translate import StyleTranslator

    over = {}
    for part in name.split("+"):
        key, _, value = part.partition("=")
        if not value:
            raise ValueError(f"candidate {name!r}: expected key=value parts joined by '+'")
        try:
            over[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            over[key] = value
    t = StyleTranslator(**{**base, **over}).fit(X, mo, ch, cl)
    return [t.synthesize_cell(content, style)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--cells", type=int, default=15)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--candidates", default="", help="candidate fixes to measure too, comma-separated, each "
                    "key=value StyleTranslator settings joined by '+' (see candidate())")
    ap.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                    help="override a translation setting of params.yaml for the diagnosed steps "
                         "(e.g. --set smooth=5.0 --set smooth_order=1: the previous default)")
    ap.add_argument("--redraw", action="store_true", help="print the tables and redraw OUT.png from an existing OUT.json")
    a = ap.parse_args(argv)
    if a.redraw:
        from nnsf.io import read_json
        from nnsf.skeleton import JOINTS

        report = read_json(Path(a.out).with_suffix(".json"))
        # The writer sorts keys: back to the pipeline's order, candidates last.
        order = [k for k in STEPS if k in report["steps"]] + [k for k in report["steps"] if k not in STEPS]
        report["steps"] = {k: report["steps"][k] for k in order}
        jt = {s: np.array(v) / 100.0 for s, v in report["joint_time_pct_torso"].items()}
        _figure(Path(a.out).with_suffix(".png"), jt, report["steps"], JOINTS, report["translation"])
        print(markdown(report))
        return 0

    from nnsf.datasets import bvh_source
    from nnsf.evaluate.translation import _pick, grid_cells
    from nnsf.factor.style_model import translator_params
    from nnsf.io import write_json
    from nnsf.params import load, require
    from nnsf.datasets.stage import complete_grid as _complete_grid

    params = load(a.params)
    kw = {"fps": float(require(params, "dataset.bvh.fps")), "azimuth": float(require(params, "dataset.bvh.azimuth")),
          "elevation": float(require(params, "dataset.bvh.elevation")), "facing": require(params, "dataset.bvh.facing"),
          "center": bool(require(params, "dataset.bvh.center"))}
    table, _ = bvh_source.read_folder(a.data, **kw)
    table, _ = _complete_grid(table)
    tp = translator_params(params)
    tp.pop("random_state")
    import ast

    for item in a.set:
        key, _, value = item.partition("=")
        if key not in tp or not value:
            print(f"error: --set: expected KEY=VALUE with KEY one of {sorted(tp)}, got {item!r}", file=sys.stderr)
            return 2
        try:
            tp[key] = ast.literal_eval(value)
        except (ValueError, SyntaxError):
            tp[key] = value
    cands = [c for c in a.candidates.split(",") if c]
    cells = _pick(grid_cells(table), a.cells)
    jobs = [(table, s, c, tp, float(require(params, "unify.margin")), int(require(params, "seed")), cands)
            for s, c in cells]
    t0 = time.perf_counter()
    if a.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor
        os.environ.setdefault("OMP_NUM_THREADS", "1")
        with ProcessPoolExecutor(a.jobs) as pool:
            results = list(pool.map(diagnose_cell, jobs))
    else:
        results = [diagnose_cell(j) for j in jobs]
    wall = time.perf_counter() - t0
    steps = list(results[0][2])
    keys = [k for k in results[0][2][steps[0]] if k != "joint_time"]
    summary = {s: {k: float(np.mean([r[2][s][k] for r in results])) for k in keys} for s in steps}
    joint_time = {s: np.nanmean(np.stack([r[2][s]["joint_time"] for r in results]), axis=0) for s in steps}
    from nnsf.skeleton import JOINTS

    report = {
        "data": Path(a.data).name, "cells": [f"{s}/{c}" for s, c, *_ in results], "translation": tp,
        "seconds_wall": wall, "steps": summary,
        "per_joint_error_pct_torso": {s: dict(zip(JOINTS, (100 * np.nanmean(jt, axis=0)).tolist()))
                                      for s, jt in joint_time.items()},
        "error_over_time_pct_torso": {s: (100 * np.nanmean(jt, axis=1)).tolist() for s, jt in joint_time.items()},
        "joint_time_pct_torso": {s: (100 * jt).tolist() for s, jt in joint_time.items()},
    }
    out = Path(a.out)
    write_json(out.with_suffix(".json"), report)
    _figure(out.with_suffix(".png"), joint_time, summary, JOINTS, tp)
    print(markdown(report))
    print(f"{len(results)} cells in {wall:.0f} s wall ({a.jobs} processes)")
    return 0


def markdown(report) -> str:
    fams = ("lr", "nn1", "angles", "all")
    g = list(_groups())
    head = ("| step | DTW % torso | jerk ratio | amplitude ratio | " + " | ".join(f"style {f} | content {f}" for f in fams)
            + " | " + " | ".join(f"z {x}" for x in g) + " |")
    lines = [head, "|---" + "|---:" * (3 + 2 * len(fams) + len(g)) + "|"]
    for s, v in report["steps"].items():
        cells = [f"{100 * v['dtw']:.1f}", f"{v['jerk']:.2f}", f"{v['amp']:.2f}"]
        cells += [f"{v[f'{w}_{f}']:.2f}" for f in fams for w in ("style", "content")]
        cells += [f"{v[f'z {x}']:.2f}" for x in g]
        lines.append(f"| {s} | " + " | ".join(cells) + " |")
    j = report["per_joint_error_pct_torso"]
    worst = sorted(j["+tempo"], key=lambda k: -j["+tempo"][k])[:6]
    lines.append("")
    lines.append("Per-joint DTW error of the default (+tempo), % torso, worst six: " +
                 ", ".join(f"{k} {j['+tempo'][k]:.1f}" for k in worst))
    lines.append("Error over the hidden clip's time (10 bins), default: " +
                 " ".join(f"{x:.1f}" for x in report["error_over_time_pct_torso"]["+tempo"]))
    return "\n".join(lines)


def _figure(path, joint_time, summary, joints, tp):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from nnsf.io import atomic_path

    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), gridspec_kw={"width_ratios": [1, 1.3]})
    jt = 100 * joint_time["+tempo"].T                                     # (17, BINS)
    im = axes[0].imshow(jt, aspect="auto", cmap="magma", origin="upper",
                        extent=(0, 1, len(joints) - 0.5, -0.5))
    axes[0].set_yticks(range(len(joints)), joints, fontsize=8)
    axes[0].set_xlabel("hidden clip's normalised time")
    order = tp.get("smooth_order", 1)
    axes[0].set_title(f"+tempo (nnsf, smooth {tp['smooth']:g}, order {order}): per-joint DTW error, % torso",
                      fontsize=9)
    fig.colorbar(im, ax=axes[0], fraction=0.05)
    groups = list(_groups())
    steps = list(summary)
    w = 0.8 / len(steps)
    for i, s in enumerate(steps):
        axes[1].bar(np.arange(len(groups)) + i * w, [summary[s][f"z {g}"] for g in groups], w, label=s)
    axes[1].set_xticks(np.arange(len(groups)) + 0.4 - w / 2, groups, rotation=20, fontsize=8)
    axes[1].set_ylabel("RMS standardised distance to the hidden clip")
    axes[1].set_title("judges' statistics: synthesis vs hidden real clip")
    axes[1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
