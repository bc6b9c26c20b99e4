"""Bits floating free of the character: the seal's crack fill with and without ``seal.touching``.

The seal fills background pixels inside the closing of the drawn pixels that lie within its crack
reach of two joined parts.  Of a gap about twice that reach wide only the middle line qualifies;
filled alone it floats in the gap, a sliver apart from the character.  ``seal.touching`` keeps only
the filled runs that touch the drawn pixels (docs/method.md §13.2).

For each AnimatedDrawings character (char1-char5) and Kenney sprite with the four motions of the
reshaping evaluation (as ``nnsf reshape-eval`` drives them: its views, its mesh sizes, the default
layered mesh with subkeys), every ``--every``-th frame is rendered twice, with the rule and without
it (``seal.touching`` replaced by the identity), alternated, and the frames with a drawn component
of 3 px² or more apart from the largest (``artefacts.detached``) are counted.  The median render
time per frame of each is printed, for each source.

Needs ../shared/data.  Run: ``python benchmarks/seal_slivers.py [--every 1]``.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from nnsf.reshape import seal as seal_module
from nnsf.reshape.artefacts import detached
from nnsf.reshape.evaluation import AZIMUTH, MOTIONS, _character, animate, build_mesh, build_rig, canvas, load_clip
from nnsf.reshape.kenney import CHARACTERS as KENNEY
from nnsf.reshape.render import MeshRenderer

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
TESTS = Path(__file__).resolve().parents[1] / "tests" / "data" / "kenney"


def items():
    """(label, item for ``evaluation._character``, mesh vertices) of every character."""
    for c in ("char1", "char2", "char3", "char4", "char5"):
        yield c, {"character": str(DATA / "animated-drawings" / "characters" / c)}, 800
    for c in KENNEY:
        yield c, {"kenney": c, "kenney_root": str(DATA / "kenney-toon"), "kenney_annotations": str(TESTS)}, 300


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--every", type=int, default=1)
    a = ap.parse_args(argv)
    if not DATA.is_dir():
        raise SystemExit(f"{DATA} not found: this benchmark needs ../shared/data")
    rule = seal_module.touching
    rows, times = [], {}
    for label, item, nv in items():
        ch = _character(item)
        mesh = build_mesh(ch.mask, ch.keypoints, nv, split="layered", texture=ch.texture,
                          extra_limbs=ch.extra_limbs)
        rig = build_rig(ch, "ours", "layered", nv, 4, base_mesh=mesh)
        for m in MOTIONS:
            clip = load_clip(str(DATA / "bandai-namco-1" / "data" / f"dataset-1_{m}.bvh"), fps=30,
                             azimuth=float(AZIMUTH.get(m, 0.0)))
            T = min(len(clip.points), 240)
            anim = animate(rig, clip.points[:T], clip.depth[:T], source=m)
            off, size = canvas(ch, anim.frames.reshape(-1, 2))
            r = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
            bad = {True: 0, False: 0}
            for t in range(0, T, a.every):
                for on in (True, False) if t % 2 == 0 else (False, True):
                    seal_module.touching = rule if on else (lambda fill, cov: fill)
                    t0 = time.perf_counter()
                    rgba = r.render(anim.frames[t] + off, anim.orders[t])
                    times.setdefault((label.startswith("char"), on), []).append(time.perf_counter() - t0)
                    bad[on] += detached(rgba[..., 3] >= 128) > 0
            seal_module.touching = rule
            rows.append((label, m, len(range(0, T, a.every)), bad[False], bad[True]))
            print(f"{label:18s} {m:17s} frames {rows[-1][2]:3d}: with a bit apart {bad[False]:3d} "
                  f"without the rule, {bad[True]:3d} with it", flush=True)
    for src, pick in (("AnimatedDrawings", lambda x: x.startswith("char")), ("Kenney", lambda x: not x.startswith("char"))):
        sel = [r for r in rows if pick(r[0])]
        print(f"{src}: {sum(r[2] for r in sel)} frames; with a bit apart: {sum(r[3] for r in sel)} without "
              f"the rule, {sum(r[4] for r in sel)} with it")
    for src, ad in (("AnimatedDrawings", True), ("Kenney", False)):
        on, off = np.median(times[ad, True]) * 1e3, np.median(times[ad, False]) * 1e3
        print(f"{src} render per frame (median): {on:.2f} ms with the rule, {off:.2f} ms without "
              f"({on / off:.3f}x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
