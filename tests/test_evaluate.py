"""Evaluation: grouped CV folds, precision vs rank, ISOMAP diagnostics, figures."""
from __future__ import annotations

import struct
import warnings

import numpy as np
import pandas as pd
import pytest
from sklearn.datasets import make_swiss_roll

from nnsf.evaluate.crossval import (TABLE_COLUMNS, folds, max_rank, precision_vs_rank,
                                    summarise, wide)
from nnsf.evaluate.figures import isomap_figure, precision_vs_rank_figure, reconstruction_figure
from nnsf.evaluate.isomap import (connected_n_neighbors, intrinsic_dimension, residual_variance,
                                  stratified_sample)

#: The four classic methods; the GP baselines have their own tests (tests/test_gp_baselines.py).
METHODS = ("nnsf", "nnsc", "nmf", "bilinear")


# --------------------------------------------------------------------------- data
def cartoon(n_classes=4, n_styles=3, clips=5, frames=8, d=16, noise=0.02, seed=0):
    """Well-separated motions: each lights up its own block of features, scaled per
    character.  Returns X (n, d) ≥ 0, motion, clip and character labels."""
    patterns = np.random.default_rng(99).random((n_classes, d // n_classes)) + 1.0
    style_gain = np.random.default_rng(98).random((n_styles, d)) * 0.5 + 0.75
    rng = np.random.default_rng(seed)
    b = d // n_classes
    X, y, g, s = [], [], [], []
    for c in range(n_classes):
        for st in range(n_styles):
            for k in range(clips):
                p = np.zeros(d)
                p[c * b:(c + 1) * b] = patterns[c]
                amp = 0.5 + rng.random((frames, 1))
                X.append(amp * p * style_gain[st] + noise * rng.random((frames, d)))
                y += [f"m{c}"] * frames
                g += [f"clip{c}-{st}-{k}"] * frames
                s += [f"char{st}"] * frames
    return np.vstack(X), np.array(y), np.array(g), np.array(s)


@pytest.fixture(scope="module")
def table():
    X, y, g, s = cartoon()
    with warnings.catch_warnings():
        warnings.simplefilter("error")        # the sweep itself must not spam warnings
        return precision_vs_rank(X, y, g, s, methods=METHODS, ranks=[1, 4, 20], n_splits=5,
                                 seed=0, max_iter=100, nnsf_params={"alpha": 0.0, "beta": 1.0})


# --------------------------------------------------------------------------- folds
def test_folds_keep_clips_whole_and_cover_every_class():
    X, y, g, _ = cartoon(clips=7)
    splits = folds(y, g, n_splits=5, seed=3)
    assert len(splits) == 5
    seen = np.concatenate([te for _, te in splits])
    assert np.array_equal(np.sort(seen), np.arange(len(y)))           # a partition of the rows
    for train, test in splits:
        assert not set(g[train]) & set(g[test])                        # no clip on both sides
        assert len(np.intersect1d(train, test)) == 0
        assert set(y[test]) == set(y)                                  # every class in every test fold


def test_folds_are_deterministic_given_seed():
    _, y, g, _ = cartoon(clips=7)
    a = folds(y, g, 5, seed=1)
    b = folds(y, g, 5, seed=1)
    c = folds(y, g, 5, seed=2)
    assert all(np.array_equal(x[1], z[1]) for x, z in zip(a, b))
    assert not all(np.array_equal(x[1], z[1]) for x, z in zip(a, c))


def test_folds_reject_too_few_clips_per_class():
    _, y, g, _ = cartoon(n_styles=1, clips=3)
    with pytest.raises(ValueError, match="at least 5 clips per class"):
        folds(y, g, n_splits=5)
    with pytest.raises(ValueError, match="n_splits"):
        folds(y, g, n_splits=1)


# -------------------------------------------------------------- precision vs rank
def test_table_layout_and_rank_clipping(table):
    assert list(table.columns) == list(TABLE_COLUMNS)
    assert len(table) == 4 * 3 * 5
    # d = 16: rank 20 runs at 16 for the factorisations; the bilinear model stops at C = 4.
    assert max_rank("nmf", 16, 3, 4) == 16 and max_rank("bilinear", 16, 3, 4) == 4
    r20 = table[table["rank"] == 20].groupby("method")["rank_used"].first()
    assert r20.to_dict() == {"nnsf": 16, "nnsc": 16, "nmf": 16, "bilinear": 4}
    assert table.loc[table["rank"] == 20, "note"].str.startswith("clipped from 20").all()
    assert (table.loc[table["rank"] <= 4, "note"] == "").all()
    # A clipped rank reuses the fit of the rank it clips to.
    bil = table[table["method"] == "bilinear"].set_index(["rank", "fold"])
    np.testing.assert_array_equal(bil.loc[20, "precision"], bil.loc[4, "precision"])
    assert table["precision"].between(0, 1).all() and (table["recon_error"] > 0).all()


def test_precision_reaches_one_at_sufficient_rank(table):
    mean = table.groupby(["method", "rank"])["precision"].mean()
    for method in METHODS:
        assert mean[(method, 4)] >= 0.99, method        # rank = number of classes separates them
    for method in ("nnsf", "nnsc", "nmf"):
        # Rank 1: V W predicts a single class, macro precision = (1/C) / C.
        assert mean[(method, 1)] == pytest.approx(1 / 16, abs=0.02), method
    err = table.groupby(["method", "rank"])["recon_error"].mean()
    assert err[("nmf", 20)] < err[("nmf", 4)] < err[("nmf", 1)]


def test_precision_vs_rank_is_deterministic(table):
    X, y, g, s = cartoon()
    again = precision_vs_rank(X, y, g, s, methods=METHODS, ranks=[1, 4, 20], n_splits=5, seed=0,
                              max_iter=100, nnsf_params={"alpha": 0.0, "beta": 1.0})
    cols = [c for c in TABLE_COLUMNS if c != "seconds"]
    pd.testing.assert_frame_equal(table[cols], again[cols])


@pytest.mark.slow  # n_jobs=2: joblib starts worker processes
def test_precision_vs_rank_parallel_matches_serial():
    X, y, g, s = cartoon(n_classes=2, n_styles=2, clips=3, d=8)
    kw = dict(methods=["nmf", "bilinear"], ranks=[2], n_splits=3, seed=0, max_iter=50)
    one = precision_vs_rank(X, y, g, s, n_jobs=1, **kw)
    two = precision_vs_rank(X, y, g, s, n_jobs=2, **kw)
    cols = [c for c in TABLE_COLUMNS if c != "seconds"]
    pd.testing.assert_frame_equal(one[cols], two[cols])


def test_precision_vs_rank_rejects_bad_arguments():
    X, y, g, s = cartoon(clips=5)
    with pytest.raises(ValueError, match="methods"):
        precision_vs_rank(X, y, g, s, methods=["pca"], ranks=[2], n_splits=5)
    with pytest.raises(ValueError, match="ranks"):
        precision_vs_rank(X, y, g, s, methods=["nmf"], ranks=[0], n_splits=5)
    with pytest.raises(ValueError, match="needs styles"):
        precision_vs_rank(X, y, g, None, methods=["bilinear"], ranks=[2], n_splits=5)
    with pytest.raises(ValueError, match="unknown parameter"):
        precision_vs_rank(X, y, g, s, methods=["nnsf"], ranks=[2], n_splits=5,
                          nnsf_params={"gamma": 1.0})
    with pytest.raises(ValueError, match="one entry per row"):
        precision_vs_rank(X, y[:-1], g, s, methods=["nmf"], ranks=[2], n_splits=5)


def test_summarise_and_wide(table):
    summary = summarise(table)
    assert len(summary) == 4 * 3
    assert list(dict.fromkeys(summary["method"])) == list(METHODS)
    sel = table[(table["method"] == "nmf") & (table["rank"] == 4)]
    row = summary[(summary["method"] == "nmf") & (summary["rank"] == 4)].iloc[0]
    assert row["precision_mean"] == pytest.approx(sel["precision"].mean())
    assert row["recon_error_sd"] == pytest.approx(sel["recon_error"].std(ddof=1))
    assert row["n_folds"] == 5 and row["rank_used"] == 4
    w = wide(summary, "precision_mean")
    assert list(w.columns) == ["rank", "nnsf", "nnsc", "nmf", "bilinear"]
    assert list(w["rank"]) == [1, 4, 20]
    assert w.loc[w["rank"] == 4, "nmf"].item() == pytest.approx(row["precision_mean"])
    with pytest.raises(ValueError, match="no column"):
        wide(summary, "f1_mean")


# ------------------------------------------------------------------------- ISOMAP
def test_plane_in_10d_has_dimension_two():
    rng = np.random.default_rng(0)
    basis = np.linalg.qr(rng.standard_normal((10, 10)))[0][:, :2]
    X = (rng.random((400, 2)) * [3.0, 1.0]) @ basis.T + 5.0
    dims, rv, emb = residual_variance(X, n_neighbors=10, max_dim=6)
    assert list(dims) == [1, 2, 3, 4, 5, 6] and emb.shape == (400, 6)
    assert rv[0] > 0.02 and rv[1] < 0.005
    assert intrinsic_dimension(dims, rv) == 2


def test_swiss_roll_has_dimension_two():
    X, _ = make_swiss_roll(800, noise=0.0, random_state=0)
    dims, rv, _ = residual_variance(X, n_neighbors=8, max_dim=3)
    assert rv[1] < 0.005 < rv[0] - rv[1]        # ISOMAP unrolls it: d = 2 captures the geodesics
    assert intrinsic_dimension(dims, rv) == 2


def test_curve_has_dimension_one():
    t = np.linspace(0, 4 * np.pi, 300)
    X = np.c_[np.cos(t), np.sin(t), 0.3 * t, np.cos(2 * t), np.zeros_like(t)]   # a 1-D curve in 5-D
    dims, rv, _ = residual_variance(X, n_neighbors=6, max_dim=5)
    assert rv[0] < 1e-3
    assert intrinsic_dimension(dims, rv) == 1


def test_residual_variance_is_one_minus_squared_correlation():
    # Hand check at d = 1 against scikit-learn's Isomap directly.
    from scipy.spatial.distance import pdist
    from sklearn.manifold import Isomap

    X = np.random.default_rng(1).random((60, 4))
    dims, rv, emb = residual_variance(X, n_neighbors=8, max_dim=3)
    iso = Isomap(n_neighbors=8, n_components=3, eigen_solver="dense").fit(X)
    geo = iso.dist_matrix_[np.triu_indices(60, 1)]
    r = np.corrcoef(geo, pdist(iso.embedding_[:, :1]))[0, 1]
    assert rv[0] == pytest.approx(1 - r ** 2, rel=1e-9)
    assert np.all(np.diff(rv) <= 1e-9)


def test_disconnected_graph_raises_neighbours_to_the_smallest_connecting_value():
    rng = np.random.default_rng(2)
    X = np.vstack([rng.random((30, 3)), rng.random((30, 3)) + 50.0])    # two far-apart clusters
    k = connected_n_neighbors(X, 5)
    assert k == 30                 # a point needs all 29 of its cluster plus one across the gap
    with pytest.warns(UserWarning, match="n_neighbors=30"):
        dims, rv, emb = residual_variance(X, n_neighbors=5, max_dim=3)
    assert np.isfinite(rv).all() and np.isfinite(emb).all() and emb.shape[0] == 60
    with pytest.warns(UserWarning, match="bridged"):
        _, rv_b, emb_b = residual_variance(X, n_neighbors=5, max_dim=3, disconnected="bridge")
    assert np.isfinite(rv_b).all() and emb_b.shape[0] == 60
    assert connected_n_neighbors(rng.random((40, 2)), 10) == 10


def test_intrinsic_dimension_rule():
    dims = np.arange(1, 7)
    assert intrinsic_dimension(dims, np.array([0.5, 0.2, 0.05, 0.045, 0.044, 0.043])) == 3
    assert intrinsic_dimension(dims, np.array([0.5, 0.4, 0.3, 0.2, 0.1, 0.0])) == 6   # never flattens
    assert intrinsic_dimension(dims, np.array([0.3, 0.28, 0.1, 0.0, 0.0, 0.0]), threshold=0.05) == 1
    with pytest.raises(ValueError):
        intrinsic_dimension(dims, np.zeros(5))


def test_stratified_sample_is_balanced_and_water_fills():
    labels = np.array(["a"] * 100 + ["b"] * 100 + ["c"] * 5)
    idx = stratified_sample(labels, 60, seed=0)
    assert len(idx) == 60 and len(np.unique(idx)) == 60 and np.all(np.diff(idx) > 0)
    counts = pd.Series(labels[idx]).value_counts().to_dict()
    assert counts == {"a": 28, "b": 27, "c": 5} or counts == {"a": 27, "b": 28, "c": 5}
    assert np.array_equal(idx, stratified_sample(labels, 60, seed=0))
    assert not np.array_equal(idx, stratified_sample(labels, 60, seed=1))
    assert np.array_equal(stratified_sample(labels, 500), np.arange(205))
    even = stratified_sample(np.repeat(np.arange(4), 50), 20, seed=0)
    assert np.bincount(np.repeat(np.arange(4), 50)[even]).tolist() == [5, 5, 5, 5]


# ------------------------------------------------------------------------ figures
def _png_size(path):
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


def test_figures_are_written_atomically_at_the_promised_size(table, tmp_path):
    summary = summarise(table)
    p = precision_vs_rank_figure(summary, tmp_path / "precision.png", chance=0.25)
    r = reconstruction_figure(summary, tmp_path / "recon.png")
    assert _png_size(p) == (1200, 750) and _png_size(r) == (1200, 750)   # 8 × 5 in at 150 dpi
    rng = np.random.default_rng(0)
    emb = rng.standard_normal((90, 2))                                   # padded to 3-D
    dims = np.arange(1, 8)
    i = isomap_figure(emb, np.repeat(["x", "y", "z"], 30), dims, 0.5 ** dims, 3, tmp_path / "iso.png")
    assert _png_size(i) == (1800, 825)
    assert sorted(f.name for f in tmp_path.iterdir()) == ["iso.png", "precision.png", "recon.png"]


def test_figure_errors_leave_no_file(tmp_path):
    with pytest.raises(ValueError, match="lacks column"):
        precision_vs_rank_figure(pd.DataFrame({"method": ["nmf"]}), tmp_path / "p.png")
    with pytest.raises(ValueError, match="disagree"):
        isomap_figure(np.zeros((5, 3)), np.zeros(4), [1], [0.1], 1, tmp_path / "i.png")
    assert list(tmp_path.iterdir()) == []
