"""Time the deformation of one frame: subkey tracking plus both ARAP steps, against dense solves.

For a character's mesh of about 800 and about 3,000 vertices, in the same run:

* **step** — one frame through :class:`nnsf.reshape.deform.Deformer`: the handle targets (the
  subkeys' Eq. 12-14), then right-hand sides and back-solves against the two sparse factors computed
  once when the deformer was built;
* **clip** — :meth:`nnsf.reshape.deform.Deformer.run` on the whole clip at once (every frame's
  right-hand sides in one solve);
* **naive** — what the prefactorised path avoids, frame by frame: assemble the same two
  least-squares systems as dense matrices, form the normal equations and ``np.linalg.solve`` them.

The character is AnimatedDrawings' char1 when ``../shared/data`` holds it, otherwise the built-in
stick figure; the clip swings one arm and one leg.  Times are the median over frames of the fastest
of ``--repeat`` runs.

    .venv/bin/python benchmarks/bench_arap.py [--frames 200] [--repeat 3] [--naive-frames 2]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from nnsf.reshape.animator import Animator
from nnsf.reshape.formats import read_character
from nnsf.skeleton import JOINT_INDEX as J

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))   # the tests' stick figure
from stick_figure import stick_figure

DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters" / "char1"


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (p - c) @ R.T + c


def clip(kp: np.ndarray, frames: int) -> np.ndarray:
    """Key points ``(frames, 17, 2)``: an arm waves by ±35°, a leg swings by ±20°."""
    out = np.repeat(kp[None], frames, 0)
    arm, leg = [J["l_elbow"], J["l_wrist"]], [J["r_knee"], J["r_ankle"]]
    for t in range(frames):
        s = np.sin(2 * np.pi * t / 48)
        out[t, arm] = _rot(kp[arm], kp[J["l_shoulder"]], -35 * s)
        out[t, leg] = _rot(kp[leg], kp[J["r_hip"]], 20 * s)
    return out


def naive_frame(arap, targets: np.ndarray) -> np.ndarray:
    """One frame the slow way: dense assembly and dense solves of both steps."""
    M1, r1 = arap.similarity_system(targets)
    A = M1.toarray()
    z = np.linalg.solve(A.T @ A, A.T @ r1)
    n = arap.n_vertices
    v1 = np.column_stack([z[:n], z[n:]])
    M2, R2 = arap.scale_system(v1, targets)
    B = M2.toarray()
    return np.linalg.solve(B.T @ B, B.T @ R2)


def per_frame_step(deformer, kp: np.ndarray, repeat: int) -> float:
    """One frame at a time: its targets (subkeys tracked from the previous frame) and both steps."""
    best = None
    for _ in range(repeat):
        deformer.tracker.reset()
        times = np.empty(len(kp))
        for t in range(len(kp)):
            t0 = time.perf_counter()
            g = np.concatenate([deformer.rig.full_keypoints(kp[t:t + 1])[0], deformer.tracker.step(kp[t])])
            deformer.arap.deform(g)
            times[t] = time.perf_counter() - t0
        best = times if best is None else np.minimum(best, times)
    return float(np.median(best))


def per_frame_clip(deformer, kp: np.ndarray, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        deformer.run(kp)
        best = min(best, time.perf_counter() - t0)
    return best / len(kp)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--naive-frames", type=int, default=2,
                    help="frames timed for the dense baseline (0: skip it)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[800, 3000])
    args = ap.parse_args(argv)
    if args.naive_frames < 0:
        ap.error("--naive-frames: expected 0 or more")
    if DATA.is_dir():
        ch, what = read_character(DATA), "char1 (AnimatedDrawings)"
    else:
        ch, what = stick_figure(height=600), "stick figure (char1 not found)"
    kp = clip(ch.keypoints, args.frames)
    print(f"character: {what}; {args.frames} frames; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores; float64")
    print(f"{'vertices':>8} {'triangles':>9} {'handles':>7} {'build ms':>9} {'step ms':>8} "
          f"{'clip ms':>8} {'naive ms':>9} {'naive/step':>10} {'max |diff| px':>13}")
    for n in args.sizes:
        t0 = time.perf_counter()
        a = Animator(ch, n_vertices=n)
        build = time.perf_counter() - t0
        d = a.deformer
        step = per_frame_step(d, kp, args.repeat)
        whole = per_frame_clip(d, kp, args.repeat)
        naive_col, ratio_col, diff_col = f"{'-':>9}", f"{'-':>10}", f"{'-':>13}"
        if args.naive_frames > 0:
            targets = d.targets(kp[: args.naive_frames])
            fast = d.arap.deform(targets)
            naive_t = []
            for f in range(args.naive_frames):
                t0 = time.perf_counter()
                slow = naive_frame(d.arap, targets[f])
                naive_t.append(time.perf_counter() - t0)
            naive = float(np.median(naive_t))
            diff = float(np.abs(slow - fast[-1]).max())
            naive_col, ratio_col, diff_col = f"{naive * 1e3:>9.1f}", f"{naive / step:>10.0f}", f"{diff:>13.2e}"
        print(f"{a.mesh.n_vertices:>8} {len(a.mesh.triangles):>9} {len(d.handles):>7} "
              f"{build * 1e3:>9.1f} {step * 1e3:>8.3f} {whole * 1e3:>8.3f} {naive_col} {ratio_col} {diff_col}", flush=True)


if __name__ == "__main__":
    main()
