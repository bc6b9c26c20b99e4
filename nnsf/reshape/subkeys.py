"""Subkey points (docs/method.md §11, paper Eq. 11-14): extra handles along each limb's curve.

* Eq. 11: the initial subkey q⁰ of sample λ_j on limb i is the mesh vertex
  nearest B_i(λ_j) (``scipy.spatial.cKDTree``).
* Eq. 12 (normalised, D4): with a = ‖p_j − q‖ and b = ‖p_{j+1} − q‖ at
  frame t, q ← q + (b Δp_j + a Δp_{j+1}) / (a + b).  For a point on the bone
  this is exactly the motion of the bone's affine interpolation, so subkeys on
  a limb stay on it under any rigid or stretching motion of the limb.
* Eq. 13-14: q is then moved to the closest point of frame t+1's curve, the
  real root in [0, 1] (or an end) of
  (A·A)λ³ + 3(A·Bv)λ² + (2 Bv·Bv + A·C)λ + Bv·C = 0 that is nearest q,
  with A = p_j − 2p_con + p_{j+1}, Bv = p_con − p_j, C = p_j − q.

**Offsets (our decision).**  Eq. 11 snaps a subkey to a vertex, so at rest
it lies off the curve by up to half the mesh spacing, and the first fit (Eq. 13) would make it jump
by that much.  The tracker therefore runs Eq. 12-14 on the curve point s = B(λ*) closest to the
rest vertex, and returns q = s + offset, where the rest offset (vertex − s) is kept constant in the
limb's frame (along d̂ and R90 d̂, pixels).  The rest pose then reproduces the rest mesh exactly and
the subkeys move continuously.  ``keep_offset=False`` returns the paper's on-curve positions
instead.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from nnsf.reshape.limbs import LIMB_PAIRS, N_LIMBS, control_from_omega, endpoints, limb_curves, rot90


# --------------------------------------------------------------------------- Eq. 13-14

def closest_on_bezier(p0, pcon, p1, q) -> tuple[np.ndarray, np.ndarray]:
    """Closest point to ``q`` on the quadratic Bézier (p0, pcon, p1), all ``(..., 2)``.

    Returns ``(lam, point)`` with shapes ``(...)`` and ``(..., 2)``.

    The roots of the cubic (Eq. 14) come from the eigenvalues of its
    companion matrices, one 3×3 per query, in a single batched
    ``np.linalg.eigvals`` call (numpy's ``roots`` takes one polynomial at a
    time).  Candidates are the real parts of all three roots clipped to
    [0, 1] (a clipped or complex candidate is merely not the nearest), the
    root of the linear equation the cubic becomes when A ≈ 0, and the ends
    0 and 1; the candidate nearest ``q`` wins.
    """
    p0, pcon, p1, q = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (p0, pcon, p1, q)))
    A = p0 - 2 * pcon + p1
    Bv = pcon - p0
    C = p0 - q
    a3 = (A * A).sum(-1)
    a2 = 3 * (A * Bv).sum(-1)
    a1 = 2 * (Bv * Bv).sum(-1) + (A * C).sum(-1)
    a0 = (Bv * C).sum(-1)
    shape = a3.shape
    scale = 2 * (Bv * Bv).sum(-1) + np.abs((A * C).sum(-1)) + a3
    cubic = a3 > 1e-12 * np.maximum(scale, 1e-300)
    comp = np.zeros(shape + (3, 3))
    safe = np.where(cubic, a3, 1.0)
    comp[..., 0, 0] = np.where(cubic, -a2 / safe, 0.0)
    comp[..., 0, 1] = np.where(cubic, -a1 / safe, 0.0)
    comp[..., 0, 2] = np.where(cubic, -a0 / safe, 0.0)
    comp[..., 1, 0] = 1.0
    comp[..., 2, 1] = 1.0
    roots = np.linalg.eigvals(comp).real if comp.size else np.zeros(shape + (3,))
    lin = np.where(np.abs(a1) > 0, -a0 / np.where(np.abs(a1) > 0, a1, 1.0), 0.0)
    cand = np.concatenate([roots, lin[..., None], np.zeros(shape + (1,)), np.ones(shape + (1,))], -1)
    cand = np.clip(cand, 0.0, 1.0)  # (..., 6)
    c = cand[..., None]
    pts = (1 - c) ** 2 * p0[..., None, :] + 2 * c * (1 - c) * pcon[..., None, :] + c ** 2 * p1[..., None, :]
    dist = ((pts - q[..., None, :]) ** 2).sum(-1)
    best = np.argmin(dist, axis=-1)[..., None]
    lam = np.take_along_axis(cand, best, -1)[..., 0]
    point = np.take_along_axis(pts, best[..., None], -2)[..., 0, :]
    return lam, point


# --------------------------------------------------------------------------- Eq. 12

def propagate(q, p0_prev, p1_prev, p0_new, p1_new) -> np.ndarray:
    """Normalised Eq. 12: move ``q`` with its limb's end points, all ``(..., 2)`` pixels.

    a = ‖p_j − q‖, b = ‖p_{j+1} − q‖ are measured at the previous frame; a
    subkey at a key point (a + b = 0 only when both ends coincide with it)
    moves with that key point.
    """
    q = np.asarray(q, dtype=np.float64)
    a = np.linalg.norm(p0_prev - q, axis=-1, keepdims=True)
    b = np.linalg.norm(p1_prev - q, axis=-1, keepdims=True)
    s = a + b
    w0 = np.where(s > 0, b / np.where(s > 0, s, 1.0), 0.5)
    return q + w0 * (p0_new - p0_prev) + (1 - w0) * (p1_new - p1_prev)


def propagate_in_frame(q, p0_prev, p1_prev, p0_new, p1_new) -> np.ndarray:
    """Alternative to Eq. 12: carry ``q`` in the limb's own frame, all ``(..., 2)``.

    q = p_j + u d + v R90 d at the previous frame; the same (u, v) on the new bone.  Exact for any
    similarity motion of the limb wherever q lies, so a subkey on a bent curve does not slide along
    it (Eq. 12 blends the end points' displacements, which is exact only on the straight bone; the
    fit of Eq. 13-14 removes the error across the curve but not along it, so the slide accumulates
    over frames).
    """
    q = np.asarray(q, dtype=np.float64)
    d0 = p1_prev - p0_prev
    dd = np.maximum((d0 * d0).sum(-1, keepdims=True), 1e-300)
    r = q - p0_prev
    u = (r * d0).sum(-1, keepdims=True) / dd
    v = (r * rot90(d0)).sum(-1, keepdims=True) / dd
    d1 = p1_new - p0_new
    return p0_new + u * d1 + v * rot90(d1)


#: Subkey propagation rules: the paper's normalised Eq. 12, or the limb frame.
PROPAGATIONS = ("eq12", "limb-frame")


# --------------------------------------------------------------------------- Eq. 11

@dataclass
class Subkeys:
    """Subkey points of a mesh.

    Attributes
    ----------
    limb : ndarray, shape (s,), int64
        Limb index (``nnsf.skeleton.LIMBS`` order).
    vertex : ndarray, shape (s,), int64
        The mesh vertex each subkey drives.
    lam : ndarray, shape (s,)
        Curve parameter λ* of the rest curve point closest to the vertex.
    offset : ndarray, shape (s, 2)
        Rest offset vertex − B(λ*) in the limb frame (d̂, R90 d̂), pixels.
    """

    limb: np.ndarray
    vertex: np.ndarray
    lam: np.ndarray
    offset: np.ndarray

    def __len__(self) -> int:
        return len(self.vertex)


def init_subkeys(vertices: np.ndarray, keypoints: np.ndarray, omega: np.ndarray,
                 per_limb: int = 4, candidates=None, whole=()) -> Subkeys:
    """Eq. 11: the vertices nearest ``per_limb`` samples of each limb's rest curve.

    Parameters
    ----------
    vertices : ``(n, 2)`` rest mesh vertices, pixels.
    keypoints : ``(17, 2)`` rest key points, pixels.
    omega : ``(8, 2)`` rest ω.
    per_limb : samples λ_j = j / (per_limb + 1), j = 1..per_limb (the
        joints themselves are key-point handles already).
    candidates : optional list of 8 vertex-index arrays, the vertices each
        limb may pick from (a split mesh: the limb's own piece).
    whole : limbs whose every candidate is a subkey (a limb under the body, carried whole by its curve).

    A vertex picked twice (a short limb on a coarse mesh) is kept once.
    """
    lam = np.arange(1, per_limb + 1) / (per_limb + 1)
    samples = limb_curves(keypoints, omega, lam)  # (8, L, 2)
    if candidates is None:
        _, idx = cKDTree(vertices).query(samples.reshape(-1, 2))
    else:  # a limb without candidate vertices gets no subkeys (index −1, dropped below)
        idx = np.concatenate([np.asarray(c)[cKDTree(vertices[c]).query(samples[i])[1]] if len(c)
                              else np.full(len(lam), -1) for i, c in enumerate(candidates)])
    limb = np.repeat(np.arange(N_LIMBS), len(lam))
    idx = np.concatenate([idx] + [candidates[i] for i in whole])
    limb = np.concatenate([limb] + [np.full(len(candidates[i]), i) for i in whole])
    keep = idx >= 0
    limb, idx = limb[keep], idx[keep]
    _, first = np.unique(idx, return_index=True)
    first = np.sort(first)
    limb, idx = limb[first], idx[first].astype(np.int64)
    p0, p1 = endpoints(keypoints)
    pc = control_from_omega(p0, p1, omega)
    q = vertices[idx]
    lam_star, s = closest_on_bezier(p0[limb], pc[limb], p1[limb], q)
    return Subkeys(limb=limb, vertex=idx, lam=lam_star, offset=_to_frame(q - s, p0[limb], p1[limb]))


def _frame(p0, p1):
    d = p1 - p0
    u = d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)
    return u, rot90(u)


def _to_frame(v, p0, p1):
    u, n = _frame(p0, p1)
    return np.stack([(v * u).sum(-1), (v * n).sum(-1)], -1)


def _from_frame(c, p0, p1):
    u, n = _frame(p0, p1)
    return c[..., :1] * u + c[..., 1:] * n


class SubkeyTracker:
    """Track subkeys through a clip with Eq. 12 (propagation) and Eq. 13-14 (fit).

    Parameters
    ----------
    subkeys : :class:`Subkeys`
    rest_keypoints : ``(17, 2)``; rest_omega : ``(8, 2)``.
    keep_offset : bool
        Add the rest offsets (module docstring).
    propagation : ``"eq12"`` (the paper, :func:`propagate`) or
        ``"limb-frame"`` (:func:`propagate_in_frame`).

    The tracker starts at the rest pose; :meth:`step` advances one frame
    and :meth:`track` runs a whole clip.  Each step is vectorised over the
    subkeys; frames are sequential because Eq. 12 is a recurrence.
    """

    def __init__(self, subkeys: Subkeys, rest_keypoints, rest_omega, keep_offset: bool = True,
                 propagation: str = "eq12"):
        if propagation not in PROPAGATIONS:
            raise ValueError(f"propagation must be one of {PROPAGATIONS}, got {propagation!r}")
        self.propagation = propagation
        self.subkeys = subkeys
        self.rest_keypoints = np.asarray(rest_keypoints, dtype=np.float64)
        self.rest_omega = np.asarray(rest_omega, dtype=np.float64)
        self.keep_offset = keep_offset
        self._pairs = LIMB_PAIRS[subkeys.limb]  # (s, 2)
        self.reset()

    def reset(self) -> None:
        """Go back to the rest pose."""
        kp, om = self.rest_keypoints, self.rest_omega
        p0, p1 = kp[self._pairs[:, 0]], kp[self._pairs[:, 1]]
        pc = control_from_omega(p0, p1, om[self.subkeys.limb])
        self._state = _bezier_at(p0, pc, p1, self.subkeys.lam)
        self._keypoints = kp.copy()

    def positions(self) -> np.ndarray:
        """Current subkey positions ``(s, 2)``, pixels."""
        p0, p1 = self._keypoints[self._pairs[:, 0]], self._keypoints[self._pairs[:, 1]]
        return self._state + _from_frame(self.subkeys.offset, p0, p1) if self.keep_offset else self._state.copy()

    def step(self, keypoints, omega=None) -> np.ndarray:
        """Advance to the next frame's key points ``(17, 2)`` and ω ``(8, 2)``; return ``(s, 2)``."""
        kp = np.asarray(keypoints, dtype=np.float64)
        om = self.rest_omega if omega is None else np.asarray(omega, dtype=np.float64)
        i0, i1 = self._pairs[:, 0], self._pairs[:, 1]
        if self.propagation == "eq12":
            s = propagate(self._state, self._keypoints[i0], self._keypoints[i1], kp[i0], kp[i1])
        else:
            s = propagate_in_frame(self._state, self._keypoints[i0], self._keypoints[i1], kp[i0], kp[i1])
        p0, p1 = kp[i0], kp[i1]
        _, s = closest_on_bezier(p0, control_from_omega(p0, p1, om[self.subkeys.limb]), p1, s)
        self._state, self._keypoints = s, kp.copy()
        return self.positions()

    def track(self, keypoints, omega=None) -> np.ndarray:
        """Positions ``(T, s, 2)`` for a clip ``(T, 17, 2)`` starting from rest; ω ``(T, 8, 2)`` or ``(8, 2)``."""
        kp = np.asarray(keypoints, dtype=np.float64)
        om = None if omega is None else np.broadcast_to(np.asarray(omega, float), kp.shape[:1] + (N_LIMBS, 2))
        self.reset()
        return np.stack([self.step(kp[t], None if om is None else om[t]) for t in range(len(kp))]) \
            if len(kp) else np.zeros((0, len(self.subkeys), 2))


def _bezier_at(p0, pc, p1, lam):
    l = np.asarray(lam, dtype=np.float64)[..., None]
    return (1 - l) ** 2 * p0 + 2 * l * (1 - l) * pc + l ** 2 * p1
