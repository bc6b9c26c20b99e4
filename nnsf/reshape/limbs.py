"""The limb model (docs/method.md §10, paper Eq. 9-10): one quadratic Bézier curve per limb.

Limb i runs from key point p_j to p_{j+1} (:data:`nnsf.skeleton.LIMBS`,
in that order; limb arrays below have 8 rows in the same order).  Its curve is

    B(λ) = (1−λ)² p_j + 2λ(1−λ) p_con + λ² p_{j+1},   λ ∈ [0, 1],

and p_con is stored relative to the bone as ω = (ω_x, ω_y):

    p_con = p_j + ω_x d + ω_y R90 d,   d = p_{j+1} − p_j,

with R90 the rotation by +90° in (x, y) axes, R90 (x, y) = (−y, x).  In image axes (y down) that
turns the bone *clockwise* on screen; ω_y > 0 bends the curve to the bone's right as seen walking
from p_j to p_{j+1}.  ω = (½, 0) is the straight, uniformly parameterised bone (``STRAIGHT``); ω is
invariant to moving, rotating and scaling the bone, which is why only ω is keyframed.

All functions broadcast over leading axes (frames), so a clip ``(T, 17, 2)``
is processed in one call.
"""
from __future__ import annotations

import numpy as np

from nnsf.skeleton import LIMBS

#: ``(8, 2)`` key-point indices (p_j, p_{j+1}) of the limbs, in LIMBS order.
LIMB_PAIRS = np.array(list(LIMBS.values()), dtype=np.int64)
N_LIMBS = len(LIMBS)

#: ω of a straight limb whose curve parameter equals the fraction along the bone.
STRAIGHT = np.array([0.5, 0.0])


def rot90(v: np.ndarray) -> np.ndarray:
    """R90 (module docstring) applied to vectors ``(..., 2)``."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def endpoints(keypoints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Limb end points p_j, p_{j+1}: ``(..., 17, 2)`` -> two ``(..., 8, 2)`` arrays."""
    kp = np.asarray(keypoints, dtype=np.float64)
    return kp[..., LIMB_PAIRS[:, 0], :], kp[..., LIMB_PAIRS[:, 1], :]


def control_from_omega(p0: np.ndarray, p1: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Eq. 10: p_con = p0 + ω_x d + ω_y R90 d, all ``(..., 2)`` (pixels; ω unitless)."""
    d = p1 - p0
    omega = np.asarray(omega, dtype=np.float64)
    return p0 + omega[..., :1] * d + omega[..., 1:] * rot90(d)


def omega_from_control(p0: np.ndarray, p1: np.ndarray, pcon: np.ndarray) -> np.ndarray:
    """Inverse of Eq. 10: ω = ((p_con − p0)·d, (p_con − p0)·R90 d) / ‖d‖², ``(..., 2)``."""
    d = p1 - p0
    r = pcon - p0
    dd = (d * d).sum(axis=-1, keepdims=True)
    if np.any(dd == 0):
        raise ValueError("a limb has zero length: its end points coincide")
    return np.concatenate([(r * d).sum(-1, keepdims=True), (r * rot90(d)).sum(-1, keepdims=True)], -1) / dd


def bezier(p0: np.ndarray, pcon: np.ndarray, p1: np.ndarray, lam) -> np.ndarray:
    """Eq. 9 at parameters ``lam``: end/control points ``(..., 2)``, lam ``(L,)`` -> ``(..., L, 2)``.

    With a scalar ``lam`` the result is ``(..., 2)``.
    """
    lam = np.asarray(lam, dtype=np.float64)
    if lam.ndim == 0:
        return (1 - lam) ** 2 * p0 + 2 * lam * (1 - lam) * pcon + lam ** 2 * p1
    l = lam[:, None]
    return ((1 - l) ** 2 * p0[..., None, :] + 2 * l * (1 - l) * pcon[..., None, :]
            + l ** 2 * p1[..., None, :])


def limb_curves(keypoints: np.ndarray, omega: np.ndarray, lam) -> np.ndarray:
    """Points on every limb's curve: ``(..., 17, 2)``, ``(..., 8, 2)``, ``(L,)`` -> ``(..., 8, L, 2)``."""
    p0, p1 = endpoints(keypoints)
    return bezier(p0, control_from_omega(p0, p1, omega), p1, lam)


def fit_omega(mask: np.ndarray, keypoints: np.ndarray, samples: int = 24, span=(0.15, 0.85),
              max_bend: float = 0.35) -> np.ndarray:
    """ω ``(8, 2)`` of the rest pose, from the silhouette's medial curve along each limb.

    For λ in ``span`` (away from the joints, where limbs merge into the body) the chord of the mask
    through p_j + λ d, perpendicular to the bone (the run of mask pixels on it nearest the bone),
    gives a medial point p_j + λ d + m(λ) n̂.  The Bézier with fixed end points that fits these
    points best in least squares has ω_x = ½ exactly (the points are spaced uniformly along d) and

        ω_y = Σ 2λ(1−λ) m(λ) / (‖d‖ Σ 4λ²(1−λ)²),

    clipped to ±``max_bend``.  A chord that reaches past 0.75 ‖d‖ on either
    side without leaving the mask (the limb lies along the body there) is
    ignored; a limb with fewer than 3 usable chords stays straight.
    """
    mask = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    H, W = mask.shape
    p0, p1 = endpoints(kp)
    omega = np.tile(STRAIGHT, (N_LIMBS, 1))
    lam = np.linspace(*span, samples)
    for i in range(N_LIMBS):
        d = p1[i] - p0[i]
        L = float(np.linalg.norm(d))
        if L < 2:
            continue
        n = rot90(d) / L
        reach = 0.75 * L
        t = np.arange(-reach, reach + 0.5, 0.5)
        base = p0[i] + lam[:, None] * d  # (S, 2)
        pts = base[:, None, :] + t[None, :, None] * n  # (S, K, 2)
        ij = np.rint(pts).astype(np.int64)
        ok = (ij[..., 0] >= 0) & (ij[..., 0] < W) & (ij[..., 1] >= 0) & (ij[..., 1] < H)
        inside = np.zeros(ok.shape, dtype=bool)
        inside[ok] = mask[ij[ok][:, 1], ij[ok][:, 0]]
        idx = np.arange(len(t))
        # The run of inside samples nearest the bone (t = 0): a strongly bent
        # limb may leave its own chord.
        near = np.argmin(np.where(inside, np.abs(t), np.inf), axis=1)[:, None]
        left = np.where(~inside & (idx < near), idx, -1).max(axis=1)
        right = np.where(~inside & (idx > near), idx, len(t)).min(axis=1)
        usable = inside.any(axis=1) & (left >= 0) & (right < len(t))
        if usable.sum() < 3:
            continue
        m = 0.5 * (t[np.maximum(left, 0)] + t[np.minimum(right, len(t) - 1)])[usable]
        w = 2 * lam[usable] * (1 - lam[usable])
        omega[i, 1] = np.clip((w * m).sum() / (L * (w * w).sum()), -max_bend, max_bend)
    return omega
