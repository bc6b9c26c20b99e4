"""Non-negative style factorization (NNSF), the paper's §4 in the row form of docs/method.md §5.

The model factorises non-negative features X (n frames × d) as X ≈ V U with
weights V ≥ 0 (n × k) and a style basis U ≥ 0 (k × d) whose rows have unit
norm, while a class map W (k × r) keeps the weights separable by class:

    C(U, V, W) = ½‖X − VU‖²_F + α ΣV + (β/2)‖VW − Y‖²_F,

with Y the one-hot class labels.  With β = 0 this is Hoyer's (2002)
non-negative sparse coding (NNSC).
"""
from __future__ import annotations

import numbers

import numpy as np
import scipy.sparse as sp
from sklearn.base import BaseEstimator, TransformerMixin, _fit_context
from sklearn.decomposition._nmf import _initialize_nmf
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_array, check_is_fitted, check_non_negative, validate_data

#: Smallest denominator of a multiplicative update; the same constant as
#: scikit-learn's NMF so that the β = 0 weight update matches it exactly.
EPSILON = np.finfo(np.float32).eps

# Backtracking of the basis step: grow the step after a success, halve it
# after a failure, give up (keep U) after this many halvings.
_STEP_GROW = 1.2
_MAX_HALVINGS = 30


class NNSF(TransformerMixin, BaseEstimator):
    """Non-negative style factorization with a class-separability term.

    Parameters
    ----------
    n_components : int or None, default=None
        Rank k: number of basis rows.  None uses the number of features.
        Must not exceed the number of features.
    alpha : float >= 0, default=0.0
        Weight of the sparseness penalty α ΣV.
    beta : float >= 0, default=0.0
        Weight of the class-separability term (β/2)‖VW − Y‖².  Used only when
        ``fit`` receives labels and ``class_in_loop`` is true.
    class_in_loop : bool, default=True
        Refit the class map W every iteration (D3, docs/method.md §6.3).  False reproduces the
        paper's Algorithm 1 as printed: W is computed once, after convergence,
        so β has no effect on U and V.
    max_iter : int, default=200
        Maximum number of iterations of ``fit``.
    tol : float >= 0, default=1e-4
        Stop when the relative change of the objective, |ΔC| / C, falls below.
    init : {"random", "nndsvd", "nndsvda", "nndsvdar"}, default="nndsvda"
        Initialisation of U and V (scikit-learn's NMF initialisations).
    v_update : {"auto", "split", "ssl"}, default="auto"
        Weight update when β > 0.  "split" is docs/method.md §6.4's multiplicative update
        with WWᵀ and W split into positive and negative parts (a heuristic);
        "ssl" is the multiplicative update of Sha, Saul & Lee (2007) for
        non-negative quadratic programs, which never raises C; "auto" starts
        with "split" and switches to "ssl" for good the first time C rises.
    transform_max_iter : int or None, default=None
        Maximum number of weight steps of ``transform`` (and of the encoding
        of the training rows the class map is fitted on); None uses
        ``max_iter``.
    eps : float > 0, default=1e-10
        Ridge added to VᵀV when solving for the class map, relative to its mean
        diagonal.
    random_state : int, RandomState or None, default=None
        Seed of the "random" and "nndsvdar" initialisations.
    dtype : {None, "float32", "float64"}, default=None
        Floating-point type of the computation and of the fitted arrays.
        None keeps the input's type (float32 stays float32, anything else
        becomes float64); "float32" halves the memory of X's copy (if any),
        V and U on large inputs, at about 1e-6 relative precision.

    Attributes
    ----------
    components_ : ndarray (k, d)
        The style basis U; every row has unit Euclidean norm.
    class_map_ : ndarray (k, r) or None
        The class map W, fitted on the final weights; None without labels.
    classes_ : ndarray (r,) or None
        Class labels seen in ``fit``.
    n_components_ : int
        The rank actually used.
    n_iter_ : int
        Number of iterations run by ``fit``.
    objective_ : ndarray (n_iter_ + 1,)
        C after initialisation and after every iteration.
    reconstruction_err_ : float
        ‖X − VU‖_F on the training data at the end of ``fit``.
    v_update_ : str
        The weight update in force at the end of ``fit``.
    n_features_in_ : int
        Number of features seen in ``fit``.

    Notes
    -----
    One iteration (Algorithm 1, docs/method.md §6): a projected-gradient basis step with
    backtracking on the unit-norm candidate; the class map
    W = (VᵀV + εI)⁻¹ VᵀY; a multiplicative weight update.  The basis step is
    accepted only if C does not rise after the rows are normalised, so with
    β = 0 the objective never increases (the weight update is Hoyer's, which
    is monotone for fixed U).  The weight update with U fixed and β = 0 is
    exactly scikit-learn's ``mu`` update of NMF's W (see docs/method.md §6.4 for the
    equivalent ``non_negative_factorization`` call).
    """

    _parameter_constraints: dict = {
        "n_components": [Interval(numbers.Integral, 1, None, closed="left"), None],
        "alpha": [Interval(numbers.Real, 0, None, closed="left")],
        "beta": [Interval(numbers.Real, 0, None, closed="left")],
        "class_in_loop": ["boolean"],
        "max_iter": [Interval(numbers.Integral, 1, None, closed="left")],
        "tol": [Interval(numbers.Real, 0, None, closed="left")],
        "init": [StrOptions({"random", "nndsvd", "nndsvda", "nndsvdar"})],
        "v_update": [StrOptions({"auto", "split", "ssl"})],
        "transform_max_iter": [Interval(numbers.Integral, 1, None, closed="left"), None],
        "eps": [Interval(numbers.Real, 0, None, closed="neither")],
        "random_state": ["random_state"],
        "dtype": [StrOptions({"float32", "float64"}), None],
    }

    def __init__(
        self,
        n_components=None,
        *,
        alpha=0.0,
        beta=0.0,
        class_in_loop=True,
        max_iter=200,
        tol=1e-4,
        init="nndsvda",
        v_update="auto",
        transform_max_iter=None,
        eps=1e-10,
        random_state=None,
        dtype=None,
    ):
        self.n_components = n_components
        self.alpha = alpha
        self.beta = beta
        self.class_in_loop = class_in_loop
        self.max_iter = max_iter
        self.tol = tol
        self.init = init
        self.v_update = v_update
        self.transform_max_iter = transform_max_iter
        self.eps = eps
        self.random_state = random_state
        self.dtype = dtype

    def _dtypes(self):
        """What ``validate_data`` may return: the chosen type, or either float type."""
        return [np.float64, np.float32] if self.dtype is None else np.dtype(self.dtype).type

    # ------------------------------------------------------------------ fit
    def fit(self, X, y=None):
        """Learn U, V (and W when ``y`` is given) from X.

        Parameters
        ----------
        X : array-like (n, d), non-negative, finite
        y : array-like (n,), optional
            Class label of every row.

        Returns
        -------
        self
        """
        self._fit(X, y)
        return self

    def fit_transform(self, X, y=None):
        """Fit, then return ``transform(X)``, ``(n, k)``.

        The weights are recomputed with U fixed and without labels, exactly as
        for new data, so that a downstream step of a ``Pipeline`` sees training
        and test rows encoded the same way.  The weights learned jointly with
        U (label-informed when β > 0) come from :meth:`fit_weights`.
        """
        return self.fit(X, y).transform(X)

    def fit_weights(self, X, y=None):
        """Fit and return the weights V ``(n, k)`` learned jointly with U."""
        return self._fit(X, y)

    @_fit_context(prefer_skip_nested_validation=True)
    def _fit(self, X, y):
        X = validate_data(self, X, dtype=self._dtypes(), ensure_min_samples=2)
        check_non_negative(X, f"{type(self).__name__} (input X)")
        n, d = X.shape
        k = d if self.n_components is None else self.n_components
        if k > d:
            raise ValueError(
                f"n_components={k} is larger than the number of features ({d}); "
                f"choose a rank of at most {d}"
            )
        if self.init != "random" and k > n:
            raise ValueError(
                f"init={self.init!r} needs n_components <= the number of samples ({n}); "
                "use init='random' or a lower rank"
            )
        labels = None
        if y is not None:
            y = np.asarray(y)
            if y.ndim != 1 or y.shape[0] != n:
                raise ValueError(f"y must be a 1-D array of {n} class labels, got shape {y.shape}")
            self.classes_, labels = np.unique(y, return_inverse=True)
        else:
            self.classes_ = None
        beta = float(self.beta) if (labels is not None and self.class_in_loop) else 0.0

        if n >= LARGE_INIT_ROWS and self.init in ("nndsvd", "nndsvda"):
            V, U = _initialize_nndsvd_lean(X, k, fill=self.init == "nndsvda")
        else:
            V, U = _initialize_nmf(X, k, init=self.init, random_state=self.random_state)
        V, U = V.astype(X.dtype, copy=False), U.astype(X.dtype, copy=False)
        # Algorithm 1, initialisation (docs/method.md §6.1): unit rows of U, V scaled so VU is kept.
        norms = np.linalg.norm(U, axis=1)
        dead = norms <= 0
        U[dead] = 1.0 / np.sqrt(d)  # a zero row has no direction to keep
        norms[dead] = 1.0
        U /= norms[:, None]
        V *= norms[None, :]

        V, U, W, history, mode = _solve(
            X, V, U, labels, alpha=float(self.alpha), beta=beta, max_iter=self.max_iter,
            tol=float(self.tol), v_update=self.v_update, eps=float(self.eps),
        )
        self.components_ = U
        self.n_components_ = k
        self.n_iter_ = len(history) - 1
        self.objective_ = np.asarray(history)
        self.v_update_ = mode
        # The class map is fitted on the training rows encoded as new rows are
        # (U fixed, no labels), so predict() applies it to weights of the same
        # kind it was fitted on.  The map learned in the loop belongs to the
        # label-informed V and mis-scores transform()ed rows at high rank.
        self.class_map_ = None
        if labels is not None:
            encoded = weights_for_basis(X, U, alpha=float(self.alpha), max_iter=self._transform_iters(),
                                        tol=float(self.tol))
            self.class_map_ = _class_map(encoded, labels, len(self.classes_), self.eps)
        self.reconstruction_err_ = _residual_norm(X, V, U)
        return V

    # ------------------------------------------------------------ transform
    def transform(self, X):
        """Weights V ``(n, k)`` of new rows, by weight steps with U fixed.

        No labels are used (β = 0).  V starts at sqrt(mean(X) / k) everywhere,
        runs at most ``max_iter`` steps and stops early when the relative
        decrease of ½‖X − VU‖² + αΣV over ten steps falls below ``tol``;
        at most ``transform_max_iter`` steps (default ``max_iter``).
        """
        check_is_fitted(self)
        X = validate_data(self, X, dtype=self._dtypes(), reset=False)
        check_non_negative(X, f"{type(self).__name__} (input X)")
        U = self.components_.astype(X.dtype, copy=False)
        return weights_for_basis(X, U, alpha=float(self.alpha), max_iter=self._transform_iters(),
                                 tol=float(self.tol))

    def _transform_iters(self):
        return self.max_iter if self.transform_max_iter is None else self.transform_max_iter

    def inverse_transform(self, X):
        """Features reconstructed from weights: ``V @ U``, ``(n, d)``."""
        check_is_fitted(self)
        V = check_array(X, dtype=[np.float64, np.float32])
        if V.ndim != 2 or V.shape[1] != self.components_.shape[0]:
            raise ValueError(
                f"expected weights with {self.components_.shape[0]} columns, got shape {V.shape}"
            )
        return V @ self.components_

    def decision_function(self, X):
        """Class scores ``transform(X) @ class_map_``, ``(n, r)``."""
        check_is_fitted(self)
        if self.class_map_ is None:
            raise ValueError("this NNSF was fitted without class labels; fit(X, y) to predict")
        return self.transform(X) @ self.class_map_

    def predict(self, X):
        """Class of every row: ``classes_[argmax(V W)]``."""
        scores = self.decision_function(X)
        return self.classes_[np.argmax(scores, axis=1)]

    def __sklearn_tags__(self):
        tags = super().__sklearn_tags__()
        tags.input_tags.positive_only = True
        tags.transformer_tags.preserves_dtype = ["float64", "float32"]
        return tags


