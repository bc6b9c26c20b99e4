"""Curve groups and the spline model of tracked outline curves.

A tracked curve is given by P control points and interpolated by a
**uniform open Catmull-Rom spline** with reflected end phantoms
(``P[-1] = 2 P[0] - P[1]``, ``P[n] = 2 P[n-1] - P[n-2]``).  It passes through
every control point, two points give a straight segment, and its samples are
a fixed linear map of the control points (:func:`catmull_rom_matrix`), which
keeps a tracker's least-squares problem sparse and its Jacobian constant.

Curve groups (docs/formats.md §2.2): the eight limbs of :data:`nnsf.skeleton.LIMBS`,
then ``torso`` (thorax → pelvis) and ``head`` (neck → head top); each has two
side curves ``<group>.a`` (on the +R90·d side of the bone d = end − start)
and ``<group>.b`` (on the −R90·d side), both running from the start joint to
the end joint.
"""
from __future__ import annotations

import numpy as np

from nnsf.skeleton.layout import JOINT_INDEX, LIMBS

#: Curve groups in the fixed order used by every array of this package.
GROUPS: tuple[str, ...] = tuple(LIMBS) + ("torso", "head")
#: (start joint, end joint) indices of every group.
GROUP_JOINTS: dict[str, tuple[int, int]] = dict(LIMBS) | {
    "torso": (JOINT_INDEX["thorax"], JOINT_INDEX["pelvis"]),
    "head": (JOINT_INDEX["neck"], JOINT_INDEX["head_top"]),
}
#: Side-curve names, two per group in :data:`GROUPS` order (a then b).
SIDE_NAMES: tuple[str, ...] = tuple(f"{g}.{s}" for g in GROUPS for s in "ab")
SIDE_INDEX: dict[str, int] = {n: i for i, n in enumerate(SIDE_NAMES)}



def catmull_rom_basis(n_ctrl: int, t: np.ndarray) -> np.ndarray:
    """Weights of the ``n_ctrl`` control points at spline parameters ``t``.

    ``t`` (any shape) runs from 0 (first control point) to ``n_ctrl - 1``
    (last); values outside are clamped.  Returns ``t.shape + (n_ctrl,)``, so
    that ``basis @ control`` gives the points.
    """
    n = int(n_ctrl)
    if n < 2:
        raise ValueError(f"a curve needs at least 2 control points, got {n}")
    t = np.clip(np.asarray(t, dtype=np.float64), 0.0, n - 1)
    seg = np.minimum(np.floor(t).astype(np.int64), n - 2)       # segment i: P_i -> P_{i+1}
    s = t - seg
    s2, s3 = s * s, s * s * s
    # Uniform Catmull-Rom weights of P_{i-1}, P_i, P_{i+1}, P_{i+2}.
    w = 0.5 * np.stack([-s3 + 2 * s2 - s, 3 * s3 - 5 * s2 + 2, -3 * s3 + 4 * s2 + s, s3 - s2],
                       axis=-1)
    # Extended points E_k = P_{k-1}, k = 0..n+1, with the reflected phantoms,
    # written as rows of an (n + 2, n) matrix over the real control points.
    ext = np.zeros((n + 2, n))
    ext[1:-1] = np.eye(n)
    ext[0, 0], ext[0, 1] = 2.0, -1.0
    ext[-1, -1], ext[-1, -2] = 2.0, -1.0
    idx = seg[..., None] + np.arange(4)                          # E indices i..i+3
    return np.einsum("...k,...kn->...n", w, ext[idx])


def catmull_rom_matrix(n_ctrl: int, n_samples: int) -> np.ndarray:
    """``(n_samples, n_ctrl)`` map from control points to samples uniform in the parameter.

    The first and last samples are the first and last control points.
    """
    if int(n_samples) < 2:
        raise ValueError(f"n_samples must be >= 2, got {n_samples}")
    return catmull_rom_basis(n_ctrl, np.linspace(0.0, n_ctrl - 1, int(n_samples)))


