"""Time one frame of reshaping: subkey update plus both ARAP steps.

For a mesh of about 800 and about 3,000 vertices, in the same run:

* **prefactorised** — :meth:`nnsf.reshape.Rig.step`: Eq. 12-14 for the
  subkeys, then right-hand sides and back-solves against the two sparse LU
  factors computed once when the rig was built;
* **clip** — :meth:`nnsf.reshape.Rig.animate` on the whole clip at once
  (subkeys frame by frame, every frame's right-hand sides in one solve);
* **naive** — what the prefactorised path avoids, frame by frame: assemble
  the same two least-squares systems as dense matrices, form the normal
  equations and ``np.linalg.solve`` them (float64).

The character is AnimatedDrawings' char1 when ``../shared/data`` holds it,
otherwise the built-in stick figure; the clip swings one arm and one leg.
Times are the median over frames of the fastest of ``--repeat`` runs.  Both
the connected mesh and the stage's default layered mesh are timed (``--meshes``);
a layered frame includes moving its joint tabs with their bones.  The vertex
count printed is the mesh's; ``solved`` is what the ARAP solves for (a layered
mesh adds its joint tabs' vertices, which follow their bones).

``--parts`` adds where a streamed frame's time goes: the handle targets
(driving the key points, the subkeys' Eq. 12-14), ARAP step 1, step 2 and
the joint tabs, each timed on its own.

    .venv/bin/python benchmarks/bench_arap.py [--frames 200] [--repeat 3] [--naive-frames 2] [--parts]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from nnsf.reshape import Rig, load_animated_drawings, stick_figure
from nnsf.skeleton import JOINT_INDEX as J

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


def naive_frame(rig: Rig, targets: np.ndarray) -> np.ndarray:
    """One frame the slow way: dense assembly and dense solves of both steps."""
    d = rig.deformer
    M1, r1 = d.similarity_system(targets)
    A = M1.toarray()
    z = np.linalg.solve(A.T @ A, A.T @ r1)
    n = d.n_vertices
    v1 = np.column_stack([z[:n], z[n:]])
    M2, R2 = d.scale_system(v1, targets)
    B = M2.toarray()
    return np.linalg.solve(B.T @ B, B.T @ R2)


def per_frame_stream(rig: Rig, kp: np.ndarray, repeat: int) -> float:
    best = None
    for _ in range(repeat):
        rig.reset()
        times = np.empty(len(kp))
        for t in range(len(kp)):
            t0 = time.perf_counter()
            rig.step(kp[t])
            times[t] = time.perf_counter() - t0
        best = times if best is None else np.minimum(best, times)
    return float(np.median(best))


def per_frame_parts(rig: Rig, kp: np.ndarray, repeat: int) -> dict[str, float]:
    """Where a streamed frame's time goes: the handle targets (driving the key points and the
    subkeys' Eq. 12-14), ARAP step 1, step 2, and moving the joint tabs; ms, median over frames of
    the fastest of ``repeat`` runs (each part timed on its own, so they add up to about a step)."""
    d = rig.deformer
    names = ("targets", "step 1", "step 2", "tabs")
    best = np.full((len(names), len(kp)), np.inf)
    for _ in range(repeat):
        rig.reset()
        for t in range(len(kp)):
            t0 = time.perf_counter()
            k = rig.drive(kp[t])
            g = k[rig.handle_keypoints]
            if rig.tracker is not None:
                g = np.concatenate([g, rig.tracker.step(k)])
            t1 = time.perf_counter()
            v1 = d.similarity_step(g)
            t2 = time.perf_counter()
            v2 = d.scale_step(v1, g)
            t3 = time.perf_counter()
            rig._with_tabs(v2[None], k[None])
            t4 = time.perf_counter()
            best[:, t] = np.minimum(best[:, t], [t1 - t0, t2 - t1, t3 - t2, t4 - t3])
    return dict(zip(names, np.median(best, axis=1) * 1e3))


def per_frame_clip(rig: Rig, kp: np.ndarray, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        rig.animate(kp)
        best = min(best, time.perf_counter() - t0)
    return best / len(kp)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--naive-frames", type=int, default=2,
                    help="frames timed for the dense baseline (0: skip it)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[800, 3000])
    ap.add_argument("--parts", action="store_true",
                    help="also print where a streamed frame's time goes (targets, step 1, step 2, tabs)")
    ap.add_argument("--meshes", nargs="+", default=["connected", "layered"], choices=["connected", "layered", "limbs"],
                    help="mesh kinds (layered: the stage's default, rigid segments plus joint tabs)")
    args = ap.parse_args(argv)
    if args.naive_frames < 0:
        ap.error("--naive-frames: expected 0 or more")
    if DATA.is_dir():
        ch, what = load_animated_drawings(DATA), "char1 (AnimatedDrawings)"
    else:
        ch, what = stick_figure(height=600), "stick figure (char1 not found)"
    kp = clip(ch.keypoints, args.frames)
    print(f"character: {what}; {args.frames} frames; load average {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores; float64")
    print(f"{'mesh':>9} {'vertices':>8} {'solved':>6} {'triangles':>9} {'handles':>7} {'build ms':>9} {'step ms':>8} "
          f"{'clip ms':>8} {'naive ms':>9} {'naive/step':>10} {'max |diff| px':>13}")
    parts = []
    for kind in args.meshes:
        for n in args.sizes:
            t0 = time.perf_counter()
            rig = Rig.build(ch, n_vertices=n, split=False if kind == "connected" else kind,
                            propagation="limb-frame")
            build = time.perf_counter() - t0
            step = per_frame_stream(rig, kp, args.repeat)
            whole = per_frame_clip(rig, kp, args.repeat)
            naive_col, ratio_col, diff_col = f"{'-':>9}", f"{'-':>10}", f"{'-':>13}"
            if args.naive_frames > 0:
                targets = rig.targets(kp[: args.naive_frames])
                fast = rig.deformer.deform(targets)
                naive_t = []
                for f in range(args.naive_frames):
                    t0 = time.perf_counter()
                    slow = naive_frame(rig, targets[f])
                    naive_t.append(time.perf_counter() - t0)
                naive = float(np.median(naive_t))
                diff = float(np.abs(slow - fast[-1]).max())
                naive_col, ratio_col, diff_col = f"{naive * 1e3:>9.1f}", f"{naive / step:>10.0f}", f"{diff:>13.2e}"
            print(f"{kind:>9} {rig.mesh.n_vertices:>8} {rig.mesh.core:>6} {len(rig.mesh.triangles):>9} {len(rig.handles):>7} "
                  f"{build * 1e3:>9.1f} {step * 1e3:>8.3f} {whole * 1e3:>8.3f} {naive_col} {ratio_col} {diff_col}", flush=True)
            if args.parts:
                parts.append((kind, rig.mesh.core, per_frame_parts(rig, kp, args.repeat)))
    if parts:
        names = list(parts[0][2])
        print("\nwhere a streamed frame's time goes (ms, each part timed alone):")
        print(f"{'mesh':>9} {'solved':>6} " + " ".join(f"{k:>8}" for k in names))
        for kind, solved, p in parts:
            print(f"{kind:>9} {solved:>6} " + " ".join(f"{p[k]:>8.3f}" for k in names))


if __name__ == "__main__":
    main()
