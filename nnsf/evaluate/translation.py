"""Held-out evaluation of style translation: leave one (style, content) cell out (docs/method.md §15.5).

For every cell of the style × content grid, the cell's real clips are hidden
and the cell is synthesised from the rest of the data: the *content* from
the other styles' clips of that content (each such clip is a source of the
per-clip methods; NNSF's default consensus synthesis uses all of them at
once), the *style* from the target style's other contents.  Each synthesised
clip is compared with the hidden real clip(s):

* ``dtw_error`` -- mean per-joint Euclidean error after DTW alignment
  (:func:`nnsf.factor.translate.dtw_align`), in template units (torso = 1.0,
  so ×100 reads as % of the torso);
* ``style_<family>``, ``content_<family>`` -- the verdict of the independent
  judges (:mod:`nnsf.evaluate.judges`: logistic regression, 1-NN and an
  angle-statistics SVM, trained on the remaining real clips as read -- raw
  key points, pixels --, told neither label; ``all`` = recognised by every
  family).  They judge each synthesis mapped to the target character's
  pixels with the inverse of the cell's unification (what a caller gets;
  ``api`` in the coordinates :func:`nnsf.translate` returns) and the hidden
  clip as read, and normalise on their own: nothing of the cell's unifier or
  the translation's template reaches them;
* ``jerk_ratio`` -- mean |second difference| of the key points (:func:`jerk`)
  over that of the target style's real training clips;
* ``style_acc`` -- does the project's own (conditioned LDA) style classifier
  trained on the remaining real clips, in the cell's template units, say the
  target style?  (Kept for comparison with earlier numbers.)
* ``content_acc`` -- does a content classifier trained on the remaining real
  clips say the cell's content?
* ``bone_error`` -- mean absolute bone-length difference over the DTW-aligned
  frame pairs, template units (a linear recombination of poses shortens or
  stretches bones; the hidden clip shows how long they look in 2D);
* ``truth_error`` -- on the synthetic set only, the DTW error against the
  exact "content in the target style" (:func:`nnsf.datasets.synthetic.clip_points`
  with the source clip's variation).

Everything that is learned (the template unifier, the factorisations, the
classifiers) is fitted on the remaining data only, inside :func:`evaluate_cell`,
a pure function of its arguments so that a task runner can fan the cells out;
:func:`leave_one_cell_out` runs them one after another.

The project's own classifiers (``style_acc``, ``content_acc``; the judges are the
evaluation's verdict, these are kept for comparison; docs/method.md §15.5): one feature
vector per clip (:func:`clip_features`: mean, standard deviation, mean
absolute velocity and the signed area swept by each key point -- 119
numbers), standardised, then linear discriminant analysis with Ledoit-Wolf
shrinkage (``LinearDiscriminantAnalysis(solver="lsqr", shrinkage="auto")``).
The style classifier is conditioned on the content, which the task fixes:
a clip's vector minus the mean vector of its content's training clips, so
that it judges how a clip departs from the content's average rather than
which content it is; the content classifier likewise is conditioned on the
style.  The classifiers were chosen by their accuracy on the *real* hidden
clips (the ``real`` row), never by the methods' scores.

This module is the protocol (the cells, what each method is fitted on, the
rows of the results table); the scores are :mod:`nnsf.evaluate.scores`, the
per-source baselines :mod:`nnsf.evaluate.cell_baselines`, the judges
:mod:`nnsf.evaluate.judges`.  Every model is refitted through the library
(:mod:`nnsf.factor`), never through a stage.  The ``heldout`` stage that runs
it and writes ``reports/heldout*`` is :mod:`nnsf.evaluate.heldout_report`; the
``translate`` stage (one clip into one style) is :func:`nnsf.factor.stage.translate`.
"""
from __future__ import annotations

import numbers
import time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from nnsf.datasets.contract import COLUMNS, features
from nnsf.errors import InputError
from nnsf.evaluate.gp_translation import GP_TRANSLATION_METHODS, fit_gp_translator, gp_translate
from nnsf.evaluate.judges import FAMILIES as JUDGE_FAMILIES
from nnsf.evaluate.judges import Judges
from nnsf.factor.baselines import BilinearModel
from nnsf.factor.style_model import StyleModel, translate_features
from nnsf.factor.timewarp import dtw_accumulate, dtw_path, joint_distance_matrix
from nnsf.factor.translate import StyleTranslator
from nnsf.skeleton import Unifier, to_points
from nnsf.evaluate.scores import ClipClassifiers, compare_clips, _unify, clip_features, jerk
from nnsf.evaluate.cell_baselines import BASELINES, CellData
from nnsf.evaluate.nnsf_variants import swapped_translation

