"""Multifactor Gaussian process model (MGPM) of Wang, Fleet & Hertzmann (ICML 2007).

A pose ``y`` (one row of features, d values) of style ``s`` (a character),
content ``c`` (a motion class) and state ``φ`` (the phase of the motion, 0 at
a clip's first frame and 1 at its last) is a draw of a Gaussian process whose
kernel is the product of one kernel per factor:

    k((s, c, φ), (s', c', φ')) = (sᵀs') · (cᵀc') · exp(−γ/2 (φ − φ')²) + b + β⁻¹ δ,

with a latent *style vector* ``s`` per style and a latent *content vector*
``c`` per content (linear kernels: the multilinear model with its weights
integrated out) and an RBF on the state; ``b`` is a bias term (a constant
mean per feature with a N(0, b) prior, integrated out: the features are
centred on their sample mean, which is not the model's mean).  Each of the
``d`` standardised feature columns is an independent draw with this kernel.
The latent vectors and the hyperparameters ``γ`` (inverse squared phase
length-scale), ``b`` and ``β`` (noise precision) maximise the log posterior

    −L = −d/2 ln|K| − ½ tr(K⁻¹ Y Yᵀ) − ½ Σ‖s‖² − ½ Σ‖c‖² + const

(GPLVM-style unit Gaussian priors on the latent vectors), by L-BFGS with the
analytic gradient (:func:`neg_log_posterior`).  The latent dimension is the
*rank*; the style vectors have ``min(rank, S)`` and the content vectors
``min(rank, C)`` dimensions (more would add nothing: S vectors span at most S
dimensions), and a rank above ``max(S, C)`` is rejected.

Training points.  A GP costs O(n³); the model is fitted on the per-cell phase
bins of :func:`nnsf.factor.gp_data.phase_bins` (``n ≤ S·C·B`` points), not on
every frame.  One objective evaluation costs one Cholesky factorisation and
one inverse of the ``n × n`` kernel matrix (≈ n³ flops, 405 points: ≈ 10 ms
on one core) plus O(n²·rank) for the gradient.

Using the model:

* :meth:`MGPM.synthesize` -- the predictive mean of any (style, content) at
  any phases, in particular a combination never observed (style translation);
* :meth:`MGPM.predict` -- the content of new frames: the (content, phase) of
  highest predictive likelihood under the frame's style (searched over every
  known style when it is not given).  The phase is searched over the bin
  centres, so the classifier sees the pose only, as the factorisations do.

What is simplified from the paper, and why, is in ``docs/gp_baselines.md``.
"""
from __future__ import annotations

import numbers

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_array, check_is_fitted
from threadpoolctl import threadpool_limits

from nnsf.factor.gp_data import bin_centres, check_int, check_labels, check_phase, phase_bins, phase_from_groups

__all__ = ["MGPM", "neg_log_posterior", "max_rank"]

# Bounds of the log hyperparameters: the phase length-scale between 0.01 and
# about 1.4 (γ from 0.5 to 10⁴), the noise variance from 1 to 10⁻⁵ of the
# (unit) variance of a standardised feature.
_LOG_GAMMA_BOUNDS = (np.log(0.5), np.log(1e4))
_LOG_BETA_BOUNDS = (0.0, np.log(1e5))
_LOG_BIAS_BOUNDS = (np.log(1e-6), np.log(1e2))
_GAMMA0, _BIAS0, _BETA0 = 16.0, 0.1, 100.0   # phase length-scale 0.25; noise 1 % of the variance


def max_rank(n_styles: int, n_contents: int) -> int:
    """Largest latent dimension the MGPM accepts: ``max(S, C)``."""
    return max(int(n_styles), int(n_contents))


def _unpack(theta, S, C, q_s, q_c):
    Sv = theta[:S * q_s].reshape(S, q_s)
    Cv = theta[S * q_s:S * q_s + C * q_c].reshape(C, q_c)
    log_gamma, log_bias, log_beta = theta[-3], theta[-2], theta[-1]
    return Sv, Cv, log_gamma, log_bias, log_beta


