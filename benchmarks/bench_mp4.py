"""MP4 encoding of `nnsf animate` frames: H.264 through PyAV against OpenCV's MPEG-4 Part 2 writer.

Renders ``--frames`` frames of a drawn character (AnimatedDrawings' char3 walking, from
``../shared/data``; the built-in stick figure when absent) as `nnsf animate` does, then
encodes them twice in the same run:

* ours, :func:`nnsf.reshape.video.write_mp4`: H.264 (libx264, yuv420p, CRF 18), written under a
  temporary name, decoded back and its frame count checked, then renamed;
* the peer, OpenCV's ``VideoWriter`` with ``mp4v`` (what ``write_mp4`` wrote before), which
  browsers refuse and which reports no write error.

Prints, for each: ms per frame (best of ``--repeat``), the mean colour error of the decoded
frames on the character's pixels (0-255 per channel) and the file size; then the time ratio.

    .venv/bin/python benchmarks/bench_mp4.py [--frames 120] [--repeat 2]
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from bench_gif import frames


def opencv_mp4v(path, images, fps: float) -> Path:
    """The peer: OpenCV's MPEG-4 Part 2 writer, frames as they are (even sizes here)."""
    import cv2

    H, W = images[0].shape[:2]
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W - W % 2, H - H % 2))
    for img in images:
        vw.write(cv2.cvtColor(np.ascontiguousarray(img[:H - H % 2, :W - W % 2]), cv2.COLOR_RGB2BGR))
    vw.release()
    return Path(path)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args(argv)

    from nnsf.reshape.video import read_mp4, write_mp4

    rows = {}
    with tempfile.TemporaryDirectory() as d:
        images, what = frames(args.frames, Path(d))
        print(what)
        H, W = images.shape[1] - images.shape[1] % 2, images.shape[2] - images.shape[2] % 2
        ink = ~(images[:, :H, :W] == 255).all(-1)
        for name, fn in (("H.264, PyAV (ours)", write_mp4), ("mp4v, OpenCV (peer)", opencv_mp4v)):
            path = Path(d) / "a.mp4"
            best = np.inf
            for _ in range(args.repeat):
                t = time.perf_counter()
                fn(path, images, 30.0)
                best = min(best, time.perf_counter() - t)
            back = read_mp4(path)[:, :H, :W]
            rows[name] = best
            err = np.abs(back.astype(np.int16) - images[:, :H, :W])[ink].mean()
            print(f"{name:22s} {1000 * best / len(images):7.1f} ms/frame  colour error {err:.2f}  "
                  f"{path.stat().st_size / 1e6:.3f} MB")
    a, b = rows.values()
    print(f"ours takes {a / b:.2f}x the peer's time")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
