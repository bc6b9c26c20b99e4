"""Rendered frames to files: PNG frames, GIF, MP4 (H.264) and a contact sheet, each written whole or not at all.

An MP4 or GIF is written under a temporary name beside its destination, decoded back (its frame
count, and the MP4's size, checked against what was asked), and only then renamed into place; a
write error (a full disk, a file size limit) is one :class:`~nnsf.io.WriteError` naming the
destination, and leaves nothing behind.

The MP4 is H.264 (``libx264``), 4:2:0 chroma (``yuv420p``) at even width and height, with its index
at the front (``+faststart``): the form browsers, phones and chat previews play.  It is encoded with
PyAV, whose wheels carry FFmpeg with libx264 and which, unlike OpenCV's ``VideoWriter``, reports
every write error.
"""
from __future__ import annotations

import errno
import itertools
import re
from fractions import Fraction
from pathlib import Path

import cv2
import numpy as np
from PIL import Image

from nnsf.io import atomic_dir, atomic_path, check_replaceable, encode_image, write_bytes


def check_frames_folder(folder, prefix: str = "frame", field: str = "folder") -> Path:
    """``folder`` if :func:`write_png_frames` may replace it: absent, empty, or holding only
    ``<prefix>_NNNN.png`` frames (an earlier run's); a folder of anything else is refused in one line."""
    return check_replaceable(folder, field, f"{prefix}_NNNN.png frames of an earlier run",
                             pattern=re.escape(prefix) + r"_\d{4,}\.png")


def write_png_frames(folder, images, prefix: str = "frame") -> list[Path]:
    """Write images ``(T, H, W, 3|4)`` (RGB[A]) as ``<folder>/<prefix>_0000.png`` …, atomically as a folder."""
    folder = Path(folder)
    names = [f"{prefix}_{t:04d}.png" for t in range(len(images))]
    check_frames_folder(folder, prefix)
    with atomic_dir(folder) as tmp:
        for name, img in zip(names, map(np.asarray, images)):
            bgr = cv2.cvtColor(img, cv2.COLOR_RGBA2BGRA if img.shape[2] == 4 else cv2.COLOR_RGB2BGR)
            write_bytes(tmp / name, encode_image(bgr, ".png"))
    return [folder / n for n in names]


#: Frames (evenly spaced, at every 4th pixel of every 4th row) that :func:`gif_palette` draws its colours from.
GIF_PALETTE_FRAMES = 16