def neg_log_posterior(theta, Y, s_idx, c_idx, phi, S, C, q_s, q_c, return_parts=False):
    """Negative log posterior of the MGPM and its gradient.

    Parameters
    ----------
    theta : array, shape (S·q_s + C·q_c + 3,)
        Style vectors (S, q_s) and content vectors (C, q_c), row-major, then
        ``ln γ``, ``ln b`` and ``ln β``.
    Y : array, shape (n, d)
        Standardised training points.
    s_idx, c_idx : int arrays, shape (n,)
        Style and content of each point (indices into the vectors).
    phi : array, shape (n,)
        Phase of each point.
    S, C, q_s, q_c : int
        Numbers of styles and contents, and their latent dimensions.
    return_parts : bool
        Also return ``(L, alpha, K⁻¹)``: the Cholesky factor, ``K⁻¹Y`` and ``K⁻¹``.

    Returns
    -------
    value : float
        ``d/2 ln|K| + ½ tr(K⁻¹YYᵀ) + ½‖Sv‖² + ½‖Cv‖² + n·d/2 ln 2π``.
    grad : ndarray, same shape as ``theta``
    """
    n, d = Y.shape
    Sv, Cv, log_gamma, log_bias, log_beta = _unpack(theta, S, C, q_s, q_c)
    gamma, bias, beta = np.exp(log_gamma), np.exp(log_bias), np.exp(log_beta)
    Sa, Ca = Sv[s_idx], Cv[c_idx]                          # (n, q_s), (n, q_c)
    A = Sa @ Sa.T                                          # style kernel
    B = Ca @ Ca.T                                          # content kernel
    D2 = (phi[:, None] - phi[None, :]) ** 2
    R = np.exp(-0.5 * gamma * D2)                          # state kernel
    Kf = A * B * R
    K = Kf + bias
    K[np.diag_indices(n)] += 1.0 / beta
    # K⁻¹ itself is needed (the gradient contracts all of dL/dK); LAPACK's
    # potri computes it from the Cholesky factor in a third of the time of
    # solving against the identity.
    L, info = lapack.dpotrf(K, lower=1, clean=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"MGPM kernel matrix is not positive definite (potrf info {info})")
    Kinv, info = lapack.dpotri(L, lower=1)
    Kinv = np.tril(Kinv) + np.tril(Kinv, -1).T
    alpha = Kinv @ Y                                       # K⁻¹ Y, (n, d)
    logdet = 2.0 * np.log(np.diag(L)).sum()
    value = (0.5 * d * logdet + 0.5 * float(np.sum(Y * alpha)) + 0.5 * float(np.sum(Sv ** 2))
             + 0.5 * float(np.sum(Cv ** 2)) + 0.5 * n * d * np.log(2 * np.pi))
    G = 0.5 * (d * Kinv - alpha @ alpha.T)                 # dL/dK, symmetric
    # dL/dSa = 2 (G∘B∘R) Sa; rows of Sa are copies of style vectors, so sum per style.
    gSa = 2.0 * (G * B * R) @ Sa
    gCa = 2.0 * (G * A * R) @ Ca
    gS = np.zeros_like(Sv)
    np.add.at(gS, s_idx, gSa)
    gC = np.zeros_like(Cv)
    np.add.at(gC, c_idx, gCa)
    gS += Sv
    gC += Cv
    g_log_gamma = float(np.sum(G * Kf * (-0.5 * gamma * D2)))
    g_log_bias = float(bias * np.sum(G))
    g_log_beta = float(-np.trace(G) / beta)
    grad = np.concatenate([gS.ravel(), gC.ravel(), [g_log_gamma, g_log_bias, g_log_beta]])
    if return_parts:
        return value, grad, (L, alpha, Kinv)
    return value, grad


