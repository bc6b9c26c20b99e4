"""Posture and swing of a style carried onto a clip of any action (docs/method.md §8.4).

A style is learned from clips of a few actions; a user's clip is usually of
another.  What carries over (docs/method.md §8.4 measures it):

* **posture** -- the style's mean pose relative to the reference (neutral)
  style, much the same whatever the action: a per-coordinate offset of the
  root-relative pose (:func:`posture_offset`);
* **swing** -- how much each joint moves, per octave band of the motion
  (:func:`band_amplitudes`).  This depends on the action (an arm swings
  with a walk, not with a bow), so the style's gain over the reference is
  taken from the training actions whose reference-style spectra look most
  like the clip's (:func:`swing_gains`), and applied per band
  (:func:`filter_bands`).

Everything works on the root-relative pose ``(n, 32)`` (16 key points minus
the root, template units); the root keeps the clip's own path.  Signals are
extended by their mirror image before the Fourier transform, so a clip that
does not end as it starts is not treated as a jump back to its first frame
(which would bend its first and last frames).  Frequencies are in Hz of the
model's frame rate; with no rate, 30 frames per second is assumed.
"""
from __future__ import annotations

import numpy as np

from nnsf.skeleton.layout import N_JOINTS

#: Octave bands of a clip's motion below the Nyquist frequency: (0, f/64], (f/64, f/32], …, (f/4, f/2].
N_BANDS: int = 6
#: Band gains are clipped to this range (a style never more than quadruples or quarters a band).
GAIN_RANGE: tuple[float, float] = (0.25, 4.0)
#: Frame rate assumed when neither the model nor the caller gives one.
DEFAULT_FPS: float = 30.0
#: Floor of a band amplitude in the log descriptor that compares clips, template units (0.1 % of the torso).
_AMPLITUDE_FLOOR: float = 1e-3
#: The style eases in over this long at the start of a clip, seconds (see :func:`ease_in`).
ONSET_SECONDS: float = 0.5


def band_edges(fps: float) -> np.ndarray:
    """Edges of the :data:`N_BANDS` octave bands, Hz, ``(N_BANDS + 1,)``: 0, fps/64, …, fps/4, fps/2."""
    nyquist = float(fps) / 2.0
    return np.array([0.0] + [nyquist / 2.0 ** k for k in range(N_BANDS - 1, -1, -1)])


def root_relative(X) -> tuple[np.ndarray, np.ndarray]:
    """Features ``(n, 34)`` -> the root-relative pose ``(n, 32)`` and the root's path ``(n, 2)``."""
    P = np.asarray(X, dtype=float).reshape(len(X), N_JOINTS, 2)
    return (P[:, 1:] - P[:, :1]).reshape(len(P), -1), P[:, 0].copy()


def from_root_relative(R, root) -> np.ndarray:
    """Inverse of :func:`root_relative`: ``(n, 32)`` and ``(n, 2)`` -> features ``(n, 34)``."""
    R = np.asarray(R, dtype=float)
    root = np.asarray(root, dtype=float)
    P = np.concatenate([np.zeros((len(R), 1, 2)), R.reshape(len(R), N_JOINTS - 1, 2)], axis=1)
    return (P + root[:, None, :]).reshape(len(R), 2 * N_JOINTS)


def _mirror_spectrum(D, fps):
    """rfft of ``D`` (n, d) extended by its mirror image, and the bins' frequencies (Hz)."""
    E = np.concatenate([D, D[::-1]], axis=0)
    return np.fft.rfft(E, axis=0), np.fft.rfftfreq(len(E), 1.0 / fps), len(E)


def band_amplitudes(R, fps: float) -> np.ndarray:
    """Root-mean-square amplitude of each coordinate's motion per octave band, ``(N_BANDS, d)``.

    ``R`` is ``(n, d)`` (any unit); the motion is its deviation from the
    clip mean.  The squares over the bands sum to the coordinate's variance
    (Parseval), so a band's value is its share of the swing, in ``R``'s unit,
    whatever the clip's length.
    """
    R = np.asarray(R, dtype=float)
    F, f, N = _mirror_spectrum(R - R.mean(axis=0), fps)
    power = 2.0 * np.abs(F) ** 2 / N ** 2
    power[-1] /= 2.0            # the Nyquist bin (N is even) has no mirror in the one-sided spectrum
    e = band_edges(fps)
    return np.stack([np.sqrt(power[(f > lo) & (f <= hi)].sum(axis=0)) for lo, hi in zip(e[:-1], e[1:])])


