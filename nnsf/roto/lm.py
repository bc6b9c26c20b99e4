"""The Levenberg-Marquardt solver of the space-time tracking energy (Eq. 1, docs/method.md §2.3).

The Gauss-Newton matrix of :class:`nnsf.roto.energy.SpaceTimeProblem` is
block-tridiagonal in time (a term couples a frame with the next at most), so
each damped step solves it with the block Thomas algorithm
(:func:`solve_block_tridiagonal`) in time linear in the number of frames.
"""
from __future__ import annotations

import numpy as np
from scipy.linalg import solveh_banded

from nnsf.roto.energy import SpaceTimeProblem

def solve_block_tridiagonal(Hd: np.ndarray, Ho: np.ndarray, g: np.ndarray) -> np.ndarray:
    """Solve H x = g for symmetric positive definite block-tridiagonal H, batched over G.

    Hd (G, T, k, k) diagonal blocks, Ho (G, T-1, k, k) the (t, t+1) blocks,
    g (G, T, k).  The G systems are stacked into one banded matrix (upper
    bandwidth 2k-1, no coupling between curves) and solved by LAPACK's
    banded Cholesky (``scipy.linalg.solveh_banded``): one call instead of a
    Python loop over frames.
    """
    G, T, k, _ = Hd.shape
    N = G * T * k
    u = 2 * k - 1
    ab = np.zeros((u + 1, N))
    base = (np.arange(G)[:, None] * T + np.arange(T)[None, :]) * k          # (G, T)
    a, b = np.triu_indices(k)
    i = base[..., None] + a
    j = base[..., None] + b
    ab[u + i - j, j] = Hd[..., a, b]
    if T > 1:
        a2, b2 = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
        a2, b2 = a2.ravel(), b2.ravel()
        i = base[:, :-1, None] + a2
        j = base[:, :-1, None] + k + b2
        ab[u + i - j, j] = Ho[..., a2, b2]
    return solveh_banded(ab, g.reshape(N), lower=False, check_finite=False).reshape(G, T, k)


def levenberg_marquardt(problem: SpaceTimeProblem, x0: np.ndarray, max_iter: int = 30,
                        ftol: float = 1e-4, lam0: float = 1e-2,
                        max_step: float = 4.0) -> tuple[np.ndarray, dict]:
    """Minimise the problem's cost with Levenberg-Marquardt on exact normal equations.

    JᵀJ is block-tridiagonal in t (each residual touches one frame or two
    adjacent ones), so every step is one batched block-Cholesky sweep over
    the G independent curves.  Marquardt damping λ·diag(JᵀJ), one λ per
    curve; a step is accepted or rejected per curve (the curves are
    independent, so one hard curve does not hold the others back), and is
    shortened so that no control point moves more than ``max_step`` px,
    which keeps it inside the range where the bilinear image model holds.
    A curve is done when an accepted step lowers its cost by less than
    ``ftol`` (relative).  Stops when all curves are done or after
    ``max_iter`` iterations (each one solve and one cost evaluation, plus
    one Jacobian evaluation if any step was accepted).
    Returns ``(x, info)``; ``info`` has ``cost`` (total), ``iterations``,
    ``jacobians``.
    """
    G, T, C = problem.G, problem.T, problem.C
    C2 = 2 * C
    free = problem.free.reshape(G, T, C2)
    fmask = free.astype(np.float64)
    P = problem.controls(np.asarray(x0, np.float64))
    lam = np.full(G, lam0)
    done = np.zeros(G, bool)
    eye = np.eye(C2)
    n_jac = 0
    need_jac = True
    it = 0
    cost = None
    while it < max_iter and not done.all():
        if need_jac:
            cost, g, Hd, Ho = problem.normal_equations(P[problem.free])
            n_jac += 1
            g = g * fmask
            Hd = Hd * fmask[..., :, None] * fmask[..., None, :]
            Ho = Ho * fmask[:, :-1, :, None] * fmask[:, 1:, None, :]
            diag = np.einsum("gtkk->gtk", Hd)
            scale = np.maximum(diag, 1e-6 * np.maximum(diag.max(axis=(1, 2), keepdims=True), 1e-9))
        it += 1
        Hl = Hd + (lam[:, None, None] * scale + (1 - fmask) + 1e-9)[..., None] * eye
        step = (-solve_block_tridiagonal(Hl, Ho, g) * fmask).reshape(G, T, C, 2)
        longest = np.linalg.norm(step, axis=-1).max(axis=(1, 2))
        step *= np.minimum(1.0, max_step / np.maximum(longest, 1e-12))[:, None, None, None]
        step[done] = 0.0
        P_new = P + step
        new_cost = problem.cost(P_new[problem.free])
        ok = np.isfinite(new_cost) & (new_cost < cost) & ~done
        rel = (cost - new_cost) / np.maximum(cost, 1e-300)
        P[ok] = P_new[ok]
        done |= ok & (rel < ftol)
        done |= ~ok & (lam > 1e8)          # no descent even with tiny steps
        lam = np.where(ok, np.maximum(lam / 3.0, 1e-7), lam * 4.0)
        need_jac = bool(ok.any())
        if not need_jac:
            continue
    total = float(problem.cost(P[problem.free]).sum())
    return P[problem.free], {"cost": total, "iterations": it, "jacobians": n_jac}