__all__ = [
    "METHODS", "DEFAULT_VARIANTS", "RESULT_COLUMNS", "grid_cells", "evaluate_cell", "leave_one_cell_out",
    "summarise", "per_style",
]

#: Every method the evaluation knows, in table order.  ``real`` is the hidden
#: clip itself: zero error by definition, its accuracies are the classifiers'
#: ceiling.
METHODS: tuple[str, ...] = (
    "nnsf", "nnsf_nosmooth", "nnsf_restore", "nnsf_swapped", "nnsf_refit", "api", "api_source", "bilinear",
    "bilinear_template", "mgpm", "cbgpm", "offset", "identity", "real",
)

#: Settings of every NNSF method on top of ``translator_params``: StyleTranslator parameters, and
#: ``synthesis`` (``"consensus"`` or ``"source"``, :meth:`~nnsf.factor.translate.StyleTranslator.synthesize_cell`)
#: or ``reading="content_basis"`` (:func:`nnsf.evaluate.nnsf_variants.swapped_translation`), which say
#: how the fitted translator makes the cell.
DEFAULT_VARIANTS: dict[str, dict] = {
    "nnsf": {},
    "nnsf_swapped": {"reading": "content_basis"},
    "nnsf_refit": {"basis": "refit", "synthesis": "source"},
    "nnsf_nosmooth": {"smooth": 0.0},
    "nnsf_restore": {"amplitude": "restore"},
}

#: The public path's methods: nnsf.translate() without and with the source clip's style.
_API: tuple[str, ...] = ("api", "api_source")

#: Settings that say how a cell is made from a fitted translator, not StyleTranslator parameters.
_CALL_OPTIONS: tuple[str, ...] = ("synthesis", "reading")

#: StyleTranslator parameters that only change how a fitted translator is
#: used (not the fit): variants differing only in these share one fit.
_USE_PARAMS: tuple[str, ...] = ("amplitude", "tempo", "transfer", "neutral")

#: Accuracy columns of the independent judges (:mod:`nnsf.evaluate.judges`):
#: ``style_<family>``, ``content_<family>`` for every family and ``all``.
JUDGE_COLUMNS: tuple[str, ...] = tuple(f"{what}_{fam}" for fam in (*JUDGE_FAMILIES, "all")
                                       for what in ("style", "content"))

#: Columns of :func:`evaluate_cell`'s rows.  ``style_acc``/``content_acc`` are
#: the project's own (conditioned LDA) classifiers, kept for comparison; the
#: judges' columns are the evaluation's verdict.
RESULT_COLUMNS: tuple[str, ...] = (
    "style", "content", "method", "dtw_error", "style_acc", "content_acc", *JUDGE_COLUMNS,
    "jerk_ratio", "bone_error", "truth_error", "n_sources", "n_hidden", "seconds",
)


# --------------------------------------------------------------------------- #
# Per-source baselines: name -> factory(cell) -> translate(X_source, source_style)
# --------------------------------------------------------------------------- #


# --------------------------------------------------------------------------- #
# Ground truth of the synthetic set
# --------------------------------------------------------------------------- #


# --------------------------------------------------------------------------- #
# Classifiers of clips
# --------------------------------------------------------------------------- #


# --------------------------------------------------------------------------- #
# One cell
# --------------------------------------------------------------------------- #
def grid_cells(table: pd.DataFrame, min_styles: int = 2) -> list[tuple[str, str]]:
    """Every (style, content) cell that can be held out and still synthesised.

    A cell qualifies when its content is performed in at least ``min_styles``
    styles (so another style can provide the content) and its style performs
    at least one other content (so the style can be learned).  Sorted.
    """
    pairs = table[["character", "motion"]].drop_duplicates().astype(str)
    n_styles = pairs.groupby("motion")["character"].nunique()
    n_contents = pairs.groupby("character")["motion"].nunique()
    ok = [(s, c) for s, c in pairs.itertuples(index=False)
          if n_styles[c] >= min_styles and n_contents[s] >= 2]
    return sorted(ok)


