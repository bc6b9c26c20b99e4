"""Style translation by non-negative style factorization (docs/method.md §8, D5; the paper's §4, end).

The paper synthesises "jump in Wukong Sun's style" by recombining a basis and
weights that come from different characters.  That only works if atom ``i``
means the same thing in both, so (D5, docs/method.md §8.1):

* fit NNSF once on all characters pooled, giving U₀ and V;
* give every character (style) ``s`` its own basis U_s by basis steps only,
  with that character's weights V_s fixed, starting from U₀
  (:func:`nnsf.factor.align.refit_basis`) -- atom ``i`` of every U_s starts as atom ``i`` of U₀;
* when bases come from separate fits instead, match their atoms to U₀ by
  cosine similarity with the Hungarian algorithm (:func:`nnsf.factor.align.match_atoms`).

Translation of a clip of content ``c`` performed in style ``a`` into style
``b`` (row form, X is ``(n, 34)``):

* ``reading="style_basis"`` (docs/method.md §8.2, the default): X̂ = V_clip U_b + b_b.
  The weights of the clip, V_clip = argmin_V≥0 ½‖X_clip − b_a − V U_a‖² + αΣV,
  carry the content and its timing; the target's basis (and offset) carry
  the style.  With ``keep_residual`` (default) the clip's own residual
  X_clip − V_clip U_a − b_a is added back, so only what the model explains
  is translated.
* ``reading="content_basis"`` (the paper's own example, where the basis
  U_nz of Nezha's jump is recombined with the weights V_ws of Wukong Sun's
  other motions): X̂ = V_style U_clip, with U_clip the basis refitted on the
  content clip alone (from U₀, its weights fixed) and V_style the weights of
  a clip of the target style, so frames and timing come from that clip.

How the per-style bases are learned (``basis``):

* ``"refit"`` -- D5 as written (docs/method.md §8.1): the pooled fit's weights fixed, basis
  steps per style from U₀.
* ``"separate"`` -- an independent NNSF per style, atoms matched to U₀ by
  :func:`nnsf.factor.align.match_atoms` (the fallback of D5).
* ``"aligned"`` (default) -- our departure, measured in
  :mod:`nnsf.evaluate.translation`: the clips of one content are aligned in
  time by DTW to a reference clip of that content (the one of median
  length), and aligned frames of different styles *share one weight row*.
  The model is x_{s,t} ≈ v_{g(t)} U_s + b_s, with g(t) the shared row of frame
  t, fitted by alternating a multiplicative update of the shared weights and
  projected-gradient basis steps per style, starting from U₀ and V of the
  pooled fit, with a ridge pulling U_s towards U₀.  In the pooled fit every
  frame has its own weights, so the weights absorb most of the style and
  refitted bases stay close to U₀ (translation then barely moves the clip);
  sharing the weights across styles forces the style into the bases.  Two
  more departures belong to it: a per-style offset b_s (posture) and free
  row lengths of U_s (how strongly a style expresses an atom).

Synthesising a whole held-out cell (``synthesis``): ``"source"`` translates
one clip of another style as above; ``"consensus"`` (default, aligned basis
only) uses the content's *shared* weights, fitted on every style that
performs it: X̂ = V_content U_target + b_target (:meth:`StyleTranslator.synthesize`),
with the amplitude the least-squares compromise loses restored and scaled
to the target style's own swing (``amplitude="style"``, the default; ``"restore"``
without the style's factor) and resampled to the target style's tempo
(``tempo=True``).  Which of these wins is measured by the held-out grid
(:mod:`nnsf.evaluate.translation`); the numbers are in the project's docs.

Units: features are unified template coordinates (template units, torso =
1.0); :func:`to_character_points` maps translated features back to a
character's pixels with :meth:`nnsf.skeleton.Unifier.inverse_transform`.

Atom correspondence is :mod:`nnsf.factor.align`, time warping and tempo
:mod:`nnsf.factor.timewarp`.  What is left here is one concept, the
:class:`StyleTranslator` estimator (about 700 of this module's lines): its
fit, encoding and synthesis methods share the fitted per-style bases,
offsets, shared content weights and tempi, and scikit-learn's estimator
contract keeps them on one class; splitting the class would only scatter
that state.
"""
from __future__ import annotations

import numbers
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from sklearn.base import BaseEstimator
from sklearn.utils.validation import check_array, check_is_fitted, check_non_negative

from nnsf.factor.nnsf import NNSF
from nnsf.factor.updates import EPSILON, _basis_step, weights_for_basis
from nnsf.factor.model_file import load_model, save_model
from nnsf.params import AMPLITUDES, BASES, SYNTHESES
from nnsf.factor.align import _free_basis_step, atom_cosines, match_atoms, refit_basis
from nnsf.factor.timewarp import _style_tempo, align_to_reference, resample_clip, second_difference_split

