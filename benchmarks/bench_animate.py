"""End to end `nnsf animate`: a 10 s BVH clip at 30 fps onto a 512 px drawing, time per part.

The drawing is AnimatedDrawings' char1 scaled so its longer side is 512 px
and centred on a 512 x 512 page (the built-in stick figure at 512 px when
``../shared/data`` is absent); the
motion is the first 10 s of a Bandai-Namco walk (a synthetic 300-frame walk
when absent), projected in the ``auto`` view and translated into a style of a
model fitted on the embedded synthetic set (a small fit, not timed).  Parts:
load (character + BVH + projection), translate, mesh (parts, mesh, deformer), retarget, deform
(ARAP of every frame), render (the MP4 is encoded on a thread meanwhile, so its CPU column
counts the encoder's work too), encode (what the encoder has left after the last frame, and the
check that decodes the file back).  Prints the fastest of ``--repeat`` runs per part and the
total; target: 5 s for the 300 frames on 2 cores.

``--baseline DIR`` (a checkout of the project before the pipeline was rewritten) runs that
checkout's own copy of this benchmark in a subprocess, in the same run, and prints its totals and
the ratio: the peer.  The load average is printed with every timing (the machine is shared).

    .venv/bin/python benchmarks/bench_animate.py [--repeat 2] [--vertices 800] [--seconds 10] [--baseline DIR]
"""
from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def _character(folder: Path):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))   # the tests' stick figure
    from stick_figure import stick_figure
    from nnsf.reshape.character import Character
    from nnsf.reshape.formats import read_character

    src = DATA / "animated-drawings" / "characters" / "char1"
    if not src.is_dir():
        return stick_figure(height=512), "stick figure (512 px)"
    ch = read_character(src)
    s = 512.0 / max(ch.shape)
    size = (int(round(ch.shape[1] * s)), int(round(ch.shape[0] * s)))
    tex = cv2.resize(ch.texture, size, interpolation=cv2.INTER_AREA)
    mask = cv2.resize(ch.mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    # Centred on a 512 x 512 page (transparent margins): a 512² drawing.
    py, px = (512 - size[1]) // 2, (512 - size[0]) // 2
    page = np.zeros((512, 512, 4), np.uint8)
    page[py:py + size[1], px:px + size[0]] = tex
    page_mask = np.zeros((512, 512), bool)
    page_mask[py:py + size[1], px:px + size[0]] = mask
    page[~page_mask, 3] = 0
    return Character(name="char1", texture=page, mask=page_mask, keypoints=ch.keypoints * s + [px, py],
                     source=str(src)), f"char1 scaled to {size[0]}x{size[1]} px on a 512x512 page"


def _timed(args, n, fps, model, bvh, tmp, workers):
    """Fastest of ``args.repeat`` runs per part: (wall, CPU, last result, MP4 frames, motion, character)."""
    from nnsf.animate.animation import Motion, animate_files, read_motion_spec
    from nnsf.datasets import synthetic

    best: dict[str, float] = {}
    best_cpu: dict[str, float] = {}
    for _ in range(args.repeat):
        t, c = time.perf_counter(), time.process_time()
        if bvh.is_file():
            motion = read_motion_spec(bvh, view="auto", fps=fps)
            what = f"{bvh.name}, view {motion.view}"
            if len(motion.points) < n:  # loop the clip to the requested length
                k = -(-n // len(motion.points))
                motion.points = np.concatenate([motion.points] * k)[:n]
                motion.depth = np.concatenate([motion.depth] * k)[:n]
        else:
            motion = Motion("walk", synthetic.clip_points("max", "walk", n), fps)
            what = "synthetic walk"
        motion.points, motion.depth = motion.points[:n], None if motion.depth is None else motion.depth[:n]
        ch, ch_what = _character(tmp)
        load, load_cpu = time.perf_counter() - t, time.process_time() - c
        res = animate_files(ch, motion, style="olga", model=model, out=tmp / "a.mp4", workers=workers,
                            n_vertices=args.vertices, progress=False, outputs={"mp4": tmp / "a.mp4"})
        res.seconds["load"] += load
        res.seconds["total"] += load
        res.cpu_seconds["load"] += load_cpu
        res.cpu_seconds["total"] += load_cpu
        for k, v in res.seconds.items():
            best[k] = min(best.get(k, np.inf), v)
            best_cpu[k] = min(best_cpu.get(k, np.inf), res.cpu_seconds[k])
    cap = cv2.VideoCapture(str(tmp / "a.mp4"))
    frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    cap.release()
    return best, best_cpu, res, frames, what, ch_what


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--vertices", type=int, default=800)
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--workers", type=int, nargs="+", default=[1, 2],
                    help="render processes; each count is timed in the same run")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a checkout of the previous pipeline: its benchmark is run too, in the same run")
    args = ap.parse_args(argv)

    from nnsf.datasets import contract, synthetic
    from nnsf.factor.style_model import StyleModel, fit_model, unify_table

    fps = 30.0
    n = int(round(args.seconds * fps))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        raw = contract.validate(synthetic.generate(characters=4, clips_per_cell=1, frames=24, seed=0), "syn")
        table, unifier = unify_table(raw, 0.5)
        fit_model([(None, table, unifier)], dict(n_components=8, max_iter=60, align_iter=40), tmp / "m.npz")
        model = StyleModel.load(tmp / "m.npz")
        bvh = DATA / "bandai-namco-1" / "data" / "dataset-1_walk_normal_001.bvh"
        for workers in args.workers:
            best, best_cpu, res, frames, what, ch_what = _timed(args, n, fps, model, bvh, tmp, workers)
            print(f"bench_animate: {res.frames} frames ({args.seconds:g} s at {fps:g} fps) of {what} onto {ch_what}, "
                  f"{args.vertices} vertices requested, {workers} render process(es); {os.cpu_count()} cores, "
                  f"load average {os.getloadavg()[0]:.1f}; fastest of {args.repeat}")
            print("  part       wall s  ms/frame   CPU s (this process; wall - CPU is time waiting for a core)")
            for k in ("load", "translate", "mesh", "retarget", "deform", "render", "encode", "total"):
                if k in best:
                    print(f"  {k:9s} {best[k]:7.2f}  {1000 * best[k] / res.frames:7.1f}   {best_cpu[k]:7.2f}")
            print(f"  target: 5 s wall for the {res.frames} frames; the MP4 holds {frames} frames")
            if args.baseline is not None:
                env = dict(os.environ, PYTHONPATH=str(args.baseline))
                out = subprocess.run([sys.executable, str(args.baseline / "benchmarks" / "bench_animate.py"),
                                      "--repeat", str(args.repeat), "--workers", str(workers),
                                      "--seconds", str(args.seconds), "--vertices", str(args.vertices)],
                                     env=env, capture_output=True, text=True, cwd=args.baseline)
                totals = re.findall(r"^\s+total\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)", out.stdout, re.M)
                renders = re.findall(r"^\s+render\s+([\d.]+)\s+([\d.]+)", out.stdout, re.M)
                if not totals:
                    print("  peer: failed:", (out.stderr or out.stdout).strip().splitlines()[-1:])
                    continue
                t_old, r_old = float(totals[-1][0]), float(renders[-1][1])
                print(f"  peer ({args.baseline}, its own benchmark, {workers} render process(es), load average "
                      f"{os.getloadavg()[0]:.1f}): total {t_old:.2f} s, render {r_old:.1f} ms/frame; "
                      f"ratio peer / ours: total {t_old / best['total']:.2f}, "
                      f"render {r_old / (1000 * best['render'] / res.frames):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