def _clip_index(table):
    clip = table["clip"].to_numpy().astype(str)
    names, first, inverse = np.unique(clip, return_index=True, return_inverse=True)
    rows = [np.flatnonzero(inverse == i) for i in range(len(names))]
    return names, rows


def _check_cell(table, style, content):
    styles = set(table["character"].astype(str))
    contents = set(table["motion"].astype(str))
    if style not in styles:
        raise InputError("table", "character", f"one of the styles {sorted(styles)}", style)
    if content not in contents:
        raise InputError("table", "motion", f"one of the contents {sorted(contents)}", content)
    ch = table["character"].astype(str).to_numpy()
    mo = table["motion"].astype(str).to_numpy()
    hidden = (ch == style) & (mo == content)
    if not hidden.any():
        raise InputError("table", "cell", f"real clips of style {style!r} performing {content!r} "
                         "to hide and compare with", "no such clip")
    if not (~hidden & (mo == content)).any():
        raise InputError("table", "cell", f"a clip of {content!r} in a style other than {style!r} "
                         "to take the content from", "none")
    if not (~hidden & (ch == style)).any():
        raise InputError("table", "cell", f"a clip of style {style!r} with a content other than "
                         f"{content!r} to learn the style from", "none")
    return hidden


def evaluate_cell(table: pd.DataFrame, style: str, content: str, *,
                  methods=METHODS,
                  translator_params: dict | None = None, variants: dict | None = None,
                  bilinear_rank: int | None = 1, bilinear_residual: bool = True, max_sources: int | None = None,
                  gp_params: dict | None = None, truth=None, margin: float = 0.5, seed: int = 0,
                  return_examples: bool = False):
    """Hide one (style, content) cell, synthesise it from the rest, score every method.

    Parameters
    ----------
    table : DataFrame
        A contract table in pixels (``clip, frame, character, motion,
        x1..y17``); ``character`` is the style, ``motion`` the content.
    style, content : the cell to hold out.
    methods : names from :data:`METHODS`.
        ``nnsf*`` -- :class:`~nnsf.factor.translate.StyleTranslator` with
        ``translator_params`` updated by ``variants[name]`` (default
        :data:`DEFAULT_VARIANTS`), each cell made by
        :meth:`~nnsf.factor.translate.StyleTranslator.synthesize_cell`
        (a consensus synthesis is the same for every source) or, with
        ``reading="content_basis"``, by
        :func:`~nnsf.evaluate.nnsf_variants.swapped_translation`; variants
        that differ only in how a fit is used (``synthesis``, ``reading``,
        ``amplitude``, ``tempo``, ``transfer``, ``neutral``) share one fit.
        ``api`` -- the public path: every source clip, as read (pixels),
        through :func:`nnsf.translate` with a
        :class:`~nnsf.factor.style_model.StyleModel` of the ``nnsf`` fit and
        the cell's unifier, read style-neutrally (the default call); judged
        in the coordinates it returns (the source clip's), its DTW error from
        the same call's template features.  ``api_source`` -- the same call
        told the source clip's style (``source_style=``).
        ``bilinear`` -- Tenenbaum & Freeman's asymmetric model fitted on the
        other styles, the target style adapted from its observed contents
        (:meth:`~nnsf.factor.baselines.BilinearModel.adapt_style`), and every
        source frame translated as x̂ = A^t (A^s)⁺ x (content vector of the
        frame under the source style, rendered in the target style).
        ``bilinear_template`` -- the same model's cell template A^t b^c, held
        for as many frames as the source clip has.
        ``mgpm``, ``cbgpm`` -- the Gaussian-process baselines
        (:mod:`nnsf.evaluate.gp_translation`) fitted on the remaining rows with
        ``gp_params`` (``rank``, ``phase_bins``, ``max_iter``), each source
        clip rendered in the target style plus its residual.
        ``offset`` -- the source clip plus the mean pose offset from its style
        to the target's (:func:`style_offset`).
        ``identity`` -- the source clip unchanged (in unified features it is
        already retargeted: mapping back with the target's inverse
        unification gives the target's proportions).
        ``real`` -- the hidden clip itself (its accuracies are the ceiling).
    translator_params : dict, optional
        Parameters shared by every NNSF method (e.g. ``n_components``).
    variants : dict name -> dict, optional
        Per-method parameter overrides; default :data:`DEFAULT_VARIANTS`.
        New names (e.g. ``"nnsf_k8": {"n_components": 8}``) may be added.
    bilinear_rank : int or None
        J of the bilinear model (None: full rank).
    max_sources : int, optional
        Use at most this many source clips (evenly spread over the sorted
        clip names); all by default.
    truth : callable, optional
        ``truth(source_clip, target_style, n_frames) -> (n_frames, 17, 2)``
        pixels of the exact translation (e.g. :class:`SyntheticTruth`); adds
        ``truth_error``.
    margin : float
        Margin of the template unifier fitted on the remaining data.
    seed : int
        Seed of the factorisations.
    return_examples : bool
        Also return, per method, the first source's synthesised features,
        the hidden clip's and the DTW path (for :func:`strip_figure`).

    Returns
    -------
    DataFrame with :data:`RESULT_COLUMNS`, one row per method: means over
    every (source clip, hidden clip) pair; accuracies are the fraction of
    source clips whose synthesis is classified right.  With
    ``return_examples``, ``(DataFrame, dict)``.

    Raises
    ------
    InputError (a ValueError)
        Unknown style or content, no hidden clip, no other clip of the
        content, or no other content of the style.
    ValueError
        Unknown method names.
    """
    style, content = str(style), str(content)
    methods = tuple(methods)
    variants = dict(DEFAULT_VARIANTS if variants is None else variants)
    bad = [m for m in methods if m not in METHODS and m not in variants]
    if bad:
        raise ValueError(f"unknown method(s) {bad}; choose from {list(METHODS)} or name them in variants")
    if max_sources is not None and not (isinstance(max_sources, numbers.Integral) and max_sources >= 1):
        raise ValueError(f"max_sources must be an integer >= 1 or None, got {max_sources!r}")
    hidden = _check_cell(table, style, content)
    t_start = time.perf_counter()

    train = table.loc[~hidden].reset_index(drop=True)
    test = table.loc[hidden].reset_index(drop=True)
    P_train = to_points(features(train))
    ch_train = train["character"].astype(str).to_numpy()
    mo_train = train["motion"].astype(str).to_numpy()
    unifier = Unifier(margin=margin).fit(P_train, ch_train)
    X = unifier.transform(P_train, ch_train)
    names, rows = _clip_index(train)
    clip_style = np.array([ch_train[r[0]] for r in rows])
    clip_content = np.array([mo_train[r[0]] for r in rows])
    clip_of_row = train["clip"].astype(str).to_numpy()

    h_names, h_rows = _clip_index(test)
    P_test = to_points(features(test))
    hidden_X = [_unify(unifier, P_test[r], style) for r in h_rows]

    # Classifiers on the remaining real clips of the grid's contents.
    grid_contents = {c for s, c in grid_cells(train)} | {content}
    keep = np.isin(clip_content, sorted(grid_contents))
    F = np.stack([clip_features(X[r]) for r in rows])
    clf = ClipClassifiers().fit(F[keep], clip_style[keep], clip_content[keep])
    # The independent judges: every remaining real clip as read (raw key points, pixels),
    # unconditioned; they normalise on their own (nnsf.evaluate.judges).  Nothing of this
    # cell's unifier reaches them: syntheses are judged in the target character's pixels.
    judges = Judges(seed=seed).fit([P_train[r] for r in rows], clip_style, clip_content)
    own = np.flatnonzero(clip_style == style)
    jerk_real = float(np.mean([jerk(X[rows[i]]) for i in own]))
    cell_data = CellData(X=X, clip_rows=rows, clip_style=clip_style, clip_content=clip_content,
                         style=style, content=content)
    baselines = {m: BASELINES[m](cell_data) for m in methods if m in BASELINES}

    # Sources: every remaining clip of the content (another style by construction).
    src = np.flatnonzero(clip_content == content)
    if max_sources is not None and len(src) > max_sources:
        src = src[np.unique(np.linspace(0, len(src) - 1, max_sources).round().astype(int))]

    # Models.
    base = dict(translator_params or {})
    base.setdefault("random_state", seed)
    translators, fitted = {}, {}
    for m in methods:
        if m in variants or m in _API:
            # ``api``, ``api_source``: the default fit, used through nnsf.translate (the public path).
            params = {**base, **variants.get(m, {})}
            call = {k: params.pop(k) for k in _CALL_OPTIONS if k in params}
            fit_params = {k: v for k, v in params.items() if k not in _USE_PARAMS}
            key = tuple(sorted((k, repr(v)) for k, v in fit_params.items()))
            if key not in fitted:
                fitted[key] = StyleTranslator(**fit_params).fit(X, mo_train, ch_train, clip_of_row)
            defaults = StyleTranslator().get_params()
            translators[m] = (fitted[key], {k: params.get(k, defaults[k]) for k in _USE_PARAMS}, call)
    bilinear = None
    if "bilinear" in methods or "bilinear_template" in methods:
        others = ch_train != style
        bilinear = BilinearModel(n_components=bilinear_rank).fit(X[others], mo_train[others], ch_train[others])
        # Contents only the target style performs carry no shared content vector.
        own = ~others & np.isin(mo_train, bilinear.classes_)
        bilinear.adapt_style(X[own], mo_train[own], style)
    gp_models = {m: fit_gp_translator(m, X, mo_train, ch_train, clip_of_row, seed=seed,
                                      **(gp_params or {"rank": 8, "phase_bins": 3, "max_iter": 50}))
                 for m in methods if m in GP_TRANSLATION_METHODS}
    fit_seconds = time.perf_counter() - t_start

    sums = {m: dict(dtw=0.0, bone=0.0, truth=0.0, n_pairs=0, n_truth=0, style=0, content=0, n=0,
                    jerk=0.0, **{k: 0 for k in JUDGE_COLUMNS})
            for m in methods}

    to_judge: list[tuple[str, np.ndarray]] = []    # judged at once at the end (one predict call)

    def judge(m, clips):
        to_judge.extend((m, x) for x in clips)

    examples = {}
    per_cell = {}           # syntheses that do not depend on the source clip
    for q in src:
        Xs = X[rows[q]]
        s_src = clip_style[q]
        X_hats = {}
        pixels = {}         # what a caller gets, where it is not the target character's pixels
        for m in methods:
            if m in _API:
                tr, use, _ = translators[m]
                tr.set_params(**use)
                # Exactly nnsf.translate(): the source clip's raw key points in, key points in
                # the clip's own coordinates out; X_hat is the same call's template features.
                # ``api`` reads the clip style-neutrally (the default call), ``api_source`` is
                # told the clip's style (source_style=).
                pixels[m], X_hats[m], _ = translate_features(
                    P_train[rows[q]], style, StyleModel(tr, unifier),
                    source_style=s_src if m == "api_source" else None)
            elif m in translators:
                tr, use, call = translators[m]
                tr.set_params(**use)
                if call.get("reading") == "content_basis":
                    X_hats[m] = swapped_translation(tr, Xs, style, content)
                elif call.get("synthesis", "consensus") == "consensus":
                    if m not in per_cell:
                        per_cell[m] = tr.synthesize(content, style)
                    X_hats[m] = per_cell[m]
                else:
                    X_hats[m] = tr.synthesize_cell(content, style, Xs, s_src, synthesis="source")
            elif m == "bilinear":
                B = bilinear.transform(Xs, np.full(len(Xs), s_src))
                X_hats[m] = bilinear.inverse_transform(B, np.full(len(Xs), style))
                if bilinear_residual:
                    X_hats[m] += Xs - bilinear.inverse_transform(B, np.full(len(Xs), s_src))
            elif m == "bilinear_template":
                X_hats[m] = np.tile(bilinear.cell_template(style, content), (len(Xs), 1))
            elif m in gp_models:
                X_hats[m] = gp_translate(gp_models[m], Xs, s_src, style, content)
            elif m in baselines:
                X_hats[m] = baselines[m](Xs, s_src)
        synth = {m: v for m, v in X_hats.items()}
        for j, Xh_ref in enumerate(hidden_X):
            res = compare_clips(synth, Xh_ref)
            for m, (err, bone) in res.items():
                sums[m]["dtw"] += err
                sums[m]["bone"] += bone
                sums[m]["n_pairs"] += 1
        if truth is not None:
            X_true = _unify(unifier, truth(names[q], style, len(Xs)), style)
            for m, (err, _) in compare_clips(synth, X_true).items():
                sums[m]["truth"] += err
                sums[m]["n_truth"] += 1
        for m, Xh in synth.items():
            f = clip_features(Xh)
            sums[m]["style"] += int(clf.predict_style(f, content)[0] == style)
            sums[m]["content"] += int(clf.predict_content(f, style)[0] == content)
            sums[m]["n"] += 1
            sums[m]["jerk"] += jerk(Xh) / max(jerk_real, 1e-12)
            # Judged in pixels: the target character's (the inverse of this cell's
            # unification, what a caller of the translation gets), or the api's own output.
            judge(m, [pixels[m] if m in pixels else unifier.inverse_transform(Xh, style)])
        if return_examples and not examples:
            for m, Xh in synth.items():
                err, path = _example_path(Xh, hidden_X[0])
                examples[m] = {"synth": Xh, "real": hidden_X[0], "path": path, "source": names[q],
                               "dtw_error": err}
    if "real" in methods:
        for Xr in hidden_X:
            f = clip_features(Xr)
            sums["real"]["style"] += int(clf.predict_style(f, content)[0] == style)
            sums["real"]["content"] += int(clf.predict_content(f, style)[0] == content)
            sums["real"]["n"] += 1
            sums["real"]["n_pairs"] += 1
            sums["real"]["jerk"] += jerk(Xr) / max(jerk_real, 1e-12)
        judge("real", [P_test[r] for r in h_rows])      # as read: raw key points
    if to_judge:
        verdict = judges.score([x for _, x in to_judge], style, content)
        who = np.array([m for m, _ in to_judge])
        for fam, (ok_s, ok_c) in verdict.items():
            for m in set(who):
                sums[m][f"style_{fam}"] += int(ok_s[who == m].sum())
                sums[m][f"content_{fam}"] += int(ok_c[who == m].sum())
    seconds = time.perf_counter() - t_start

    out = []
    for m in methods:
        s = sums[m]
        out.append({
            "style": style, "content": content, "method": m,
            "dtw_error": s["dtw"] / s["n_pairs"] if s["n_pairs"] else np.nan,
            "style_acc": s["style"] / s["n"] if s["n"] else np.nan,
            "content_acc": s["content"] / s["n"] if s["n"] else np.nan,
            **{k: s[k] / s["n"] if s["n"] else np.nan for k in JUDGE_COLUMNS},
            "jerk_ratio": s["jerk"] / s["n"] if s["n"] else np.nan,
            "bone_error": s["bone"] / s["n_pairs"] if s["n_pairs"] else np.nan,
            "truth_error": s["truth"] / s["n_truth"] if s["n_truth"] else np.nan,
            "n_sources": int(len(src)) if m != "real" else 0,
            "n_hidden": len(hidden_X),
            "seconds": seconds,
        })
    frame = pd.DataFrame(out, columns=list(RESULT_COLUMNS))
    frame.attrs["fit_seconds"] = fit_seconds
    if return_examples:
        return frame, examples
    return frame


