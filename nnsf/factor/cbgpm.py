"""Constraint-based Gaussian process model of style (CBGPM), after Ma, Le & Deng (SCA 2009).

Ma et al. learn a facial *editing style* -- the mapping from an original
facial pose to the pose an animator made of it -- as a Gaussian process
regression from a few (original, edited) example pairs that act as
constraints the learned mapping must meet, and transfer the learned style to
new sequences by applying the mapping to their frames.  This module carries
that model over to body motion (the choices, and why, are in
``docs/gp_baselines.md``):

* poses are reduced to their first ``k`` principal components (the *rank*;
  PCA on the training frames), ``z = (x − x̄) Pᵀ``;
* the "original" pose of content ``c`` at phase bin ``b`` is the style-free
  content template ``μ[c, b]`` of the additive fit
  ``Z[s, c, b] ≈ μ[c, b] + o[s]`` of the per-cell phase-bin means
  (:func:`additive_fit`), and the "edited" pose is style ``s``'s own
  ``Z[s, c, b]``: every observed cell gives ``B`` editing pairs;
* each style's edit is ``Δ_s(u) = o[s] + h_s(u)`` with ``h_s`` a zero-mean GP
  over the original pose ``u`` (RBF kernel, ``σ² exp(−‖u − u'‖² / 2ℓ²)``)
  conditioned on the pairs as *constraints*: noise-free up to a relative
  jitter ``η`` (``jitter``), so the learned style reproduces every example
  to that tolerance;
* ``σ²`` and ``ℓ`` (shared by the styles, the feature directions independent
  draws) maximise the summed log marginal likelihood, by L-BFGS with the
  analytic gradient (:func:`neg_log_marginal`).

Synthesis of (style ``s``, content ``c``) is ``μ[c, b] + Δ_s(μ[c, b])``,
decoded back to features and interpolated over phase: for an observed cell
it meets the constraints (the cell's own bin means), for an unseen one the
style's edit is extrapolated from its other contents.  Classification picks
the (content, phase bin) template of the frame's style nearest to the frame.

Cost: one ``n_s × n_s`` Cholesky per style and evaluation, ``n_s = C·B``
points (15 × 3 = 45 on the embedded set), so fitting is dominated by the PCA
and the binning, not by the GP.
"""
from __future__ import annotations

import numbers

import numpy as np
from scipy.linalg import lapack
from scipy.optimize import minimize
from sklearn.base import BaseEstimator
from sklearn.decomposition import PCA
from sklearn.utils.validation import check_array, check_is_fitted
from threadpoolctl import threadpool_limits

from nnsf.factor.gp_data import check_int, check_labels, check_phase, interpolate_bins, phase_bins, phase_from_groups

__all__ = ["CBGPM", "additive_fit", "neg_log_marginal"]

_LOG_SCALE_BOUNDS = (np.log(1e-8), np.log(1e4))


def additive_fit(Z, observed, n_iter: int = 200, tol: float = 1e-12):
    """Least-squares fit ``Z[s, c, b] ≈ μ[c, b] + o[s]`` over the observed entries.

    Parameters
    ----------
    Z : array, shape (S, C, B, k)
        Per-cell phase-bin means (any value where unobserved).
    observed : bool array, shape (S, C, B)

    Returns
    -------
    mu : ndarray (C, B, k)
        Style-free content templates (NaN where no style has the bin).
    offset : ndarray (S, k)
        Style offsets, mean zero over the styles (the gauge of the fit).

    Alternating exact minimisation: each step solves for one block with the
    other fixed, so the squared error never rises; on a complete grid the
    first pair of steps is already exact.
    """
    S, C, B, k = Z.shape
    w = observed[..., None].astype(float)
    Zw = np.where(observed[..., None], Z, 0.0)
    n_sc = w.sum(axis=0)                                   # (C, B, 1) styles per bin
    n_s = w.sum(axis=(1, 2))                               # (S, 1) bins per style
    offset = np.zeros((S, k))
    mu = np.zeros((C, B, k))
    last = np.inf
    for _ in range(n_iter):
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = (Zw - w * offset[:, None, None, :]).sum(axis=0) / n_sc
        mu0 = np.nan_to_num(mu)
        offset = (Zw - w * mu0[None]).sum(axis=(1, 2)) / np.maximum(n_s, 1.0)
        err = float(np.sum(w * (Zw - mu0[None] - offset[:, None, None, :]) ** 2))
        if last - err <= tol * max(err, 1e-300):
            break
        last = err
    shift = offset.mean(axis=0)
    return mu + shift, offset - shift


