"""Time contour tracking of one 48-frame 256×256 clip between two keyframes.

The clip is rendered by :func:`nnsf.frames.render.render_clip` (character
"bruno", walk; keyframes at frames 0 and 47 only, so all 46 in-between
frames of every side curve are unknowns: 8 limbs + torso + head = 20 curves
of 5 control points).  The trackers run with the options the pipeline runs:
the ``track`` section of ``--params`` (default params.yaml, read as the
``track`` stage reads it), so "ours" starts from ``init: limb``.  In the
same run it times

* **ours**     — limb start, then the space-time LM solve with sketch term and colour penalty;
* **ours, snap profile / snap edge** — "ours" ended by the snap (``snap: 2``
  to the keyframes' colour profile; ``snap: 3`` to the strongest colour edge),
  the options for flat-colour art (docs/results.md, tracking);
* **ours, init linear** — the same solver from linear interpolation (the
  library's default options, what this benchmark timed before the flow starts);
* **agarwala** — the same solver without sketch term and colour penalty (dense-flow start);
* **lk**       — per-frame pyramidal Lucas-Kanade on the control points;

as wall seconds per clip (best of ``--repeat``), the process's CPU seconds
(which a busy machine inflates much less than the wall time) and frames per
second, prints
the point-to-curve error of each against the ground truth and the key-point
PCK at 0.05 × torso, and a cProfile summary of one "ours" run (where the
time goes).  BLAS threads are pinned to 1; the solver itself is
single-threaded numpy.  The target is 10 s per clip for "ours".

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
from nnsf.roto.keypoints import fit_keypoint_model, keypoints_from_curves  # noqa: E402
from nnsf.params import load  # noqa: E402
from nnsf.skeleton import JOINT_INDEX  # noqa: E402
from nnsf.roto.metrics import curve_errors, error_summary, pck  # noqa: E402
from nnsf.roto.solve import keyframe_curves, track_clip  # noqa: E402
from nnsf.roto.options import track_options  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=48)
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--character", default="bruno")
    ap.add_argument("--motion", default="walk")
    ap.add_argument("--params", default="params.yaml")
    args = ap.parse_args()
    options = track_options(load(args.params))

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
    model = fit_keypoint_model(ann)
    tk = truth["keypoints"]
    torso = np.linalg.norm(tk[:, JOINT_INDEX["thorax"]] - tk[:, JOINT_INDEX["pelvis"]], axis=-1)
    print(f"options (--params {args.params}): init {options['init']}, w_slide {options['slide']:g}, "
          f"edge_gate {options['edge_gate']:g}")
    print(f"{'tracker':<20} {'s/clip':>8} {'CPU s':>7} {'frames/s':>9} {'mean px':>8} {'p95 px':>8} "
          f"{'PCK':>6}")
    # the snap options (docs/method.md §2.3) timed on the same clip: their cost over plain "ours"
    runs = (("ours", "ours", options),
            ("ours, snap profile", "ours", {**options, "snap": 2.0, "snap_to": "profile"}),
            ("ours, snap edge", "ours", {**options, "snap": 3.0, "snap_to": "edge"}),
            ("ours, init linear", "ours", {}),
            ("agarwala", "agarwala", options), ("lk", "lk", options))
    for label, method, opts in runs:
        best = cpu = np.inf
        for _ in range(args.repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            out = track_clip(frames, ann, method, **opts)
            best = min(best, time.perf_counter() - t0)
            cpu = min(cpu, time.process_time() - c0)
        err = error_summary(curve_errors(out[inb], true_sides[inb]))
        kp = keypoints_from_curves(out, names, model)
        score = pck(kp[inb], tk[inb], torso[inb], 0.05)
        print(f"{label:<20} {best:8.2f} {cpu:7.2f} {len(frames) / best:9.1f} {err['mean_px']:8.2f} "
              f"{err['p95_px']:8.2f} {score:6.3f}")
    prof = cProfile.Profile()
    prof.enable()
    track_clip(frames, ann, "ours", **options)
    prof.disable()
    buf = io.StringIO()
    pstats.Stats(prof, stream=buf).sort_stats("tottime").print_stats(12)
    print("\ncProfile of one 'ours' run (top 12 by own time):")
    print("\n".join(line for line in buf.getvalue().splitlines()[6:] if line.strip()))


if __name__ == "__main__":
    main()
