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


#: Frames (evenly spaced, at every 4th pixel of every 4th row) that :func:`gif_palette` draws its colours from.
GIF_PALETTE_FRAMES = 16


def _over_white(img: np.ndarray) -> np.ndarray:
    """RGB ``(H, W, 3)`` uint8 of an RGB(A) image, RGBA composited over white (GIF has 1-bit transparency)."""
    img = np.asarray(img)
    if img.shape[2] == 4:
        a = img[..., 3:4].astype(np.float32) / 255.0
        img = np.clip(np.rint(img[..., :3] * a + 255.0 * (1 - a)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img[..., :3])


def gif_palette(images, colors: int = 256) -> np.ndarray:
    """One palette for a whole animation: ``(k, 3)`` uint8 RGB, ``k ≤ colors`` (≤ 256).

    ``images`` ``(T, H, W, 3|4)`` RGB(A).  The colours come from up to
    :data:`GIF_PALETTE_FRAMES` evenly spaced frames at every 4th pixel of every 4th row:
    Pillow's median cut refined by k-means (``kmeans=1``) for ``colors − 1`` entries,
    then the sample's most common colour (the page) exactly, so the page
    stays its own colour and not the mean of a box of near-whites.

    Why one palette and not one per frame: a drawn character keeps its
    colours from frame to frame, so one palette loses little, while a palette
    per frame rounds the same colour differently in neighbouring frames (a
    still pixel flickers) and its median cut costs several times the mapping (``benchmarks/bench_gif.py``).
    """
    from PIL import Image

    n = len(images)
    idx = np.unique(np.linspace(0, n - 1, min(n, GIF_PALETTE_FRAMES)).round().astype(int))
    sample = np.concatenate([_over_white(images[i])[::4, ::4] for i in idx], axis=0)
    codes, counts = np.unique(_rgb_codes(sample), return_counts=True)
    page = int(codes[np.argmax(counts)])
    q = Image.fromarray(sample, "RGB").quantize(colors=max(1, colors - 1), method=Image.Quantize.MEDIANCUT,
                                                kmeans=1, dither=Image.Dither.NONE)
    found = np.asarray(q.getpalette()[:3 * (colors - 1)], np.uint8).reshape(-1, 3)  # trimmed to the colours found
    return np.vstack([found, [[page >> 16, (page >> 8) & 255, page & 255]]]).astype(np.uint8)


def _rgb_codes(rgb: np.ndarray) -> np.ndarray:
    """24-bit code ``r·2¹⁶ + g·2⁸ + b`` of each RGB pixel ``(..., 3)`` uint8, int32 ``(...)``."""
    rgb = rgb.astype(np.int32)
    return (rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]


class _NearestColour:
    """Index of the nearest palette entry (Euclidean RGB) for each pixel, exact, cached per colour.

    Hand-written because Pillow's mapping to a given palette first rounds a
    colour to a box of 8 levels per channel: measured, a white page mapped to
    a palette's 250 grey although the palette held white.  A k-d tree
    (``scipy.spatial.cKDTree``) answers each colour not met before; a
    2²⁴-entry table remembers the answers, so a frame costs a gather.
    """

    def __init__(self, palette: np.ndarray):
        from scipy.spatial import cKDTree

        self._tree = cKDTree(np.asarray(palette, dtype=np.float64))
        self._table = np.full(1 << 24, -1, np.int16)

    def __call__(self, rgb: np.ndarray) -> np.ndarray:
        codes = _rgb_codes(rgb)
        out = self._table[codes]
        new = out < 0
        if new.any():
            fresh = np.unique(codes[new])
            cols = np.stack([fresh >> 16, (fresh >> 8) & 255, fresh & 255], axis=1)
            self._table[fresh] = self._tree.query(cols)[1]
            out = self._table[codes]
        return out.astype(np.uint8)


def write_gif(path, images, fps: float) -> Path:
    """Write RGB(A) images ``(T, H, W, 3|4)`` as a looping GIF (Pillow), atomically.

    RGBA is composited over white.  Every frame is mapped, without dithering,
    to the nearest colours of one palette (:func:`gif_palette`), which the
    file holds once as its global colour table.
    """
    from PIL import Image

    path = Path(path)
    palette = gif_palette(images)
    nearest = _NearestColour(palette)
    entries = palette.ravel().tolist()
    frames = []
    for img in images:
        f = Image.fromarray(nearest(_over_white(img)), "P")
        f.putpalette(entries)
        frames.append(f)
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], loop=0,
                       duration=int(round(1000.0 / fps)), disposal=1, optimize=False)
    return path


def read_gif(path) -> np.ndarray:
    """The frames of a GIF as RGB ``(T, H, W, 3)`` uint8 (Pillow), each as a viewer shows it."""
    from PIL import Image

    out = []
    with Image.open(path) as im:
        for t in range(im.n_frames):
            im.seek(t)
            out.append(np.asarray(im.convert("RGB")))
    return np.array(out)


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
                frame = np.full((He, We, 3), 255, np.uint8)
                frame[:H, :W] = _over_white(img)
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