def over_white(img: np.ndarray) -> np.ndarray:
    """RGB ``(H, W, 3)`` uint8 of an RGB(A) image, RGBA composited over white (GIF has 1-bit transparency)."""
    img = np.asarray(img)
    if img.shape[2] == 4:
        a = img[..., 3:4].astype(np.float32) / 255.0
        img = np.clip(np.rint(img[..., :3] * a + 255.0 * (1 - a)), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(img[..., :3])


def gif_palette(images, colors: int = 256) -> np.ndarray:
    """One palette for a whole animation: ``(k, 3)`` uint8 RGB, ``k ≤ colors`` (≤ 256).

    ``images`` ``(T, H, W, 3|4)`` RGB(A).  The colours come from up to :data:`GIF_PALETTE_FRAMES`
    evenly spaced frames at every 4th pixel of every 4th row: Pillow's median cut refined by k-means
    (``kmeans=1``) for ``colors − 1`` entries, then the sample's most common colour (the page)
    exactly, so the page stays its own colour and not the mean of a box of near-whites.

    Why one palette and not one per frame: a drawn character keeps its
    colours from frame to frame, so one palette loses little, while a palette
    per frame rounds the same colour differently in neighbouring frames (a
    still pixel flickers) and its median cut costs several times the mapping (``benchmarks/bench_gif.py``).
    """
    n = len(images)
    idx = np.unique(np.linspace(0, n - 1, min(n, GIF_PALETTE_FRAMES)).round().astype(int))
    sample = np.concatenate([over_white(images[i])[::4, ::4] for i in idx], axis=0)
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

    Hand-written because Pillow's mapping to a given palette first rounds a colour to a box of 8
    levels per channel: measured, a white page mapped to a palette's 250 grey although the palette
    held white.  A k-d tree (``scipy.spatial.cKDTree``) answers each colour not met before; a
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

    RGBA is composited over white.  Every frame is mapped, without dithering, to the nearest colours
    of one palette (:func:`gif_palette`), which the file holds once as its global colour table.
    Written under a temporary name, decoded back (frame count) and renamed; a write error is a
    :class:`~nnsf.io.WriteError` naming ``path``.
    """
    path = Path(path)
    palette = gif_palette(images)
    nearest = _NearestColour(palette)
    entries = palette.ravel().tolist()
    frames, indexed = [], []
    for img in images:
        indexed.append(nearest(over_white(img)))
        f = Image.fromarray(indexed[-1], "P")
        f.putpalette(entries)
        frames.append(f)
    # Pillow writes a frame identical to the one before it once, holding it longer: count those.
    distinct = 1 + sum(not np.array_equal(a, b) for a, b in zip(indexed[1:], indexed[:-1]))
    with atomic_path(path) as tmp:
        frames[0].save(tmp, format="GIF", save_all=True, append_images=frames[1:], loop=0,
                       duration=int(round(1000.0 / fps)), disposal=1, optimize=False)
        with Image.open(tmp) as back:
            n = back.n_frames
        if n != distinct:
            raise OSError(errno.EIO, f"decoded back {n} frames, expected {distinct}")
    return path


def read_gif(path) -> np.ndarray:
    """The frames of a GIF as RGB ``(T, H, W, 3)`` uint8 (Pillow), each as a viewer shows it."""
    out = []
    with Image.open(path) as im:
        for t in range(im.n_frames):
            im.seek(t)
            out.append(np.asarray(im.convert("RGB")))
    return np.array(out)


#: The MP4 video codec (H.264) and pixel format every writer here uses.
MP4_CODEC = "libx264"
MP4_PIX_FMT = "yuv420p"
#: x264's constant-rate factor: 18 keeps a drawing's flat colours and ink lines without visible
#: blocking (x264's own default, 23, smears thin lines) at a few hundred kB per second of 512 px.
MP4_CRF = 18
#: x264's frame threads, a fixed count: its bytes depend on the count, which FFmpeg takes from the cores.
MP4_THREADS = 4
#: libx264's options; on a CPU with AVX-512 (OpenCV's feature 13, ``CPU_AVX_512F``), x264's code only up to
#: AVX2.  Why: x264's AVX-512 MB-tree kernel (``mbtree_propagate_list``) takes 8 macroblocks a step and, past
#: the last row of a frame not a multiple of 8 macroblocks wide, adds in what it reads from memory the encoder
#: never wrote, so the bytes changed with what the process had freed before.  The AVX2 form stops at the row's end.
MP4_OPTIONS = {"crf": str(MP4_CRF), **({"x264-params": "asm=AVX2"} if cv2.checkHardwareSupport(13) else {})}


def write_mp4(path, images, fps: float) -> Path:
    """Write RGB(A) images ``(T, H, W, 3|4)`` as an H.264 MP4 at ``fps``, whole or not at all.

    ``images``: an array, or any iterable of frames (each is encoded as it comes).  Odd sizes are
    padded by one white pixel (4:2:0 chroma needs even dimensions); RGBA is composited over
    white.  The file is written under a temporary name, decoded back, and renamed only when it
    holds the ``T`` frames given, at the padded size.  Raises :class:`~nnsf.io.WriteError` naming
    ``path`` on any write error (nothing is left behind).
    """
    import av

    path = Path(path)
    if not (fps > 0 and np.isfinite(fps)):
        raise ValueError(f"fps must be > 0, got {fps!r}")
    images = iter(images)
    first = np.asarray(next(images))
    H, W = first.shape[:2]
    He, We = H + H % 2, W + W % 2
    rate = Fraction(float(fps)).limit_denominator(1001)        # exact, as FFmpeg wants: 29.97 -> 30000/1001
    with atomic_path(path) as tmp:
        with av.open(str(tmp), mode="w", format="mp4", options={"movflags": "+faststart"}) as container:
            stream = container.add_stream(MP4_CODEC, rate=rate, options=MP4_OPTIONS)
            stream.width, stream.height, stream.pix_fmt = We, He, MP4_PIX_FMT
            stream.codec_context.thread_type, stream.codec_context.thread_count = "FRAME", MP4_THREADS
            frame = np.full((He, We, 3), 255, np.uint8)
            for T, img in enumerate(itertools.chain([first], images), 1):
                frame[:H, :W] = over_white(img)
                container.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
            container.mux(stream.encode())                     # flush the frames x264 holds back
        n, size = _mp4_frames(tmp)
        if (n, size) != (T, (We, He)):
            raise OSError(errno.EIO, f"decoded back {n} frames of {size[0]}x{size[1]} px, "
                          f"expected {T} of {We}x{He}")
    return path


def _mp4_frames(path) -> tuple[int, tuple[int, int]]:
    """Frames and ``(width, height)`` of an MP4's video, by decoding it; ``OSError`` if it cannot be read."""
    import av

    n, size = 0, (0, 0)
    with av.open(str(path)) as container:
        for frame in container.decode(video=0):
            n, size = n + 1, (frame.width, frame.height)
    return n, size


def read_mp4(path) -> np.ndarray:
    """The frames of an MP4 as RGB ``(T, H, W, 3)`` uint8 (PyAV)."""
    import av

    with av.open(str(path)) as container:
        return np.array([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])


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
