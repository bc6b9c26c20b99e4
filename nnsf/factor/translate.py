"""Style translation by non-negative style factorization (docs/method.md §8, D5; the paper's §4, end).

The paper synthesises "jump in Wukong Sun's style" by recombining a basis and
weights that come from different characters.  That only works if atom ``i``
means the same thing in both, so every style's basis is derived from one
pooled NNSF fit (U₀, V), starting from U₀ (D5, docs/method.md §8.1):

* ``basis="refit"`` -- D5 as written: the pooled weights fixed, basis steps
  per style from U₀ (:func:`nnsf.factor.align.refit_basis`);
* ``basis="aligned"`` (default) -- the clips of one content are aligned in
  time by DTW to a reference clip of that content, and aligned frames of
  different styles share one weight row, which forces the style into the
  bases: x_{s,t} ≈ v_{g(t)} U_s + b_s with a per-style offset b_s, fitted by
  alternating a multiplicative update of the shared weights (with a
  second-order temporal smoothness term) and projected-gradient basis steps
  per style, pulled towards U₀ by a ridge.

Uses of a fitted translator (row form, X is ``(n, 34)``, template units):

* :meth:`StyleTranslator.translate` -- a clip of a known style: X̂ = V U_b + b_b
  plus the clip's residual X − V U_a − b_a (docs/method.md §8.2);
* :meth:`StyleTranslator.synthesize` -- a whole (content, style) cell from the
  content's shared weights, amplitude restored and scaled to the style's,
  resampled to its tempo (docs/method.md §8.3);
* :meth:`StyleTranslator.translate_clip` -- the public path, a clip of any
  action and any body (``transfer``, docs/method.md §8.4): the recombination
  above read from the reference style, and the style's swing per octave band
  taken from the training actions most like the clip
  (:mod:`nnsf.factor.style_transfer`).

Units: unified template coordinates (torso = 1.0); :func:`to_character_points`
maps translated features back to a character's pixels.  Atom correspondence
is :mod:`nnsf.factor.align`, time :mod:`nnsf.factor.timewarp`, posture and
swing :mod:`nnsf.factor.style_transfer`.  What is left here is one concept,
the :class:`StyleTranslator` estimator: its fit, encoding and synthesis
methods share the fitted bases, offsets, shared content weights, tempi and
per-cell statistics, and scikit-learn's estimator contract keeps them on one
class.
"""
from __future__ import annotations

from numbers import Integral, Real
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from sklearn.base import BaseEstimator, _fit_context
from sklearn.utils._param_validation import Interval, StrOptions
from sklearn.utils.validation import check_array, check_is_fitted, check_non_negative

from nnsf.factor import style_transfer as st
from nnsf.factor.align import refit_basis
from nnsf.factor.model_file import ModelView, load_model, save_model
from nnsf.factor.nnsf import NNSF
from nnsf.factor.timewarp import _style_tempo, align_to_reference, resample_clip, second_difference_split
from nnsf.factor.updates import EPSILON, _basis_step, weights_for_basis
from nnsf.params import AMPLITUDES, BASES, SYNTHESES, TRANSFERS

__all__ = ["BASES", "SYNTHESES", "AMPLITUDES", "TRANSFERS", "StyleTranslator", "to_character_points"]

#: Projected-gradient basis steps per style in one alternation of the aligned fit.
_BASIS_STEPS = 3


def _labels(name, values, n):
    values = np.asarray(values)
    if values.shape != (n,):
        raise ValueError(f"{name} must give one label per row of X ({n}), got shape {values.shape}")
    return values.astype(str)


def _finite_mean(A) -> np.ndarray:
    """Mean over the first axis of the finite entries; NaN where there is none."""
    seen = np.isfinite(A).sum(axis=0)
    return np.where(seen > 0, np.where(np.isfinite(A), A, 0.0).sum(axis=0) / np.maximum(seen, 1), np.nan)


def _runs(*columns) -> np.ndarray:
    """Clip ids from runs of consecutive rows with equal labels, ``(n,)`` str."""
    n = len(columns[0])
    change = np.zeros(n, dtype=bool)
    change[0] = True
    for col in columns:
        change[1:] |= col[1:] != col[:-1]
    return np.char.add("run", np.cumsum(change).astype(str))