def filter_bands(R, fps: float, gains) -> np.ndarray:
    """``R`` ``(n, d)`` with each coordinate's motion about its mean scaled per band by ``gains`` ``(N_BANDS, d)``.

    The gain of a frequency is interpolated linearly in log gain over log
    frequency between the bands' geometric centres (constant beyond the
    outer centres), so the spectrum is not cut into steps; the mean is kept.
    """
    R = np.asarray(R, dtype=float)
    mean = R.mean(axis=0)
    F, f, N = _mirror_spectrum(R - mean, fps)
    e = band_edges(fps)
    centres = np.sqrt(np.maximum(e[:-1], e[1] / 2.0) * e[1:])
    logf = np.log(np.maximum(f, f[1] if len(f) > 1 else 1.0))
    log_gain = np.log(np.asarray(gains, dtype=float))
    G = np.stack([np.interp(logf, np.log(centres), log_gain[:, j]) for j in range(R.shape[1])], axis=1)
    G[0] = 0.0
    return mean + np.fft.irfft(F * np.exp(G), N, axis=0)[: len(R)]


def describe(amplitudes) -> np.ndarray:
    """The vector that compares the motion of clips: log band amplitudes, flattened."""
    return np.log(np.asarray(amplitudes, dtype=float).ravel() + _AMPLITUDE_FLOOR)


def content_weights(descriptor, references) -> np.ndarray:
    """Weights ``(C,)`` of the training contents for a clip, from how alike their motions are.

    ``references`` ``(C, m)``: each content's :func:`describe` vector in the
    reference style; ``descriptor`` ``(m,)`` the clip's.  A Gaussian kernel
    of the Euclidean distances with a bandwidth of half their median, so the
    nearest few contents dominate whatever the scale; sums to 1.
    """
    d = np.linalg.norm(np.asarray(references, dtype=float) - np.asarray(descriptor, dtype=float), axis=1)
    h = 0.5 * float(np.median(d))
    w = np.ones_like(d) if h <= 0 else np.exp(-0.5 * (d / h) ** 2)
    if not w.sum() > 0:
        w = (d == d.min()).astype(float)
    return w / w.sum()


def swing_gains(target, reference, weights) -> np.ndarray:
    """Band gains ``(N_BANDS, d)``: Σ_c w_c A(target, c) / Σ_c w_c A(reference, c), clipped to :data:`GAIN_RANGE`.

    ``target``, ``reference`` ``(C, N_BANDS, d)`` band amplitudes per shared
    content; a ratio of weighted sums, so a content where the reference
    hardly moves does not blow up; 1 where the reference does not move.
    """
    w = np.asarray(weights, dtype=float)[:, None, None]
    num = (w * np.asarray(target, dtype=float)).sum(axis=0)
    den = (w * np.asarray(reference, dtype=float)).sum(axis=0)
    g = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 1.0)
    return np.clip(g, *GAIN_RANGE)


def posture_offset(target, reference) -> np.ndarray:
    """Mean root-relative pose of the target style minus the reference's, over shared contents, ``(d,)``.

    ``target``, ``reference`` ``(C, d)``: each shared content's mean pose in
    the two styles; every content weighs the same (posture is the part of a
    style that does not depend on the action).
    """
    return np.mean(np.asarray(target, dtype=float) - np.asarray(reference, dtype=float), axis=0)


def ease_in(n: int, fps: float) -> np.ndarray:
    """Weights ``(n,)`` rising from 0 at the first frame to 1 after :data:`ONSET_SECONDS` (half a cosine).

    The change a style makes is multiplied by them, so a clip starts in its
    own pose and settles into the style's without a jump; at most a quarter
    of a short clip is spent easing in.
    """
    m = min(int(round(ONSET_SECONDS * float(fps))), n // 4)
    w = np.ones(n)
    if m > 0:
        w[:m] = 0.5 - 0.5 * np.cos(np.pi * np.arange(m) / m)
    return w