__all__ = ["READINGS", "BASES", "SYNTHESES", "AMPLITUDES", "StyleTranslator", "to_character_points"]

#: Which factor carries the style: the basis (docs/method.md §8) or the weights (the paper's example).
READINGS: tuple[str, ...] = ("style_basis", "content_basis")
# BASES (how per-style bases with corresponding atoms are obtained), SYNTHESES
# (where the content of a synthesised cell comes from: one source clip, or the
# content's shared weights) and AMPLITUDES (amplitude calibration of a
# consensus synthesis) are the params.yaml choices, defined in nnsf.params.


# --------------------------------------------------------------------------- #
# Atom correspondence
# --------------------------------------------------------------------------- #


# --------------------------------------------------------------------------- #
# Dynamic time warping
# --------------------------------------------------------------------------- #


# --------------------------------------------------------------------------- #
# The translator
# --------------------------------------------------------------------------- #
def _labels(name, values, n):
    values = np.asarray(values)
    if values.shape != (n,):
        raise ValueError(f"{name} must give one label per row of X ({n}), got shape {values.shape}")
    return values.astype(str)


def _runs(*columns) -> np.ndarray:
    """Clip ids from runs of consecutive rows with equal labels, ``(n,)`` str."""
    n = len(columns[0])
    change = np.zeros(n, dtype=bool)
    change[0] = True
    for col in columns:
        change[1:] |= col[1:] != col[:-1]
    return np.char.add("run", np.cumsum(change).astype(str))


