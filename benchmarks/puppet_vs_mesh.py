"""The previous default (the rigid "paper puppet" and its repair passes) against the one connected
mesh, on the same measures: should the puppet stay as a named option?

For each drawing × motion, the previous pipeline (``--baseline DIR``: a checkout of the project
before the rewrite) renders every frame in a subprocess on its own code and saves them; this
checkout's :class:`nnsf.reshape.artefacts.FrameMeasures`, which shares no code with either renderer,
measures both sets of frames against the drawing.  Written: one row per (drawing, motion,
pipeline) with the frames that show a detached piece, a crack, a notch beyond the drawing's or more
spikes than the drawing, and the render time per frame (same machine, same run).

    .venv/bin/python benchmarks/puppet_vs_mesh.py --baseline /tmp/base --data ../shared/data \\
        --out reports/reshape_puppet_vs_mesh.csv [--frames 60]
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

ITEMS = [(f"animated-drawings/characters/char{i}", m) for i in range(1, 7)
         for m in ("bandai-namco-1/data/dataset-1_punch_normal_001.bvh", "synthetic:ollie/jump")]

#: The previous pipeline's frames, on its own code: RGBA frames and the key points that drove them.
PEER = r"""
import sys, time
import numpy as np
from nnsf.datasets import synthetic
from nnsf.datasets.views import load_clip_in_view
from nnsf.reshape.formats import read_character
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import animate, build_rig, canvas
data, char, motion, frames, out = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), sys.argv[5]
ch = read_character(f"{data}/{char}")
if motion.startswith("synthetic:"):
    who, what = motion[10:].split("/")
    pts, depth = synthetic.clip_points(who, what, 48), None
else:
    clip, _ = load_clip_in_view(f"{data}/{motion}", view="side" if ch.body == "quadruped" else "auto", fps=30.0)
    pts, depth = clip.points, clip.depth
pts = pts[:frames]
depth = None if depth is None else depth[:frames]
rig = build_rig(ch)
anim = animate(rig, pts, depth)
offset, size = canvas(ch, anim.frames)
r = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
t = time.perf_counter()
images = np.stack([r.render(v + offset, o) for v, o in zip(anim.frames, anim.orders)])
ms = 1000 * (time.perf_counter() - t) / len(images)
np.savez_compressed(out, images=images, keypoints=anim.keypoints + offset, ms=ms)
"""


def ours(data: Path, char: str, motion: str, frames: int):
    from nnsf.reshape.animator import Animator, canvas
    from nnsf.reshape.evaluation import _character, _motion

    ch = _character(char, [data])
    _, pts, depth, _, _ = _motion(motion, [data], ch)
    pts, depth = pts[:frames], None if depth is None else depth[:frames]
    a = Animator(ch)
    anim = a.animate(pts, depth)
    offset, size = canvas(anim.frames, shape=ch.shape)
    r = a.renderer(size)
    t = time.perf_counter()
    images = [r.render(v + offset, o) for v, o in zip(anim.frames, anim.orders)]
    return ch, images, anim.keypoints + offset, 1000 * (time.perf_counter() - t) / len(images)


def measure(ch, images, keypoints) -> dict:
    from nnsf.reshape.artefacts import FrameMeasures

    m = FrameMeasures(ch.texture, ch.mask, ch.keypoints)
    rest = m.rest()
    rows = [m(img, kp) for img, kp in zip(images, keypoints)]
    return {"frames": len(rows),
            "frames_with_detached": sum(r["detached"] > rest["detached"] for r in rows),
            "frames_with_cracks": sum(r["cracks"] > rest["cracks"] for r in rows),
            "frames_notch_over_rest": sum(r["notch_beyond_rest"] > 4 for r in rows),
            "frames_spikes_over_rest": sum(r["spikes"] > rest["spikes"] for r in rows),
            "crack_px_mean": float(np.mean([r["crack_px"] for r in rows])),
            "notch_beyond_rest_mean": float(np.mean([r["notch_beyond_rest"] for r in rows]))}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--baseline", type=Path, required=True)
    ap.add_argument("--data", type=Path, required=True)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--frames", type=int, default=60)
    a = ap.parse_args(argv)
    rows = []
    env = dict(os.environ, PYTHONPATH=str(a.baseline))
    with tempfile.TemporaryDirectory() as tmp:
        for char, motion in ITEMS:
            ch, images, kp, ms = ours(a.data, char, motion, a.frames)
            rows.append({"character": ch.name, "motion": Path(motion).stem, "pipeline": "connected mesh",
                         "render_ms": ms, **measure(ch, images, kp)})
            npz = Path(tmp) / "peer.npz"
            subprocess.run([sys.executable, "-c", PEER, str(a.data.resolve()), char, motion, str(a.frames), str(npz)],
                           env=env, check=True, cwd=a.baseline)
            got = np.load(npz)
            rows.append({"character": ch.name, "motion": Path(motion).stem, "pipeline": "paper puppet (previous)",
                         "render_ms": float(got["ms"]), **measure(ch, got["images"], got["keypoints"])})
            print(pd.DataFrame(rows[-2:]).to_string(index=False), flush=True)
    df = pd.DataFrame(rows)
    from nnsf.io import write_csv

    write_csv(a.out, df)
    print(df.groupby("pipeline")[[c for c in df.columns if c.startswith(("frames_", "render"))]].sum().to_string())
    print(f"load average {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
