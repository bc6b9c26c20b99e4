"""Deformation metrics (docs/method.md §15.7), vectorised over frames and triangles.

Every triangle's rest→deformed map is affine; its linear part J ``(2, 2)``
solves J [e₁ e₂]_rest = [e₁ e₂]_deformed for two edges.  Its singular values
σ1 ≥ σ2 measure stretch: a rigid map has σ1 = σ2 = 1, a flip has det J < 0.

Arrays: rest vertices ``(n, 2)``; deformed ``(n, 2)`` or ``(T, n, 2)``;
triangles ``(t, 3)``, counter-clockwise at rest.  Lengths are pixels.
"""
from __future__ import annotations

import numpy as np

from nnsf.reshape.limbs import N_LIMBS, control_from_omega, endpoints
from nnsf.reshape.mesh import boundary_edges, triangle_areas
from nnsf.reshape.parts import PART_INDEX
from nnsf.reshape.subkeys import closest_on_bezier
from nnsf.skeleton import LIMBS
from nnsf.reshape.arap import barycentric
from nnsf.reshape.limbs import bezier, omega_from_control
from nnsf.reshape.mesh import _components, triangle_adjacency


def jacobians(rest: np.ndarray, deformed: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Linear part J of every triangle's affine map, ``(..., t, 2, 2)``."""
    p = rest[triangles]
    Dr = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]], axis=-1)  # (t, 2, 2), edges as columns
    q = deformed[..., triangles, :]
    Dd = np.stack([q[..., 1, :] - q[..., 0, :], q[..., 2, :] - q[..., 0, :]], axis=-1)
    return Dd @ np.linalg.inv(Dr)


