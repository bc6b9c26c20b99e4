"""Where the Kenney sprites' tear pixels lie: in the slits the artist drew, or elsewhere.

The tear measure (:func:`nnsf.reshape.artefacts.tear_pixels`) counts page
pixels within 3 px of two joined parts.  A Kenney sprite is drawn with slits of
a few pixels between arm and body, sleeve and vest, which it counts at rest
already (``tear_px_rest``), and which widen as the arm swings out.  The seal
keeps those slits open on purpose (:class:`nnsf.reshape.seal.DrawnGaps`): it
finds them at rest and carries each slit pixel by its two nearest parts.

For each of the six sprites × the four motions of the reshaping evaluation,
rendered as ``nnsf reshape-eval`` renders them (layered mesh, subkeys, every
frame), this prints the tear pixels per frame and the share of them inside the
carried slits (the seal's keep mask of that frame), and the same over all
pairs.  A tear pixel outside them is a crack the seal left.  The share is a
diagnosis of the measure, not a score: the slits are the method's own.

Needs ../shared/data.  Run: ``python benchmarks/kenney_slit_tears.py``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.datasets.bvh_source import load_clip
from nnsf.reshape.artefacts import frame_tears
from nnsf.reshape.evaluation import AZIMUTH, HEAD, KC, MOTIONS
from nnsf.reshape.kenney import kenney_character
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import animate, build_rig, canvas

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"


def main(max_frames: int = 240) -> None:
    total = inside = 0
    print(f"{'character':18s} {'motion':17s} {'tear px/frame':>13s} {'in drawn slits':>14s}")
    for name in KC:
        ch, _ = kenney_character(name, DATA / "kenney-toon", ROOT / "tests" / "data" / "kenney")
        rig = build_rig(ch, "ours", "layered", 300, 4)
        for motion in MOTIONS:
            clip = load_clip(DATA / "bandai-namco-1" / "data" / f"dataset-1_{motion}.bvh", fps=30,
                             azimuth=float(AZIMUTH.get(motion, 0.0)))
            T = min(max_frames, len(clip.points))
            anim = animate(rig, clip.points[:T], clip.depth[:T], head=HEAD.get(name, "motion"))
            off, size = canvas(ch, anim.frames)
            r = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
            n = k = 0
            for t in range(T):
                V = anim.frames[t] + off
                tp = frame_tears(*r.render_labelled(V, anim.orders[t], labels=True))  # as the evaluation counts
                n += int(tp.sum())
                if r._gaps is not None:  # the renderer's carried slits: what its seal keeps open
                    k += int((tp & r._gaps.mask(r._gaps.points(V), 0, 0, *size)).sum())
            total, inside = total + n, inside + k
            print(f"{name:18s} {motion:17s} {n / T:13.2f} {k / max(n, 1):14.1%}")
    print(f"all pairs: {total} tear pixels, {inside} ({inside / max(total, 1):.2%}) in the drawn slits, "
          f"{total - inside} elsewhere")


if __name__ == "__main__":
    main()