class StyleTranslator(BaseEstimator):
    """Translate motion between styles by recombining NNSF weights and bases.

    Parameters
    ----------
    n_components : int, default=16
        Rank k of the pooled NNSF.
    alpha : float >= 0, default=0.01
        Sparseness weight on V (NNSF's α), also used when encoding clips.
    beta : float >= 0, default=0.0
        Class-separability weight of the pooled fit; 0 (the pipeline's
        value) gives Hoyer's NNSC.
    label : {"content", "style"}, default="content"
        The labels of the pooled fit's class term.
    class_in_loop : bool, default=True
        NNSF's D3 flag (docs/method.md §6.3).
    reading : {"style_basis", "content_basis"}, default="style_basis"
        Which factor carries the style (see the module docstring).
    basis : {"aligned", "refit", "separate"}, default="aligned"
        How per-style bases with corresponding atoms are learned.
    ridge : float >= 0, default=0.5
        Pull of per-style bases towards U₀ (:func:`refit_basis`).
    refit_iter : int, default=100
        Basis steps of a per-style (or per-clip) refit.
    align_iter : int, default=150
        Alternations of the ``"aligned"`` fit (one weight update and
        ``basis_steps`` basis steps per style each).
    basis_steps : int, default=3
        Basis steps per style in one alternation of the ``"aligned"`` fit.
    realign : int, default=0
        ``"aligned"`` only: rounds of re-alignment.  After the alternations,
        every clip is aligned again by DTW, now to the model's rendering of
        its content in the clip's own style (V_c U_s + b_s), and the
        alternations run again from where they were.
    style_offset : bool, default=True
        Give every style an unconstrained offset b_s (d,), its posture, next
        to its non-negative basis: x ≈ v U_s + b_s.  Offsets are centred
        (their frame-weighted mean over styles is zero), so b_s is how style s
        departs from the average posture; with ``"aligned"`` they are fitted
        in the alternation, otherwise set afterwards to the centred mean
        residual of each style.  False is the plain model x ≈ v U_s.
    smooth : float >= 0, default=20.0
        ``"aligned"`` only: weight λ of a temporal smoothness term on the
        shared weights along each content's rows, relative to the data term
        (λ = ``smooth`` × the mean number of frames mapped to a row).  Each
        shared row is otherwise fitted on its own, and DTW maps a different
        mix of frames of the clips to neighbouring rows, so the consensus
        jitters from row to row.  Also the weight of the same term when one
        clip is encoded on the public path (:meth:`encode_smooth`, one frame
        per row).
    smooth_order : {1, 2}, default=2
        Which difference the term penalises: 1, (λ/2) Σ_t ‖v_t − v_{t+1}‖²
        (velocity: Cai et al.'s graph-regularised update with the chain
        graph); 2, (λ/2) Σ_t ‖v_{t−1} − 2v_t + v_{t+1}‖² (acceleration,
        :func:`second_difference_split`).  The first order damps every
        frequency of the motion, the swing with the jitter: on Bandai-Namco-1
        the smoothed consensus moved only half the amplitude of the real
        clips, and restoring it (``amplitude``) multiplied the jitter back
        in.  The second order leaves slow motion (a stride, a wave) almost
        untouched and damps frame-to-frame jitter (README, style translation).
    free_norms : bool, default=False
        ``"aligned"`` only: let the rows of each style's basis take any
        length.  With weights shared across styles the length of atom i in
        U_s is identifiable -- it is how strongly style s expresses that
        atom (a bigger swing, a deeper bow) -- whereas unit rows can only
        turn an atom, not scale it.  The scale shared by all styles stays
        fixed: after every alternation atom i is divided by its mean length
        over the styles (and its shared weights multiplied by it).
    keep_residual : bool, default=True
        Add back the part of the weighted clip that its own basis does not
        reproduce: X̂ = V U_target + (X − V U_source).  The factorisation then
        changes only what it models (the style) and the clip keeps its
        details; False gives the plain recombination X̂ = V U_target.
    synthesis : {"consensus", "source"}, default="consensus"
        How :meth:`synthesize_cell` makes a cell: from the content's shared
        weights (``"aligned"`` basis only) or by translating a source clip.
    amplitude : {"restore", "style", "none"}, default="style"
        Consensus: undo the amplitude the shared weights lose (see
        :meth:`synthesize`); ``"style"`` also applies the target style's own
        amplitude relative to the other styles.  One clip
        (:meth:`translate_clip`, the public path): ``"style"`` scales the
        clip's swing by :meth:`swing_ratio`; the others leave it.
    tempo : bool, default=True
        Resample a synthesised cell to the target style's tempo
        (:attr:`style_tempo_`).
    max_iter : int, default=150
        Iterations of the pooled NNSF fit and of encoding a clip.
    tol : float, default=1e-5
        Relative tolerance of the pooled fit and of encoding.
    init : str, default="nndsvda"
        Initialisation of the pooled fit.
    random_state : int or None, default=0

    Attributes
    ----------
    nnsf_ : NNSF
        The pooled fit; ``nnsf_.components_`` is U₀.
    components_ : ndarray (k, d)
        U₀.
    style_bases_ : dict style -> ndarray (k, d)
        U_s, atoms in U₀'s order.
    styles_, contents_ : ndarray of str
        Labels seen in ``fit``.
    atom_cosine_ : dict style -> ndarray (k,)
        Cosine between atom i of U_s and of U₀ (how far the style moved it).
    style_offsets_ : dict style -> ndarray (d,)
        b_s (zeros with ``style_offset=False``), template units.
    content_means_ : dict content -> ndarray (d,)
        Mean feature row of each content over all styles (used to choose the
        style clip of the ``"content_basis"`` reading).
    clips_ : dict (style, content) -> list of ndarray (n_q, d)
        The training clips, for the ``"content_basis"`` reading.
    style_tempo_ : dict style -> float
        Median over the style's clips of length / mean length of that
        content's clips (contents of at least two styles): < 1 is faster.
    shared_weights_, frame_rows_, content_rows_, reference_clips_
        ``"aligned"`` only: the shared weights ``(R, k)``, the shared row of
        every training frame ``(n,)``, each content's rows ``(start, stop)``
        and its reference clip.
    """

    def __init__(self, n_components=16, *, alpha=0.01, beta=0.0, label="content", class_in_loop=True,
                 reading="style_basis", basis="aligned", ridge=0.5, refit_iter=100, align_iter=150,
                 basis_steps=3, realign=0, style_offset=True, smooth=20.0, smooth_order=2, free_norms=False,
                 keep_residual=True,
                 synthesis="consensus", amplitude="style", tempo=True,
                 max_iter=150, tol=1e-5, init="nndsvda", random_state=0):
        self.n_components = n_components
        self.alpha = alpha
        self.beta = beta
        self.label = label
        self.class_in_loop = class_in_loop
        self.reading = reading
        self.basis = basis
        self.ridge = ridge
        self.refit_iter = refit_iter
        self.align_iter = align_iter
        self.basis_steps = basis_steps
        self.realign = realign
        self.style_offset = style_offset
        self.smooth = smooth
        self.smooth_order = smooth_order
        self.free_norms = free_norms
        self.keep_residual = keep_residual
        self.synthesis = synthesis
        self.amplitude = amplitude
        self.tempo = tempo
        self.max_iter = max_iter
        self.tol = tol
        self.init = init
        self.random_state = random_state

    # ------------------------------------------------------------------ checks
    def _check_params(self):
        if self.reading not in READINGS:
            raise ValueError(f"reading must be one of {READINGS}, got {self.reading!r}")
        if self.basis not in BASES:
            raise ValueError(f"basis must be one of {BASES}, got {self.basis!r}")
        if self.synthesis not in SYNTHESES:
            raise ValueError(f"synthesis must be one of {SYNTHESES}, got {self.synthesis!r}")
        if self.amplitude not in AMPLITUDES:
            raise ValueError(f"amplitude must be one of {AMPLITUDES}, got {self.amplitude!r}")
        if self.label not in ("content", "style"):
            raise ValueError(f"label must be 'content' or 'style', got {self.label!r}")
        for name in ("ridge", "alpha", "beta", "tol", "smooth"):
            v = getattr(self, name)
            if not (isinstance(v, numbers.Real) and not isinstance(v, bool) and v >= 0):
                raise ValueError(f"{name} must be a number >= 0, got {v!r}")
        if self.smooth_order not in (1, 2) or isinstance(self.smooth_order, bool):
            raise ValueError(f"smooth_order must be 1 or 2, got {self.smooth_order!r}")
        for name, lo in (("refit_iter", 1), ("align_iter", 1), ("basis_steps", 1), ("max_iter", 1),
                         ("realign", 0)):
            v = getattr(self, name)
            if not (isinstance(v, numbers.Integral) and not isinstance(v, bool) and v >= lo):
                raise ValueError(f"{name} must be an integer >= {lo}, got {v!r}")

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
    def fit(self, X, content, style, clip=None):
        """Learn U₀, the per-style bases and what the chosen reading needs.

        Parameters
        ----------
        X : array (n, d), non-negative unified features (template units),
            frames of a clip in time order.
        content : array (n,), motion class of every row.
        style : array (n,), style (character) of every row.
        clip : array (n,), optional
            Clip of every row; by default every run of consecutive rows with
            the same style and content is one clip.  Only the ``"aligned"``
            basis and the ``"content_basis"`` reading use clips.

        Returns
        -------
        self
        """
        self._check_params()
        X = check_array(X, dtype=np.float64, ensure_min_samples=2)
        check_non_negative(X, "StyleTranslator.fit")
        n, d = X.shape
        content = _labels("content", content, n)
        style = _labels("style", style, n)
        clip = _runs(style, content) if clip is None else _labels("clip", clip, n)
        if len(np.unique(style)) < 2:
            raise ValueError("StyleTranslator.fit needs frames of at least two styles")

        labels = content if self.label == "content" else style
        use_labels = self.beta > 0 and len(np.unique(labels)) > 1
        self.nnsf_ = NNSF(self.n_components, alpha=self.alpha, beta=self.beta,
                          class_in_loop=self.class_in_loop, max_iter=self.max_iter, tol=self.tol,
                          init=self.init, random_state=self.random_state)
        V = self.nnsf_.fit_weights(X, labels if use_labels else None)
        U0 = self.nnsf_.components_
        self.components_ = U0
        self.n_features_in_ = d
        self.styles_ = np.unique(style)
        self.contents_ = np.unique(content)

        if self.basis == "refit":
            bases = {s: refit_basis(X[style == s], V[style == s], U0, max_iter=self.refit_iter,
                                    ridge=self.ridge) for s in self.styles_}
        elif self.basis == "separate":
            bases = {}
            for s in self.styles_:
                rows = style == s
                sub = NNSF(U0.shape[0], alpha=self.alpha, beta=0.0, max_iter=self.max_iter,
                           tol=self.tol, init=self.init if rows.sum() >= U0.shape[0] else "random",
                           random_state=self.random_state).fit(X[rows])
                perm, _ = match_atoms(U0, sub.components_)
                bases[s] = sub.components_[perm]
        else:
            bases, offsets, self.reference_clips_ = self._fit_aligned(X, V, U0, style, content, clip)
        if self.basis != "aligned":
            offsets = np.zeros((len(self.styles_), d))
            if self.style_offset:
                s_idx = np.searchsorted(self.styles_, style)
                for i, s in enumerate(self.styles_):
                    rows = s_idx == i
                    offsets[i] = (X[rows] - weights_for_basis(
                        X[rows], bases[s], alpha=float(self.alpha), max_iter=self.max_iter,
                        tol=float(self.tol)) @ bases[s]).mean(axis=0)
                offsets -= np.bincount(s_idx, minlength=len(self.styles_)) @ offsets / n
        self.style_bases_ = bases
        self.style_offsets_ = {s: offsets[i] for i, s in enumerate(self.styles_)}
        self.atom_cosine_ = {s: np.diag(atom_cosines(U0, U)) for s, U in bases.items()}
        self.content_means_ = {c: X[content == c].mean(axis=0) for c in self.contents_}
        # The content_basis reading takes weights from a clip of the target
        # style: keep every clip's frames by (style, content).
        self.clips_ = {}
        for q in np.unique(clip):
            rows = np.flatnonzero(clip == q)
            key = (style[rows[0]], content[rows[0]])
            self.clips_.setdefault(key, []).append(X[rows])
        self.style_tempo_ = _style_tempo(self.clips_)
        return self

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
        members = {}
        for c in self.contents_:
            names = [q for q, f in zip(clip_names, first) if content[f] == c]
            lengths = np.array([len(clip_rows[q]) for q in names])
            # Reference: the clip of median length (deterministic, and not an
            # outlier in tempo), ties to the first name.
            order = np.argsort(lengths, kind="stable")
            refs[c] = names[order[(len(order) - 1) // 2]]
            members[c] = names
            m = len(clip_rows[refs[c]])
            self.content_rows_[c] = (offset, offset + m)
            offset += m
        R = offset

        def align(targets):
            """Shared row of every frame: DTW of each clip to its content's target."""
            g = np.empty(n, dtype=int)
            for c, names in members.items():
                a = self.content_rows_[c][0]
                for q in names:
                    rows = clip_rows[q]
                    target = targets(c, q)
                    r = np.arange(len(rows)) if target is None else align_to_reference(X[rows], target)
                    g[rows] = a + r
            return g

        # First alignment: to the reference clip itself (raw features).
        g = align(lambda c, q: None if q == refs[c] else X[clip_rows[refs[c]]])
        # Shared weights start as the mean pooled weights of the frames of a row.
        M = sp.csr_matrix((np.ones(n), (g, np.arange(n))), shape=(R, n))
        counts = np.asarray(M.sum(axis=1)).ravel()
        W = np.maximum(np.asarray(M @ V) / np.maximum(counts, 1)[:, None], EPSILON)
        bases = np.stack([U0.copy() for _ in styles])                          # (S, k, d)
        offsets = np.zeros((len(styles), X.shape[1]))
        for round_ in range(self.realign + 1):
            if round_ > 0:
                # Re-align every clip to the model's rendering of its content in
                # its own style, V_c U_s + b_s: like is then compared with like,
                # and the reference clip's own style no longer biases the warp.
                def target(c, q):
                    a, b = self.content_rows_[c]
                    i = s_idx[clip_rows[q][0]]
                    return np.maximum(W[a:b] @ bases[i] + offsets[i], 0.0)
                g = align(target)
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
        step_fn = _free_basis_step if self.free_norms else _basis_step
        W = np.maximum(W, EPSILON)     # a row no frame maps to any more keeps a live start
        smooth = float(self.smooth)
        second = smooth > 0 and self.smooth_order == 2
        if second:
            Lpos, Lneg = second_difference_split(list(self.content_rows_.values()), R)
            lam2 = smooth * float(counts.mean())
        elif smooth > 0:
            # Chain graph of each content's rows: link[r] joins rows r and r + 1.
            link = np.ones(max(R - 1, 0))
            for a, b in self.content_rows_.values():
                if b < R:
                    link[b - 1] = 0.0
            deg = np.zeros(R)
            deg[:-1] += link
            deg[1:] += link
            lam_s = np.full(R, smooth * float(counts.mean()))
        Xb = X
        for _ in range(self.align_iter):
            if self.style_offset:
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
            if second:
                # Gradient λ L W of (λ/2)Σ‖v_{r−1} − 2v_r + v_{r+1}‖², L = D₂ᵀD₂ split by sign.
                num = num + lam2 * (Lneg @ W)
                den = den + lam2 * (Lpos @ W)
            elif smooth > 0:
                # Gradient of (λ/2)Σ‖v_r − v_{r+1}‖² split by sign: λ(deg·v_r) − λ(Σ neighbours).
                nb = np.zeros_like(W)
                nb[1:] += link[:, None] * W[:-1]
                nb[:-1] += link[:, None] * W[1:]
                num = num + lam_s[:, None] * nb
                den = den + (lam_s * deg)[:, None] * W
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
                for _ in range(self.basis_steps):
                    U, steps[i] = step_fn(U, VtV, VtX, steps[i])
                bases[i] = U
                if self.style_offset:
                    offsets[i] = (X[rows] - Vs @ U).mean(axis=0)
            if self.style_offset:
                offsets -= n_of @ offsets / n_of.sum()
            if self.free_norms:
                # Only the styles' relative atom lengths are identifiable: keep
                # each atom's mean length over the styles at 1.
                scale = np.linalg.norm(bases, axis=2).mean(axis=0)
                scale = np.where(scale > 0, scale, 1.0)
                bases /= scale[None, :, None]
                W *= scale[None, :]
        return W, bases, offsets

    # --------------------------------------------------------------- translate
    def encode(self, X_clip, style_name=None) -> np.ndarray:
        """Weights ``(n, k)`` of a clip under style ``style_name``'s basis (U₀ if None)."""
        check_is_fitted(self, "style_bases_")
        X_clip = self._check_X(X_clip, "StyleTranslator.encode")
        if style_name is None:
            U = self.components_
        else:
            style_name = self._check_style(style_name, "source")
            U = self.style_bases_[style_name]
            X_clip = np.maximum(X_clip - self.style_offsets_[style_name], 0.0)
        return weights_for_basis(X_clip, U, alpha=float(self.alpha), max_iter=self.max_iter, tol=float(self.tol))

    def nearest_content(self, X_clip) -> str:
        """The fitted content whose mean feature row is nearest the clip's mean."""
        check_is_fitted(self, "content_means_")
        m = np.asarray(X_clip, dtype=float).mean(axis=0)
        names = list(self.content_means_)
        d = [np.linalg.norm(m - self.content_means_[c]) for c in names]
        return names[int(np.argmin(d))]

    def style_clip(self, target_style, content) -> np.ndarray:
        """A fitted clip of ``target_style``, of ``content`` if there is one, else of the
        content whose mean pose is nearest; shape ``(n, d)``."""
        target_style = self._check_style(target_style, "target")
        have = [c for (s, c) in self.clips_ if s == target_style]
        if content in have:
            c = content
        else:
            ref = self.content_means_.get(content)
            if ref is None:
                raise ValueError(f"unknown content {content!r}; fitted contents: {list(self.contents_)}")
            c = min(have, key=lambda h: float(np.linalg.norm(self.content_means_[h] - ref)))
        return self.clips_[(target_style, c)][0]

    def translate(self, X_clip, source_style, target_style, *, content=None, style_clip=None) -> np.ndarray:
        """Features of the clip's motion in the target style, template units.

        Parameters
        ----------
        X_clip : array (n, d), non-negative unified features of one clip.
        source_style : style the clip is performed in.
        target_style : style to translate to.
        content : the clip's content; only the ``"content_basis"`` reading
            uses it (to pick a clip of the target style), inferred from the
            nearest content mean when None.
        style_clip : array (m, d), optional
            ``"content_basis"`` reading only: the target-style clip whose
            weights are used; by default :meth:`style_clip`.

        Returns
        -------
        X_hat : ndarray (n, d) for ``"style_basis"`` (the clip's frames and
        timing), ``(m, d)`` for ``"content_basis"`` (the style clip's).

        Raises
        ------
        ValueError
            For an unknown style or content, or features of the wrong width.
        """
        check_is_fitted(self, "style_bases_")
        X_clip = self._check_X(X_clip, "StyleTranslator.translate")
        source_style = self._check_style(source_style, "source")
        target_style = self._check_style(target_style, "target")
        if content is not None and str(content) not in self.content_means_:
            raise ValueError(f"unknown content {content!r}; fitted contents: {list(self.contents_)}")
        if self.reading == "style_basis":
            U_src = self.style_bases_[source_style]
            V = self.encode(X_clip, source_style)
            X_hat = V @ self.style_bases_[target_style] + self.style_offsets_[target_style]
            if self.keep_residual:
                X_hat += X_clip - (V @ U_src + self.style_offsets_[source_style])
            return X_hat
        # content_basis: the clip's own basis (refitted from U0 with its
        # weights fixed) recombined with the weights of a target-style clip.
        U0 = self.components_
        V_clip = self.encode(X_clip, None)
        U_clip = refit_basis(X_clip, V_clip, U0, max_iter=self.refit_iter, ridge=self.ridge)
        if style_clip is None:
            c = str(content) if content is not None else self.nearest_content(X_clip)
            style_clip = self.style_clip(target_style, c)
        style_clip = self._check_X(style_clip, "StyleTranslator.translate (style_clip)")
        V_style = self.encode(style_clip, None)
        X_hat = V_style @ U_clip
        if self.keep_residual:
            X_hat += style_clip - V_style @ U0
        return X_hat

    def synthesize(self, content, target_style) -> np.ndarray:
        """The model's own clip of ``content`` in ``target_style``, ``(m, d)``, template units.

        Only for ``basis="aligned"``: X̂ = V_c U_t + b_t with V_c the content's
        shared weights (one row per frame of its reference clip, fitted on
        every style that performs it), U_t and b_t the target's basis and
        offset.  The content comes from all its clips at once instead of one
        source clip.  Then, as the parameters say:

        * ``amplitude="restore"``: V_c is a least-squares compromise of
          several time-aligned performances, so it moves less than any one of
          them.  Each coordinate's deviation from the clip mean is scaled by
          g_j = mean_q sd(X_q)_j / mean_q sd(V_c U_{s_q} + b_{s_q})_j over
          the fitted clips q of the content (their own styles s_q): the
          model's own shrinkage, measured where the truth is known.  This
          restores the content's amplitude averaged over its styles.
        * ``amplitude="style"``: the same, times h_t, the target style's own
          amplitude: over its fitted clips of the other contents that other
          styles perform too, Σ sd(X_q) / Σ g_{c_q} sd(V_{c_q} U_t + b_t)
          (per coordinate; a style that swings wider than its restored
          renderings gets h > 1).
        * ``tempo=True``: resampled (linear interpolation) to the content's
          mean clip length times the target style's tempo
          (:attr:`style_tempo_`).
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
        other styles perform too: Σ sd(X_q) / Σ g_{c_q} sd(render(c_q, t)) (ratio of sums, so
        a single content does not dominate; 1 where the style has no such content)."""
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

    def synthesize_cell(self, content, target_style, X_source=None, source_style=None) -> np.ndarray:
        """The cell (``content`` in ``target_style``) the way ``synthesis`` says.

        ``"consensus"``: :meth:`synthesize`; ``"source"``: :meth:`translate`
        of ``X_source`` (performed in ``source_style``), then resampled to the
        target's tempo when ``tempo`` is on.
        """
        if self.synthesis == "consensus" and self.reading == "style_basis":
            return self.synthesize(content, target_style)
        if X_source is None or source_style is None:
            raise ValueError(f"synthesis={self.synthesis!r} with reading={self.reading!r} needs a "
                             "source clip and its style")
        X_hat = self.translate(X_source, source_style, target_style, content=content)
        if self.tempo and self.reading == "style_basis":
            ts, ss = self.style_tempo_.get(str(target_style), 1.0), self.style_tempo_.get(str(source_style), 1.0)
            X_hat = resample_clip(X_hat, max(2, int(round(len(X_hat) * ts / ss))))
        return X_hat

    def reconstruct(self, X_clip, style_name) -> np.ndarray:
        """``encode(X_clip, style) @ U_style``: the clip as the style's basis reproduces it, (n, d)."""
        style_name = self._check_style(style_name, "source")
        return self.encode(X_clip, style_name) @ self.style_bases_[style_name] + self.style_offsets_[style_name]

    # ------------------------------------------------------- new clips, files
    def translate_unseen(self, X_clip, target_style, source_style=None) -> np.ndarray:
        """Features ``(n, d)`` of a clip of a style the model was not fitted on, in ``target_style``.

        With ``source_style`` (a fitted style) this is :meth:`translate`.
        Without, the clip is encoded with the pooled basis U₀ (no offset),
        the style-neutral reading, and recombined with the target's basis and
        offset: X̂ = V U_t + b_t, plus the clip's residual X − V U₀ with
        ``keep_residual``.  The clip keeps its frames and timing.
        """
        check_is_fitted(self, "style_bases_")
        if source_style is not None:
            return self.translate(X_clip, source_style, target_style)
        X_clip = self._check_X(X_clip, "StyleTranslator.translate_unseen")
        target_style = self._check_style(target_style, "target")
        V = self.encode(X_clip, None)
        X_hat = V @ self.style_bases_[target_style] + self.style_offsets_[target_style]
        if self.keep_residual:
            X_hat += X_clip - V @ self.components_
        return X_hat

    def encode_smooth(self, X_clip, basis) -> np.ndarray:
        """Weights ``(n, k)`` of one clip for ``basis`` ``(k, d)`` with the model's temporal smoothness.

        Minimises ½‖X − VU‖² + αΣV + (λ/2)Σ_t ‖v_t − v_{t+1}‖² over V ≥ 0 with
        λ = ``smooth`` (one frame per row, the same weight relative to the
        data term as the aligned fit's shared rows): the per-frame encoding
        (:func:`~nnsf.factor.nnsf.weights_for_basis`), then ``max_iter``
        graph-regularised multiplicative updates on the clip's chain of
        frames (Cai et al.'s update, as in the aligned fit).  ``smooth`` 0
        is the per-frame encoding.
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
        if self.smooth_order == 2:
            Lpos, Lneg = second_difference_split([(0, len(X))], len(X))
            for _ in range(int(self.max_iter)):
                V *= (XUt + lam * (Lneg @ V)) / np.maximum(V @ UUt + alpha + lam * (Lpos @ V), EPSILON)
            return V
        deg = np.full(len(X), 2.0)
        deg[[0, -1]] = 1.0
        for _ in range(int(self.max_iter)):
            nb = np.zeros_like(V)
            nb[1:] += V[:-1]
            nb[:-1] += V[1:]
            V *= (XUt + lam * nb) / np.maximum(V @ UUt + alpha + lam * deg[:, None] * V, EPSILON)
        return V

    def translate_clip(self, X_clip, target_style, source_style=None) -> np.ndarray:
        """One clip of any body into ``target_style``: the public path (:func:`nnsf.translate`).

        The steps of the held-out default (:meth:`synthesize`) that do not
        need the clip's content label, applied to the caller's clip:

        * weights encoded with the model's temporal smoothness
          (:meth:`encode_smooth`), under the source style's basis and offset
          when ``source_style`` is given, else style-neutrally under U₀;
        * X̂ = V U_t + b_t, plus the clip's residual X − (V U_src + b_src)
          with ``keep_residual``;
        * with ``tempo``, resampled to the target style's tempo relative to
          the source's (:attr:`style_tempo_`; a clip of unknown style is
          taken at the average tempo, 1.0).

        * with ``amplitude="style"``, each coordinate's swing about the
          clip mean is scaled by :meth:`swing_ratio` (how much wider the
          target style moves than the source style, or than the average
          style when the source is unknown), before the tempo.

        The amplitude restore of a consensus synthesis has no counterpart:
        one clip's own weights reproduce it at its full amplitude (no
        compromise over performances to undo), so ``"restore"`` and
        ``"none"`` leave the swing as the recombination gives it.
        Returns ``(m, d)``.
        """
        check_is_fitted(self, "style_bases_")
        X_clip = self._check_X(X_clip, "StyleTranslator.translate_clip")
        target_style = self._check_style(target_style, "target")
        if source_style is None:
            U_src, b_src, tempo_src = self.components_, np.zeros(X_clip.shape[1]), 1.0
        else:
            source_style = self._check_style(source_style, "source")
            U_src, b_src = self.style_bases_[source_style], self.style_offsets_[source_style]
            tempo_src = self.style_tempo_.get(source_style, 1.0)
        V = self.encode_smooth(np.maximum(X_clip - b_src, 0.0), U_src)
        X_hat = V @ self.style_bases_[target_style] + self.style_offsets_[target_style]
        if self.keep_residual:
            X_hat += X_clip - (V @ U_src + b_src)
        if self.amplitude == "style":
            mean = X_hat.mean(axis=0)
            X_hat = np.maximum(mean + (X_hat - mean) * self.swing_ratio(target_style, source_style), 0.0)
        if self.tempo:
            ratio = self.style_tempo_.get(target_style, 1.0) / max(tempo_src, 1e-12)
            X_hat = resample_clip(X_hat, max(2, int(round(len(X_hat) * ratio))))
        return X_hat

    def swing_ratio(self, target_style, source_style=None) -> np.ndarray:
        """k (d,): the target style's swing over the source's, per coordinate, from the fitted clips.

        With S(s, c) the mean over the fitted clips of style s and content c
        of each coordinate's standard deviation over the clip's frames,
        k = Σ_c S(t, c) / Σ_c S(src, c) over the contents c both styles
        perform (a ratio of sums, so one content does not dominate).  An
        unknown source (None) is the average style: S(src, c) is the mean of
        S(s, c) over every style s that performs c, and c runs over the
        target's contents.  1 where the denominator is zero or the styles
        share no content; all ones when source and target are the same style.
        """
        check_is_fitted(self, "clips_")
        target_style = self._check_style(target_style, "target")
        if source_style is not None:
            source_style = self._check_style(source_style, "source")
        ones = np.ones(self.n_features_in_)
        if source_style == target_style:
            return ones
        S = {key: np.mean([Xq.std(axis=0) for Xq in lst], axis=0) for key, lst in self.clips_.items()}
        num, den = np.zeros_like(ones), np.zeros_like(ones)
        for (s, c), sd in S.items():
            if s != target_style:
                continue
            if source_style is None:
                ref = np.mean([v for (s2, c2), v in S.items() if c2 == c], axis=0)
            elif (source_style, c) in S:
                ref = S[(source_style, c)]
            else:
                continue
            num += sd
            den += ref
        return np.where(den > 1e-12, num / np.maximum(den, 1e-12), 1.0)

    def save(self, path, *, unifier=None, features_sha256=None, source="") -> Path:
        """Write the fitted translator to one ``.npz`` (:mod:`nnsf.factor.model_file`); returns the path."""
        return save_model(self, path, unifier=unifier, features_sha256=features_sha256, source=source)

    @classmethod
    def load(cls, path) -> "StyleTranslator":
        """A translator read from a file written by :meth:`save`.

        Raises :class:`nnsf.errors.InputError` naming the file and what is
        wrong (not a model, another format version, an array missing).
        """
        return load_model(path, cls)[0]


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