def _example_path(A, B):
    C = joint_distance_matrix(A, B)
    D = dtw_accumulate(C)
    p = dtw_path(D)
    return float(D[-1, -1] / len(p)), p


# --------------------------------------------------------------------------- #
# All cells
# --------------------------------------------------------------------------- #
def leave_one_cell_out(table: pd.DataFrame, cells=None, *, progress=None, **kwargs) -> pd.DataFrame:
    """Run :func:`evaluate_cell` for every cell, one after another.

    Parameters
    ----------
    table : contract table in pixels.
    cells : list of (style, content), optional; default :func:`grid_cells`.
    progress : callable(i, n, cell, seconds), optional, called after each cell.
    **kwargs : passed to :func:`evaluate_cell`.

    Returns
    -------
    DataFrame with :data:`RESULT_COLUMNS`, one row per (cell, method).
    """
    missing = [c for c in COLUMNS[:4] if c not in table.columns]
    if missing:
        raise InputError("table", missing[0], "a column of the feature-matrix contract")
    cells = grid_cells(table) if cells is None else [(str(s), str(c)) for s, c in cells]
    if not cells:
        raise InputError("table", "cells", "at least one (style, content) cell whose content "
                         "another style performs and whose style performs another content", "none")
    parts = []
    for i, (s, c) in enumerate(cells):
        t0 = time.perf_counter()
        parts.append(evaluate_cell(table, s, c, **kwargs))
        if progress is not None:
            progress(i, len(cells), (s, c), time.perf_counter() - t0)
    return pd.concat(parts, ignore_index=True)


