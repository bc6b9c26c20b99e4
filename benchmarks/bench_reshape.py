"""Time the reshaping per frame: deformation and rendering, against the previous renderer.

In one run, on AnimatedDrawings' char1 scaled into a 512 x 512 page when ``../shared/data`` holds
it (else the built-in stick figure at 512 px), driven by 120 frames of a Bandai-Namco walk (else a
synthetic walk):

* **ours**: :class:`nnsf.reshape.animator.Animator` (one connected mesh, subkeys, two-step ARAP)
  and :class:`nnsf.reshape.render.Renderer`, per frame;
* **the peer** (``--baseline DIR``, a checkout of the project before the pipeline was rewritten,
  e.g. ``git worktree add /tmp/base <commit>``): its layered "paper puppet" rig and its renderer
  with the seal and outline redraw, the same character and motion, run in a subprocess on that
  checkout's code;
* **scaling**: ours at the drawing's 0.5, 1 and 2 times size (a quarter, one and four times the
  pixels): time per frame and per megapixel of page.

Times are medians over frames (wall) and CPU time per frame; ratios are peer / ours.  The load
average is printed with them (the machine is shared).  Target: render at most 8 ms per frame at
512 x 512.

    .venv/bin/python benchmarks/bench_reshape.py [--baseline /tmp/base] [--frames 120]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
PAGE = 512


def page_character(scale: float = 1.0):
    """char1 (or the stick figure) scaled so its longer side is ``scale`` × 512 px, on a square page."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))   # the tests' stick figure
    from stick_figure import stick_figure
    from nnsf.reshape.character import Character
    from nnsf.reshape.formats import read_character

    side = int(round(PAGE * scale))
    src = DATA / "animated-drawings" / "characters" / "char1"
    if not src.is_dir():
        ch = stick_figure(height=side)
        return ch, f"stick figure ({side} px)"
    ch = read_character(src)
    s = side / max(ch.shape)
    size = (int(round(ch.shape[1] * s)), int(round(ch.shape[0] * s)))
    tex = cv2.resize(ch.texture, size, interpolation=cv2.INTER_AREA)
    mask = cv2.resize(ch.mask.astype(np.uint8), size, interpolation=cv2.INTER_NEAREST) > 0
    py, px = (side - size[1]) // 2, (side - size[0]) // 2
    page = np.zeros((side, side, 4), np.uint8)
    page[py:py + size[1], px:px + size[0]] = tex
    pm = np.zeros((side, side), bool)
    pm[py:py + size[1], px:px + size[0]] = mask
    page[~pm, 3] = 0
    return Character("char1", page, pm, ch.keypoints * s + [px, py], source=str(src)), \
        f"char1 scaled to {size[0]}x{size[1]} px on a {side}x{side} page"


def motion(frames: int):
    bvh = DATA / "bandai-namco-1" / "data" / "dataset-1_walk_normal_001.bvh"
    if bvh.is_file():
        from nnsf.datasets.views import load_clip_in_view

        clip, _ = load_clip_in_view(bvh, "auto", 30.0)
        return clip.points[:frames], clip.depth[:frames], bvh.name
    from nnsf.datasets import synthetic

    return synthetic.clip_points("max", "walk", frames), None, "synthetic walk"


def ours(frames: int, scale: float = 1.0) -> dict:
    from nnsf.reshape.animator import Animator

    ch, what = page_character(scale)
    pts, depth, mname = motion(frames)
    a = Animator(ch)
    t = time.perf_counter()
    anim = a.animate(pts, depth)
    deform = (time.perf_counter() - t) / len(pts)
    r = a.renderer(ch.shape)
    wall, c0 = [], time.process_time()
    for v, o in zip(anim.frames, anim.orders):
        t = time.perf_counter()
        r.render(v, o, (255, 255, 255))
        wall.append(time.perf_counter() - t)
    return {"render_ms": 1000 * float(np.median(wall)), "render_cpu_ms": 1000 * (time.process_time() - c0) / len(wall),
            "deform_ms": 1000 * deform, "vertices": a.mesh.n_vertices, "pixels": ch.shape[0] * ch.shape[1],
            "character": what, "motion": mname}


#: The peer's per-frame loop, run on the baseline checkout's code (its own API).
PEER = r"""
import json, sys, time
import numpy as np
sys.path.insert(0, sys.argv[1])
from bench_reshape import page_character, motion
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import animate, build_rig
frames = int(sys.argv[2])
ch, what = page_character()
pts, depth, mname = motion(frames)
rig = build_rig(ch)
t = time.perf_counter()
anim = animate(rig, pts, depth)
deform = (time.perf_counter() - t) / len(pts)
r = MeshRenderer.for_mesh(rig.mesh, ch, size=ch.shape)
wall, c0 = [], time.process_time()
for v, o in zip(anim.frames, anim.orders):
    t = time.perf_counter()
    r.render(v, o, background=(255, 255, 255))
    wall.append(time.perf_counter() - t)
print(json.dumps({"render_ms": 1000 * float(np.median(wall)), "render_cpu_ms": 1000 * (time.process_time() - c0) / len(wall),
                  "deform_ms": 1000 * deform, "vertices": int(rig.mesh.n_vertices)}))
"""


def peer(baseline: Path, frames: int) -> dict:
    env = dict(os.environ, PYTHONPATH=str(baseline), OMP_NUM_THREADS="1")
    out = subprocess.run([sys.executable, "-c", PEER, str(Path(__file__).parent), str(frames)], env=env,
                         capture_output=True, text=True, check=True, cwd=baseline)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", type=Path, default=None, help="a checkout of the previous pipeline")
    ap.add_argument("--frames", type=int, default=120)
    a = ap.parse_args(argv)
    new = ours(a.frames)
    print(f"bench_reshape: {a.frames} frames of {new['motion']} onto {new['character']}; {os.cpu_count()} cores, "
          f"load average {os.getloadavg()[0]:.1f}")
    print(f"  ours: render {new['render_ms']:.2f} ms/frame (median wall), {new['render_cpu_ms']:.2f} ms CPU; "
          f"deform {new['deform_ms']:.2f} ms/frame; {new['vertices']} vertices")
    if a.baseline is not None:
        old = peer(a.baseline, a.frames)
        print(f"  peer: render {old['render_ms']:.2f} ms/frame (median wall), {old['render_cpu_ms']:.2f} ms CPU; "
              f"deform {old['deform_ms']:.2f} ms/frame; {old['vertices']} vertices; load average "
              f"{os.getloadavg()[0]:.1f}")
        print(f"  ratio peer / ours: render {old['render_ms'] / new['render_ms']:.2f} (wall), "
              f"{old['render_cpu_ms'] / new['render_cpu_ms']:.2f} (CPU)")
    for s in (0.5, 1.0, 2.0):
        r = ours(min(a.frames, 60), s)
        print(f"  scale {s:g}: {r['pixels'] / 1e6:.2f} MP page, render {r['render_ms']:.2f} ms/frame wall, "
              f"{r['render_cpu_ms']:.2f} ms CPU, {r['render_cpu_ms'] / (r['pixels'] / 1e6):.1f} ms CPU per megapixel")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
