"""GIF encoding of `nnsf animate` frames: one palette per animation against a palette per frame.

Renders ``--frames`` frames of a drawn character (AnimatedDrawings' char3 walking, from
``../shared/data``; the built-in stick figure when absent) as `nnsf animate` does, then
encodes them twice in the same run:

* ours, :func:`nnsf.reshape.video.write_gif`: one palette (median cut of a frame sample),
  each frame mapped to its nearest colours;
* the peer, Pillow's median cut per frame (what ``write_gif`` did before 2026-12-06).

Prints, for each: ms per frame (best of ``--repeat``), the mean colour error on the
character's pixels (0-255 per channel), page pixels not decoded exactly, the share of
still pixels (same input colour in two neighbouring frames) whose decoded colour changes
(flicker), and the file size.

    .venv/bin/python benchmarks/bench_gif.py [--frames 120] [--repeat 2]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


def frames(n: int, folder: Path) -> tuple[np.ndarray, str]:
    """Frames ``(n, H, W, 3)`` RGB of `nnsf animate` (its PNG output, read back), and what they show."""
    import cv2

    from nnsf.animate.animation import animate_files

    src = DATA / "animated-drawings" / "characters" / "char3"
    character = str(src) if src.is_dir() else "stick"
    res = animate_files(character, f"synthetic:pip/walk/{n}", out=folder / "frames", progress=False)
    images = np.stack([cv2.cvtColor(cv2.imread(str(f)), cv2.COLOR_BGR2RGB)
                       for f in sorted((folder / "frames").glob("*.png"))])
    return images, f"{character}, {len(images)} frames of a synthetic walk, {images.shape[2]} x {images.shape[1]} px"


def per_frame_median_cut(path: Path, images: np.ndarray, fps: float) -> None:
    """The peer: Pillow's median cut for each frame on its own."""
    from PIL import Image

    fr = [Image.fromarray(i, "RGB").quantize(colors=255, method=Image.Quantize.MEDIANCUT,
                                             dither=Image.Dither.NONE) for i in images]
    fr[0].save(path, format="GIF", save_all=True, append_images=fr[1:], loop=0,
               duration=int(round(1000.0 / fps)), disposal=1, optimize=False)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)

    from nnsf.reshape.video import read_gif, write_gif

    rows = {}
    with tempfile.TemporaryDirectory() as d:
        images, what = frames(args.frames, Path(d))
        print(what)
        page = (images == 255).all(-1)
        still = (images[1:] == images[:-1]).all(-1)
        for name, fn in (("one palette (ours)", write_gif), ("median cut per frame (peer)", per_frame_median_cut)):
            path = Path(d) / "a.gif"
            best = np.inf
            for _ in range(args.repeat):
                t = time.perf_counter()
                fn(path, images, 30.0)
                best = min(best, time.perf_counter() - t)
            back = read_gif(path)
            rows[name] = best
            err = np.abs(back.astype(np.int16) - images)[~page].mean()
            flicker = ((back[1:] != back[:-1]).any(-1) & still).sum() / max(1, still.sum())
            print(f"{name:30s} {1000 * best / len(images):7.1f} ms/frame  colour error {err:.2f}  "
                  f"page px off {int((back[page] != 255).any(-1).sum())}  flicker {100 * flicker:.3f} % "
                  f"of still px  {path.stat().st_size / 1e6:.2f} MB")
    a, b = rows.values()
    print(f"ours is {b / a:.1f}x faster than the peer")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
