"""Per-frame cost of the render-time seal (nnsf.reshape.seal) and of the artefact measures.

Renders char1 kicking (layered mesh, subkeys) with and without the seal and
prints milliseconds per frame; needs ../shared/data.  Run:
``python benchmarks/bench_seal.py``.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from nnsf.datasets.bvh_source import load_clip
from nnsf.reshape.artefacts import frame_artefacts, ink_threshold
from nnsf.reshape.character import load_animated_drawings
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import animate, build_rig, canvas

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def main(frames: int = 60) -> None:
    ch = load_animated_drawings(DATA / "animated-drawings" / "characters" / "char1")
    clip = load_clip(DATA / "bandai-namco-1" / "data" / "dataset-1_kick_normal_001.bvh", fps=30)
    rig = build_rig(ch, "ours", "layered", 800, 4)
    anim = animate(rig, clip.points[:frames], clip.depth[:frames])
    off, size = canvas(ch, anim.frames)
    thr = ink_threshold(ch.texture, ch.mask)
    times = {}
    for seal in (False, True):
        r = MeshRenderer.for_mesh(rig.mesh, ch, size=size, seal=seal)
        r.render(anim.frames[0] + off, anim.orders[0])
        t0 = time.perf_counter()
        for t in range(frames):
            r.render(anim.frames[t] + off, anim.orders[t], background=(255, 255, 255))
        times[seal] = (time.perf_counter() - t0) / frames * 1e3
    r = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    imgs = [r.render_labelled(anim.frames[t] + off, anim.orders[t], labels=True) for t in range(frames)]
    t0 = time.perf_counter()
    for rgba, lab in imgs:
        frame_artefacts(rgba, lab, thr, 90.0)
    art = (time.perf_counter() - t0) / frames * 1e3
    print(f"char1 kick, layered mesh, {size[1]} x {size[0]} canvas, {frames} frames:")
    print(f"  render without seal   {times[False]:6.1f} ms/frame")
    print(f"  render with seal      {times[True]:6.1f} ms/frame  (seal: +{times[True] - times[False]:.1f} ms)")
    print(f"  artefact measures     {art:6.1f} ms/frame  (evaluation only)")
    print(np.round([times[False], times[True], art], 1))


if __name__ == "__main__":
    main()
