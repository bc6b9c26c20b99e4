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
  (:func:`filter_bands`) in the four octaves of human movement, 0.5-8 Hz.

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

#: Edges of the octave bands a clip's motion is measured in, Hz: drift slower than one cycle in two
#: seconds, the four octaves of human movement 0.5-8 Hz, and tremor and capture noise above.
BAND_EDGES: tuple[float, ...] = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, np.inf)
N_BANDS: int = len(BAND_EDGES) - 1
#: The bands a style's swing is transferred in (0.5-8 Hz).  Below, a take's posture drifts over
#: seconds as the take was cut; above is tremor and noise: their ratios are not a style's.
SWING_BANDS: np.ndarray = np.array([0.5 <= lo and hi <= 8.0 for lo, hi in zip(BAND_EDGES[:-1], BAND_EDGES[1:])])
#: Band gains are clipped to this range (a style never more than quadruples or quarters a band).
GAIN_RANGE: tuple[float, float] = (0.25, 4.0)
#: Frame rate assumed when neither the model nor the caller gives one.
DEFAULT_FPS: float = 30.0
#: Floor of a band amplitude in the log descriptor that compares clips, template units (0.1 % of the torso).
_AMPLITUDE_FLOOR: float = 1e-3
#: The style eases in over this long at the start of a clip, seconds (see :func:`ease_in`).
ONSET_SECONDS: float = 0.5


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
    """Root-mean-square amplitude of each coordinate's motion per band of :data:`BAND_EDGES`, ``(N_BANDS, d)``.

    ``R`` is ``(n, d)`` (any unit); the motion is its deviation from the
    clip mean.  The squares over the bands sum to the coordinate's variance
    (Parseval), so a band's value is its share of the swing, in ``R``'s unit,
    whatever the clip's length.
    """
    R = np.asarray(R, dtype=float)
    F, f, N = _mirror_spectrum(R - R.mean(axis=0), fps)
    power = 2.0 * np.abs(F) ** 2 / N ** 2
    power[-1] /= 2.0            # the Nyquist bin (N is even) has no mirror in the one-sided spectrum
    e = BAND_EDGES
    return np.stack([np.sqrt(power[(f > lo) & (f <= hi)].sum(axis=0)) for lo, hi in zip(e[:-1], e[1:])])


def resolved_bands(n: int, fps: float) -> np.ndarray:
    """Which octave bands a clip of ``n`` frames can measure, ``(N_BANDS,)`` bool.

    The mirror-extended clip (``2n`` frames) has Fourier bins every
    ``fps / 2n`` Hz; a band no bin falls in says nothing about the motion at
    those frequencies (a short take cannot show a slow sway), so its zero
    amplitude is no evidence and must not enter a ratio.
    """
    f = np.fft.rfftfreq(2 * int(n), 1.0 / fps)[1:]
    e = BAND_EDGES
    return np.array([bool(((f > lo) & (f <= hi)).any()) for lo, hi in zip(e[:-1], e[1:])])


def filter_bands(R, fps: float, gains) -> np.ndarray:
    """``R`` ``(n, d)`` with each coordinate's motion about its mean scaled per band by ``gains`` ``(N_BANDS, d)``.

    The gain of a frequency is interpolated linearly in log gain over log
    frequency between the bands' geometric centres (constant beyond the
    outer centres), so the spectrum is not cut into steps; the mean is kept.
    """
    R = np.asarray(R, dtype=float)
    mean = R.mean(axis=0)
    F, f, N = _mirror_spectrum(R - mean, fps)
    e = np.array(BAND_EDGES)
    lo = np.maximum(e[:-1], e[1] / 2.0)
    centres = np.sqrt(lo * np.where(np.isfinite(e[1:]), e[1:], 2.0 * lo))
    logf = np.log(np.maximum(f, f[1] if len(f) > 1 else 1.0))
    log_gain = np.log(np.asarray(gains, dtype=float))
    G = np.stack([np.interp(logf, np.log(centres), log_gain[:, j]) for j in range(R.shape[1])], axis=1)
    G[0] = 0.0
    return mean + np.fft.irfft(F * np.exp(G), N, axis=0)[: len(R)]


def describe(amplitudes) -> np.ndarray:
    """The vector that compares the motion of clips: log band amplitudes, flattened (NaN: not measured)."""
    return np.log(np.asarray(amplitudes, dtype=float).ravel() + _AMPLITUDE_FLOOR)


def content_weights(descriptor, references) -> np.ndarray:
    """Weights ``(C,)`` of the training contents for a clip, from how alike their motions are.

    ``references`` ``(C, m)``: each content's :func:`describe` vector in the
    reference style; ``descriptor`` ``(m,)`` the clip's.  Distances are
    Euclidean over the entries both measured (scaled to all ``m``); a Gaussian
    kernel of them with a bandwidth of half their median, so the nearest few
    contents dominate whatever the scale; sums to 1.
    """
    ref = np.asarray(references, dtype=float)
    diff = ref - np.asarray(descriptor, dtype=float)
    both = np.isfinite(diff)
    shared = both.sum(axis=1)
    sq = np.where(both, diff, 0.0) ** 2
    d = np.where(shared > 0, np.sqrt(sq.sum(axis=1) * ref.shape[1] / np.maximum(shared, 1)), np.inf)
    finite = np.isfinite(d)
    if not finite.any():
        return np.full(len(d), 1.0 / len(d))
    h = 0.5 * float(np.median(d[finite]))
    w = np.where(finite, 1.0, 0.0) if h <= 0 else np.where(finite, np.exp(-0.5 * (d / max(h, 1e-300)) ** 2), 0.0)
    if not w.sum() > 0:
        w = (d == d[finite].min()).astype(float)
    return w / w.sum()


def swing_gains(target, reference, weights) -> np.ndarray:
    """Band gains ``(N_BANDS, d)``: Σ_c w_c A(target, c) / Σ_c w_c A(reference, c), clipped to :data:`GAIN_RANGE`.

    ``target``, ``reference`` ``(C, N_BANDS, d)`` band amplitudes per shared
    content, NaN where a cell's clips cannot measure a band
    (:func:`resolved_bands`): each band's sums run over the contents both
    styles measured it in.  A ratio of weighted sums, so a content where the
    reference hardly moves does not blow up; 1 where the reference does not
    move, where no content measured the band and outside :data:`SWING_BANDS`.
    """
    t = np.asarray(target, dtype=float)
    r = np.asarray(reference, dtype=float)
    w = np.broadcast_to(np.asarray(weights, dtype=float)[:, None, None], t.shape)
    both = np.isfinite(t) & np.isfinite(r)
    num = np.where(both, w * np.where(both, t, 0.0), 0.0).sum(axis=0)
    den = np.where(both, w * np.where(both, r, 0.0), 0.0).sum(axis=0)
    g = np.where(den > 1e-12, num / np.maximum(den, 1e-12), 1.0)
    g[~SWING_BANDS] = 1.0
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
