"""Stick figures of 17-point clips: animated GIF, MP4 and a PNG strip of frames.

Every function takes one clip or a list of clips, each either key points
``(n, 17, 2)`` or feature rows ``(n, 34)`` (``x1, y1 … x17, y17``), in any
one unit (pixels or template units), image axes (y down).  Several clips are
drawn side by side on shared axes, so their sizes and places compare; clips
of different lengths loop over the longest, shorter ones hold their last
frame.

Rendering goes through :class:`matplotlib.figure.Figure` and the Agg canvas
(no ``pyplot``, no global backend), and files are written atomically
(:func:`nnsf.io.atomic_path`).  GIF and PNG bytes depend only on the inputs.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.io import atomic_path
from nnsf.skeleton.layout import BONES, N_FEATURES, N_JOINTS, to_points

__all__ = ["as_clips", "render_frames", "write_stick_gif", "write_stick_mp4", "write_stick_strip",
           "contact_sheet"]


def as_clips(sequences) -> list[np.ndarray]:
    """One clip or a list of clips -> list of float arrays ``(n, 17, 2)``.

    Raises ``ValueError`` for anything that is not ``(n >= 1, 17, 2)`` points
    or ``(n >= 1, 34)`` features.
    """
    if isinstance(sequences, np.ndarray) and (
            sequences.ndim == 2 or (sequences.ndim == 3 and sequences.shape[-2:] == (N_JOINTS, 2))):
        sequences = [sequences]
    out = []
    for s in sequences:
        a = np.asarray(s, dtype=float)
        if a.ndim == 2 and a.shape[1] == N_FEATURES:
            a = to_points(a)
        if a.ndim != 3 or a.shape[1:] != (N_JOINTS, 2) or len(a) == 0:
            raise ValueError(f"stick figures need (n >= 1, 17, 2) points or (n, 34) features, "
                             f"got shape {a.shape}")
        if not np.isfinite(a).all():
            raise ValueError("stick figures need finite coordinates")
        out.append(a)
    if not out:
        raise ValueError("stick figures need at least one clip")
    return out


def _limits(clips, pad=0.08):
    allp = np.concatenate([c.reshape(-1, 2) for c in clips])
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    half = float(max(hi - lo)) * (0.5 + pad) or 1.0
    mid = (lo + hi) / 2
    return (mid[0] - half, mid[0] + half), (mid[1] - half, mid[1] + half)


def _panels(clips, titles, colors, size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    titles = list(titles) if titles is not None else [""] * len(clips)
    colors = list(colors) if colors is not None else [f"C{i}" for i in range(len(clips))]
    if len(titles) != len(clips) or len(colors) != len(clips):
        raise ValueError(f"need one title and colour per clip ({len(clips)})")
    xlim, ylim = _limits(clips)
    fig = Figure(figsize=(size * len(clips), size + 0.35), dpi=100)
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.9, wspace=0.04)
    canvas = FigureCanvasAgg(fig)
    artists = []
    for i, (title, col) in enumerate(zip(titles, colors)):
        ax = fig.add_subplot(1, len(clips), i + 1)
        ax.set_xlim(*xlim)
        ax.set_ylim(ylim[1], ylim[0])          # image axes: y down
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(title, fontsize=9)
        bones = [ax.plot([], [], color=col, linewidth=2.5, solid_capstyle="round")[0] for _ in BONES]
        dots = ax.plot([], [], linestyle="none", marker="o", markersize=3, color="0.2")[0]
        label = ax.text(0.02, 0.02, "", transform=ax.transAxes, fontsize=7, color="0.4")
        artists.append((bones, dots, label))
    return fig, canvas, artists


def render_frames(sequences, *, titles=None, colors=None, size: float = 2.6) -> list[np.ndarray]:
    """Render every time step of the clips side by side.

    Returns a list (one per frame of the longest clip) of RGB images
    ``(h, w, 3)`` uint8; the panel of a clip shows its frame number.
    """
    clips = as_clips(sequences)
    fig, canvas, artists = _panels(clips, titles, colors, size)
    frames = []
    for t in range(max(len(c) for c in clips)):
        for clip, (bones, dots, label) in zip(clips, artists):
            k = min(t, len(clip) - 1)
            p = clip[k]
            for line, (a, b) in zip(bones, BONES):
                line.set_data([p[a, 0], p[b, 0]], [p[a, 1], p[b, 1]])
            dots.set_data(p[:, 0], p[:, 1])
            label.set_text(f"frame {k + 1}/{len(clip)}")
        canvas.draw()
        frames.append(np.asarray(canvas.buffer_rgba())[..., :3].copy())
    return frames


def write_stick_gif(path, sequences, *, titles=None, fps: float = 15.0, size: float = 2.6,
                    colors=None) -> Path:
    """Write the clips side by side as a looping animated GIF (atomically).

    ``fps``: frames per second of the animation (> 0); ``size``: inches per
    panel at 100 dpi.  Returns the path.
    """
    from PIL import Image

    if not (isinstance(fps, (int, float)) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps!r}")
    images = [Image.fromarray(f) for f in render_frames(sequences, titles=titles, colors=colors, size=size)]
    path = Path(path)
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(round(1000.0 / fps)), loop=0, optimize=False)
    return path


def write_stick_mp4(path, sequences, *, titles=None, fps: float = 15.0, size: float = 2.6,
                    colors=None) -> Path:
    """Write the clips side by side as an MP4 (OpenCV's ``mp4v`` codec), atomically.

    Raises ``RuntimeError`` when OpenCV cannot open an MP4 writer here.
    """
    import cv2

    if not (isinstance(fps, (int, float)) and fps > 0):
        raise ValueError(f"fps must be > 0, got {fps!r}")
    frames = render_frames(sequences, titles=titles, colors=colors, size=size)
    h, w = frames[0].shape[:2]
    h2, w2 = h - h % 2, w - w % 2            # codecs want even sizes
    path = Path(path)
    with atomic_path(path, suffix=".mp4") as tmp:
        writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (w2, h2))
        if not writer.isOpened():
            raise RuntimeError("OpenCV could not open an MP4 writer (mp4v)")
        try:
            for f in frames:
                writer.write(np.ascontiguousarray(f[:h2, :w2, ::-1]))
        finally:
            writer.release()
    return path


def write_stick_strip(path, sequences, *, titles=None, n_frames: int = 8, colors=None,
                      size: float = 1.5) -> Path:
    """A PNG strip: one row per clip, ``n_frames`` evenly spaced frames across.

    Rows share one scale, so sizes compare.  Returns the path.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    clips = as_clips(sequences)
    if not (isinstance(n_frames, int) and n_frames >= 1):
        raise ValueError(f"n_frames must be an integer >= 1, got {n_frames!r}")
    titles = list(titles) if titles is not None else [""] * len(clips)
    colors = list(colors) if colors is not None else [f"C{i}" for i in range(len(clips))]
    # One scale for every panel: the largest per-frame extent of any clip.
    ext = max(float(np.ptp(c, axis=1).max()) for c in clips) * 0.6 or 1.0
    fig = Figure(figsize=(size * n_frames + 1.2, size * len(clips) + 0.2), dpi=100)
    fig.subplots_adjust(left=0.1, right=0.995, bottom=0.01, top=0.97, wspace=0.03, hspace=0.06)
    FigureCanvasAgg(fig)
    for r, (clip, title, col) in enumerate(zip(clips, titles, colors)):
        picks = np.unique(np.linspace(0, len(clip) - 1, n_frames).round().astype(int))
        for f, k in enumerate(picks):
            ax = fig.add_subplot(len(clips), n_frames, r * n_frames + f + 1)
            p = clip[k]
            for a, b in BONES:
                ax.plot([p[a, 0], p[b, 0]], [p[a, 1], p[b, 1]], color=col, linewidth=2,
                        solid_capstyle="round")
            mid = (p.min(axis=0) + p.max(axis=0)) / 2
            ax.set_xlim(mid[0] - ext, mid[0] + ext)
            ax.set_ylim(mid[1] + ext, mid[1] - ext)
            ax.set_aspect("equal")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.text(0.03, 0.03, str(k + 1), transform=ax.transAxes, fontsize=6, color="0.5")
            if f == 0:
                ax.set_ylabel(title, fontsize=8)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return path


def contact_sheet(gif_path, png_path, n: int = 6) -> Path:
    """Save ``n`` evenly spaced frames of a GIF stacked vertically as one PNG (to look at)."""
    from PIL import Image

    with Image.open(gif_path) as im:
        picks = np.unique(np.linspace(0, im.n_frames - 1, n).round().astype(int))
        frames = []
        for k in picks:
            im.seek(int(k))
            frames.append(im.convert("RGB"))
    w, h = frames[0].size
    sheet = Image.new("RGB", (w, h * len(frames)), "white")
    for i, f in enumerate(frames):
        sheet.paste(f, (0, i * h))
    path = Path(png_path)
    with atomic_path(path) as tmp:
        sheet.save(tmp, format="PNG")
    return path
