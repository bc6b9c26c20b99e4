"""Time contour tracking of one 48-frame 256×256 clip between two keyframes.

The clip is rendered by :func:`nnsf.frames.render.render_clip` (character
"bruno", walk; keyframes at frames 0 and 47 only, so all 46 in-between
frames of every side curve are unknowns: 8 limbs + torso + head = 20 curves
of 5 control points).  In the same run it times

* **ours**     — space-time LM solve with sketch term and colour penalty;
* **agarwala** — the same solver without sketch term and colour penalty;
* **lk**       — per-frame pyramidal Lucas-Kanade on the control points;

as seconds per clip (best of ``--repeat``) and frames per second, prints
the point-to-curve error of each against the ground truth, and a cProfile
summary of one "ours" run (where the time goes).  BLAS threads are pinned
to 1; the solver itself is single-threaded numpy.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking.py [--repeat 2] [--frames 48]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from nnsf.frames.annotation import read_annotation  # noqa: E402
from nnsf.frames.clips import read_clip  # noqa: E402
from nnsf.frames.render import render_clip  # noqa: E402
from nnsf.io import read_npz  # noqa: E402
from nnsf.track.metrics import curve_errors, error_summary  # noqa: E402
from nnsf.track.solve import keyframe_curves, track_clip  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--character", default="bruno")
    ap.add_argument("--motion", default="walk")
    args = ap.parse_args()

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "clip"
        render_clip(folder, args.character, args.motion, args.frames, size=args.size,
                    keyframe_every=0)
        ann = read_annotation(folder / "annotation.json")
        frames = read_clip(folder, ann)
        truth = read_npz(folder / "truth.npz")
    names, _ = keyframe_curves(ann)
    side = [str(n) for n in truth["side_names"]]
    true_sides = truth["sides"][:, [side.index(n) for n in names]]
    inb = np.ones(len(frames), bool)
    inb[ann.keyframe_indices] = False
    print(f"clip: {args.character}-{args.motion}, {len(frames)} frames {args.size}x{args.size}, "
          f"keyframes {ann.keyframe_indices}, {len(names)} curves x "
          f"{len(ann.keyframes[0].curves[names[0]])} control points, "
          f"{int(inb.sum())} in-between frames")
    print(f"{'tracker':<10} {'s/clip':>8} {'frames/s':>9} {'mean px':>8} {'p95 px':>8}")
    for method in ("ours", "agarwala", "lk"):
        best = np.inf
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = track_clip(frames, ann, method)
            best = min(best, time.perf_counter() - t0)
        err = error_summary(curve_errors(out[inb], true_sides[inb]))
        print(f"{method:<10} {best:8.2f} {len(frames) / best:9.1f} {err['mean_px']:8.2f} "
              f"{err['p95_px']:8.2f}")
    prof = cProfile.Profile()
    prof.enable()
    track_clip(frames, ann, "ours")
    prof.disable()
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(12)
    print("\ncProfile of one 'ours' run (top 12 by own time):")
    print("\n".join(line for line in buf.getvalue().splitlines()[6:] if line.strip()))


if __name__ == "__main__":
    main()
