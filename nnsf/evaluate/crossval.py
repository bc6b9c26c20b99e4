"""Held-out precision and reconstruction error versus rank (docs/method.md §15.1).

The paper's Fig. 7 made objective: for every method and rank, fit on the
training folds, encode the held-out frames with the basis fixed, and score

* macro precision of the predicted class (``argmax(V_test W)`` for the
  factorisations, nearest cell mean for the bilinear model, the most likely
  (content, phase) under the frame's style for the two Gaussian-process
  models), and
* relative reconstruction error ``‖X_test − X̂_test‖_F / ‖X_test‖_F``.

Folds are grouped by clip (:func:`folds`), so consecutive, nearly identical
frames of one clip never sit on both sides of a split.
"""
from __future__ import annotations

import numbers
import time
import warnings

import numpy as np
import pandas as pd
from joblib import Parallel, delayed
from sklearn.exceptions import ConvergenceWarning
from sklearn.metrics import accuracy_score, precision_score
from sklearn.model_selection import StratifiedGroupKFold
from threadpoolctl import threadpool_limits

from nnsf.factor.baselines import BilinearModel, NMFClassifier, make_nnsc
from nnsf.factor.cbgpm import CBGPM
from nnsf.factor.gp_data import check_phase, phase_from_groups
from nnsf.factor.mgpm import MGPM
from nnsf.factor.nnsf import NNSF
from nnsf.params import METHODS

# METHODS (nnsf.params): the methods, in the order tables and figures list them.

#: The methods fitted on (style, content, phase) rather than on frames alone.
GP_METHODS: tuple[str, ...] = ("mgpm", "cbgpm")

#: Settings of the Gaussian-process baselines and their defaults.
GP_DEFAULTS: dict = {"phase_bins": 3, "max_iter": 60}

#: Columns of :func:`precision_vs_rank`'s table.
TABLE_COLUMNS: tuple[str, ...] = (
    "method", "rank", "rank_used", "fold", "precision", "accuracy", "recon_error",
    "n_train", "n_test", "n_iter", "seconds", "note",
)

# Parameters of NNSF that precision_vs_rank sets itself.
_OWN_PARAMS = ("n_components", "max_iter", "random_state")


