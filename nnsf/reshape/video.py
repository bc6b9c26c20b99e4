"""Rendered frames to files: PNG frames, GIF, MP4 (H.264 where OpenCV has it) and a contact sheet, each written atomically.
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.io import atomic_dir, atomic_path

#: The MP4 codec this OpenCV build writes (probed once, :func:`mp4_codec`).
_MP4_CODEC: str | None = None


def _bgr(img: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if img.shape[2] == 4 else cv2.COLOR_RGB2BGR)


def write_png_frames(folder, images, prefix: str = "frame") -> list[Path]:
    """Write images ``(T, H, W, 3|4)`` (RGB[A]) as ``<folder>/<prefix>_0000.png`` …, atomically as a folder."""
    folder = Path(folder)
    names = [f"{prefix}_{t:04d}.png" for t in range(len(images))]
    with atomic_dir(folder) as tmp:
        for name, img in zip(names, images):
            if not cv2.imwrite(str(tmp / name), _bgr(np.asarray(img))):
                raise OSError(f"could not write {folder / name}")
    return [folder / n for n in names]


def write_gif(path, images, fps: float) -> Path:
    """Write RGB(A) images ``(T, H, W, 3|4)`` as a looping GIF (Pillow), atomically."""
    from PIL import Image

    path = Path(path)
    frames = []
    for img in images:
        img = np.asarray(img)
        if img.shape[2] == 4:  # GIF has 1-bit transparency; composite over white instead
            a = img[..., 3:4].astype(np.float32) / 255.0
            img = np.clip(np.rint(img[..., :3] * a + 255.0 * (1 - a)), 0, 255).astype(np.uint8)
        frames.append(Image.fromarray(img, "RGB").quantize(colors=255, method=Image.Quantize.MEDIANCUT,
                                                            dither=Image.Dither.NONE))
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], loop=0,
                       duration=int(round(1000.0 / fps)), disposal=1, optimize=False)
    return path


def mp4_codec() -> str:
    """The MP4 codec this OpenCV build can write: ``avc1`` (H.264, plays in browsers and
    QuickTime) when its FFmpeg has an H.264 encoder, else ``mp4v`` (MPEG-4 Part 2, which
    many browsers and QuickTime do not play; VLC and FFmpeg do).  Probed once per process on
    a scratch file, with FFmpeg's complaints about a missing encoder kept off the terminal.
    The opencv-python wheels ship FFmpeg without an H.264 encoder, so there it is ``mp4v``."""
    global _MP4_CODEC
    if _MP4_CODEC is None:
        import os
        import sys
        import tempfile

        _MP4_CODEC = "mp4v"
        with tempfile.TemporaryDirectory() as d:
            probe = os.path.join(d, "probe.mp4")
            sys.stderr.flush()
            saved = os.dup(2)
            try:
                with open(os.devnull, "w") as null:
                    os.dup2(null.fileno(), 2)
                    vw = cv2.VideoWriter(probe, cv2.VideoWriter_fourcc(*"avc1"), 24.0, (64, 64))
                    ok = vw.isOpened()
                    if ok:
                        vw.write(np.zeros((64, 64, 3), np.uint8))
                    vw.release()
            finally:
                os.dup2(saved, 2)
                os.close(saved)
            if ok and os.path.getsize(probe) > 0:
                _MP4_CODEC = "avc1"
    return _MP4_CODEC


def write_mp4(path, images, fps: float) -> Path:
    """Write RGB(A) images ``(T, H, W, 3|4)`` as MP4, atomically: H.264 when this OpenCV can
    encode it, else ``mp4v`` (:func:`mp4_codec`).

    Odd sizes are padded by one pixel (the codec wants even dimensions);
    RGBA is composited over white.  Raises ``OSError`` if OpenCV cannot open
    the writer (no video backend).
    """
    path = Path(path)
    images = [np.asarray(i) for i in images]
    H, W = images[0].shape[:2]
    He, We = H + H % 2, W + W % 2
    codec = mp4_codec()
    with atomic_path(path) as tmp:
        vw = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*codec), float(fps), (We, He))
        if not vw.isOpened():
            raise OSError(f"OpenCV could not open an {codec} video writer for {path}")
        try:
            for img in images:
                if img.shape[2] == 4:
                    a = img[..., 3:4].astype(np.float32) / 255.0
                    img = np.clip(np.rint(img[..., :3] * a + 255.0 * (1 - a)), 0, 255).astype(np.uint8)
                frame = np.full((He, We, 3), 255, np.uint8)
                frame[:H, :W] = img
                vw.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
        finally:
            vw.release()
        if tmp.stat().st_size == 0:
            raise OSError(f"OpenCV wrote an empty video for {path}")
    return path


def contact_sheet(images, columns: int = 6, scale: float = 0.5, labels=None) -> np.ndarray:
    """Tile images ``(T, H, W, C)`` into one RGB(A) image (for looking at a GIF's frames)."""
    images = [np.asarray(i) for i in images]
    small = [cv2.resize(i, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA) for i in images]
    h, w, c = small[0].shape
    rows = -(-len(small) // columns)
    sheet = np.full((rows * h, columns * w, c), 255, np.uint8)
    for k, img in enumerate(small):
        r, q = divmod(k, columns)
        sheet[r * h:(r + 1) * h, q * w:(q + 1) * w] = img
        if labels is not None:
            cv2.putText(sheet, str(labels[k]), (q * w + 4, r * h + 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                        (0, 0, 0) + ((255,) if c == 4 else ()), 1, cv2.LINE_AA)
    return sheet