# ------------------------------------------------------------ initialisation
#: From this many rows on, NNDSVD(a) takes the SVD from the d × d Gram matrix
#: (:func:`_initialize_nndsvd_lean`) instead of scikit-learn's randomized SVD,
#: whose power iterations hold several n × (k + 10) arrays at once (3.5 × the
#: input at k = 20, d = 34).  Below it, results are scikit-learn's exactly.
LARGE_INIT_ROWS = 100_000


def _initialize_nndsvd_lean(X, k, fill):
    """NNDSVD (Boutsidis & Gallopoulos 2008) with memory of V's size only.

    The same construction as scikit-learn's ``_initialize_nmf(init="nndsvd"
    / "nndsvda")``, from the exact top-k SVD of the tall matrix X: the right
    singular vectors and values from the eigen-decomposition of XᵀX (d × d,
    accumulated by row blocks in float64), each left singular vector
    X v_j / s_j computed one column at a time.  Nothing of size n × d is
    allocated, and of size n × k only V itself.

    Returns V ``(n, k)`` and U ``(k, d)`` in X's dtype.
    """
    n, d = X.shape
    gram = np.zeros((d, d))
    for start in range(0, n, CHUNK_ROWS):
        block = np.asarray(X[start:start + CHUNK_ROWS], dtype=np.float64)
        gram += block.T @ block
    evals, evecs = np.linalg.eigh(gram)
    order = np.argsort(evals)[::-1][:k]
    sing = np.sqrt(np.maximum(evals[order], 0.0))
    right = evecs[:, order].T                         # (k, d)
    V = np.zeros((n, k), dtype=X.dtype)
    U = np.zeros((k, d), dtype=X.dtype)
    tiny = np.finfo(np.float64).tiny
    for j in range(k):
        y = right[j]
        x = X @ y.astype(X.dtype, copy=False)
        x = x.astype(np.float64, copy=False) / max(sing[j], tiny)
        if j == 0:
            # The leading singular pair of a non-negative matrix has one sign.
            V[:, 0] = np.sqrt(sing[0]) * np.abs(x)
            U[0] = np.sqrt(sing[0]) * np.abs(y)
            continue
        xp, yp = np.maximum(x, 0), np.maximum(y, 0)
        xn, yn = np.maximum(-x, 0), np.maximum(-y, 0)
        xp_nrm, yp_nrm = np.linalg.norm(xp), np.linalg.norm(yp)
        xn_nrm, yn_nrm = np.linalg.norm(xn), np.linalg.norm(yn)
        m_p, m_n = xp_nrm * yp_nrm, xn_nrm * yn_nrm
        if m_p > m_n:
            u, v, sigma = xp / max(xp_nrm, tiny), yp / max(yp_nrm, tiny), m_p
        else:
            u, v, sigma = xn / max(xn_nrm, tiny), yn / max(yn_nrm, tiny), m_n
        lbd = np.sqrt(sing[j] * sigma)
        V[:, j] = lbd * u
        U[j] = lbd * v
    eps = 1e-6  # scikit-learn's threshold for "zero" in NNDSVD
    V[V < eps] = 0
    U[U < eps] = 0
    if fill:
        avg = X.mean()
        V[V == 0] = avg
        U[U == 0] = avg
    return V, U


# ---------------------------------------------------------------- the solver
# Algorithm 1 (docs/method.md §6).  The paper's Eq. 6 (re-modelling V on the
# eigenvectors of a correlation matrix) is not implemented; docs/method.md §7
# gives the reasons.
def _one_hot(labels, r, dtype):
    """Y as a sparse one-hot ``(n, r)`` matrix."""
    n = len(labels)
    return sp.csr_matrix((np.ones(n, dtype=dtype), (np.arange(n), labels)), shape=(n, r))


def _class_map(V, labels, r, eps):
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


def _solve(X, V, U, labels, *, alpha, beta, max_iter, tol, v_update, eps):
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


def _residual_norm(X, V, U, chunk=CHUNK_ROWS):
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
