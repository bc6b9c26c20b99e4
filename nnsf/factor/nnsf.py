"""Non-negative style factorization (NNSF), the paper's §4 in the row form of docs/method.md §5.

The model factorises non-negative features X (n frames × d) as X ≈ V U with
weights V ≥ 0 (n × k) and a style basis U ≥ 0 (k × d) whose rows have unit
norm, while a class map W (k × r) keeps the weights separable by class:

    C(U, V, W) = ½‖X − VU‖²_F + α ΣV + (β/2)‖VW − Y‖²_F,

with Y the one-hot class labels.  With β = 0 this is Hoyer's (2002)
non-negative sparse coding (NNSC).

This module is the scikit-learn estimator (parameters, initialisation,
fit/transform/predict); its updates, Algorithm 1 and Eq. 5, 7 and 8, are
:mod:`nnsf.factor.updates`.
"""
from __future__ import annotations

import numbers

import numpy as np
from sklearn.base import BaseEstimator, TransformerMixin, _fit_context
from sklearn.decomposition._nmf import _initialize_nmf
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_array, check_is_fitted, check_non_negative, validate_data

from nnsf.factor.updates import CHUNK_ROWS, class_map, residual_norm, solve, weights_for_basis


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

        V, U, W, history, mode = solve(
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
            self.class_map_ = class_map(encoded, labels, len(self.classes_), self.eps)
        self.reconstruction_err_ = residual_norm(X, V, U)
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