def summarise(results: pd.DataFrame) -> pd.DataFrame:
    """Mean of every metric per method over cells (each cell weighs the same).

    Adds ``dtw_error_pct`` (% of the torso length) and ``cells``.
    """
    metrics = ["dtw_error", "style_acc", "content_acc", *JUDGE_COLUMNS, "jerk_ratio", "bone_error",
               "truth_error"]
    order = [m for m in METHODS if m in set(results["method"])] + \
        [m for m in dict.fromkeys(results["method"]) if m not in METHODS]
    g = results.groupby("method", sort=False)[metrics].mean().reindex(order)
    g["dtw_error_pct"] = 100.0 * g["dtw_error"]
    g["cells"] = results.groupby("method", sort=False).size().reindex(order)
    return g.reset_index()


def per_style(results: pd.DataFrame) -> pd.DataFrame:
    """Mean metrics per (style, method), for the per-style figure."""
    metrics = ["dtw_error", "style_acc", "content_acc", *JUDGE_COLUMNS, "bone_error"]
    return results.groupby(["style", "method"], sort=True)[metrics].mean().reset_index()


# --------------------------------------------------------------------------- #
# The held-out stage's methods, fan-out jobs and targets
# --------------------------------------------------------------------------- #
#: Methods of the held-out stage, in table order (``real`` is the ceiling row).
STAGE_METHODS: tuple[str, ...] = ("nnsf", "nnsf_nosmooth", "nnsf_restore", "nnsf_swapped", "nnsf_refit", "api",
                                  "api_source", "bilinear", "mgpm", "cbgpm", "offset", "identity", "real")

