"""What the two Gaussian-process baselines are fitted on: per-cell phase bins.

A GP costs O(n³) time and O(n²) memory in its number of training points n, so
neither GP baseline (:mod:`nnsf.factor.mgpm`, :mod:`nnsf.factor.cbgpm`) is fitted
on every frame.  Each is fitted on a *documented subsample*: for every
observed (style, content) cell, its frames are put into ``B`` equal bins of
the motion's phase (the frame's position in its clip, 0 at the first frame, 1
at the last) and each bin is replaced by the mean of its frames, at the mean
phase of its frames.  A full grid
of S styles × C contents gives at most ``n = S·C·B`` points, e.g. 9 × 15 × 3 =
405 for the embedded dataset -- instead of 9,720 frames.

Shapes: ``X`` is ``(n_frames, d)``; the subsample is ``(n_points, d)`` with
one style, content and phase per point.
"""
from __future__ import annotations

import numbers

import numpy as np

__all__ = ["phase_from_groups", "check_phase", "phase_bins", "bin_centres", "interpolate_bins"]


def phase_from_groups(groups) -> np.ndarray:
    """Phase in [0, 1] of every row from its position within its clip.

    ``groups`` (n,) is the clip of each row; rows of a clip are taken in the
    order given (the contract sorts by clip, then frame).  A clip of one frame
    has phase 0.

    Returns
    -------
    ndarray of float, shape (n,)
    """
    groups = np.asarray(groups)
    if groups.ndim != 1:
        raise ValueError(f"groups must be one-dimensional, got shape {groups.shape}")
    _, inverse, counts = np.unique(groups, return_inverse=True, return_counts=True)
    # Position of each row among the rows of its clip, in table order.
    order = np.argsort(inverse, kind="stable")
    position = np.empty(len(groups), dtype=float)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    position[order] = np.arange(len(groups)) - np.repeat(starts, counts)
    span = np.maximum(counts[inverse] - 1, 1)
    return position / span


def check_phase(phase, n) -> np.ndarray:
    """``phase`` as a float array of shape (n,) with values in [0, 1]."""
    phase = np.asarray(phase, dtype=float)
    if phase.shape != (n,):
        raise ValueError(f"phase must give one value per row of X ({n}), got shape {phase.shape}")
    if not np.all(np.isfinite(phase)) or phase.min() < 0 or phase.max() > 1:
        raise ValueError("phase must lie in [0, 1] (0: first frame of a clip, 1: last)")
    return phase


def bin_centres(n_bins: int) -> np.ndarray:
    """Phases of the ``n_bins`` bin centres, ``(b + ½) / B``; shape (B,)."""
    return (np.arange(n_bins) + 0.5) / n_bins


def phase_bins(X, style, content, phase, n_bins: int, field: str = "phase_bins"):
    """Mean frame per (style, content, phase bin): the GP baselines' training points.

    Parameters
    ----------
    X : array, shape (n, d)
    style, content : arrays, shape (n,)
    phase : array, shape (n,), values in [0, 1]
    n_bins : int >= 1
        ``B``; must not exceed the frames of the smallest observed cell
        (otherwise some bins would be empty: the subsample would be larger
        than the data).
    field : str
        Name used for ``n_bins`` in the error message.

    Returns
    -------
    styles : ndarray (S,), sorted style labels
    contents : ndarray (C,), sorted content labels
    means : ndarray (S, C, B, d), NaN where a bin is empty or a cell missing
    observed : ndarray of bool (S, C, B)
    mean_phase : ndarray (S, C, B)
        Mean phase of the frames in each bin (NaN where empty): the state a
        bin mean stands for (near, but at the ends not at, the bin centre).

    Raises
    ------
    ValueError
        ``n_bins`` not an integer >= 1, or larger than the smallest cell.
    """
    X = np.asarray(X, dtype=float)
    n, d = X.shape
    if not (isinstance(n_bins, numbers.Integral) and not isinstance(n_bins, bool) and n_bins >= 1):
        raise ValueError(f"{field} must be an integer >= 1, got {n_bins!r}")
    style, content = np.asarray(style), np.asarray(content)
    styles, s_idx = np.unique(style, return_inverse=True)
    contents, c_idx = np.unique(content, return_inverse=True)
    S, C = len(styles), len(contents)
    cell_size = np.bincount(s_idx * C + c_idx, minlength=S * C)
    smallest = int(cell_size[cell_size > 0].min())
    if n_bins > smallest:
        raise ValueError(f"{field}={n_bins} exceeds the frames of the smallest (style, content) "
                         f"cell ({smallest}): the subsample cannot be larger than the data")
    b_idx = np.minimum((np.asarray(phase, dtype=float) * n_bins).astype(int), n_bins - 1)
    flat = (s_idx * C + c_idx) * n_bins + b_idx
    counts = np.bincount(flat, minlength=S * C * n_bins).astype(float)
    sums = np.zeros((S * C * n_bins, d))
    np.add.at(sums, flat, X)
    with np.errstate(invalid="ignore", divide="ignore"):
        means = sums / counts[:, None]
    means[counts == 0] = np.nan
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_phase = np.bincount(flat, weights=np.asarray(phase, dtype=float), minlength=S * C * n_bins) / counts
    shape = (S, C, n_bins)
    return (styles, contents, means.reshape(*shape, d), (counts > 0).reshape(shape),
            mean_phase.reshape(shape))


def interpolate_bins(values, phase) -> np.ndarray:
    """Piecewise-linear interpolation of per-bin values at arbitrary phases.

    ``values`` (B, k) are given at the bin centres; phases before the first or
    after the last centre take the end value.  Returns ``(len(phase), k)``.
    """
    values = np.asarray(values, dtype=float)
    phase = np.asarray(phase, dtype=float)
    centres = bin_centres(values.shape[0])
    if values.shape[0] == 1:
        return np.repeat(values, len(phase), axis=0)
    return np.stack([np.interp(phase, centres, values[:, j]) for j in range(values.shape[1])], axis=1)


def check_int(name, value, lo=1):
    """Raise ``ValueError`` unless ``value`` is an integer (not a bool) of at least ``lo``."""
    if not (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= lo):
        raise ValueError(f"{name} must be an integer >= {lo}, got {value!r}")


def check_labels(values, n, what):
    """``values`` as an array of shape ``(n,)``: one label per row of X, else ``ValueError``."""
    values = np.asarray(values)
    if values.shape != (n,):
        raise ValueError(f"{what} must give one label per row of X ({n}), got shape {values.shape}")
    return values
