"""Deformation measures (docs/method.md §15.7), vectorised over frames and triangles.

Every triangle's rest → deformed map is affine; its linear part J ``(2, 2)`` solves
J [e₁ e₂]_rest = [e₁ e₂]_deformed for two edges.  Its singular values σ1 ≥ σ2 measure stretch:
a rigid map has σ1 = σ2 = 1, a flip has det J < 0.  Arrays: rest vertices ``(n, 2)``, deformed
``(n, 2)`` or ``(T, n, 2)``, triangles ``(t, 3)`` counter-clockwise at rest; lengths in pixels.
"""
from __future__ import annotations

import numpy as np

from nnsf.reshape.arap import barycentric
from nnsf.reshape.limbs import N_LIMBS, bezier, control_from_omega, endpoints, omega_from_control
from nnsf.reshape.mesh import boundary_edges, triangle_areas


def jacobians(rest: np.ndarray, deformed: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Linear part J of every triangle's affine map, ``(..., t, 2, 2)``."""
    p = rest[triangles]
    Dr = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=-1)
    q = deformed[..., triangles, :]
    Dd = np.stack([q[..., 1, :] - q[..., 0, :], q[..., 2, :] - q[..., 0, :]], axis=-1)
    return Dd @ np.linalg.inv(Dr)


