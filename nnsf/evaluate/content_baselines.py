"""Baselines of the leave-one-content-out evaluation: pose offset, spectral transfer (docs/method.md §15.5).

Both transfer a style onto a clip of an action the style was never seen in,
from examples of the style and of the clip's own (source) style performing
*other* actions.  They work per joint coordinate of the root-relative pose
``(n, d)`` (key points minus the root, any one unit), and each is one numpy
function of the clips, sharing nothing with the translation they are
compared with:

* :func:`offset_transfer` -- the clip plus the mean pose offset from the
  source style to the target (:func:`mean_pose_offset`);
* :func:`spectral_transfer` -- spectral style transfer after Yumer & Mitra,
  *Spectral style transfer for human motion between independent actions*
  (SIGGRAPH 2016), as the project reads it: per coordinate, the magnitude
  spectrum of the target style and of the source style, each averaged over
  the contents both perform; the clip's spectrum multiplied by their ratio
  (clipped to [0.25, 4]) with its phase kept; then the mean pose offset.

A training clip's magnitude spectrum is |rfft(x − mean x)| / m on its own
frequency grid k/m (cycles per frame), interpolated linearly onto the input
clip's grid k/n, so clips of any length are averaged on one grid.  Per
(style, content) the clips are averaged first, then the contents.
"""
from __future__ import annotations

import numpy as np

#: The spectral ratio is clipped to this range.
RATIO_RANGE: tuple[float, float] = (0.25, 4.0)


def _shared(target: dict, source: dict) -> list:
    shared = sorted(set(target) & set(source))
    if not shared:
        raise ValueError("the target and source styles share no content to compare them on")
    return shared


def mean_pose_offset(target: dict, source: dict) -> np.ndarray:
    """Mean over shared contents of (mean pose of the target's clips − the source's), ``(d,)``.

    ``target``, ``source``: content -> list of clips ``(m, d)``; a cell's mean
    pose is the mean over its clips of each clip's mean frame.
    """
    def cell(clips):
        return np.mean([np.asarray(Q, dtype=float).mean(axis=0) for Q in clips], axis=0)

    return np.mean([cell(target[c]) - cell(source[c]) for c in _shared(target, source)], axis=0)


def offset_transfer(R, target: dict, source: dict) -> np.ndarray:
    """``R`` ``(n, d)`` plus :func:`mean_pose_offset` of ``target`` over ``source``."""
    return np.asarray(R, dtype=float) + mean_pose_offset(target, source)


def magnitude_spectrum(Q, n: int) -> np.ndarray:
    """|rfft(Q − mean Q)| / m of a clip ``Q`` ``(m, d)``, interpolated onto the grid of ``n`` frames,
    ``(n // 2 + 1, d)``."""
    Q = np.asarray(Q, dtype=float)
    m = len(Q)
    A = np.abs(np.fft.rfft(Q - Q.mean(axis=0), axis=0)) / m
    f_in, f_q = np.fft.rfftfreq(n), np.fft.rfftfreq(m)
    return np.stack([np.interp(f_in, f_q, A[:, j]) for j in range(Q.shape[1])], axis=1)


def spectral_transfer(R, target: dict, source: dict) -> np.ndarray:
    """The clip ``R`` ``(n, d)`` in the target style by spectral transfer (module docstring).

    ``target``, ``source``: content -> list of clips ``(m, d)`` of the two
    styles (the hidden content excluded by the caller).  Where the source's
    averaged magnitude is zero the ratio is 1; the mean (frequency 0) is the
    clip's, then the mean pose offset is added.
    """
    R = np.asarray(R, dtype=float)
    n = len(R)
    shared = _shared(target, source)

    def spectrum(cells):
        return np.mean([np.mean([magnitude_spectrum(Q, n) for Q in cells[c]], axis=0) for c in shared], axis=0)

    S, N = spectrum(target), spectrum(source)
    ratio = np.ones_like(N)
    live = N > 1e-12 * max(float(N.max()), np.finfo(float).tiny)
    ratio[live] = np.clip(S[live] / N[live], *RATIO_RANGE)
    ratio[0] = 1.0
    mean = R.mean(axis=0)
    out = np.fft.irfft(np.fft.rfft(R - mean, axis=0) * ratio, n, axis=0)
    return out + mean + mean_pose_offset(target, source)
