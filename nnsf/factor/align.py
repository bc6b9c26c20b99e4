"""Atoms that mean the same thing in every style's basis (D5, docs/method.md §8.1).

A basis and weights from different fits can only be recombined if atom ``i``
means the same in both.  :func:`refit_basis` gives a style its own basis
by basis steps only (the projected-gradient U step of Algorithm 1, lines
1-3, on the objective of Eq. 5 with the style's weights fixed), starting
from the pooled fit's U₀, so atom ``i`` starts as atom ``i`` of U₀;
:func:`atom_cosines` measures how far a style turned each atom.
"""
from __future__ import annotations

import numpy as np

from nnsf.factor.updates import _basis_step

def refit_basis(X, V, U0, *, max_iter: int = 100, tol: float = 1e-6, ridge: float = 0.0) -> np.ndarray:
    """Basis steps only: U ≥ 0, unit rows, minimising ½‖X − VU‖² (+ ridge), V fixed.

    Starts from ``U0`` and takes the projected-gradient steps of NNSF's basis
    update (:func:`nnsf.factor.nnsf._basis_step`, with its backtracking), so
    atom ``i`` of the result is atom ``i`` of ``U0`` moved towards the data.

    Parameters
    ----------
    X : array (n, d), non-negative features (template units).
    V : array (n, k), non-negative weights, fixed.
    U0 : array (k, d), the starting basis (rows of unit norm).
    max_iter : int, number of basis steps at most.
    tol : float, stop when the relative decrease of the objective is below.
    ridge : float >= 0
        Adds ``λ‖U − U0‖²_F`` with ``λ = ridge · trace(VᵀV) / k`` (relative,
        so it does not depend on the scale of V).  Atoms the data use little
        then stay near ``U0`` instead of drifting; 0 is D5 as written (docs/method.md §8.1).

    Returns
    -------
    U : ndarray (k, d), unit-norm rows.
    """
    X = np.asarray(X, dtype=float)
    V = np.asarray(V, dtype=float)
    U = np.array(U0, dtype=float, copy=True)
    if X.shape[0] != V.shape[0] or V.shape[1] != U.shape[0] or X.shape[1] != U.shape[1]:
        raise ValueError(f"refit_basis: shapes X {X.shape}, V {V.shape}, U0 {U.shape} do not agree "
                         "(need X (n, d), V (n, k), U0 (k, d))")
    VtV = V.T @ V
    VtX = V.T @ X
    return _refit_from_grams(VtV, VtX, U, max_iter=max_iter, tol=tol, ridge=ridge)


def _refit_from_grams(VtV, VtX, U0, *, max_iter, tol, ridge):
    k = VtV.shape[0]
    U = np.array(U0, dtype=float, copy=True)
    if ridge > 0:
        # ½‖X − VU‖² + (λ/2)‖U − U0‖² has the Grams VᵀV + λI and VᵀX + λU0.
        lam = ridge * max(float(np.trace(VtV)) / k, np.finfo(float).tiny)
        VtV = VtV + lam * np.eye(k)
        VtX = VtX + lam * U0
    top = float(np.linalg.eigvalsh(VtV)[-1])
    if top <= 0:           # no weight at all: nothing moves the basis
        return U
    step = 1.0 / top

    def fit(B):
        return float(np.vdot(B @ B.T, VtV) - 2.0 * np.vdot(VtX, B))

    prev = fit(U)
    for _ in range(int(max_iter)):
        U, step = _basis_step(U, VtV, VtX, step)
        cur = fit(U)
        if prev - cur <= tol * max(abs(prev), 1e-300):
            break
        prev = cur
    return U


def atom_cosines(U_ref, U) -> np.ndarray:
    """Cosine similarity of every atom pair, ``(k_ref, k)``; rows of zero norm give 0."""
    A = np.asarray(U_ref, dtype=float)
    B = np.asarray(U, dtype=float)
    na = np.linalg.norm(A, axis=1, keepdims=True)
    nb = np.linalg.norm(B, axis=1, keepdims=True)
    return (A / np.where(na > 0, na, 1.0)) @ (B / np.where(nb > 0, nb, 1.0)).T