def singular_values(J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ1 ≥ σ2 ≥ 0 and det of 2×2 maps ``(..., 2, 2)`` in closed form: for J = [[a, b], [c, d]],
    σ1,2 = (√((a+d)² + (c−b)²) ± √((a−d)² + (b+c)²)) / 2."""
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    s, r = np.hypot(a + d, c - b), np.hypot(a - d, b + c)
    return 0.5 * (s + r), 0.5 * np.abs(s - r), a * d - b * c


def arap_energy(rest, deformed, triangles) -> np.ndarray:
    """Σ area·((σ1−1)² + (σ2−1)²), px², per frame ``(...)``."""
    s1, s2, _ = singular_values(jacobians(rest, deformed, triangles))
    return (triangle_areas(rest, triangles) * ((s1 - 1) ** 2 + (s2 - 1) ** 2)).sum(-1)


def stretch_ratio(rest, deformed, triangles) -> np.ndarray:
    """σ1/σ2 per triangle ``(..., t)``; ``inf`` for a collapsed triangle."""
    s1, s2, _ = singular_values(jacobians(rest, deformed, triangles))
    return np.where(s2 > 0, s1 / np.where(s2 > 0, s2, 1.0), np.inf)


def flipped(rest, deformed, triangles) -> np.ndarray:
    """Number of triangles whose orientation reversed (det J ≤ 0), per frame ``(...)``."""
    return (triangle_areas(deformed, triangles) <= 0).sum(-1)


def _segments_cross(p, q, r, s) -> np.ndarray:
    """Whether segments p–q and r–s properly cross, broadcast over ``(..., 2)``."""
    def orient(a, b, c):
        return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1]) - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))
    return (orient(p, q, r) * orient(p, q, s) < 0) & (orient(r, s, p) * orient(r, s, q) < 0)


def outline_self_crossings(deformed: np.ndarray, triangles: np.ndarray, parts=None,
                           budget: int = 2_000_000) -> np.ndarray:
    """Crossing pairs of outline edges (not sharing a vertex) per frame ``(...)``; with ``parts``
    ``(t,)`` only edges of the same part count (a limb over the body is an overlap, not a fold).
    Brute force over edge pairs, ``budget`` pairs × frames at a time."""
    tris = np.asarray(triangles)
    E = boundary_edges(tris)
    i, j = np.triu_indices(len(E), k=1)
    skip = (E[i, 0] == E[j, 0]) | (E[i, 0] == E[j, 1]) | (E[i, 1] == E[j, 0]) | (E[i, 1] == E[j, 1])
    if parts is not None:
        edge_part = {}
        for t, p in zip(tris, np.asarray(parts)):
            for k in range(3):
                edge_part[(int(t[k]), int(t[(k + 1) % 3]))] = int(p)
        ep = np.array([edge_part[(int(a), int(b))] for a, b in E])
        skip |= ep[i] != ep[j]
    i, j = i[~skip], j[~skip]
    V = np.asarray(deformed, dtype=np.float64)
    out = np.zeros(V.shape[:-2], dtype=np.int64)
    step = max(1, budget // max(1, int(np.prod(V.shape[:-2]))))
    for k in range(0, len(i), step):
        a, c = E[i[k:k + step]], E[j[k:k + step]]
        out += _segments_cross(V[..., a[:, 0], :], V[..., a[:, 1], :], V[..., c[:, 0], :], V[..., c[:, 1], :]).sum(-1)
    return out


def temporal_jitter(frames: np.ndarray) -> float:
    """Mean ‖v_{t+1} − 2 v_t + v_{t−1}‖ over vertices and frames, px / frame² (the key points' own
    acceleration is part of it: compare methods on the same motion)."""
    V = np.asarray(frames, dtype=np.float64)
    return float(np.linalg.norm(V[2:] - 2 * V[1:-1] + V[:-2], axis=-1).mean()) if len(V) >= 3 else 0.0


def limb_bending(omega: np.ndarray) -> np.ndarray:
    """Bending of each limb curve relative to its length², ``(..., 8)`` from ω ``(..., 8, 2)``:
    ∫‖B″‖²dλ/‖d‖² = 4((1 − 2ω_x)² + (2ω_y)²), zero for a straight limb."""
    om = np.asarray(omega, dtype=np.float64)
    return 4 * ((1 - 2 * om[..., 0]) ** 2 + (2 * om[..., 1]) ** 2)


def deformed_bending(mesh, rest_keypoints, rest_omega, frames, keypoints) -> np.ndarray:
    """Bending of each limb as deformed ``(T, 8)``: the rest curve's midpoint, embedded in the limb's
    own triangles, is carried by the deformation to m_t; the quadratic through the frame's end points
    with B(½) = m_t has p_con = 2 m_t − (p_j + p_{j+1})/2, hence ω_t (Eq. 10) and its bending."""
    V = np.asarray(frames, dtype=np.float64)
    p0r, p1r = endpoints(rest_keypoints)
    mid = bezier(p0r, control_from_omega(p0r, p1r, rest_omega), p1r, 0.5)
    p0, p1 = endpoints(keypoints)
    out = np.full((len(V), N_LIMBS), np.nan)
    for i in range(N_LIMBS):
        tris = mesh.triangles[(mesh.parts == 2 + i) & (mesh.layer == 0)]
        if not len(tris):
            continue
        bary, k = barycentric(mesh.vertices, tris, mid[i:i + 1])
        mt = np.einsum("k,tkc->tc", bary[0], V[:, tris[k[0]]])
        with np.errstate(all="ignore"):
            out[:, i] = limb_bending(omega_from_control(p0[:, i], p1[:, i], 2 * mt - 0.5 * (p0[:, i] + p1[:, i])))
    return out


def driving_failures(rest, frames, triangles, max_ratio: float = 3.0, parts=None) -> np.ndarray:
    """Per frame ``(T,)``: a flip, a self-crossing outline or some σ1/σ2 > ``max_ratio`` (the paper's Fig. 4b)."""
    frames = np.asarray(frames, dtype=np.float64)
    return ((flipped(rest, frames, triangles) > 0) | (outline_self_crossings(frames, triangles, parts) > 0)
            | (stretch_ratio(rest, frames, triangles).max(-1) > max_ratio))


def deformation_report(mesh, frames, keypoints, rest_keypoints, rest_omega) -> dict[str, float]:
    """The §15.7 deformation numbers of a clip ``(T, n, 2)`` as one flat dict."""
    frames = np.asarray(frames, dtype=np.float64)
    rest, tris = mesh.vertices, mesh.triangles
    ratio, energy = stretch_ratio(rest, frames, tris), arap_energy(rest, frames, tris)
    bend = deformed_bending(mesh, rest_keypoints, rest_omega, frames, keypoints)
    rest_bend = limb_bending(rest_omega)
    fail = driving_failures(rest, frames, tris, parts=mesh.parts)
    return {"arap_energy_mean": float(energy.mean()), "arap_energy_max": float(energy.max()),
            "stretch_ratio_mean": float(ratio.mean()), "stretch_ratio_max": float(ratio.max()),
            "flipped_triangles": int(flipped(rest, frames, tris).sum()),
            "temporal_jitter": temporal_jitter(frames), "driving_failure_ratio": float(fail.mean()),
            "limb_bending_mean": float(np.nanmean(bend)),
            "limb_bending_change": float(np.nanmean(np.abs(bend - rest_bend)))}
