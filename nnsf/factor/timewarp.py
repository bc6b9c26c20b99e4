"""Time in style translation: dynamic time warping, resampling to a style's tempo, temporal smoothness (docs/method.md §8).

* :func:`joint_distance_matrix`, :func:`dtw_accumulate`, :func:`dtw_path`,
  :func:`dtw_align`: DTW of two clips of key points (mean per-joint
  Euclidean distance), used to align the clips of one content before the
  aligned fit and to score translations (docs/method.md §15.5);
* :func:`align_to_reference`, :func:`resample_clip`, the per-style tempo;
* :func:`second_difference_split`: the second-difference operator of the
  weights' temporal smoothness, split by clip.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from nnsf.skeleton.layout import N_FEATURES, N_JOINTS

def joint_distance_matrix(A, B) -> np.ndarray:
    """Mean per-joint Euclidean distance between every frame pair.

    Parameters
    ----------
    A : array (..., n, 34); B : array (..., m, 34)
        Feature rows ``x1, y1, … x17, y17`` in any one unit (leading batch
        dimensions broadcast).

    Returns
    -------
    array (..., n, m), in the features' unit.
    """
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    if A.shape[-1] != N_FEATURES or B.shape[-1] != N_FEATURES:
        raise ValueError(f"expected {N_FEATURES} feature columns, got {A.shape} and {B.shape}")
    out = None
    # One joint at a time keeps the work array at n × m instead of n × m × 34.
    for j in range(N_JOINTS):
        dx = A[..., :, None, 2 * j] - B[..., None, :, 2 * j]
        dy = A[..., :, None, 2 * j + 1] - B[..., None, :, 2 * j + 1]
        dist = np.sqrt(dx * dx + dy * dy)
        out = dist if out is None else out + dist
    return out / N_JOINTS


def dtw_accumulate(cost) -> np.ndarray:
    """Accumulated DTW cost ``D`` of a cost matrix (symmetric steps, unit weights).

    ``D[i, j] = C[i, j] + min(D[i−1, j−1], D[i−1, j], D[i, j−1])``.  Each row
    is computed at once: the in-row recursion D[i, j] = min(t[j], D[i, j−1] +
    C[i, j]) is a min-plus scan, D[i, j] = S[j] + min_{l ≤ j}(t[l] − S[l]) with S
    the running sum of the row's costs, i.e. ``np.minimum.accumulate``.

    Parameters
    ----------
    cost : array (..., n, m), non-negative; leading dimensions are a batch.

    Returns
    -------
    D : array (..., n, m); ``D[..., -1, -1]`` is the DTW distance (sum of the
    costs along the best path).
    """
    C = np.asarray(cost, dtype=float)
    if C.ndim < 2 or C.shape[-1] == 0 or C.shape[-2] == 0:
        raise ValueError(f"dtw: need a cost matrix (..., n, m) with n, m >= 1, got {C.shape}")
    D = np.empty_like(C)
    D[..., 0, :] = np.cumsum(C[..., 0, :], axis=-1)
    best = np.empty(C.shape[:-2] + C.shape[-1:])
    for i in range(1, C.shape[-2]):
        prev = D[..., i - 1, :]
        best[..., 0] = prev[..., 0]
        np.minimum(prev[..., 1:], prev[..., :-1], out=best[..., 1:])
        row = C[..., i, :]
        S = np.cumsum(row, axis=-1)
        t = best + row - S
        D[..., i, :] = np.minimum.accumulate(t, axis=-1) + S
    return D


def dtw_path(D) -> np.ndarray:
    """Backtrack the best path through an accumulated cost ``D`` (n, m).

    Returns
    -------
    path : int array (L, 2) of (i, j) pairs from (0, 0) to (n−1, m−1),
    monotone in both, each step (1, 1), (1, 0) or (0, 1).  Ties prefer the
    diagonal step.
    """
    D = np.asarray(D)
    i, j = D.shape[0] - 1, D.shape[1] - 1
    out = [(i, j)]
    while i > 0 or j > 0:
        if i == 0:
            j -= 1
        elif j == 0:
            i -= 1
        else:
            a, b, c = D[i - 1, j - 1], D[i - 1, j], D[i, j - 1]
            if a <= b and a <= c:
                i, j = i - 1, j - 1
            elif b <= c:
                i -= 1
            else:
                j -= 1
        out.append((i, j))
    return np.array(out[::-1], dtype=int)


def dtw_align(A, B):
    """DTW of two clips of features by mean per-joint distance.

    Parameters
    ----------
    A : array (n, 34); B : array (m, 34) (or a batch ``(b, n, 34)`` of clips of
        equal length against one ``B``).

    Returns
    -------
    error : float (or array (b,))
        Mean per-joint Euclidean distance over the pairs of the best path
        (the accumulated cost divided by the path length), in the features'
        unit -- zero iff ``A`` is a time warp of ``B``.
    path : int array (L, 2), or a list of them for a batch.
    """
    A = np.asarray(A, dtype=float)
    C = joint_distance_matrix(A, np.asarray(B, dtype=float))
    D = dtw_accumulate(C)
    if C.ndim == 2:
        p = dtw_path(D)
        return float(D[-1, -1] / len(p)), p
    paths = [dtw_path(d) for d in D]
    return np.array([d[-1, -1] / len(p) for d, p in zip(D, paths)]), paths


def align_to_reference(X, X_ref) -> np.ndarray:
    """Reference frame of every frame of ``X`` (n, 34) under DTW to ``X_ref`` (m, 34).

    Where DTW maps a frame to several reference frames, their rounded mean is
    used.  Returns an int array (n,) of indices into ``X_ref``.
    """
    _, path = dtw_align(X, X_ref)
    n = np.asarray(X).shape[0]
    sums = np.bincount(path[:, 0], weights=path[:, 1], minlength=n)
    counts = np.bincount(path[:, 0], minlength=n)
    return np.rint(sums / counts).astype(int)


def resample_clip(X, m: int) -> np.ndarray:
    """Clip ``X`` (n, d) resampled to ``m`` frames by linear interpolation (ends kept)."""
    X = np.asarray(X, dtype=float)
    n = len(X)
    if m == n or n == 1:
        return X.copy() if n != 1 else np.repeat(X, m, axis=0)
    t = np.linspace(0.0, n - 1.0, int(m))
    i0 = np.minimum(np.floor(t).astype(int), n - 2)
    w = (t - i0)[:, None]
    return X[i0] * (1.0 - w) + X[i0 + 1] * w


def _style_tempo(clips: dict) -> dict:
    """Per style, the median of (clip length / mean length of that content's clips).

    Only contents performed by at least two styles count (a content of one
    style says nothing about tempo); styles without such a clip get 1.0.
    ``clips`` maps (style, content) -> list of arrays.
    """
    by_content: dict[str, list[int]] = {}
    n_styles: dict[str, set] = {}
    for (s, c), lst in clips.items():
        by_content.setdefault(c, []).extend(len(x) for x in lst)
        n_styles.setdefault(c, set()).add(s)
    ratios: dict[str, list[float]] = {}
    for (s, c), lst in clips.items():
        if len(n_styles[c]) >= 2:
            ratios.setdefault(s, []).extend(len(x) / np.mean(by_content[c]) for x in lst)
    # Sorted, not a set's order: a set of strings iterates in a per-process hash order, which
    # would make the saved model's bytes differ from run to run.
    return {s: float(np.median(ratios[s])) if s in ratios else 1.0 for s in sorted({s for s, _ in clips})}


def second_difference_split(chains, R: int):
    """``(L⁺, L⁻)``, sparse ``(R, R)``: L = D₂ᵀD₂ = L⁺ − L⁻ split by sign, both non-negative.

    D₂ has one row e_r − 2e_{r+1} + e_{r+2} for every three consecutive rows
    inside one chain (``chains``: ``(start, stop)`` row ranges), so
    ½‖D₂W‖² is the summed squared second difference (acceleration) of the
    rows of W along each chain.  The gradient L W splits into L⁺W − L⁻W with
    non-negative parts, the form a multiplicative update needs (as the
    first-difference graph Laplacian splits into degree and adjacency).
    """
    r0 = np.concatenate([np.arange(a, b - 2) for a, b in chains if b - a >= 3] or [np.zeros(0, int)])
    m = len(r0)
    D2 = sp.csr_matrix((np.tile([1.0, -2.0, 1.0], m),
                        (np.repeat(np.arange(m), 3), (r0[:, None] + np.arange(3)).ravel())), shape=(m, R))
    L = (D2.T @ D2).tocsr()
    Lpos = L.multiply(L > 0).tocsr()
    Lneg = (-L).multiply(L < 0).tocsr()
    return Lpos, Lneg