def sample_curve(control: np.ndarray, n_samples: int) -> np.ndarray:
    """Points of the spline: control ``(..., P, 2)`` -> ``(..., n_samples, 2)`` (same units)."""
    control = np.asarray(control, dtype=np.float64)
    return catmull_rom_matrix(control.shape[-2], n_samples) @ control



def _project(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest points on a fine polyline: distances ``(..., N)`` and positions in vertex units.

    Finds the nearest vertex with one matrix product, then projects onto its
    two adjacent segments.  Exact when the nearest polyline point lies on a
    segment touching the nearest vertex (true for polylines much finer than
    their curvature, as here).
    """
    q = np.asarray(points, dtype=np.float64)
    c = np.asarray(polyline, dtype=np.float64)
    batch = np.broadcast_shapes(q.shape[:-2], c.shape[:-2])
    q = np.broadcast_to(q, batch + q.shape[-2:]).reshape(-1, q.shape[-2], 2)
    c = np.broadcast_to(c, batch + c.shape[-2:]).reshape(-1, c.shape[-2], 2)
    M = c.shape[1]
    d2 = (c * c).sum(-1)[:, None, :] - 2.0 * np.matmul(q, c.transpose(0, 2, 1))
    k = np.argmin(d2, axis=2)                                      # (B, N)
    rows = np.arange(c.shape[0])[:, None]
    best_d = np.full(k.shape, np.inf)
    best_t = k.astype(np.float64)
    for lo in (k - 1, k):                                          # segments (k-1, k) and (k, k+1)
        lo = np.clip(lo, 0, M - 2)
        a, b = c[rows, lo], c[rows, lo + 1]
        ab = b - a
        u = np.clip(((q - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300), 0.0, 1.0)
        d = np.linalg.norm(q - (a + u[..., None] * ab), axis=-1)
        better = d < best_d
        best_d = np.where(better, d, best_d)
        best_t = np.where(better, lo + u, best_t)
    shape = batch + (q.shape[1],)
    return best_d.reshape(shape), best_t.reshape(shape)


def fit_control_points(truth: np.ndarray, n_ctrl: int = 5, iterations: int = 8,
                       dense: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """Fit control points so that the spline follows dense curve samples.

    truth ``(..., N, 2)``: samples along each curve, in order (N >= n_ctrl).
    The end control points are the curve's end samples exactly; the inner
    ones are found by alternating a linear least-squares solve with
    re-projecting every sample onto the spline (drawn as ``dense`` samples).
    Returns ``(control (..., n_ctrl, 2), error (...,))``, error = the largest
    distance (px) of a truth sample from the spline.
    """
    truth = np.asarray(truth, dtype=np.float64)
    n = int(n_ctrl)
    batch, N = truth.shape[:-2], truth.shape[-2]
    X = truth.reshape(-1, N, 2)
    B = X.shape[0]
    # Initial parameters: chord length, scaled to [0, n-1].
    seg = np.linalg.norm(np.diff(X, axis=1), axis=-1)
    cum = np.concatenate([np.zeros((B, 1)), np.cumsum(seg, axis=1)], axis=1)
    t = cum / np.maximum(cum[:, -1:], 1e-12) * (n - 1)
    Mg = catmull_rom_matrix(n, dense)                             # (dense, n)
    step = (n - 1) / (dense - 1)
    ctrl = np.empty((B, n, 2))
    ctrl[:, 0], ctrl[:, -1] = X[:, 0], X[:, -1]
    for it in range(iterations):
        if n > 2:
            W = catmull_rom_basis(n, t)                           # (B, N, n)
            rhs = X - W[..., :1] * X[:, None, 0] - W[..., -1:] * X[:, None, -1]
            A = W[..., 1:-1]
            AtA = np.einsum("bki,bkj->bij", A, A) + 1e-9 * np.eye(n - 2)
            Atr = np.einsum("bki,bkd->bid", A, rhs)
            ctrl[:, 1:-1] = np.linalg.solve(AtA, Atr)
        dist, pos = _project(X, Mg @ ctrl)
        t = pos * step
        t[:, 0], t[:, -1] = 0.0, n - 1
    return ctrl.reshape(batch + (n, 2)), dist.max(axis=-1).reshape(batch)