def neg_log_marginal(theta, inputs, targets, jitter):
    """Summed negative log marginal likelihood of the per-style edit GPs, and its gradient.

    Parameters
    ----------
    theta : array (2,)
        ``ln σ²`` and ``ln ℓ``.
    inputs : list of arrays (n_s, k)
        Original poses (content templates) of each style's editing pairs.
    targets : list of arrays (n_s, k)
        Edits minus the style offset (the GP's zero-mean part).
    jitter : float
        ``η``: the constraint tolerance, the noise variance relative to ``σ²``.

    Returns
    -------
    value : float
        ``Σ_s k/2 ln|K_s| + ½ tr(K_s⁻¹ T_s T_sᵀ) + n_s k/2 ln 2π``,
        ``K_s = σ² (R_s + η I)``.
    grad : ndarray (2,)
    """
    log_s2, log_l = float(theta[0]), float(theta[1])
    s2, ell2 = np.exp(log_s2), np.exp(2 * log_l)
    value, g = 0.0, np.zeros(2)
    for U, T in zip(inputs, targets):
        n, k = T.shape
        D2 = np.maximum(((U[:, None, :] - U[None, :, :]) ** 2).sum(-1), 0.0)
        R = np.exp(-0.5 * D2 / ell2)
        K = s2 * (R + jitter * np.eye(n))
        L, info = lapack.dpotrf(K, lower=1, clean=1)
        if info != 0:
            raise np.linalg.LinAlgError(f"CBGPM kernel matrix is not positive definite (info {info})")
        Kinv, _ = lapack.dpotri(L, lower=1)
        Kinv = np.tril(Kinv) + np.tril(Kinv, -1).T
        alpha = Kinv @ T
        value += k * np.log(np.diag(L)).sum() + 0.5 * float(np.sum(T * alpha)) + 0.5 * n * k * np.log(2 * np.pi)
        G = 0.5 * (k * Kinv - alpha @ alpha.T)
        g[0] += float(np.sum(G * K))                       # dK/d ln σ² = K
        g[1] += float(np.sum(G * s2 * R * D2 / ell2))      # dK/d ln ℓ = σ² R ∘ D²/ℓ²
    return value, g