class MGPM(BaseEstimator):
    """Multifactor GP over (style, content, phase) -> pose (Wang, Fleet & Hertzmann 2007).

    Parameters
    ----------
    n_components : int >= 1
        Rank: the latent dimension (style vectors use ``min(rank, S)``,
        content vectors ``min(rank, C)``).  At most ``max(S, C)``.
    phase_bins : int >= 1
        ``B``: training points per (style, content) cell, the means of ``B``
        equal phase bins (:func:`nnsf.factor.gp_data.phase_bins`).  At most
        the frames of the smallest cell.
    max_iter : int >= 1
        L-BFGS iterations.
    tol : float > 0
        L-BFGS ``ftol`` (relative decrease of the objective that stops it).
    random_state : int or None
        Seeds a 10⁻³ perturbation of the SVD initialisation (breaks ties
        between latent directions); the fit is deterministic given it.

    Attributes
    ----------
    classes_ : ndarray (C,)
        Content labels.
    styles_ : ndarray (S,)
        Style labels.
    style_vectors_ : ndarray (S, q_s)
    content_vectors_ : ndarray (C, q_c)
    n_components_ : int
        ``max(q_s, q_c)``, the rank used.
    gamma_, bias_, beta_ : float
        RBF inverse squared length-scale (per unit phase²), bias variance
        and noise precision (per unit standardised variance).
    mean_, scale_ : ndarray (d,)
        Feature standardisation (the GP models ``(x − mean_) / scale_``).
    n_train_points_ : int
        ``n``, the training points after binning.
    objective_ : float
        Final negative log posterior (per the docstring of
        :func:`neg_log_posterior`).
    n_iter_ : int
        L-BFGS iterations run.
    """

    def __init__(self, n_components=3, phase_bins=3, max_iter=60, tol=1e-7, random_state=None):
        self.n_components = n_components
        self.phase_bins = phase_bins
        self.max_iter = max_iter
        self.tol = tol
        self.random_state = random_state

    # ------------------------------------------------------------------ fit
    def fit(self, X, y, style, phase=None, groups=None):
        """Fit from frames ``X`` (n, d), contents ``y`` (n,), styles (n,) and phases (n,).

        ``phase`` defaults to each row's position in its clip (``groups``, the
        clip of each row, in table order); one of the two is required.
        """
        # One BLAS thread: the matrices are a few hundred wide at most, and
        # threaded BLAS on them ran several times slower on a loaded 2-core machine.
        with threadpool_limits(1, user_api="blas"):
            return self._fit(X, y, style, phase, groups)

    def _fit(self, X, y, style, phase, groups):
        X = check_array(X, dtype=np.float64, ensure_all_finite=True)
        n, d = X.shape
        check_int("n_components", self.n_components)
        check_int("phase_bins", self.phase_bins)
        check_int("max_iter", self.max_iter)
        if not (isinstance(self.tol, numbers.Real) and not isinstance(self.tol, bool) and self.tol > 0):
            raise ValueError(f"tol must be a number > 0, got {self.tol!r}")
        y = check_labels(y, n, "y")
        style = check_labels(style, n, "style")
        if phase is None:
            if groups is None:
                raise ValueError("MGPM.fit needs phase (n,) or groups (the clip of each row)")
            phase = phase_from_groups(check_labels(groups, n, "groups"))
        phase = check_phase(phase, n)

        styles, contents, means, observed, mean_phase = phase_bins(X, style, y, phase, self.phase_bins)
        S, C, Bn = observed.shape
        top = max_rank(S, C)
        if self.n_components > top:
            raise ValueError(f"n_components={self.n_components} exceeds the MGPM's limit on these "
                             f"data, max(styles, contents) = max({S}, {C}) = {top}")
        q_s, q_c = min(self.n_components, S), min(self.n_components, C)
        s_idx, c_idx, b_idx = np.nonzero(observed)
        P = means[observed]                                 # (n_points, d)
        phi = mean_phase[observed]
        self.mean_ = P.mean(axis=0)
        scale = P.std(axis=0)
        self.scale_ = np.where(scale > 1e-12 * max(scale.max(), 1e-300), scale, 1.0)
        Y = (P - self.mean_) / self.scale_

        theta0 = self._initial(Y, s_idx, c_idx, S, C, q_s, q_c)
        bounds = [(None, None)] * (S * q_s + C * q_c) + [_LOG_GAMMA_BOUNDS, _LOG_BIAS_BOUNDS,
                                                          _LOG_BETA_BOUNDS]
        args = (Y, s_idx, c_idx, phi, S, C, q_s, q_c)
        res = minimize(neg_log_posterior, theta0, args=args, jac=True, method="L-BFGS-B",
                       bounds=bounds, options={"maxiter": int(self.max_iter), "ftol": float(self.tol)})
        value, _, (_, alpha, Kinv) = neg_log_posterior(res.x, *args, return_parts=True)
        Sv, Cv, log_gamma, log_bias, log_beta = _unpack(res.x, S, C, q_s, q_c)

        self.n_features_in_ = d
        self.classes_ = contents
        self.styles_ = styles
        self.style_vectors_ = Sv.copy()
        self.content_vectors_ = Cv.copy()
        self.n_components_ = max(q_s, q_c)
        self.gamma_ = float(np.exp(log_gamma))
        self.beta_ = float(np.exp(log_beta))
        self.bias_ = float(np.exp(log_bias))
        self.n_train_points_ = int(len(Y))
        self.objective_ = float(value)
        self.n_iter_ = int(res.nit)
        self.observed_ = observed.any(axis=2)
        self._train = (Sv[s_idx], Cv[c_idx], phi)
        self._alpha, self._Kinv = alpha, Kinv
        return self

    def _initial(self, Y, s_idx, c_idx, S, C, q_s, q_c):
        """Latent vectors from SVDs of the cell means (the bilinear model's start), ln γ₀, ln b₀, ln β₀."""
        d = Y.shape[1]
        sums = np.zeros((S, C, d))
        np.add.at(sums, (s_idx, c_idx), Y)
        counts = np.zeros((S, C))
        np.add.at(counts, (s_idx, c_idx), 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            M = sums / counts[:, :, None]
        # A missing cell starts from its content's mean over the styles that have it.
        content_mean = np.nanmean(np.where(counts[:, :, None] > 0, M, np.nan), axis=0)
        M = np.where(counts[:, :, None] > 0, M, content_mean[None])

        def factor(mat, k, rows):
            U, sv, _ = np.linalg.svd(mat, full_matrices=False)
            U = np.pad(U, ((0, 0), (0, max(0, k - U.shape[1]))))[:, :k]
            sv = np.pad(sv, (0, max(0, k - sv.shape[0])))[:k]
            w = sv / max(np.sqrt(np.sum(sv ** 2)), 1e-300)
            # Σ over rows of ‖vector‖² = rows: kernel values of order 1 on unit-variance data.
            return U * w * np.sqrt(rows)

        Sv = factor(M.reshape(S, C * d), q_s, S)
        Cv = factor(M.transpose(1, 0, 2).reshape(C, S * d), q_c, C)
        rng = np.random.default_rng(self.random_state)
        Sv = Sv + 1e-3 * rng.standard_normal(Sv.shape)
        Cv = Cv + 1e-3 * rng.standard_normal(Cv.shape)
        return np.concatenate([Sv.ravel(), Cv.ravel(), [np.log(_GAMMA0), np.log(_BIAS0), np.log(_BETA0)]])

    # ------------------------------------------------------------ prediction
    def _index(self, labels, known, what):
        labels = np.atleast_1d(np.asarray(labels))
        pos = np.searchsorted(known, labels)
        pos = np.minimum(pos, len(known) - 1)
        bad = known[pos] != labels
        if bad.any():
            raise ValueError(f"unknown {what} {labels[bad][:5].tolist()}; the model knows "
                             f"{known.tolist()[:10]}")
        return pos

    def _predict_std(self, s_pos, c_pos, phi):
        """Standardised predictive mean (m, d) and variance (m,) at (style, content, phase) rows."""
        Sa, Ca, Phi = self._train
        sv, cv = self.style_vectors_[s_pos], self.content_vectors_[c_pos]
        ks = (sv @ Sa.T) * (cv @ Ca.T) * np.exp(-0.5 * self.gamma_ * (phi[:, None] - Phi[None, :]) ** 2)
        ks += self.bias_
        mean = ks @ self._alpha
        kss = np.sum(sv ** 2, axis=1) * np.sum(cv ** 2, axis=1) + self.bias_
        var = kss - np.sum((ks @ self._Kinv) * ks, axis=1) + 1.0 / self.beta_
        return mean, np.maximum(var, 1e-12)

    def synthesize(self, style, content, phase) -> np.ndarray:
        """Predictive mean pose of (``style``, ``content``) at ``phase`` (m,): ``(m, d)`` features.

        The combination need not have been observed: this is the model's
        synthesis of an unseen (style, content) cell.
        """
        check_is_fitted(self, "style_vectors_")
        phase = check_phase(np.atleast_1d(np.asarray(phase, dtype=float)), np.size(phase))
        m = len(phase)
        s_pos = np.repeat(self._index([style], self.styles_, "style"), m)
        c_pos = np.repeat(self._index([content], self.classes_, "content"), m)
        mean, _ = self._predict_std(s_pos, c_pos, phase)
        return self.mean_ + self.scale_ * mean

    def _scores(self, X, style):
        """Best log-likelihood per content (n, C) and the pose achieving it (n, C, d)."""
        check_is_fitted(self, "style_vectors_")
        X = check_array(X, dtype=np.float64, ensure_all_finite=True)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"X has {X.shape[1]} features, the model was fitted on {self.n_features_in_}")
        n, d = X.shape
        Z = (X - self.mean_) / self.scale_
        C = len(self.classes_)
        grid = bin_centres(self.phase_bins)
        G = len(grid)
        c_pos = np.repeat(np.arange(C), G)
        phi = np.tile(grid, C)
        best = np.full((n, C), -np.inf)
        pose = np.zeros((n, C, d))
        if style is None:
            groups = [(i, np.ones(n, bool)) for i in range(len(self.styles_))]
        else:
            style = check_labels(style, n, "style")
            pos = self._index(style, self.styles_, "style")
            groups = [(i, pos == i) for i in np.unique(pos)]
        for i, rows in groups:
            mean, var = self._predict_std(np.full(len(c_pos), i), c_pos, phi)   # (C·G, d), (C·G,)
            Zr = Z[rows]
            d2 = (Zr ** 2).sum(1)[:, None] - 2 * Zr @ mean.T + (mean ** 2).sum(1)[None, :]
            ll = -0.5 * d2 / var[None, :] - 0.5 * d * np.log(var)[None, :]     # (n_rows, C·G)
            ll = ll.reshape(-1, C, G)
            arg = ll.argmax(axis=2)
            top = np.take_along_axis(ll, arg[:, :, None], axis=2)[:, :, 0]
            better = top > best[rows]
            cand = mean.reshape(C, G, d)[np.arange(C)[None, :], arg]           # (n_rows, C, d)
            sub_best, sub_pose = best[rows], pose[rows]
            sub_best[better] = top[better]
            sub_pose[better] = cand[better]
            best[rows], pose[rows] = sub_best, sub_pose
        return best, self.mean_ + self.scale_ * pose

    def decision_function(self, X, style=None):
        """Best predictive log-likelihood of each row under each content, ``(n, C)``."""
        return self._scores(X, style)[0]

    def predict(self, X, style=None):
        """Content of each row (``style`` (n,) known styles, or None to search all styles)."""
        return self.classes_[np.argmax(self._scores(X, style)[0], axis=1)]

    def reconstruct(self, X, style=None):
        """The predicted pose (n, d) of each row's best (content, phase)."""
        best, pose = self._scores(X, style)
        return pose[np.arange(len(best)), np.argmax(best, axis=1)]
