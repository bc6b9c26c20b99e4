"""The updates of NNSF: Algorithm 1 and the class map (docs/method.md §5-§6).

* :func:`_objective`: Eq. 7, C(U, V, W) = ½‖X − VU‖²_F + α ΣV + (β/2)‖VW − Y‖²_F
  (Eq. 5, Hoyer's NNSC objective, with β = 0);
* :func:`_basis_step`: Algorithm 1, lines 1-3 (projected gradient step on U,
  negative entries to 0, rows to unit norm), with backtracking;
* :func:`weight_step` / :func:`_weight_pass`: Algorithm 1, line 4, Hoyer's
  multiplicative update of V (β = 0); :func:`_class_weight_step`: line 4 with
  the class term;
* :func:`class_map_from_grams`: Eq. 8, W = (VᵀV)⁻¹ VᵀY in row form;
* :func:`solve`: the iteration (line 5) until C settles.

The paper's Eq. 6 (re-modelling V on the eigenvectors of a correlation
matrix) is not implemented: docs/method.md §7 gives the reasons (rank one as
printed, ψ never given, outside Eq. 7 and Algorithm 1, and the projection
would leave the non-negative set).  The estimator is :class:`nnsf.factor.nnsf.NNSF`.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp

#: Smallest denominator of a multiplicative update; the same constant as
#: scikit-learn's NMF so that the β = 0 weight update matches it exactly.
EPSILON = np.finfo(np.float32).eps

# Backtracking of the basis step: grow the step after a success, halve it
# after a failure, give up (keep U) after this many halvings.
_STEP_GROW = 1.2
_MAX_HALVINGS = 30


# Algorithm 1 (docs/method.md §6).  The paper's Eq. 6 (re-modelling V on the
# eigenvectors of a correlation matrix) is not implemented; docs/method.md §7
# gives the reasons.
def _one_hot(labels, r, dtype):
    """Y as a sparse one-hot ``(n, r)`` matrix."""
    n = len(labels)
    return sp.csr_matrix((np.ones(n, dtype=dtype), (np.arange(n), labels)), shape=(n, r))


def class_map(V, labels, r, eps):
    """W* = (VᵀV + εI)⁻¹ VᵀY for integer labels, ``(k, r)``."""
    Y = _one_hot(labels, r, V.dtype)
    return class_map_from_grams(V.T @ V, np.asarray((Y.T @ V).T), eps)


def class_map_from_grams(VtV, VtY, eps):
    """W = (VᵀV + λI)⁻¹ VᵀY from the Gram matrices, λ = eps · trace(VᵀV) / k.

    The ridge is relative to the mean diagonal so the result does not depend
    on the units of V; it keeps the solve posed when an atom is unused.
    """
    k = VtV.shape[0]
    # Eq. 8 in row form (docs/method.md §6.3).
    ridge = eps * max(float(np.trace(VtV)) / k, np.finfo(VtV.dtype).tiny)
    return np.linalg.solve(VtV + ridge * np.eye(k, dtype=VtV.dtype), VtY)


def _objective(XX, VtV, VtX, U, v_sum, alpha, beta, W=None, VtY=None, n=0):
    """C from Gram matrices only (no n × d product):

    ½(‖X‖² − 2⟨VᵀX, U⟩ + ⟨VᵀV, UUᵀ⟩) + αΣV + (β/2)(⟨WᵀVᵀV, Wᵀ⟩ − 2⟨VᵀY, W⟩ + n).
    """
    # Eq. 7 (docs/method.md §5); with beta = 0 it is Eq. 5, Hoyer's NNSC objective.
    fit = 0.5 * (XX - 2.0 * np.vdot(VtX, U) + np.vdot(VtV, U @ U.T))
    value = max(fit, 0.0) + alpha * v_sum
    if beta > 0:
        value += 0.5 * beta * (np.vdot(W.T @ VtV, W.T) - 2.0 * np.vdot(VtY, W) + n)
    return float(value)


def _basis_step(U, VtV, VtX, step):
    """Projected gradient step on U with backtracking; rows kept at unit norm.

    Only the ½‖X − VU‖² part of C depends on U, and it is evaluated from the
    Gram matrices, so each trial costs O(k²d).  A candidate is accepted when
    this part does not rise *after* normalisation; otherwise the step halves.
    Returns the new U and the step to start from next time.
    """
    def fit(B):
        return np.vdot(B @ B.T, VtV) - 2.0 * np.vdot(VtX, B)

    grad = VtV @ U - VtX
    current = fit(U)
    for _ in range(_MAX_HALVINGS):
        cand = U - step * grad                      # Algorithm 1, line 1 (docs/method.md §6.2)
        np.maximum(cand, 0, out=cand)               # line 2: negative entries to 0
        norms = np.linalg.norm(cand, axis=1)
        dead = norms <= 0
        if dead.any():
            cand[dead] = U[dead]
            norms[dead] = 1.0
        cand /= norms[:, None]                      # line 3: rows to unit norm
        if fit(cand) <= current:
            return cand, step * _STEP_GROW
        step *= 0.5
    return U, step


def solve(X, V, U, labels, *, alpha, beta, max_iter, tol, v_update, eps):
    """Run NNSF iterations from (V, U); return V, U, W, objective history, update mode.

    With the class term, the rows are first sorted by class (a copy of X and
    V, undone on return): the terms Y(·) and VᵀY then act on contiguous blocks
    of rows instead of gathering a row per label.
    """
    n, d = X.shape
    use_class = beta > 0
    blocks = order = None
    if use_class:
        order = np.argsort(labels, kind="stable")
        X, V = X[order], V[order]
        bounds = np.concatenate([[0], np.cumsum(np.bincount(labels, minlength=int(labels.max()) + 1))])
        blocks = [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    XX = float(np.vdot(X, X))
    mode = "split" if v_update == "auto" else v_update
    # With the class term, two n × k work buffers reused by every weight
    # step; without it the step runs by row blocks (:func:`_weight_pass`)
    # and needs nothing of size n besides V.
    work = (np.empty_like(V), np.empty_like(V)) if use_class else None

    VtV = V.T @ V
    VtX = V.T @ X
    W = VtY = None
    if use_class:
        VtY = _block_sums(V, blocks)
        W = class_map_from_grams(VtV, VtY, eps)
    history = [_objective(XX, VtV, VtX, U, float(V.sum()), alpha, beta, W, VtY, n)]
    step = 1.0 / max(float(np.linalg.eigvalsh(VtV)[-1]), np.finfo(float).tiny)

    for _ in range(max_iter):
        # Algorithm 1, lines 1-3 (docs/method.md §6.2): the basis step.
        U, step = _basis_step(U, VtV, VtX, step)
        if use_class:
            # Eq. 8 refitted every iteration (D3, docs/method.md §6.3), then
            # Algorithm 1, line 4 with the class term (docs/method.md §6.4).
            W = class_map_from_grams(VtV, VtY, eps)
            _class_weight_step(X, V, U, blocks, alpha, beta, W, mode, work)
            VtY = _block_sums(V, blocks)
            VtV = V.T @ V
            VtX = V.T @ X
            v_sum = float(V.sum())
        else:
            # Algorithm 1, line 4 (docs/method.md §6.4): Hoyer's update, beta = 0.
            VtV, VtX, v_sum = _weight_pass(X, V, U, alpha)
        # Algorithm 1, line 5 (docs/method.md §6.5): iterate until C settles.
        history.append(_objective(XX, VtV, VtX, U, v_sum, alpha, beta, W, VtY, n))
        prev, cur = history[-2], history[-1]
        if use_class and v_update == "auto" and mode == "split" and cur > prev * (1 + 1e-9):
            mode = "ssl"
        if abs(prev - cur) <= tol * max(abs(cur), np.finfo(float).tiny):
            break
    if order is not None:
        unsorted = np.empty_like(V)
        unsorted[order] = V
        V = unsorted
    return V, U, W, history, mode


#: Rows per block of the blocked weight pass: a block of X, V and the two
#: work buffers (about 1.2 MB at d = 34, k = 20 in float64) stays in cache
#: between the matrix products and the element-wise update.  Measured at
#: 200,000 × 34, k = 20, one BLAS thread: the pass took 1.30 × the floor
#: (X Uᵀ + VᵀX) with 2048 rows, 1.35 × with 1024, 1.49 × with 4096 and
#: 1.80 × unblocked.
CHUNK_ROWS = 2048


def _weight_pass(X, V, U, alpha, chunk=CHUNK_ROWS):
    """Hoyer's update of V in place (β = 0), fused with the Grams of the new V.

    Per block of rows: V_b ← V_b ⊙ (X_b Uᵀ) ⊘ max(V_b UUᵀ + α, ε), then
    VᵀV += V_bᵀV_b and VᵀX += V_bᵀX_b while the block is in cache.  The
    update is :func:`weight_step`'s, row for row.  Work memory is two
    ``(chunk, k)`` buffers; nothing of size n is allocated.

    Returns VᵀV ``(k, k)``, VᵀX ``(k, d)`` and ΣV of the updated V.
    """
    n, d = X.shape
    k = U.shape[0]
    dt = V.dtype
    Ut = np.ascontiguousarray(U.T)
    UUt = U @ U.T
    VtV = np.zeros((k, k), dtype=dt)
    VtX = np.zeros((k, d), dtype=dt)
    v_sum = 0.0
    m = min(chunk, n)
    num_buf, den_buf = np.empty((m, k), dtype=dt), np.empty((m, k), dtype=dt)
    # When α ≥ ε the denominator V UUᵀ + α (all terms ≥ 0) never falls below ε.
    clamp = not alpha >= EPSILON
    for start in range(0, n, chunk):
        Xb, Vb = X[start:start + chunk], V[start:start + chunk]
        num, den = num_buf[: len(Xb)], den_buf[: len(Xb)]
        np.matmul(Xb, Ut, out=num)
        np.matmul(Vb, UUt, out=den)
        if alpha > 0:
            den += alpha
        if clamp:
            np.maximum(den, EPSILON, out=den)
        num /= den
        Vb *= num
        VtV += Vb.T @ Vb
        VtX += Vb.T @ Xb
        v_sum += float(Vb.sum())
    return VtV, VtX, v_sum


def residual_norm(X, V, U, chunk=CHUNK_ROWS):
    """‖X − VU‖_F by blocks of rows (no n × d temporary)."""
    total = 0.0
    for start in range(0, X.shape[0], chunk):
        R = X[start:start + chunk] - V[start:start + chunk] @ U
        total += float(np.vdot(R, R))
    return float(np.sqrt(total))


def _block_sums(V, blocks):
    """VᵀY for rows sorted by class: the sum of each block of rows, ``(k, r)``."""
    return np.add.reduceat(V, [b.start for b in blocks], axis=0).T


def _add_by_block(out, rows_by_class, blocks):
    """``out += Y @ rows_by_class`` for rows sorted by class: one row added per block."""
    for c, rows in enumerate(blocks):
        out[rows] += rows_by_class[c]


def weight_step(X, V, U, alpha, work=None, XUt=None):
    """Hoyer's multiplicative update of V in place, for fixed U and β = 0.

    V ← V ⊙ (X Uᵀ) ⊘ max(V UUᵀ + α, ε).  The operations are those of
    scikit-learn's ``mu`` update of NMF's W (docs/method.md §6.4), except that a
    denominator below ε is raised to ε where scikit-learn replaces only exact
    zeros; the two agree whenever α ≥ ε.  ``work`` is a pair of ``(n, k)``
    buffers; ``XUt`` a precomputed X Uᵀ when U does not change between calls.
    """
    num, den = work if work is not None else (np.empty_like(V), np.empty_like(V))
    if XUt is None:
        np.matmul(X, U.T, out=num)
    else:
        np.copyto(num, XUt)
    np.matmul(V, U @ U.T, out=den[:, : V.shape[1]])
    den = den[:, : V.shape[1]]
    if alpha > 0:
        den += alpha
    np.maximum(den, EPSILON, out=den)
    num /= den
    V *= num


def _class_weight_step(X, V, U, blocks, alpha, beta, W, mode, work):
    """Multiplicative update of V in place with the class term (β > 0).

    "split" (docs/method.md §6.4):
        num = XUᵀ + β[V(WWᵀ)⁻ + Y(W⁺)ᵀ],  den = V(UUᵀ) + α + β[V(WWᵀ)⁺ + Y(W⁻)ᵀ].
    "ssl" (Sha, Saul & Lee 2007), per row the quadratic ½vAvᵀ + bvᵀ with
    A = UUᵀ + βWWᵀ and b = α − XUᵀ − βYWᵀ:
        v ← v ⊙ (−b + sqrt(b² + 4(vA⁺)⊙(vA⁻))) ⊘ (2vA⁺).
    Rows are sorted by class and ``blocks`` holds each class's rows, so the
    Y(·)ᵀ terms are one row added per block.  ``work`` is a pair of
    contiguous ``(n, k)`` buffers.
    """
    num, den = work
    UUt = U @ U.T
    WWt = W @ W.T
    if mode == "ssl":
        A = UUt + beta * WWt
        P, N = np.maximum(A, 0), np.maximum(-A, 0)
    else:
        P = UUt + beta * np.maximum(WWt, 0)
        N = beta * np.maximum(-WWt, 0)
    np.matmul(X, U.T, out=num)
    if mode == "ssl":
        _add_by_block(num, beta * W.T, blocks)
        np.subtract(alpha, num, out=num)        # b
        np.matmul(V, N, out=den)
        pos = V @ P
        den *= pos
        den *= 4.0
        den += np.square(num)
        np.sqrt(den, out=den)
        den -= num                              # −b + sqrt(b² + 4 (vA⁺)(vA⁻))
        pos *= 2.0
        np.maximum(pos, EPSILON, out=pos)
        den /= pos
        V *= den
    else:
        np.matmul(V, N, out=den)
        num += den
        _add_by_block(num, beta * np.maximum(W, 0).T, blocks)
        np.matmul(V, P, out=den)
        _add_by_block(den, beta * np.maximum(-W, 0).T, blocks)
        if alpha > 0:
            den += alpha
        np.maximum(den, EPSILON, out=den)
        num /= den
        V *= num


def weights_for_basis(X, U, *, alpha=0.0, max_iter=200, tol=1e-4):
    """Non-negative weights V ``(n, k)`` with X ≈ V U for a fixed basis U ``(k, d)``.

    Multiplicative updates (:func:`weight_step`) of ½‖X − VU‖² + αΣV from
    V = sqrt(mean(X)/k), the start and update of scikit-learn's NMF ``mu``
    solver with ``update_H=False``.  Every ten steps the objective is checked;
    the loop stops when its decrease over those steps, relative to its first
    value, is below ``tol`` (scikit-learn's rule).
    """
    n, d = X.shape
    k = U.shape[0]
    V = np.full((n, k), np.sqrt(X.mean() / k), dtype=X.dtype)
    XUt = X @ U.T
    UUt = U @ U.T
    XX = float(np.vdot(X, X))
    m = min(CHUNK_ROWS, n)
    work = (np.empty((m, k), dtype=X.dtype), np.empty((m, k), dtype=X.dtype))

    def objective():
        return 0.5 * (XX - 2.0 * np.vdot(XUt, V) + np.vdot(V.T @ V, UUt)) + alpha * float(V.sum())

    first = previous = objective() if tol > 0 else 0.0
    for it in range(1, max_iter + 1):
        for start in range(0, n, CHUNK_ROWS):
            stop = min(n, start + CHUNK_ROWS)
            weight_step(X[start:stop], V[start:stop], U, alpha,
                        (work[0][: stop - start], work[1][: stop - start]), XUt=XUt[start:stop])
        if tol > 0 and it % 10 == 0:
            current = objective()
            if (previous - current) / max(first, np.finfo(float).tiny) < tol:
                break
            previous = current
    return V