class StyleTranslator(BaseEstimator):
    """Translate motion between styles: NNSF bases per style, and posture and swing for unseen actions.

    Parameters
    ----------
    n_components : int, default=16
        Rank k of the pooled NNSF.
    alpha : float >= 0, default=0.01
        Sparseness weight on V (NNSF's α), also used when encoding clips.
    beta : float >= 0, default=0.0
        Class-separability weight of the pooled fit; 0 gives Hoyer's NNSC.
    label : {"content", "style"}, default="content"
        The labels of the pooled fit's class term (used when ``beta > 0``).
    basis : {"aligned", "refit"}, default="aligned"
        How per-style bases with corresponding atoms are learned (module docstring).
    ridge : float >= 0, default=0.5
        Pull of per-style bases towards U₀ (:func:`~nnsf.factor.align.refit_basis`).
    align_iter : int >= 1, default=150
        Alternations of the ``"aligned"`` fit.
    smooth : float >= 0, default=20.0
        Weight λ of the second-order temporal smoothness of the weights
        (their acceleration along each content's shared rows, relative to the
        data term: λ = ``smooth`` × the mean number of frames per row; one
        frame per row when a single clip is encoded, :meth:`encode_smooth`).
        DTW maps a different mix of frames to neighbouring shared rows, so
        without it the consensus jitters from row to row; the second
        difference leaves slow motion (a stride, a wave) almost untouched.
    amplitude : {"style", "restore", "none"}, default="style"
        :meth:`synthesize`: undo the amplitude the shared weights lose
        (``"restore"``), and also apply the target style's own amplitude
        relative to the other styles (``"style"``).
    tempo : bool, default=True
        :meth:`synthesize`: resample the cell to the target style's tempo
        (:attr:`style_tempo_`).
    transfer : {"recombine_swing", "offset_swing", "recombine"}, default="recombine_swing"
        How :meth:`translate_clip` (the public path) carries a style onto a
        clip of any action, from the reference style (``source_style``, else
        ``neutral``):

        * ``"recombine"``: the paper's recombination, X̂ = V U_t + b_t plus the
          clip's residual, V the clip's weights under the reference's basis;
        * ``"offset_swing"``: the clip plus the style's mean pose offset
          (:func:`~nnsf.factor.style_transfer.posture_offset`), with its
          swing scaled per octave band
          (:func:`~nnsf.factor.style_transfer.swing_gains`);
        * ``"recombine_swing"``: the recombination, then the swing per band.
    neutral : str or None, default=None
        The style a clip of unknown style is read as on the public path (a
        user's own motion is usually unstyled: the style library's
        ``normal``/``neutral`` style).  None: the average of the styles (the
        pooled basis U₀ with no offset; every style's statistics averaged).
    max_iter : int >= 1, default=150
        Iterations of the pooled NNSF fit, of a per-style refit and of
        encoding a clip.
    tol : float >= 0, default=1e-5
        Relative tolerance of the pooled fit and of encoding.
    random_state : int, RandomState or None, default=0

    Attributes
    ----------
    nnsf_ : NNSF
        The pooled fit; ``nnsf_.components_`` is U₀.
    components_ : ndarray (k, d)
        U₀.
    style_bases_ : dict style -> ndarray (k, d)
        U_s, atoms in U₀'s order.
    style_offsets_ : dict style -> ndarray (d,)
        b_s, the style's posture, template units (centred over the styles).
    styles_, contents_ : ndarray of str
        Labels seen in ``fit``.
    clips_ : dict (style, content) -> list of ndarray (n_q, d)
        The training clips.
    style_tempo_ : dict style -> float
        Median over the style's clips of length / mean length of that
        content's clips (contents of at least two styles): < 1 is faster.
    cells_ : ndarray (K, 2) of str
        The fitted (style, content) cells, in the order of the two below.
    cell_pose_ : ndarray (K, 32)
        Mean root-relative pose of each cell (its clips' mean), template units.
    cell_bands_ : ndarray (K, N_BANDS, 32)
        Mean band amplitudes of each cell's clips
        (:func:`~nnsf.factor.style_transfer.band_amplitudes`), template units;
        NaN in a band none of the cell's clips is long enough to measure.
    fps_ : float or None
        Frame rate of the training clips (``fit(..., fps=)``).
    shared_weights_, frame_rows_, content_rows_, reference_clips_
        ``"aligned"`` only: the shared weights ``(R, k)``, the shared row of
        every training frame ``(n,)``, each content's rows ``(start, stop)``
        and its reference clip.
    """

    _parameter_constraints: dict = {
        "n_components": [Interval(Integral, 1, None, closed="left")],
        "alpha": [Interval(Real, 0, None, closed="left")],
        "beta": [Interval(Real, 0, None, closed="left")],
        "label": [StrOptions({"content", "style"})],
        "basis": [StrOptions(set(BASES))],
        "ridge": [Interval(Real, 0, None, closed="left")],
        "align_iter": [Interval(Integral, 1, None, closed="left")],
        "smooth": [Interval(Real, 0, None, closed="left")],
        "amplitude": [StrOptions(set(AMPLITUDES))],
        "tempo": ["boolean"],
        "transfer": [StrOptions(set(TRANSFERS))],
        "neutral": [str, None],
        "max_iter": [Interval(Integral, 1, None, closed="left")],
        "tol": [Interval(Real, 0, None, closed="left")],
        "random_state": ["random_state"],
    }

    def __init__(self, n_components=16, *, alpha=0.01, beta=0.0, label="content", basis="aligned", ridge=0.5,
                 align_iter=150, smooth=20.0, amplitude="style", tempo=True, transfer="recombine_swing",
                 neutral=None, max_iter=150, tol=1e-5, random_state=0):
        self.n_components = n_components
        self.alpha = alpha
        self.beta = beta
        self.label = label
        self.basis = basis
        self.ridge = ridge
        self.align_iter = align_iter
        self.smooth = smooth
        self.amplitude = amplitude
        self.tempo = tempo
        self.transfer = transfer
        self.neutral = neutral
        self.max_iter = max_iter
        self.tol = tol
        self.random_state = random_state

    # ------------------------------------------------------------------ checks
    def _check_X(self, X, who):
        X = check_array(X, dtype=np.float64, ensure_min_samples=1)
        check_non_negative(X, who)
        if hasattr(self, "n_features_in_") and X.shape[1] != self.n_features_in_:
            raise ValueError(f"{who}: X has {X.shape[1]} features, the translator was fitted on "
                             f"{self.n_features_in_}")
        return X

    def _check_style(self, s, role):
        check_is_fitted(self, "style_bases_")
        if str(s) not in self.style_bases_:
            raise ValueError(f"unknown {role} style {s!r}; fitted styles: {sorted(self.style_bases_)}")
        return str(s)

    # --------------------------------------------------------------------- fit
    @_fit_context(prefer_skip_nested_validation=True)
    def fit(self, X, content, style, clip=None, fps=None):
        """Learn U₀, the per-style bases and offsets, and the per-cell posture and swing.

        Parameters
        ----------
        X : array (n, d), non-negative unified features (template units),
            frames of a clip in time order.
        content : array (n,), motion class of every row.
        style : array (n,), style (character) of every row.
        clip : array (n,), optional
            Clip of every row; by default every run of consecutive rows with
            the same style and content is one clip.
        fps : float, optional
            Frame rate of the clips (Hz); the swing's octave bands are in Hz of it.

        Returns
        -------
        self
        """
        X = check_array(X, dtype=np.float64, ensure_min_samples=2)
        check_non_negative(X, "StyleTranslator.fit")
        n, d = X.shape
        content = _labels("content", content, n)
        style = _labels("style", style, n)
        clip = _runs(style, content) if clip is None else _labels("clip", clip, n)
        if len(np.unique(style)) < 2:
            raise ValueError("StyleTranslator.fit needs frames of at least two styles")
        if self.neutral is not None and str(self.neutral) not in set(style):
            raise ValueError(f"neutral style {self.neutral!r} is not among the fitted styles "
                             f"{sorted(set(style))}")
        if fps is not None and not (isinstance(fps, Real) and fps > 0):
            raise ValueError(f"fps must be a number > 0 or None, got {fps!r}")

        labels = content if self.label == "content" else style
        use_labels = self.beta > 0 and len(np.unique(labels)) > 1
        self.nnsf_ = NNSF(self.n_components, alpha=self.alpha, beta=self.beta, max_iter=self.max_iter,
                          tol=self.tol, random_state=self.random_state)
        V = self.nnsf_.fit_weights(X, labels if use_labels else None)
        U0 = self.nnsf_.components_
        self.components_ = U0
        self.n_features_in_ = d
        self.styles_ = np.unique(style)
        self.contents_ = np.unique(content)

        if self.basis == "refit":
            bases = {s: refit_basis(X[style == s], V[style == s], U0, max_iter=self.max_iter, ridge=self.ridge)
                     for s in self.styles_}
            s_idx = np.searchsorted(self.styles_, style)
            offsets = np.zeros((len(self.styles_), d))
            for i, s in enumerate(self.styles_):
                rows = s_idx == i
                offsets[i] = (X[rows] - weights_for_basis(
                    X[rows], bases[s], alpha=float(self.alpha), max_iter=self.max_iter,
                    tol=float(self.tol)) @ bases[s]).mean(axis=0)
            offsets -= np.bincount(s_idx, minlength=len(self.styles_)) @ offsets / n
        else:
            bases, offsets, self.reference_clips_ = self._fit_aligned(X, V, U0, style, content, clip)
        self.style_bases_ = bases
        self.style_offsets_ = {s: offsets[i] for i, s in enumerate(self.styles_)}
        self.clips_ = {}
        for q in np.unique(clip):
            rows = np.flatnonzero(clip == q)
            key = (style[rows[0]], content[rows[0]])
            self.clips_.setdefault(key, []).append(X[rows])
        self.style_tempo_ = _style_tempo(self.clips_)
        self.fps_ = None if fps is None else float(fps)
        self._fit_cells()
        return self

    def _fit_cells(self):
        """Per (style, content) cell: the mean root-relative pose and band amplitudes of its clips."""
        rate = self.fps_ or st.DEFAULT_FPS
        keys = sorted(self.clips_)
        poses, bands = [], []
        for key in keys:
            rel = [st.root_relative(Xq)[0] for Xq in self.clips_[key]]
            poses.append(np.mean([R.mean(axis=0) for R in rel], axis=0))
            # Each band averaged over the clips long enough to measure it (NaN: none is).
            bands.append(_finite_mean(np.stack([
                np.where(st.resolved_bands(len(R), rate)[:, None], st.band_amplitudes(R, rate), np.nan)
                for R in rel])))
        self.cells_ = np.array(keys, dtype=str).reshape(len(keys), 2)
        self.cell_pose_ = np.stack(poses)
        self.cell_bands_ = np.stack(bands)

    def _fit_aligned(self, X, V, U0, style, content, clip):
        """Per-style bases with weights shared by DTW-aligned frames of one content.

        Returns the bases, the offsets ``(S, d)`` and, per content, the
        reference clip's name.
        """
        n = X.shape[0]
        styles = self.styles_
        s_idx = np.searchsorted(styles, style)
        clip_names, first = np.unique(clip, return_index=True)
        clip_rows = {q: np.flatnonzero(clip == q) for q in clip_names}
        refs, offset, self.content_rows_ = {}, 0, {}
        g = np.empty(n, dtype=int)
        for c in self.contents_:
            names = [q for q, f in zip(clip_names, first) if content[f] == c]
            lengths = np.array([len(clip_rows[q]) for q in names])
            # Reference: the clip of median length (deterministic, and not an
            # outlier in tempo), ties to the first name.
            order = np.argsort(lengths, kind="stable")
            refs[c] = names[order[(len(order) - 1) // 2]]
            m = len(clip_rows[refs[c]])
            self.content_rows_[c] = (offset, offset + m)
            # Shared row of every frame: DTW of each clip to its content's reference clip.
            for q in names:
                rows = clip_rows[q]
                r = np.arange(m) if q == refs[c] else align_to_reference(X[rows], X[clip_rows[refs[c]]])
                g[rows] = offset + r
            offset += m
        R = offset
        # Shared weights start as the mean pooled weights of the frames of a row.
        M = sp.csr_matrix((np.ones(n), (g, np.arange(n))), shape=(R, n))
        counts = np.asarray(M.sum(axis=1)).ravel()
        W = np.maximum(np.asarray(M @ V) / np.maximum(counts, 1)[:, None], EPSILON)
        bases = np.stack([U0.copy() for _ in styles])                          # (S, k, d)
        offsets = np.zeros((len(styles), X.shape[1]))
        W, bases, offsets = self._alternate(X, s_idx, g, R, W, bases, offsets, U0)
        self.shared_weights_ = W
        self.frame_rows_ = g
        return {s: bases[i] for i, s in enumerate(styles)}, offsets, refs

    def _alternate(self, X, s_idx, g, R, W, bases, offsets, U0):
        """``align_iter`` alternations of the shared weights and per-style bases/offsets."""
        n, k = X.shape[0], U0.shape[0]
        S = bases.shape[0]
        M = sp.csr_matrix((np.ones(n), (g, np.arange(n))), shape=(R, n))      # frames -> rows
        counts = np.asarray(M.sum(axis=1)).ravel()
        cnt = np.zeros((R, S))
        np.add.at(cnt, (g, s_idx), 1.0)
        rows_of = [np.flatnonzero(s_idx == i) for i in range(S)]
        n_of = np.array([len(r) for r in rows_of], dtype=float)
        steps = np.zeros(S)
        alpha = float(self.alpha)
        W = np.maximum(W, EPSILON)     # a row no frame maps to any more keeps a live start
        lam2 = float(self.smooth) * float(counts.mean())
        if lam2 > 0:
            Lpos, Lneg = second_difference_split(list(self.content_rows_.values()), R)
        for _ in range(self.align_iter):
            # The non-negative part models X − b_s; a coordinate the offset
            # would push below zero is held at zero.
            Xb = np.maximum(X - offsets[s_idx], 0.0)
            # Weight step: Hoyer's update of every shared row over all frames mapped to it.
            XU = np.empty((n, k))
            for i, rows in enumerate(rows_of):
                XU[rows] = Xb[rows] @ bases[i].T
            num = np.asarray(M @ XU)
            den = np.zeros_like(W)
            for i in range(S):
                # Σ_s cnt[r, s] · w_r U_s U_sᵀ, one (R × k)(k × k) product per style.
                den += cnt[:, i, None] * (W @ (bases[i] @ bases[i].T))
            if alpha > 0:
                den += alpha * counts[:, None]
            if lam2 > 0:
                # Gradient λ L W of (λ/2)Σ‖v_{r−1} − 2v_r + v_{r+1}‖², L = D₂ᵀD₂ split by sign.
                num = num + lam2 * (Lneg @ W)
                den = den + lam2 * (Lpos @ W)
            W *= num / np.maximum(den, EPSILON)
            # Basis steps per style, weights fixed.
            for i, rows in enumerate(rows_of):
                Vs = W[g[rows]]
                VtV, VtX = Vs.T @ Vs, Vs.T @ Xb[rows]
                if self.ridge > 0:
                    lam = self.ridge * max(float(np.trace(VtV)) / k, np.finfo(float).tiny)
                    VtV = VtV + lam * np.eye(k)
                    VtX = VtX + lam * U0
                if steps[i] == 0:
                    steps[i] = 1.0 / max(float(np.linalg.eigvalsh(VtV)[-1]), np.finfo(float).tiny)
                U = bases[i]
                for _ in range(_BASIS_STEPS):
                    U, steps[i] = _basis_step(U, VtV, VtX, steps[i])
                bases[i] = U
                offsets[i] = (X[rows] - Vs @ U).mean(axis=0)
            offsets -= n_of @ offsets / n_of.sum()
        return W, bases, offsets

    # --------------------------------------------------------------- encoding
    def encode(self, X_clip, style_name=None) -> np.ndarray:
        """Weights ``(n, k)`` of a clip under style ``style_name``'s basis and offset (U₀ if None)."""
        check_is_fitted(self, "style_bases_")
        X_clip = self._check_X(X_clip, "StyleTranslator.encode")
        if style_name is None:
            U = self.components_
        else:
            style_name = self._check_style(style_name, "source")
            U = self.style_bases_[style_name]
            X_clip = np.maximum(X_clip - self.style_offsets_[style_name], 0.0)
        return weights_for_basis(X_clip, U, alpha=float(self.alpha), max_iter=self.max_iter, tol=float(self.tol))

    def encode_smooth(self, X_clip, basis) -> np.ndarray:
        """Weights ``(n, k)`` of one clip for ``basis`` ``(k, d)`` with the model's temporal smoothness.

        Minimises ½‖X − VU‖² + αΣV + (λ/2)Σ_t ‖v_{t−1} − 2v_t + v_{t+1}‖²
        over V ≥ 0 with λ = ``smooth`` (one frame per row): the per-frame
        encoding (:func:`~nnsf.factor.updates.weights_for_basis`), then
        ``max_iter`` multiplicative updates with the second-difference
        operator split by sign (:func:`~nnsf.factor.timewarp.second_difference_split`).
        ``smooth`` 0 is the per-frame encoding.
        """
        X = np.asarray(X_clip, dtype=float)
        U = np.asarray(basis, dtype=float)
        alpha = float(self.alpha)
        V = weights_for_basis(X, U, alpha=alpha, max_iter=self.max_iter, tol=float(self.tol))
        lam = float(self.smooth)
        if lam <= 0 or len(X) < 3:
            return V
        XUt, UUt = X @ U.T, U @ U.T
        V = np.maximum(V, EPSILON)
        Lpos, Lneg = second_difference_split([(0, len(X))], len(X))
        for _ in range(int(self.max_iter)):
            V *= (XUt + lam * (Lneg @ V)) / np.maximum(V @ UUt + alpha + lam * (Lpos @ V), EPSILON)
        return V

    # -------------------------------------------------------- known contents
    def translate(self, X_clip, source_style, target_style) -> np.ndarray:
        """A clip of ``source_style`` in ``target_style``: X̂ = V U_t + b_t + (X − V U_s − b_s), ``(n, d)``.

        V = argmin_V≥0 ½‖max(X − b_s, 0) − V U_s‖² + αΣV (:meth:`encode`); the
        clip keeps its frames, timing and what the model does not explain.
        Raises ValueError for an unknown style or features of the wrong width.
        """
        check_is_fitted(self, "style_bases_")
        X_clip = self._check_X(X_clip, "StyleTranslator.translate")
        source_style = self._check_style(source_style, "source")
        target_style = self._check_style(target_style, "target")
        V = self.encode(X_clip, source_style)
        U_src, b_src = self.style_bases_[source_style], self.style_offsets_[source_style]
        return V @ self.style_bases_[target_style] + self.style_offsets_[target_style] + X_clip - (V @ U_src + b_src)

    def synthesize(self, content, target_style) -> np.ndarray:
        """The model's own clip of ``content`` in ``target_style``, ``(m, d)``, template units.

        Only for ``basis="aligned"``: X̂ = V_c U_t + b_t with V_c the content's
        shared weights (one row per frame of its reference clip, fitted on
        every style that performs it), U_t and b_t the target's basis and
        offset.  Then, as the parameters say:

        * ``amplitude="restore"``: V_c is a least-squares compromise of
          several time-aligned performances, so it moves less than any one of
          them.  Each coordinate's deviation from the clip mean is scaled by
          g_j = mean_q sd(X_q)_j / mean_q sd(V_c U_{s_q} + b_{s_q})_j over
          the fitted clips q of the content (their own styles s_q).
        * ``amplitude="style"``: the same, times h_t, the target style's own
          amplitude: over its fitted clips of the other contents that other
          styles perform too, Σ sd(X_q) / Σ g_{c_q} sd(V_{c_q} U_t + b_t).
        * ``tempo=True``: resampled (linear interpolation) to the content's
          mean clip length times the target style's tempo (:attr:`style_tempo_`).
        """
        check_is_fitted(self, "style_bases_")
        if self.basis != "aligned":
            raise ValueError("synthesize needs basis='aligned' (shared per-content weights)")
        target_style = self._check_style(target_style, "target")
        content = str(content)
        if content not in self.content_rows_:
            raise ValueError(f"unknown content {content!r}; fitted contents: {list(self.contents_)}")
        X_hat = self._render(content, target_style)
        if self.amplitude in ("restore", "style"):
            gain = self._content_gain(content)
            if self.amplitude == "style":
                gain = gain * self._style_gain(target_style, content)
            mean = X_hat.mean(axis=0)
            X_hat = np.maximum(mean + (X_hat - mean) * gain, 0.0)
        if self.tempo:
            lengths = [len(Xq) for (s, c), lst in self.clips_.items() if c == content for Xq in lst]
            m = max(2, int(round(np.mean(lengths) * self.style_tempo_.get(target_style, 1.0))))
            X_hat = resample_clip(X_hat, m)
        return X_hat

    def _content_gain(self, content) -> np.ndarray:
        """g_c (d,): mean sd of the content's fitted clips over mean sd of the model's renderings
        of the content in those clips' styles (1 where the rendering does not move)."""
        have = [(s, Xq) for (s, c), lst in self.clips_.items() if c == content for Xq in lst]
        num = np.mean([Xq.std(axis=0) for _, Xq in have], axis=0)
        den = np.mean([self._render(content, s).std(axis=0) for s, _ in have], axis=0)
        return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 1.0)

    def _style_gain(self, style_name, content) -> np.ndarray:
        """h_t (d,): how much more (or less) the target style's own clips move than their
        content-restored renderings, over the style's contents other than ``content`` that
        other styles perform too (ratio of sums; 1 where the style has no such content)."""
        num = np.zeros(self.n_features_in_)
        den = np.zeros(self.n_features_in_)
        for (s, c), lst in self.clips_.items():
            if s != style_name or c == content or not any(s2 != s for (s2, c2) in self.clips_ if c2 == c):
                continue
            r = self._render(c, s).std(axis=0) * self._content_gain(c)
            for Xq in lst:
                num += Xq.std(axis=0)
                den += r
        return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 1.0)

    def _render(self, content, style_name):
        a, b = self.content_rows_[content]
        return self.shared_weights_[a:b] @ self.style_bases_[style_name] + self.style_offsets_[style_name]

    def synthesize_cell(self, content, target_style, X_source=None, source_style=None, *,
                        synthesis="consensus") -> np.ndarray:
        """The cell (``content`` in ``target_style``): ``synthesis="consensus"`` is
        :meth:`synthesize`; ``"source"`` :meth:`translate` of ``X_source`` (performed in
        ``source_style``), resampled to the target's tempo relative to the source's when
        ``tempo`` is on."""
        if synthesis not in SYNTHESES:
            raise ValueError(f"synthesis must be one of {SYNTHESES}, got {synthesis!r}")
        if synthesis == "consensus":
            return self.synthesize(content, target_style)
        if X_source is None or source_style is None:
            raise ValueError("synthesis='source' needs a source clip and its style")
        X_hat = self.translate(X_source, source_style, target_style)
        if self.tempo:
            ts = self.style_tempo_.get(str(target_style), 1.0)
            ss = self.style_tempo_.get(str(source_style), 1.0)
            X_hat = resample_clip(X_hat, max(2, int(round(len(X_hat) * ts / ss))))
        return X_hat

    # ---------------------------------------------------------- the public path
    def _reference_cells(self, target_style, reference):
        """Shared contents and their (pose, bands) in the target and the reference style.

        ``reference`` None is the average style: per content, the mean of
        every style that performs it.
        """
        idx = {(s, c): i for i, (s, c) in enumerate(map(tuple, self.cells_))}
        contents = [c for (s, c) in idx if s == target_style and (reference is None or (reference, c) in idx)]
        if not contents:
            return None
        t = [idx[(target_style, c)] for c in contents]
        if reference is None:
            groups = [[i for (s, c2), i in idx.items() if c2 == c] for c in contents]
            ref_pose = np.stack([self.cell_pose_[g].mean(axis=0) for g in groups])
            ref_bands = np.stack([_finite_mean(self.cell_bands_[g]) for g in groups])
        else:
            r = [idx[(reference, c)] for c in contents]
            ref_pose, ref_bands = self.cell_pose_[r], self.cell_bands_[r]
        return self.cell_pose_[t], ref_pose, self.cell_bands_[t], ref_bands

    def translate_clip(self, X_clip, target_style, source_style=None, fps=None) -> np.ndarray:
        """One clip of any action and body into ``target_style``: the public path (:func:`nnsf.translate`).

        The clip is read as ``source_style`` if given, else as the model's
        ``neutral`` style (the average style when that is None); ``transfer``
        says what is carried (class docstring).  The swing's band gains come
        from the contents both styles perform, weighted by how alike the
        clip's motion and the reference style's clips of each content are
        (:func:`~nnsf.factor.style_transfer.content_weights`).  The change
        eases in over the first half second
        (:func:`~nnsf.factor.style_transfer.ease_in`), so the clip starts in
        its own pose.  The clip keeps its frames and timing.

        Parameters
        ----------
        X_clip : array (n, d), non-negative unified features of one clip.
        target_style, source_style : fitted styles (source optional).
        fps : the clip's frame rate; by default the model's (``fps_``).
            A clip at another rate is resampled to the model's for the
            transfer and back.

        Returns
        -------
        ndarray (n, d), template units.
        """
        check_is_fitted(self, "cells_")
        X_clip = self._check_X(X_clip, "StyleTranslator.translate_clip")
        target_style = self._check_style(target_style, "target")
        reference = self.neutral if source_style is None else self._check_style(source_style, "source")
        if reference is not None:
            reference = self._check_style(reference, "neutral")
        rate = float(self.fps_ or st.DEFAULT_FPS)
        n = len(X_clip)
        X = X_clip
        if fps is not None and self.fps_ is not None and float(fps) != rate and n > 1:
            X = resample_clip(X_clip, max(2, int(round(n * rate / float(fps)))))
        if reference == target_style:
            return X_clip.copy()
        if self.transfer == "offset_swing":
            X_hat = X
        else:
            U_ref = self.components_ if reference is None else self.style_bases_[reference]
            b_ref = np.zeros(X.shape[1]) if reference is None else self.style_offsets_[reference]
            V = self.encode_smooth(np.maximum(X - b_ref, 0.0), U_ref)
            X_hat = V @ self.style_bases_[target_style] + self.style_offsets_[target_style] \
                + X - (V @ U_ref + b_ref)
        cells = self._reference_cells(target_style, reference)
        if self.transfer != "recombine" and cells is not None:
            t_pose, r_pose, t_bands, r_bands = cells
            R, root = st.root_relative(X_hat)
            if self.transfer == "offset_swing":
                R = R + st.posture_offset(t_pose, r_pose)
            R_in = st.root_relative(X)[0]
            A_in = np.where(st.resolved_bands(len(R_in), rate)[:, None], st.band_amplitudes(R_in, rate), np.nan)
            w = st.content_weights(st.describe(A_in), np.stack([st.describe(b) for b in r_bands]))
            R = st.filter_bands(R, rate, st.swing_gains(t_bands, r_bands, w))
            X_hat = st.from_root_relative(R, root)
        X_hat = X + st.ease_in(len(X), rate)[:, None] * (X_hat - X)
        if len(X) != n:
            X_hat = resample_clip(X_hat, n)
        return X_hat

    # --------------------------------------------------------------- files
    def save(self, path, *, unifier=None, features_sha256=None, source="", view=None) -> Path:
        """Write the fitted translator to one ``.npz`` (:mod:`nnsf.factor.model_file`) as the model's
        only view; returns the path."""
        return save_model([ModelView(view, self, unifier)], path, features_sha256=features_sha256, source=source)

    @classmethod
    def load(cls, path) -> "StyleTranslator":
        """A translator read from a file written by :meth:`save`.

        Raises :class:`nnsf.errors.InputError` naming the file and what is
        wrong (not a model, another format version, an array missing).
        """
        return load_model(path, cls)[0][0].translator


# --------------------------------------------------------------------------- #
# Back to pixels, and a quick look
# --------------------------------------------------------------------------- #
def to_character_points(features, character: str, unifier) -> np.ndarray:
    """Translated features ``(n, 34)`` -> pixel key points ``(n, 17, 2)`` of ``character``.

    Uses the target character's inverse unification, P = W_char⁻¹ (X − o)
    (:meth:`nnsf.skeleton.Unifier.inverse_transform`), so the motion takes the
    character's own bone proportions and place on the canvas.
    """
    return unifier.inverse_transform(np.asarray(features, dtype=float), character)