def folds(y, groups, n_splits: int = 10, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stratified folds grouped by clip.

    Parameters
    ----------
    y : array, shape (n,)
        Class of each frame (stratification target).
    groups : array, shape (n,)
        Clip of each frame; a clip is never split across train and test.
    n_splits : int >= 2
    seed : int
        Seed of the group shuffle, so the folds are reproducible.

    Returns
    -------
    list of (train_index, test_index), each a sorted int array.

    Raises
    ------
    ValueError
        When some class has fewer clips than ``n_splits`` -- such a class
        would be missing from some test fold and, with one clip, from some
        training fold.
    """
    y = np.asarray(y)
    groups = np.asarray(groups)
    if y.ndim != 1 or groups.shape != y.shape:
        raise ValueError(f"y and groups must be 1-D arrays of the same length, got shapes "
                         f"{y.shape} and {groups.shape}")
    if not (isinstance(n_splits, numbers.Integral) and not isinstance(n_splits, bool) and n_splits >= 2):
        raise ValueError(f"n_splits must be an integer >= 2, got {n_splits!r}")
    clips = pd.DataFrame({"y": y, "g": groups}).drop_duplicates()
    per_class = clips.groupby("y", sort=True)["g"].nunique()
    short = per_class[per_class < n_splits]
    if len(short):
        detail = ", ".join(f"{c!r}: {k}" for c, k in short.head(5).items())
        raise ValueError(f"{n_splits}-fold CV grouped by clip needs at least {n_splits} clips per "
                         f"class; too few clips for {detail}. Lower the number of folds or add clips.")
    cv = StratifiedGroupKFold(n_splits=n_splits, shuffle=True, random_state=seed)
    return [(np.sort(tr), np.sort(te)) for tr, te in cv.split(np.zeros(len(y)), y, groups)]


def max_rank(method: str, n_features: int, n_styles: int, n_classes: int) -> int:
    """Largest rank ``method`` supports on data of this size.

    The factorisations need ``k ≤ d`` (NNDSVD initialisation, and docs/method.md §15.1's
    ``k = 1..34``); the bilinear model's content vectors live in at most
    ``min(S·d, C)`` dimensions; the MGPM's latent vectors in at most
    ``max(S, C)`` (style vectors ``min(k, S)``, content vectors ``min(k, C)``);
    the CBGPM works in ``k ≤ d`` principal components.
    """
    if method == "bilinear":
        return min(n_styles * n_features, n_classes)
    if method == "mgpm":
        return max(n_styles, n_classes)
    return n_features


def _make(method, rank, max_iter, seed, nnsf_params, gp_params=None):
    if method == "nnsf":
        return NNSF(n_components=rank, max_iter=max_iter, random_state=seed, **nnsf_params)
    if method == "nnsc":
        kw = {k: v for k, v in nnsf_params.items() if k != "beta"}
        return make_nnsc(n_components=rank, max_iter=max_iter, random_state=seed, **kw)
    if method == "nmf":
        # Plain NMF: no sparseness term, so it is the unregularised baseline;
        # it shares NNSF's initialisation so the comparison is like for like.
        return NMFClassifier(n_components=rank, alpha=0.0, max_iter=max_iter,
                             init=nnsf_params.get("init", "nndsvda"), random_state=seed)
    if method == "bilinear":
        return BilinearModel(n_components=rank)
    gp = {**GP_DEFAULTS, **(gp_params or {})}
    if method == "mgpm":
        return MGPM(n_components=rank, phase_bins=gp["phase_bins"], max_iter=gp["max_iter"],
                    random_state=seed)
    if method == "cbgpm":
        return CBGPM(n_components=rank, phase_bins=gp["phase_bins"], max_iter=gp["max_iter"])
    raise ValueError(f"unknown method {method!r}; choose from {', '.join(METHODS)}")


def _check_nnsf_params(nnsf_params):
    nnsf_params = dict(nnsf_params or {})
    allowed = set(NNSF().get_params()) - set(_OWN_PARAMS)
    unknown = sorted(set(nnsf_params) - allowed)
    if unknown:
        raise ValueError(f"nnsf_params: unknown parameter(s) {unknown}; allowed: {sorted(allowed)} "
                         f"({', '.join(_OWN_PARAMS)} are set by precision_vs_rank)")
    return nnsf_params


def _score_fold(method, rank, max_iter, seed, nnsf_params, X, y, styles, train, test, blas_threads,
                phase=None, gp_params=None):
    """Fit one model on ``train`` and score it on ``test``; returns a dict of metrics."""
    with threadpool_limits(blas_threads, user_api="blas"), warnings.catch_warnings():
        # Hitting max_iter is expected in a sweep; the table's n_iter shows it.
        warnings.simplefilter("ignore", ConvergenceWarning)
        model = _make(method, rank, max_iter, seed, nnsf_params, gp_params)
        t0 = time.perf_counter()
        if method in ("bilinear",) + GP_METHODS:
            if method == "bilinear":
                model.fit(X[train], y[train], styles[train])
            else:
                model.fit(X[train], y[train], styles[train], phase[train])
            Xt, st = X[test], styles[test]
            known = np.isin(st, model.styles_)
            pred = np.empty(len(test), dtype=model.classes_.dtype)
            recon = np.empty((len(test), X.shape[1]))
            # Test frames of a style the training folds never saw are classified
            # by searching every known style (the style is inferred, not given).
            for mask, style in ((known, st[known]), (~known, None)):
                if mask.any():
                    pred[mask] = model.predict(Xt[mask], style)
                    recon[mask] = model.reconstruct(Xt[mask], style)
            rank_used, n_iter = model.n_components_, model.n_iter_
        else:
            model.fit(X[train], y[train])
            V = model.transform(X[test])
            pred = model.classes_[np.argmax(V @ model.class_map_, axis=1)]
            recon = model.inverse_transform(V)
            rank_used, n_iter = model.components_.shape[0], model.n_iter_
        seconds = time.perf_counter() - t0
    y_test = y[test]
    return {
        "rank_used": int(rank_used),
        "precision": float(precision_score(y_test, pred, average="macro", zero_division=0)),
        "accuracy": float(accuracy_score(y_test, pred)),
        "recon_error": float(np.linalg.norm(X[test] - recon) / np.linalg.norm(X[test])),
        "n_train": int(len(train)),
        "n_test": int(len(test)),
        "n_iter": int(n_iter),
        "seconds": seconds,
    }


def score_fold(job: tuple) -> dict:
    """:func:`_score_fold` on one packed argument tuple (for a task runner's map)."""
    return _score_fold(*job)


def precision_vs_rank(X, y, groups, styles=None, methods=METHODS, ranks=(2, 4, 8, 16, 34),
                      n_splits: int = 10, seed: int = 0, max_iter: int = 200,
                      nnsf_params: dict | None = None, n_jobs: int = 1,
                      blas_threads: int | None = 1, mapper=None, phase=None,
                      gp_params: dict | None = None) -> pd.DataFrame:
    """Cross-validated precision and reconstruction error for every method and rank.

    Parameters
    ----------
    X : array, shape (n, d), non-negative
        Unified features, one frame per row.
    y : array, shape (n,)
        Class (motion) of each frame.
    groups : array, shape (n,)
        Clip of each frame (fold grouping).
    styles : array, shape (n,), optional
        Style (character) of each frame; required for ``"bilinear"``.
    methods : sequence of {"nnsf", "nnsc", "nmf", "bilinear", "mgpm", "cbgpm"}
        ``nnsf``: NNSF with ``nnsf_params``; ``nnsc``: the same with β = 0
        (α kept); ``nmf``: scikit-learn NMF (α = 0) + class map;
        ``bilinear``: Tenenbaum & Freeman's asymmetric model; ``mgpm``:
        Wang et al.'s multifactor GP (:class:`~nnsf.factor.mgpm.MGPM`);
        ``cbgpm``: the constraint-based GP of style after Ma et al.
        (:class:`~nnsf.factor.cbgpm.CBGPM`).  The last three need ``styles``.
    ranks : sequence of int >= 1
        Requested ranks.  A rank above what a method supports
        (:func:`max_rank`: ``d`` for the factorisations, ``min(S·d, C)`` for
        the bilinear model) is clipped to that bound; the row keeps the
        requested ``rank``, gives ``rank_used`` and says so in ``note``.
        Each (method, rank_used, fold) is fitted once and shared by every
        requested rank that clips to it.
    n_splits, seed
        Folds of :func:`folds`; ``seed`` also seeds every model's
        initialisation, so the table is deterministic given ``seed``
        (apart from the ``seconds`` column, wall time of fit + scoring).
    max_iter : int
        Iterations of every factorisation.  Hitting it is not an error
        (scikit-learn's ConvergenceWarning is silenced); ``n_iter`` shows it.
    nnsf_params : dict, optional
        Other NNSF parameters (``alpha``, ``beta``, ``class_in_loop``,
        ``tol``, ``init``, ...).  ``nnsc`` and ``nmf`` share ``init``; ``nnsc``
        also ``alpha``, ``tol`` and the rest except ``beta``.
    n_jobs : int
        Worker processes (joblib) over the (method, rank, fold) fits; 1 runs
        them in this process.  The table is the same for any ``n_jobs``.
        Ignored when ``mapper`` is given.
    mapper : callable, optional
        ``mapper(fn, jobs) -> list`` running :func:`score_fold` over the
        packed fit jobs in order, e.g. on a Prefect task runner (the pipeline
        passes one, so folds fan out on the configured runner).
    phase : array, shape (n,), optional
        Phase of each frame in its clip, in [0, 1] (the GP models' state);
        by default each row's position within its clip (``groups``, rows in
        table order).
    gp_params : dict, optional
        ``phase_bins`` (training points per cell and the phases searched when
        classifying) and ``max_iter`` (L-BFGS iterations) of the GP models;
        defaults :data:`GP_DEFAULTS`.
    blas_threads : int or None
        BLAS threads per fit (``threadpoolctl``).  The matrices are thin
        (d = 34), so one thread is fastest: with several threads the
        factorisations ran 2-10× *slower* per iteration on a 2-core machine
        under load (thread oversubscription).  None leaves BLAS alone.

    Returns
    -------
    pandas.DataFrame
        One row per (method, rank, fold) with columns :data:`TABLE_COLUMNS`.
        ``precision`` is ``precision_score(average="macro", zero_division=0)``
        over the classes that occur in the fold's truth or predictions;
        ``recon_error`` is relative (dimensionless); for the bilinear model
        the reconstruction is its nearest cell mean ``A^s b^ĉ``, for the GP models the
        pose they predict at the chosen (content, phase).
    """
    X = np.asarray(X, dtype=float)
    if X.ndim != 2:
        raise ValueError(f"X must be 2-D (frames × features), got shape {X.shape}")
    n, d = X.shape
    y = np.asarray(y)
    groups = np.asarray(groups)
    if y.shape != (n,) or groups.shape != (n,):
        raise ValueError(f"y and groups need one entry per row of X ({n}), got shapes "
                         f"{y.shape} and {groups.shape}")
    methods = list(methods)
    bad = [m for m in methods if m not in METHODS]
    if bad or not methods:
        raise ValueError(f"methods must be a non-empty list from {', '.join(METHODS)}, got {methods!r}")
    ranks = list(ranks)
    if not ranks or not all(isinstance(r, numbers.Integral) and not isinstance(r, bool) and r >= 1
                            for r in ranks):
        raise ValueError(f"ranks must be a non-empty list of integers >= 1, got {ranks!r}")
    for name, value in (("max_iter", max_iter), ("n_jobs", n_jobs)):
        if not (isinstance(value, numbers.Integral) and not isinstance(value, bool) and value >= 1):
            raise ValueError(f"{name} must be an integer >= 1, got {value!r}")
    if blas_threads is not None and not (isinstance(blas_threads, numbers.Integral) and blas_threads >= 1):
        raise ValueError(f"blas_threads must be None or an integer >= 1, got {blas_threads!r}")
    if any(m in methods for m in ("bilinear",) + GP_METHODS):
        if styles is None:
            who = next(m for m in methods if m in ("bilinear",) + GP_METHODS)
            raise ValueError(f"the {who} method needs styles (the character of each frame)")
        styles = np.asarray(styles)
        if styles.shape != (n,):
            raise ValueError(f"styles needs one entry per row of X ({n}), got shape {styles.shape}")
    gp_params = dict(gp_params or {})
    unknown = sorted(set(gp_params) - set(GP_DEFAULTS))
    if unknown:
        raise ValueError(f"gp_params: unknown parameter(s) {unknown}; allowed: {sorted(GP_DEFAULTS)}")
    if any(m in methods for m in GP_METHODS):
        phase = phase_from_groups(groups) if phase is None else check_phase(phase, n)
    if any(m in methods for m in ("nnsf", "nnsc")):
        nnsf_params = _check_nnsf_params(nnsf_params)
    else:
        nnsf_params = dict(nnsf_params or {})

    splits = folds(y, groups, n_splits, seed)
    n_styles = len(np.unique(styles)) if styles is not None else 1
    n_classes = len(np.unique(y))

    # Plan first: which (method, rank_used, fold) fits are needed, each once.
    plan = []                                            # (method, rank, used, note)
    for method in methods:
        top = max_rank(method, d, n_styles, n_classes)
        for rank in ranks:
            used = min(int(rank), top)
            note = "" if used == rank else f"clipped from {rank} to {used} (max for {method})"
            plan.append((method, int(rank), used, note))
    keys = list(dict.fromkeys((m, used, f) for m, _, used, _ in plan for f in range(len(splits))))
    jobs = [(m, used, max_iter, seed, nnsf_params, X, y, styles, splits[f][0], splits[f][1],
             blas_threads, phase, gp_params) for m, used, f in keys]
    if mapper is not None:
        scored = list(mapper(score_fold, jobs))
    else:
        scored = Parallel(n_jobs=n_jobs)(delayed(_score_fold)(*job) for job in jobs)
    results = dict(zip(keys, scored))

    rows = []
    for method, rank, used, note in plan:
        for f in range(len(splits)):
            res = results[(method, used, f)]
            # The bilinear model clips further on a fold that lacks a style or class.
            row_note = note or (f"clipped from {rank} to {res['rank_used']} (max for {method})"
                                if res["rank_used"] != rank else "")
            rows.append({"method": method, "rank": rank, "fold": f, "note": row_note, **res})
    return pd.DataFrame(rows, columns=list(TABLE_COLUMNS))


def summarise(table: pd.DataFrame) -> pd.DataFrame:
    """Mean and standard deviation over folds per (method, rank).

    The standard deviation is the sample one (``ddof=1``), the fold-to-fold
    spread; it is 0 for a single fold.

    Returns
    -------
    DataFrame with columns ``method, rank, rank_used, n_folds, precision_mean,
    precision_sd, accuracy_mean, accuracy_sd, recon_error_mean, recon_error_sd,
    seconds_mean, note``, methods in :data:`METHODS` order, ranks ascending.
    """
    missing = [c for c in ("method", "rank", "fold", "precision", "recon_error") if c not in table]
    if missing:
        raise ValueError(f"summarise: table lacks column(s) {missing}")
    value_cols = [c for c in ("precision", "accuracy", "recon_error", "seconds") if c in table]
    g = table.groupby(["method", "rank"], sort=False)
    out = g[value_cols].agg(["mean", "std"])
    out.columns = [f"{c}_{'sd' if s == 'std' else s}" for c, s in out.columns]
    out = out.fillna({c: 0.0 for c in out.columns if c.endswith("_sd")})
    out.insert(0, "n_folds", g["fold"].nunique())
    if "rank_used" in table:
        out.insert(0, "rank_used", g["rank_used"].max())
    if "note" in table:
        out["note"] = g["note"].agg(lambda s: next((x for x in s if isinstance(x, str) and x), ""))
    out = out.drop(columns=[c for c in ("seconds_sd",) if c in out]).reset_index()
    order = {m: i for i, m in enumerate(METHODS)}
    out = out.sort_values(["method", "rank"], key=lambda s: s.map(order) if s.name == "method" else s,
                          kind="stable").reset_index(drop=True)
    return out


def wide(summary: pd.DataFrame, value: str = "precision_mean") -> pd.DataFrame:
    """Pivot ``summary`` to one row per rank and one column per method.

    Columns are ``rank`` then the methods present, in :data:`METHODS` order
    (``rank, nnsf, nnsc, nmf, bilinear, mgpm, cbgpm``) -- the CSV shape ``dvc plots``
    renders as one line per method.
    """
    if value not in summary:
        raise ValueError(f"wide: summary has no column {value!r}; choose from "
                         f"{[c for c in summary.columns if c not in ('method', 'rank')]}")
    table = summary.pivot(index="rank", columns="method", values=value)
    cols = [m for m in METHODS if m in table.columns] + [m for m in table.columns if m not in METHODS]
    table = table.loc[:, cols].sort_index().reset_index()
    table.columns.name = None
    return table