def singular_values(J: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """σ1 ≥ σ2 ≥ 0 and det of 2×2 maps ``(..., 2, 2)``, closed form.

    For J = [[a, b], [c, d]]: σ1,2 = (√((a+d)² + (c−b)²) ± √((a−d)² + (b+c)²)) / 2
    (the similarity and anti-similarity parts of J); a batched SVD gives the
    same but is several times slower on ``(T, t)`` stacks.
    """
    a, b, c, d = J[..., 0, 0], J[..., 0, 1], J[..., 1, 0], J[..., 1, 1]
    s = np.hypot(a + d, c - b)
    r = np.hypot(a - d, b + c)
    return 0.5 * (s + r), 0.5 * np.abs(s - r), a * d - b * c


def arap_energy(rest, deformed, triangles) -> np.ndarray:
    """Σ area·((σ1−1)² + (σ2−1)²), px², per frame ``(...)``."""
    s1, s2, _ = singular_values(jacobians(rest, deformed, triangles))
    area = triangle_areas(rest, triangles)
    return (area * ((s1 - 1) ** 2 + (s2 - 1) ** 2)).sum(-1)


def stretch_ratio(rest, deformed, triangles) -> np.ndarray:
    """σ1/σ2 per triangle ``(..., t)``; ``inf`` for a collapsed triangle."""
    s1, s2, _ = singular_values(jacobians(rest, deformed, triangles))
    with np.errstate(divide="ignore"):
        return np.where(s2 > 0, s1 / np.where(s2 > 0, s2, 1.0), np.inf)


def flipped(rest, deformed, triangles) -> np.ndarray:
    """Number of triangles whose orientation reversed (det J ≤ 0), per frame ``(...)``."""
    return (triangle_areas(deformed, triangles) <= 0).sum(-1)


def _segments_cross(p, q, r, s) -> np.ndarray:
    """Whether segments p–q and r–s properly cross, broadcast over ``(..., 2)``."""
    def orient(a, b, c):
        return np.sign((b[..., 0] - a[..., 0]) * (c[..., 1] - a[..., 1])
                       - (b[..., 1] - a[..., 1]) * (c[..., 0] - a[..., 0]))
    return (orient(p, q, r) * orient(p, q, s) < 0) & (orient(r, s, p) * orient(r, s, q) < 0)


def outline_self_crossings(deformed: np.ndarray, triangles: np.ndarray, pieces=None,
                           budget: int = 2_000_000) -> np.ndarray:
    """Number of crossing pairs of outline edges (edges not sharing a vertex), per frame ``(...)``.

    With ``pieces`` ``(t,)`` (a split mesh) only edges of the same piece,
    and of the same edge-connected group of its triangles, count: a limb
    drawn over the body (or a joint tab under its parent) is an overlap, not
    a fold.

    Brute force over edge pairs, ``budget`` (pairs × frames) at a time:
    outlines have a few hundred edges, so O(b²) vectorised beats a sweep
    line written in Python.
    """
    E = boundary_edges(triangles)
    i, j = np.triu_indices(len(E), k=1)
    share = (E[i, 0] == E[j, 0]) | (E[i, 0] == E[j, 1]) | (E[i, 1] == E[j, 0]) | (E[i, 1] == E[j, 1])
    if pieces is not None:
        # Only a sheet folding over itself counts: edges of the same piece and of the same
        # edge-connected group of its triangles (a pieced mesh's joint tab is a group of its own).

        tri = np.asarray(triangles)
        a, b = triangle_adjacency(tri)
        same = np.asarray(pieces)[a] == np.asarray(pieces)[b]
        group = _components(len(tri), a[same], b[same])
        vp = np.zeros(int(tri.max()) + 1, dtype=np.int64)
        vp[tri.ravel()] = np.repeat(group, 3)
        share |= vp[E[i, 0]] != vp[E[j, 0]]
    i, j = i[~share], j[~share]
    V = np.asarray(deformed, dtype=np.float64)
    out = np.zeros(V.shape[:-2], dtype=np.int64)
    step = max(1, budget // max(1, int(np.prod(V.shape[:-2]))))
    for k in range(0, len(i), step):
        a, c = E[i[k:k + step]], E[j[k:k + step]]
        out += _segments_cross(V[..., a[:, 0], :], V[..., a[:, 1], :],
                               V[..., c[:, 0], :], V[..., c[:, 1], :]).sum(-1)
    return out


def limb_widths(vertices: np.ndarray, triangles: np.ndarray, parts: np.ndarray, keypoints: np.ndarray,
                omega: np.ndarray, span=(0.2, 0.8)) -> np.ndarray:
    """Width of each limb ``(..., 8)``, pixels: twice the median distance from
    the limb part's outline vertices to its curve, over curve parameters in ``span``.

    vertices ``(..., n, 2)``, keypoints ``(..., 17, 2)``, ω ``(..., 8, 2)``.
    A limb with no outline vertex in ``span`` gets NaN.
    """
    V = np.asarray(vertices, dtype=np.float64)
    kp = np.asarray(keypoints, dtype=np.float64)
    om = np.broadcast_to(np.asarray(omega, dtype=np.float64), kp.shape[:-2] + (N_LIMBS, 2))
    p0, p1 = endpoints(kp)
    pc = control_from_omega(p0, p1, om)
    E = boundary_edges(triangles)
    parts = np.asarray(parts)
    out = np.full(V.shape[:-2] + (N_LIMBS,), np.nan)
    for li, name in enumerate(LIMBS):
        part = PART_INDEX[name]
        in_part = np.zeros(V.shape[-2], dtype=bool)
        in_part[triangles[parts == part].ravel()] = True
        idx = np.unique(E.ravel())
        idx = idx[in_part[idx]]
        if idx.size == 0:
            continue
        q = V[..., idx, :]
        lam, pt = closest_on_bezier(p0[..., li:li + 1, :], pc[..., li:li + 1, :], p1[..., li:li + 1, :], q)
        dist = np.linalg.norm(q - pt, axis=-1)
        use = (lam >= span[0]) & (lam <= span[1])
        dist = np.where(use, dist, np.nan)
        with np.errstate(all="ignore"):
            ok = use.any(-1)
            med = np.nanmedian(np.where(ok[..., None], dist, 0.0), axis=-1)
        out[..., li] = np.where(ok, 2 * med, np.nan)
    return out


def width_drift(widths: np.ndarray) -> np.ndarray:
    """|w_t / w_0 − 1| per frame and limb, from widths ``(T, 8)`` with row 0 the rest pose."""
    w = np.asarray(widths, dtype=np.float64)
    return np.abs(w / w[:1] - 1)


def temporal_jitter(frames: np.ndarray) -> float:
    """Mean ‖v_{t+1} − 2 v_t + v_{t−1}‖ over vertices and frames, pixels per frame².

    The acceleration of the mesh; compare methods on the same key points,
    since the key points' own acceleration is part of it.
    """
    V = np.asarray(frames, dtype=np.float64)
    if len(V) < 3:
        return 0.0
    return float(np.linalg.norm(V[2:] - 2 * V[1:-1] + V[:-2], axis=-1).mean())


def limb_bending(omega: np.ndarray) -> np.ndarray:
    """Bending energy of each limb curve relative to its length², ``(..., 8)`` from ω ``(..., 8, 2)``.

    For a quadratic Bézier B'' = 2A is constant, so ∫₀¹‖B''‖² dλ / ‖d‖² =
    4‖A‖²/‖d‖² = 4 ((1 − 2ω_x)² + (2ω_y)²): zero for a straight limb.
    """
    om = np.asarray(omega, dtype=np.float64)
    return 4 * ((1 - 2 * om[..., 0]) ** 2 + (2 * om[..., 1]) ** 2)


def driving_failures(rest, frames, triangles, max_ratio: float = 3.0, pieces=None) -> np.ndarray:
    """Per frame ``(T,)``: a flip, a self-crossing outline or some σ1/σ2 > ``max_ratio``.

    ``pieces``: see :func:`outline_self_crossings`.
    """
    frames = np.asarray(frames, dtype=np.float64)
    return ((flipped(rest, frames, triangles) > 0)
            | (outline_self_crossings(frames, triangles, pieces) > 0)
            | (stretch_ratio(rest, frames, triangles).max(-1) > max_ratio))


def driving_failure_ratio(rest, frames, triangles, max_ratio: float = 3.0, pieces=None) -> float:
    """The paper's Fig. 4b measure: share of frames that are driving failures."""
    f = driving_failures(rest, frames, triangles, max_ratio, pieces)
    return float(f.mean()) if f.size else 0.0


def deformation_report(rest, frames, triangles, parts=None, keypoints=None, omega=None,
                       rest_keypoints=None, rest_omega=None, pieces=None) -> dict[str, float]:
    """All §6.5 numbers for a clip ``(T, n, 2)`` as one flat dict.

    Width drift needs ``parts``, the clip's key points ``(T, 17, 2)`` and ω,
    and the rest key points / ω (the reference width).  ``pieces``: see
    :func:`outline_self_crossings`.
    """
    frames = np.asarray(frames, dtype=np.float64)
    s1, s2, _ = singular_values(jacobians(rest, frames, triangles))
    ratio = np.where(s2 > 0, s1 / np.where(s2 > 0, s2, 1.0), np.inf)
    area = triangle_areas(rest, triangles)
    energy = (area * ((s1 - 1) ** 2 + (s2 - 1) ** 2)).sum(-1)
    report = {
        "arap_energy_mean": float(energy.mean()),
        "arap_energy_max": float(energy.max()),
        "stretch_ratio_max": float(ratio.max()),
        "stretch_ratio_mean": float(ratio.mean()),
        "flipped_triangles": int(flipped(rest, frames, triangles).sum()),
        "temporal_jitter": temporal_jitter(frames),
        "driving_failure_ratio": driving_failure_ratio(rest, frames, triangles, pieces=pieces),
    }
    if parts is not None and keypoints is not None and omega is not None:
        w0 = limb_widths(rest, triangles, parts, rest_keypoints, rest_omega)
        w = limb_widths(frames, triangles, parts, keypoints, omega)
        with np.errstate(all="ignore"):
            drift = np.abs(w / w0 - 1)
        report["width_drift_mean"] = float(np.nanmean(drift)) if np.isfinite(drift).any() else float("nan")
        report["width_drift_max"] = float(np.nanmax(drift)) if np.isfinite(drift).any() else float("nan")
    return report


def deformed_bending(rig, frames: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """Bending energy of each limb as deformed, ``(T, 8)`` (same units as :func:`limb_bending`).

    The rest curve's midpoint B₀(½) is embedded in the limb's own triangles
    (barycentric, layer 0, the piece holding most of the limb) and carried by
    the deformation to m_t; the quadratic through the frame's end points
    with B(½) = m_t has control point p_con = 2 m_t − (p_j + p_{j+1})/2,
    hence ω_t (Eq. 10) and its bending.  A limb that stays straight scores
    0; a rigidly moved bent limb keeps its rest score.
    """
    m = rig.mesh
    V = np.asarray(frames, dtype=np.float64)
    kp = rig.drive(keypoints)  # in the character's sense -> the rig's (pivots moved on a pieced mesh)
    p0r, p1r = endpoints(rig.rest_keypoints)
    mid = bezier(p0r, control_from_omega(p0r, p1r, rig.rest_omega), p1r, 0.5)  # (8, 2)
    p0, p1 = endpoints(kp)
    out = np.full((len(V), N_LIMBS), np.nan)
    for i, name in enumerate(LIMBS):
        sel = (m.parts == PART_INDEX[name]) & (m.layer == 0)
        if not sel.any():
            continue
        piece = np.bincount(m.pieces[sel]).argmax()
        tris = m.triangles[sel & (m.pieces == piece)]
        bary, k = barycentric(m.vertices, tris, mid[i:i + 1])
        mt = np.einsum("k,tkc->tc", bary[0], V[:, tris[k[0]]])
        pc = 2 * mt - 0.5 * (p0[:, i] + p1[:, i])
        with np.errstate(all="ignore"):
            out[:, i] = limb_bending(omega_from_control(p0[:, i], p1[:, i], pc))
    return out
