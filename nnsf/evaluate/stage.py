"""The stages of the evaluate package: ``evaluate``, ``isomap`` and the ``sweep``'s points.

* ``evaluate``: grouped 10-fold cross-validation of held-out precision and
  reconstruction error vs rank for NNSF (Eq. 5, 7-8) and the baselines
  (docs/method.md §15.1-§15.3);
* ``isomap``: the residual variance of the encoded weights V (the paper's
  Fig. 6, docs/method.md §15.4);
* ``sweep``: :func:`sweep_grid` lists the α/β/rank points and
  :func:`sweep_point` cross-validates one (the flow fans them out).

The held-out translation stage (``heldout``) is :func:`nnsf.evaluate.heldout_report.heldout`.
"""
from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.evaluate.crossval import precision_vs_rank, summarise, wide
from nnsf.evaluate.figures import isomap_figure, precision_vs_rank_figure, reconstruction_figure
from nnsf.evaluate.isomap import intrinsic_dimension, residual_variance, stratified_sample
from nnsf.factor.figures import fold_figure
from nnsf.io import read_npz, write_csv, write_json
from nnsf.params import require, source_of
from nnsf.pipeline import (
    FEATURES_CSV, MODEL_PATH, NNSF_MODEL, REPORTS, StageResult, check_rank, label_column, need_several, nnsf_params,
)
from nnsf.publish import publish_stage, publishing, recover


def cv_table(features_csv, label: str):
    """``(table, X, y)`` of the features stage's table for a cross-validation grouped by clip.

    Refused (naming the file and column) unless it holds at least two clips
    and two classes of ``label``.
    """
    table = contract.read_features(features_csv)
    need_several(table, "clip", features_csv, "to hold out in cross-validation grouped by clip")
    need_several(table, label, features_csv, f"(nnsf.label: {label}): precision over one class is "
                 "1.0 for any model")
    return table, contract.features(table), table[label].to_numpy()


def evaluate(params: dict, features_csv=FEATURES_CSV, reports=REPORTS, mapper=None) -> StageResult:
    """Grouped 10-fold CV: precision and reconstruction vs rank for every method.

    Writes ``reports/metrics.json`` (DVC metrics), the fold table
    ``reports/cv_folds.csv``, the summary ``reports/precision_vs_rank.csv``
    (mean ± sd), plot data ``reports/plots/{precision,recon_error}_vs_rank.csv``
    and the figures ``reports/figures/{precision,reconstruction}_vs_rank.png``.
    ``mapper(fn, jobs)`` fans the (method, rank, fold) fits out (see
    :func:`nnsf.evaluate.crossval.precision_vs_rank`).
    """
    ranks = [int(r) for r in require(params, "evaluate.ranks")]
    for r in ranks:
        check_rank(params, r, "evaluate.ranks")
    methods = list(require(params, "evaluate.methods"))
    n_splits = int(require(params, "evaluate.folds"))
    max_iter = int(require(params, "evaluate.max_iter"))
    seed = int(require(params, "seed"))
    label = label_column(params)
    kw = nnsf_params(params)
    nnsf_rank = int(require(params, "nnsf.rank"))
    table, X, y = cv_table(features_csv, label)
    groups = table["clip"].to_numpy()
    styles = table["character"].to_numpy()
    gp_params, phase = _gp_settings(params, table, methods)
    try:
        folds_table = precision_vs_rank(
            X, y, groups, styles=styles, methods=methods, ranks=ranks, n_splits=n_splits,
            seed=seed, max_iter=max_iter, nnsf_params=kw, n_jobs=2, mapper=mapper,
            phase=phase, gp_params=gp_params,
        )
    except ValueError as exc:
        if "fold" in str(exc) or "clips" in str(exc):
            raise InputError(source_of(params), "evaluate.folds", "at most the number of clips per class",
                             reason=str(exc)) from None
        raise
    summary = summarise(folds_table)
    reports = Path(reports)
    # Wall times vary from run to run, and iteration counts with the float noise of
    # another CPU wherever a tolerance stops a fit: both go to MLflow, not into the
    # versioned tables.
    fit_seconds = float(folds_table["seconds"].sum())
    iterations = folds_table.groupby("method", sort=False)["n_iter"].mean()
    chance = 1.0 / len(np.unique(y))
    metrics = _evaluate_metrics(summary, nnsf_rank, label, n_splits, chance)
    # The files are published as one set (nnsf.publish: staged, committed,
    # moved, manifest reports/evaluate.manifest.json last): a killed run
    # never leaves some new files beside old ones.
    with publishing(reports, "evaluate") as out:
        write_csv(out / "cv_folds.csv", folds_table.drop(columns=["seconds", "n_iter"]))
        write_csv(out / "precision_vs_rank.csv", summary.drop(columns=["seconds_mean"], errors="ignore"))
        write_csv(out / "plots" / "precision_vs_rank.csv", wide(summary, "precision_mean"))
        write_csv(out / "plots" / "recon_error_vs_rank.csv", wide(summary, "recon_error_mean"))
        staged = [
            precision_vs_rank_figure(
                summary, out / "figures" / "precision_vs_rank.png", chance=chance,
                title=f"Held-out precision vs rank ({label} classes, {n_splits}-fold CV grouped by clip)"),
            reconstruction_figure(summary, out / "figures" / "reconstruction_vs_rank.png"),
        ]
        write_json(out / "metrics.json", metrics)
    figs = [reports / Path(f).relative_to(out) for f in staged]
    flat = {f"{m}_{k}": v for m, d in metrics["methods"].items() for k, v in d.items()
            if isinstance(v, (int, float))}
    flat["cv_fit_seconds"] = round(fit_seconds, 3)
    flat.update({f"{m}_iterations_mean": float(n) for m, n in iterations.items()})
    return StageResult(
        params={"ranks": ",".join(map(str, ranks)), "methods": ",".join(methods), "folds": n_splits,
                "max_iter": max_iter, "seed": seed, "label": label, "rank": nnsf_rank, **kw,
                **{f"gp_{k}": v for k, v in (gp_params or {}).items()}},
        metrics=flat, artifacts=figs + [reports / "precision_vs_rank.csv"],
    )


