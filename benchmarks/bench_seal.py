"""Per-frame cost of the render-time seal (nnsf.reshape.seal), of the outline redraw
(``MeshRenderer._reink``) and of the artefact measures.

Renders char1 kicking (layered mesh, subkeys) three ways, each the fastest of
three passes: without seal and redraw, with the seal, with both (the
default), and prints milliseconds per frame; needs ../shared/data.  Also
counts the pixels the redraw inks outside the sealed pieces (a stroke
laid half outside a new edge is a bump beside the drawn outline).  Then a Kenney
sprite with and without its drawn slits, and char5 with and without the
acute-corner step of its 2 px seal.  The default's line "without the
hairline fill" times ``seal_mask(hairline=False)`` (``seal.hairlines``).  Run:
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


def _time(r, anim, off, frames, repeat):
    r.render(anim.frames[0] + off, anim.orders[0])
    best = np.inf
    for _ in range(repeat):  # the fastest of ``repeat`` passes: least disturbed by other work on the machine
        t0 = time.perf_counter()
        for t in range(frames):
            r.render(anim.frames[t] + off, anim.orders[t], background=(255, 255, 255))
        best = min(best, time.perf_counter() - t0)
    return best / frames * 1e3


def main(frames: int = 60, repeat: int = 3) -> None:
    import os

    ch = load_animated_drawings(DATA / "animated-drawings" / "characters" / "char1")
    clip = load_clip(DATA / "bandai-namco-1" / "data" / "dataset-1_kick_normal_001.bvh", fps=30)
    rig = build_rig(ch, "ours", "layered", 800, 4)
    anim = animate(rig, clip.points[:frames], clip.depth[:frames])
    off, size = canvas(ch, anim.frames)
    thr = ink_threshold(ch.texture, ch.mask)
    full = MeshRenderer.for_mesh(rig.mesh, ch, size=size)  # seal and outline redraw on (the default)
    plain = MeshRenderer.for_mesh(rig.mesh, ch, size=size, seal=False)
    style = plain.reink
    plain.reink = None
    sealed = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    sealed.reink = None
    nohair = MeshRenderer.for_mesh(rig.mesh, ch, size=size)  # the default without the hairline step
    nohair._seal_kw["hairline"] = False
    times = {"plain": _time(plain, anim, off, frames, repeat), "seal": _time(sealed, anim, off, frames, repeat),
             "full": _time(full, anim, off, frames, repeat), "nohair": _time(nohair, anim, off, frames, repeat)}
    imgs = [full.render_labelled(anim.frames[t] + off, anim.orders[t], labels=True) for t in range(frames)]
    outside = [int(((rgba[..., 3] >= 128) & (sealed.render(anim.frames[t] + off, anim.orders[t])[..., 3] < 128)).sum())
               for t, (rgba, _) in enumerate(imgs)]
    t0 = time.perf_counter()
    for rgba, lab in imgs:
        frame_artefacts(rgba, lab, thr, 90.0)
    art = (time.perf_counter() - t0) / frames * 1e3
    print(f"char1 kick, layered mesh, {size[1]} x {size[0]} canvas, {frames} frames, fastest of {repeat}; "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print(f"  render, no seal, no outline redraw  {times['plain']:6.1f} ms/frame")
    print(f"  + seal                              {times['seal']:6.1f} ms/frame  (seal: +{times['seal'] - times['plain']:.1f} ms)")
    print(f"  + outline redraw (the default)      {times['full']:6.1f} ms/frame  "
          f"(redraw: +{times['full'] - times['seal']:.1f} ms; line width {style[1]:g} px)")
    print(f"  the default without the hairline fill {times['nohair']:6.1f} ms/frame  "
          f"(hairlines: {times['full'] / times['nohair']:.3f}x)")
    print(f"  ink the redraw adds outside the pieces {np.mean(outside):7.1f} px/frame (max {max(outside)})")
    print(f"  artefact measures                   {art:6.1f} ms/frame  (evaluation only)")
    sprite(frames, repeat)
    corners(frames, repeat)


def corners(frames: int, repeat: int) -> None:
    """char5 (277 px, a 2 px scale closing), whose acute corners the 3 px closing's short runs seal
    (``seal_mask(corner=...)``): its cost against the seal without that step."""
    from nnsf.reshape.formats import read_character

    ch = read_character(DATA / "animated-drawings" / "characters" / "char5")  # extra arms: not the biped reader
    clip = load_clip(DATA / "bandai-namco-1" / "data" / "dataset-1_walk_normal_001.bvh", fps=30)
    rig = build_rig(ch, "ours", "layered", 800, 4)
    anim = animate(rig, clip.points[:frames], clip.depth[:frames], arms="drawing")
    off, size = canvas(ch, anim.frames)
    with_corners = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    without = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    del without._seal_kw["corner"]  # the hairline fill stays on in both
    t = {k: _time(r, anim, off, frames, repeat) for k, r in (("without", without), ("corners", with_corners))}
    print(f"char5 walk, {size[1]} x {size[0]} canvas, scale closing {with_corners._seal_kw['close']} px")
    print(f"  render (seal, outline redraw)       {t['without']:6.1f} ms/frame")
    print(f"  + acute corners (3 px short runs)   {t['corners']:6.1f} ms/frame  (+{t['corners'] - t['without']:.2f} ms; "
          f"{t['corners'] / t['without']:.3f}x)")


def sprite(frames: int, repeat: int) -> None:
    """A 128 px Kenney sprite, where the seal keeps the drawing's own gaps (``seal.DrawnGaps``):
    its cost against the seal at the drawing's scale (1 px closing, no drawn gaps)."""
    from nnsf.reshape.kenney import kenney_character

    ch, _ = kenney_character("robot", DATA / "kenney-toon", Path(__file__).resolve().parents[1] / "tests" / "data" / "kenney")
    clip = load_clip(DATA / "bandai-namco-1" / "data" / "dataset-1_kick_normal_001.bvh", fps=30)
    rig = build_rig(ch, "ours", "layered", 300, 4)
    anim = animate(rig, clip.points[:frames], clip.depth[:frames])
    off, size = canvas(ch, anim.frames)
    plain = MeshRenderer.for_mesh(rig.mesh, ch, size=size, seal=False)
    plain.reink = None
    gaps = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    gaps.reink = None
    narrow = MeshRenderer.for_mesh(rig.mesh, ch, size=size)
    narrow.reink = None
    narrow._gaps, narrow._seal_kw["close"] = None, narrow._seal_kw["tab_close"]
    t = {k: _time(r, anim, off, frames, repeat) for k, r in (("plain", plain), ("narrow", narrow), ("gaps", gaps))}
    print(f"robot kick (Kenney), {size[1]} x {size[0]} canvas, {len(gaps._gaps or [])} drawn-slit pixels")
    print(f"  render, no seal, no outline redraw  {t['plain']:6.1f} ms/frame")
    print(f"  + seal, 1 px closing                {t['narrow']:6.1f} ms/frame  (+{t['narrow'] - t['plain']:.2f} ms)")
    print(f"  + seal, 3 px closing, drawn slits   {t['gaps']:6.1f} ms/frame  (+{t['gaps'] - t['plain']:.2f} ms; "
          f"{t['gaps'] / t['narrow']:.2f}x the 1 px seal's frame)")


if __name__ == "__main__":
    main()