#: Summary metrics of ``reports/heldout.json`` per method: name there -> column.
SUMMARY_METRICS: dict[str, str] = {
    "dtw_error": "dtw_error", "dtw_error_pct_torso": "dtw_error_pct", "style_acc": "style_acc",
    "content_acc": "content_acc", **{k: k for k in JUDGE_COLUMNS}, "jerk_ratio": "jerk_ratio",
    "bone_err": "bone_error", "truth_error": "truth_error",
}


@dataclass(frozen=True)
class CellJob:
    """One held-out cell for a task runner: the table, the cell and ``evaluate_cell``'s options."""

    table: pd.DataFrame
    style: str
    content: str
    kwargs: dict


def run_cell(job: CellJob):
    """Evaluate one cell (one BLAS thread): ``(rows, examples or None, error text or None)``.

    Bad input (an :class:`InputError`) is returned as text, so that the other
    cells' results are kept and the stage can name every failed cell.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        try:
            out = evaluate_cell(job.table, job.style, job.content, **job.kwargs)
        except InputError as exc:
            return None, None, str(exc)
    if isinstance(out, tuple):
        return out[0], out[1], None
    return out, None, None


def _pick(cells, n):
    """``n`` cells spread evenly over the sorted list (all when n is 0 or ≥ len)."""
    if n <= 0 or n >= len(cells):
        return list(cells)
    return [cells[i] for i in np.unique(np.linspace(0, len(cells) - 1, n).round().astype(int))]


#: What the default translation (``nnsf``) is held to, on every judge family: close to the hidden
#: clip, and recognised in the target style and in its content by judges that share nothing
#: with it.
TARGET_DTW: float = 0.17            # DTW error ≤ 17 % of the torso (template units: torso = 1)
TARGET_STYLE: float = 0.45          # style accuracy ≥ 0.45
TARGET_CONTENT: float = 0.70        # content accuracy ≥ 0.70
#: Baselines the default is compared with (``beats`` in the check), where they were run.
TARGET_BASELINES: tuple[str, ...] = ("offset", "bilinear", "identity", "mgpm", "cbgpm")