def clip_phase(table: pd.DataFrame) -> np.ndarray:
    """Phase in [0, 1] of every row: its ``frame`` relative to its clip's first and last frame."""
    frame = table["frame"].to_numpy(float)
    by_clip = table.groupby("clip", sort=False)["frame"]
    lo = by_clip.transform("min").to_numpy(float)
    hi = by_clip.transform("max").to_numpy(float)
    return np.where(hi > lo, (frame - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0)


def _gp_settings(params: dict, table: pd.DataFrame, methods) -> tuple[dict | None, np.ndarray | None]:
    """``evaluate.gp`` settings and per-row phases when a GP baseline is requested, else (None, None).

    The subsample (``evaluate.gp.phase_bins`` bins per cell) cannot be larger
    than the data: every bin needs a frame even for a cell with one clip, so
    the bins may not outnumber the frames of the shortest clip.
    """
    if not any(m in ("mgpm", "cbgpm") for m in methods):
        return None, None
    bins = int(require(params, "evaluate.gp.phase_bins"))
    shortest = int(table.groupby("clip").size().min())
    if bins > shortest:
        raise InputError(source_of(params), "evaluate.gp.phase_bins",
                         f"at most the frames of the shortest clip ({shortest}); the GP models' "
                         "subsample cannot be larger than the data", bins)
    return {"phase_bins": bins, "max_iter": int(require(params, "evaluate.gp.max_iter"))}, clip_phase(table)


def _evaluate_metrics(summary: pd.DataFrame, nnsf_rank: int, label: str, folds: int, chance: float) -> dict:
    """metrics.json: per method the best precision and the values at ``nnsf.rank``."""
    out = {"label": label, "folds": folds, "chance_precision": chance, "methods": {}}
    for method, part in summary.groupby("method", sort=False):
        part = part.sort_values("rank")
        best = part.loc[part["precision_mean"].idxmax()]
        entry = {
            "best_precision": float(best["precision_mean"]),
            "best_rank": int(best["rank"]),
        }
        at = part[part["rank"] == nnsf_rank]
        if len(at):
            entry["precision_at_rank"] = float(at["precision_mean"].iloc[0])
            entry["precision_sd_at_rank"] = float(at["precision_sd"].iloc[0])
            entry["recon_error_at_rank"] = float(at["recon_error_mean"].iloc[0])
        for _, row in part.iterrows():
            entry[f"precision_k{int(row['rank'])}"] = float(row["precision_mean"])
        out["methods"][method] = entry
    return out


def isomap(params: dict, model=MODEL_PATH, features_csv=FEATURES_CSV, reports=REPORTS) -> StageResult:
    """ISOMAP of V (the paper's Fig. 6): residual variance and intrinsic dimension.

    The weights embedded are the training frames *encoded* with U fixed
    (``V_encoded``), the representation every new frame gets; the
    label-informed V of the fit collapses into class clusters when β is large.
    Rows are sampled evenly over characters (``isomap.samples``; ISOMAP
    needs O(n²) memory).  A disconnected neighbour graph is bridged by its
    closest pairs of points rather than by raising the neighbour count, which
    keeps the geodesics local.  Writes ``reports/isomap.json``, the curve
    ``reports/plots/isomap_residual.csv`` and ``reports/figures/isomap.png``
    (3D embedding coloured by character, residual-variance curve).
    """
    samples = int(require(params, "isomap.samples"))
    neighbors = int(require(params, "isomap.neighbors"))
    max_dim = int(require(params, "isomap.max_dim"))
    seed = int(require(params, "seed"))

    recover(reports, "factorize", wait=True)  # the model of a killed factorize: its set is settled first
    fitted = read_npz(model, NNSF_MODEL, what="model written by the factorize stage")
    V, characters = fitted["V_encoded"], fitted["character"]
    rows = stratified_sample(characters, samples, seed)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        dims, rv, embedding = residual_variance(V[rows], n_neighbors=neighbors, max_dim=max_dim,
                                                disconnected="bridge")
    notes = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    dim = intrinsic_dimension(dims, rv)
    result = {
        "intrinsic_dimension": int(dim),
        "residual_variance_at_intrinsic": float(rv[dim - 1]),
        "residual_variance_3d": float(rv[min(3, len(rv)) - 1]),
        "samples": int(len(rows)),
        "notes": notes,
    }

    def write(out: Path) -> StageResult:
        write_csv(out / "plots" / "isomap_residual.csv",
                  pd.DataFrame({"dim": dims, "residual_variance": rv}))
        fig = isomap_figure(embedding[:, :3], characters[rows], dims, rv, dim,
                            out / "figures" / "isomap.png",
                            title=f"ISOMAP of the NNSF weights V, frames encoded with U fixed "
                                  f"({len(rows)} frames, rank {V.shape[1]})")
        write_json(out / "isomap.json", result)
        return StageResult(
            params={"samples": samples, "neighbors": neighbors, "max_dim": max_dim, "seed": seed},
            metrics={k: v for k, v in result.items() if not isinstance(v, list)}, artifacts=[fig],
        )

    return publish_stage("isomap", reports, "isomap.json", write)


def sweep_grid(params: dict) -> list[dict]:
    """The α/β/rank points of ``sweep``: a list of ``{"alpha", "beta", "rank"}`` dicts."""
    ranks = [int(r) for r in require(params, "sweep.rank")]
    for r in ranks:
        check_rank(params, r, "sweep.rank")
    return [
        {"alpha": float(a), "beta": float(b), "rank": r}
        for a, b, r in itertools.product(require(params, "sweep.alpha"), require(params, "sweep.beta"), ranks)
    ]


def sweep_point(params: dict, point: dict, features_csv=FEATURES_CSV, figure_dir=None) -> StageResult:
    """Cross-validate NNSF at one sweep point (``sweep.folds`` folds, grouped by clip).

    Metrics: mean and sd over folds of held-out macro precision and relative
    reconstruction error.  With ``figure_dir``, also draws the per-fold
    precision and the basis of a fit on all frames at this point.
    """
    kw = nnsf_params(params)
    kw.update(alpha=float(point["alpha"]), beta=float(point["beta"]))
    rank = int(point["rank"])
    check_rank(params, rank, "sweep.rank")
    seed = int(require(params, "seed"))
    n_splits = int(require(params, "sweep.folds"))
    max_iter = int(require(params, "sweep.max_iter"))
    label = label_column(params)
    table, X, y = cv_table(features_csv, label)
    folds_table = precision_vs_rank(
        X, y, table["clip"].to_numpy(), methods=["nnsf"], ranks=[rank], n_splits=n_splits, seed=seed,
        max_iter=max_iter, nnsf_params=kw, n_jobs=1,
    )
    prec = folds_table["precision"].to_numpy(float)
    err = folds_table["recon_error"].to_numpy(float)
    metrics = {
        "precision_mean": float(prec.mean()), "precision_sd": float(prec.std(ddof=1)) if len(prec) > 1 else 0.0,
        "recon_error_mean": float(err.mean()), "recon_error_sd": float(err.std(ddof=1)) if len(err) > 1 else 0.0,
        "seconds": float(folds_table["seconds"].sum()),
    }
    artifacts = []
    if figure_dir is not None:
        name = f"sweep_a{kw['alpha']:g}_b{kw['beta']:g}_k{rank}.png"
        artifacts.append(fold_figure(folds_table, Path(figure_dir) / name,
                                     title=f"α = {kw['alpha']:g}, β = {kw['beta']:g}, rank {rank}"))
    return StageResult(params={"alpha": kw["alpha"], "beta": kw["beta"], "rank": rank,
                               "folds": n_splits, "max_iter": max_iter, "label": label},
                       metrics=metrics, artifacts=artifacts)

