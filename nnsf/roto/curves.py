"""The curve model: an open uniform Catmull-Rom spline through control points.

A curve with control points ``P`` of shape ``(C, 2)`` (px, x right, y down)
is the piecewise cubic through P_0 .. P_{C-1}; the missing end neighbours
are reflected (P_{-1} = 2 P_0 - P_1, P_C = 2 P_{C-1} - P_{C-2}), so two
control points give a straight segment traversed at constant speed.  The
uniform parameterisation keeps every sample a fixed LINEAR combination of
the control points: ``samples = B0 @ P``, ``tangents = B1 @ P``,
``second derivatives = B2 @ P`` with constant matrices ``(n, C)`` per
``(C, n)``.  That makes the tracker's Jacobians cheap (see
:mod:`nnsf.roto.energy`).

Derivatives are taken with respect to the sample index (not the spline
parameter), so ``|B1 @ P|`` is roughly the spacing between samples in px and
``B2 @ P`` the discrete curvature vector in px: the shape terms then have
pixel units at every control-point count.

The same spline as :func:`nnsf.frames.curves.catmull_rom_matrix` (annotations
and rendered ground truth); ``B0`` equals it to within one rounding (2e-16).
The two are kept apart on purpose: merging them would move the tracker's and
the renderer's results by that rounding and so every versioned output hash,
for no change in the model.
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np


def _extension(n_control: int) -> np.ndarray:
    """Matrix ``(C + 2, C)`` appending the reflected end neighbours."""
    C = n_control
    E = np.zeros((C + 2, C))
    E[1:C + 1] = np.eye(C)
    E[0, 0], E[0, 1] = 2.0, -1.0
    E[C + 1, C - 1], E[C + 1, C - 2] = 2.0, -1.0
    return E


@lru_cache(maxsize=64)
def _basis_cached(n_control: int, n_samples: int):
    C, n = n_control, n_samples
    u = np.linspace(0.0, C - 1.0, n)
    seg = np.minimum(np.floor(u).astype(int), C - 2)
    s = u - seg
    s2, s3 = s * s, s * s * s
    w0 = 0.5 * np.stack([-s + 2 * s2 - s3, 2 - 5 * s2 + 3 * s3, s + 4 * s2 - 3 * s3, -s2 + s3], 1)
    w1 = 0.5 * np.stack([-1 + 4 * s - 3 * s2, -10 * s + 9 * s2, 1 + 8 * s - 9 * s2, -2 * s + 3 * s2], 1)
    w2 = 0.5 * np.stack([4 - 6 * s, -10 + 18 * s, 8 - 18 * s, -2 + 6 * s], 1)
    E = _extension(C)
    out = []
    h = (C - 1.0) / (n - 1.0)  # spline parameter per sample step
    for W, scale in ((w0, 1.0), (w1, h), (w2, h * h)):
        ext = np.zeros((n, C + 2))
        # segment k uses extended points k .. k+3 (i.e. P_{k-1} .. P_{k+2})
        cols = seg[:, None] + np.arange(4)[None, :]
        np.put_along_axis(ext, cols, W, axis=1)
        M = scale * ext @ E
        M[np.abs(M) < 1e-14] = 0.0
        M.setflags(write=False)
        out.append(M)
    return tuple(out)


def basis(n_control: int, n_samples: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constant sampling matrices ``(B0, B1, B2)``, each ``(n_samples, n_control)``.

    ``B0 @ P`` are ``n_samples`` points equally spaced in the spline parameter
    from P_0 to P_{C-1}; ``B1 @ P`` the tangents and ``B2 @ P`` the second
    derivatives, both per sample step (px).  Read-only, cached.
    """
    if n_control < 2:
        raise ValueError(f"a curve needs at least 2 control points, got {n_control}")
    if n_samples < 2:
        raise ValueError(f"need at least 2 samples, got {n_samples}")
    return _basis_cached(int(n_control), int(n_samples))


def sample(P: np.ndarray, n_samples: int) -> np.ndarray:
    """Points on the curve(s): ``(..., C, 2)`` control points -> ``(..., n_samples, 2)``."""
    P = np.asarray(P, dtype=np.float64)
    B0, _, _ = basis(P.shape[-2], n_samples)
    return np.einsum("nc,...cd->...nd", B0, P)


def tangents(P: np.ndarray, n_samples: int) -> np.ndarray:
    """Tangents per sample step ``(..., n_samples, 2)`` (px)."""
    P = np.asarray(P, dtype=np.float64)
    _, B1, _ = basis(P.shape[-2], n_samples)
    return np.einsum("nc,...cd->...nd", B1, P)


def rot90(v: np.ndarray) -> np.ndarray:
    """+90° rotation of vectors ``(..., 2)``: (x, y) -> (-y, x) (same R90 as the limb model)."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def normals(P: np.ndarray, n_samples: int) -> np.ndarray:
    """Unit normals R90·t/|t| ``(..., n_samples, 2)``; the normal points to side "a"."""
    t = tangents(P, n_samples)
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    return rot90(t / np.maximum(norm, 1e-9))


def dense(P: np.ndarray, spacing: float = 0.25) -> np.ndarray:
    """The curve sampled densely (about ``spacing`` px apart) as a polyline ``(m, 2)``.

    ``P`` is one curve ``(C, 2)``.  Used to compare tracked curves with truth.
    """
    P = np.asarray(P, dtype=np.float64)
    coarse = sample(P, 8 * (P.shape[0] - 1) + 1)
    length = float(np.linalg.norm(np.diff(coarse, axis=0), axis=1).sum())
    n = int(np.clip(np.ceil(length / spacing), 2, 20000)) + 1
    return sample(P, n)


def project_to_polyline(points: np.ndarray, polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest points on polylines.

    points (..., N, 2), polyline (..., M, 2) with the same leading shape.
    Returns ``dist (..., N)`` and ``nearest (..., N, 2)`` (px); brute force
    over all M-1 segments, exact.  :func:`nearest_vertex` gives the index.
    """
    dist, nearest, _ = polyline_projection(points, polyline)
    return dist, nearest


def nearest_vertex(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Index (..., N) of the polyline vertex closest to each point's projection."""
    return polyline_projection(points, polyline)[2]


def polyline_projection(points, polyline):
    """``(dist, nearest, vertex)`` of each point's projection onto a polyline (brute force, exact).

    The shapes of :func:`project_to_polyline`, plus ``vertex (..., N)``: the
    index of the polyline vertex nearest the projection.
    """
    q = np.asarray(points, np.float64)[..., :, None, :]            # (..., N, 1, 2)
    c = np.asarray(polyline, np.float64)
    a = c[..., None, :-1, :]                                        # (..., 1, M-1, 2)
    ab = c[..., None, 1:, :] - a
    u = ((q - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-300)
    u = np.clip(u, 0.0, 1.0)
    near = a + u[..., None] * ab                                    # (..., N, M-1, 2)
    d = np.linalg.norm(q - near, axis=-1)
    k = np.argmin(d, axis=-1)
    dist = np.take_along_axis(d, k[..., None], -1)[..., 0]
    nearest = np.take_along_axis(near, k[..., None, None], -2)[..., 0, :]
    uk = np.take_along_axis(u, k[..., None], -1)[..., 0]
    return dist, nearest, k + (uk > 0.5)