class CBGPM(BaseEstimator):
    """Style as a constrained GP edit of style-free content templates (after Ma et al. 2009).

    Parameters
    ----------
    n_components : int >= 1
        Rank: principal components of the pose space the GP works in; at
        most the number of features.
    phase_bins : int >= 1
        ``B``: editing pairs per observed (style, content) cell, the means of
        ``B`` equal phase bins.  At most the frames of the smallest cell.
    max_iter : int >= 1
        L-BFGS iterations for ``σ²`` and ``ℓ``.
    jitter : float > 0
        ``η``: the constraints hold up to a noise variance of ``η σ²``.

    Attributes
    ----------
    classes_, styles_ : ndarrays of the content and style labels
    pca_ : sklearn.decomposition.PCA
    templates_ : ndarray (C, B, k)
        Style-free content templates ``μ`` (PCA coordinates).
    offsets_ : ndarray (S, k)
    signal_var_, length_scale_ : float
        ``σ²`` (PCA units²) and ``ℓ`` (PCA units).
    observed_ : bool ndarray (S, C)
    n_train_points_ : int
        Editing pairs (observed style × content × bin).
    n_components_ : int
    n_iter_ : int
    """

    def __init__(self, n_components=8, phase_bins=3, max_iter=50, jitter=1e-6):
        self.n_components = n_components
        self.phase_bins = phase_bins
        self.max_iter = max_iter
        self.jitter = jitter

    def fit(self, X, y, style, phase=None, groups=None):
        """Fit from frames ``X`` (n, d), contents ``y``, styles and phases (or clips ``groups``)."""
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
        if not (isinstance(self.jitter, numbers.Real) and not isinstance(self.jitter, bool)
                and self.jitter > 0):
            raise ValueError(f"jitter must be a number > 0, got {self.jitter!r}")
        if self.n_components > min(d, n):
            raise ValueError(f"n_components={self.n_components} exceeds the CBGPM's limit on these "
                             f"data, min(features, frames) = {min(d, n)}")
        y = check_labels(y, n, "y")
        style = check_labels(style, n, "style")
        if phase is None:
            if groups is None:
                raise ValueError("CBGPM.fit needs phase (n,) or groups (the clip of each row)")
            phase = phase_from_groups(check_labels(groups, n, "groups"))
        phase = check_phase(phase, n)
        styles, contents, means, observed, _ = phase_bins(X, style, y, phase, self.phase_bins)

        self.pca_ = PCA(n_components=self.n_components, svd_solver="full").fit(X)
        Z = np.where(observed[..., None], means, 0.0)
        Z = np.where(observed[..., None], self.pca_.transform(Z.reshape(-1, d)).reshape(*observed.shape, -1), 0.0)
        mu, offset = additive_fit(Z, observed)
        inputs, targets = [], []
        for i in range(len(styles)):
            ok = observed[i]
            inputs.append(mu[ok])
            targets.append(Z[i][ok] - mu[ok] - offset[i])
        # Start ℓ at the median distance between original poses, σ² at the residual variance.
        U_all = np.concatenate(inputs)
        dist = np.sqrt(((U_all[:, None] - U_all[None]) ** 2).sum(-1))
        ell0 = float(np.median(dist[dist > 0])) if np.any(dist > 0) else 1.0
        s20 = float(np.mean(np.concatenate(targets) ** 2)) or 1.0
        theta0 = np.array([np.log(max(s20, 1e-8)), np.log(ell0)])
        bounds = [_LOG_SCALE_BOUNDS, (np.log(1e-3 * ell0), np.log(1e3 * ell0))]
        res = minimize(neg_log_marginal, theta0, args=(inputs, targets, float(self.jitter)), jac=True,
                       method="L-BFGS-B", bounds=bounds, options={"maxiter": int(self.max_iter)})
        self.signal_var_ = float(np.exp(res.x[0]))
        self.length_scale_ = float(np.exp(res.x[1]))
        self.n_iter_ = int(res.nit)
        self._gp = []
        for U, T in zip(inputs, targets):
            K = self._kernel(U, U) + self.jitter * self.signal_var_ * np.eye(len(U))
            self._gp.append((U, np.linalg.solve(K, T)))
        self.n_features_in_ = d
        self.classes_ = contents
        self.styles_ = styles
        self.templates_ = mu
        self.offsets_ = offset
        self.observed_ = observed.any(axis=2)
        self.n_train_points_ = int(observed.sum())
        self.n_components_ = int(self.n_components)
        self._cell_templates = {}
        return self

    def _kernel(self, A, B):
        D2 = ((A[:, None, :] - B[None, :, :]) ** 2).sum(-1)
        return self.signal_var_ * np.exp(-0.5 * D2 / self.length_scale_ ** 2)

    def _index(self, labels, known, what):
        labels = np.atleast_1d(np.asarray(labels))
        pos = np.minimum(np.searchsorted(known, labels), len(known) - 1)
        bad = known[pos] != labels
        if bad.any():
            raise ValueError(f"unknown {what} {labels[bad][:5].tolist()}; the model knows "
                             f"{known.tolist()[:10]}")
        return pos

    def edit(self, style, originals) -> np.ndarray:
        """Style ``style``'s learned edit ``Δ_s(u)`` of original poses ``u`` (m, k), PCA coordinates."""
        check_is_fitted(self, "templates_")
        i = int(self._index([style], self.styles_, "style")[0])
        U, alpha = self._gp[i]
        originals = np.asarray(originals, dtype=float)
        return self.offsets_[i] + self._kernel(originals, U) @ alpha

    def _templates(self, i):
        """Per-bin templates (C, B, k) of style index ``i`` in PCA coordinates."""
        if i not in self._cell_templates:
            C, B, k = self.templates_.shape
            mu = self.templates_.reshape(-1, k)
            ok = np.all(np.isfinite(mu), axis=1)
            out = np.full_like(mu, np.nan)
            U, alpha = self._gp[i]
            out[ok] = mu[ok] + self.offsets_[i] + self._kernel(mu[ok], U) @ alpha
            self._cell_templates[i] = out.reshape(C, B, k)
        return self._cell_templates[i]

    def synthesize(self, style, content, phase) -> np.ndarray:
        """Pose of (``style``, ``content``) at ``phase`` (m,): ``(m, d)`` features.

        Templates per bin centre, linearly interpolated in phase; any
        combination, observed or not.
        """
        check_is_fitted(self, "templates_")
        phase = check_phase(np.atleast_1d(np.asarray(phase, dtype=float)), np.size(phase))
        i = int(self._index([style], self.styles_, "style")[0])
        c = int(self._index([content], self.classes_, "content")[0])
        T = self._templates(i)[c]                                   # (B, k)
        ok = np.all(np.isfinite(T), axis=1)
        T = T[ok] if ok.any() else T
        return self.pca_.inverse_transform(interpolate_bins(T, phase))

    def _scores(self, X, style):
        """Negative squared distance (n, C) to each content's nearest bin template, and that template."""
        check_is_fitted(self, "templates_")
        X = check_array(X, dtype=np.float64, ensure_all_finite=True)
        if X.shape[1] != self.n_features_in_:
            raise ValueError(f"X has {X.shape[1]} features, the model was fitted on {self.n_features_in_}")
        n = X.shape[0]
        Zx = self.pca_.transform(X)
        C, B, k = self.templates_.shape
        best = np.full((n, C), -np.inf)
        pose = np.zeros((n, C, k))
        if style is None:
            groups = [(i, np.ones(n, bool)) for i in range(len(self.styles_))]
        else:
            pos = self._index(check_labels(style, n, "style"), self.styles_, "style")
            groups = [(i, pos == i) for i in np.unique(pos)]
        for i, rows in groups:
            T = self._templates(i).reshape(C * B, k)
            T = np.where(np.isfinite(T), T, 1e150)                  # an empty bin is never nearest
            Zr = Zx[rows]
            d2 = (Zr ** 2).sum(1)[:, None] - 2 * Zr @ T.T + (T ** 2).sum(1)[None, :]
            d2 = d2.reshape(-1, C, B)
            arg = d2.argmin(axis=2)
            top = -np.take_along_axis(d2, arg[:, :, None], axis=2)[:, :, 0]
            cand = T.reshape(C, B, k)[np.arange(C)[None, :], arg]
            better = top > best[rows]
            sub_best, sub_pose = best[rows], pose[rows]
            sub_best[better] = top[better]
            sub_pose[better] = cand[better]
            best[rows], pose[rows] = sub_best, sub_pose
        return best, pose

    def decision_function(self, X, style=None):
        """Minus the squared distance (PCA space) to each content's nearest template, ``(n, C)``."""
        return self._scores(X, style)[0]

    def predict(self, X, style=None):
        """Content of each row (``style`` (n,) known styles, or None to search all)."""
        return self.classes_[np.argmax(self._scores(X, style)[0], axis=1)]

    def reconstruct(self, X, style=None):
        """The nearest template (n, d) in features."""
        best, pose = self._scores(X, style)
        return self.pca_.inverse_transform(pose[np.arange(len(best)), np.argmax(best, axis=1)])
