"""The Gaussian-process baselines of Fig. 7: MGPM (Wang et al. 2007) and CBGPM (after Ma et al. 2009).

Oracles: finite differences for the analytic gradients, data drawn from the
MGPM's own generative model (the fit must recover a hidden combination
better than the bilinear model), and a style whose answer is known exactly
for the CBGPM.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from scipy.optimize import approx_fprime

from nnsf.datasets.contract import COLUMNS
from nnsf.errors import InputError
from nnsf.evaluate.crossval import max_rank, precision_vs_rank
from nnsf.evaluate.gp_translation import fit_gp_translator, gp_translate, translation_gp_params
from nnsf.factor.baselines import BilinearModel
from nnsf.factor.cbgpm import CBGPM, additive_fit, neg_log_marginal
from nnsf.factor.gp_data import phase_bins, phase_from_groups
from nnsf.factor.mgpm import MGPM, neg_log_posterior

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(autouse=True)
def one_blas_thread():
    """Small matrices: threaded BLAS only adds contention on a shared 2-core machine."""
    from threadpoolctl import threadpool_limits
    with threadpool_limits(1, user_api="blas"):
        yield


# ------------------------------------------------------------------ gradients
def test_mgpm_gradient_matches_finite_differences():
    rng = np.random.default_rng(0)
    S, C, q_s, q_c, n, d = 3, 4, 2, 3, 30, 5
    theta = rng.normal(size=S * q_s + C * q_c + 3)
    theta[-3:] = np.log(5.0), np.log(0.3), np.log(20.0)
    Y = rng.normal(size=(n, d))
    args = (Y, rng.integers(0, S, n), rng.integers(0, C, n), rng.random(n), S, C, q_s, q_c)
    value, grad = neg_log_posterior(theta, *args)
    fd = approx_fprime(theta, lambda t: neg_log_posterior(t, *args)[0], 1e-6)
    np.testing.assert_allclose(grad, fd, rtol=1e-4, atol=1e-4 * np.abs(fd).max())
    assert np.isfinite(value)


def test_cbgpm_gradient_matches_finite_differences():
    rng = np.random.default_rng(1)
    inputs = [rng.normal(size=(12, 3)), rng.normal(size=(9, 3))]
    targets = [rng.normal(size=(12, 3)), rng.normal(size=(9, 3))]
    theta = np.array([np.log(0.7), np.log(1.3)])
    _, grad = neg_log_marginal(theta, inputs, targets, 1e-3)
    fd = approx_fprime(theta, lambda t: neg_log_marginal(t, inputs, targets, 1e-3)[0], 1e-7)
    np.testing.assert_allclose(grad, fd, rtol=1e-4)


# ------------------------------------------------------------------ data helpers
def grid_table(values, T):
    """Rows of a full (style, content) grid with one clip of ``T`` frames per cell.

    ``values`` is (S, C, T, d); returns X (n, d), content, style, clip, phase.
    """
    S, C = values.shape[:2]
    X, y, s, g = [], [], [], []
    for i in range(S):
        for j in range(C):
            X.append(values[i, j])
            y += [f"c{j}"] * T
            s += [f"s{i}"] * T
            g += [f"s{i}-c{j}"] * T
    g = np.array(g)
    return np.vstack(X), np.array(y), np.array(s), g, phase_from_groups(g)


def mgpm_draw(S=4, C=4, T=10, d=6, q=2, gamma=8.0, noise=1e-3, seed=0):
    """Poses drawn from the MGPM's own prior: product of linear style, linear content, RBF phase."""
    rng = np.random.default_rng(seed)
    sv, cv = rng.normal(size=(S, q)), rng.normal(size=(C, q))
    si, ci, ti = np.meshgrid(np.arange(S), np.arange(C), np.arange(T), indexing="ij")
    si, ci, ti = si.ravel(), ci.ravel(), ti.ravel()
    phi = ti / (T - 1)
    K = (sv[si] @ sv[si].T) * (cv[ci] @ cv[ci].T) * np.exp(-0.5 * gamma * (phi[:, None] - phi[None]) ** 2)
    K[np.diag_indices_from(K)] += noise
    F = np.linalg.cholesky(K) @ rng.normal(size=(len(K), d))
    return F.reshape(S, C, T, d)


# ------------------------------------------------------------------ MGPM oracle
def test_mgpm_recovers_a_hidden_combination_of_its_own_model_better_than_bilinear():
    T = 10
    values = mgpm_draw(T=T)
    X, y, s, g, phase = grid_table(values, T)
    hide = (s == "s0") & (y == "c0")
    truth = values[0, 0]
    model = MGPM(n_components=2, phase_bins=T, max_iter=200, random_state=0).fit(
        X[~hide], y[~hide], s[~hide], phase[~hide])
    err_gp = np.sqrt(np.mean((model.synthesize("s0", "c0", np.linspace(0, 1, T)) - truth) ** 2))

    bil = BilinearModel(n_components=2).fit(X[~hide], y[~hide], s[~hide])
    err_template = np.sqrt(np.mean((bil.cell_template("s0", "c0") - truth) ** 2))
    # Bilinear translation of every other style's c0 clip, frame by frame: A^t (A^s)⁺ x.
    errs = []
    for src in ("s1", "s2", "s3"):
        Xs = X[(s == src) & (y == "c0")]
        B = bil.transform(Xs, np.full(T, src))
        errs.append(np.sqrt(np.mean((bil.inverse_transform(B, np.full(T, "s0")) - truth) ** 2)))
    scale = np.sqrt(np.mean(truth ** 2))
    assert err_gp < 0.5 * min(err_template, min(errs)), (err_gp, err_template, errs)
    assert err_gp < 0.25 * scale, (err_gp, scale)


def test_mgpm_fits_and_classifies_with_state():
    T = 10
    values = mgpm_draw(T=T, seed=3)
    X, y, s, g, phase = grid_table(values, T)
    model = MGPM(n_components=2, phase_bins=5, max_iter=100, random_state=0).fit(X, y, s, groups=g)
    assert model.n_train_points_ == 4 * 4 * 5
    assert model.style_vectors_.shape == (4, 2) and model.content_vectors_.shape == (4, 2)
    assert (model.predict(X, s) == y).mean() > 0.9
    assert model.reconstruct(X[:7], s[:7]).shape == (7, 6)
    # The fit is deterministic given random_state.
    again = MGPM(n_components=2, phase_bins=5, max_iter=100, random_state=0).fit(X, y, s, groups=g)
    np.testing.assert_array_equal(model.style_vectors_, again.style_vectors_)


# ------------------------------------------------------------------ CBGPM known answers
def offset_styles(S=4, C=5, T=8, d=6, seed=0):
    """Every style is one common motion per content plus a constant pose offset of its own."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 1, T)[:, None]
    motion = rng.normal(size=(C, 1, d)) + np.sin(2 * np.pi * t * rng.uniform(0.5, 1.5, (C, 1, d)))
    offsets = rng.normal(size=(S, 1, 1, d))
    return motion[None] + offsets, offsets


def test_additive_fit_is_exact_on_an_additive_grid_with_a_missing_cell():
    values, offsets = offset_styles()
    observed = np.ones(values.shape[:3], bool)
    observed[0, 0] = False
    mu, off = additive_fit(values, observed)
    np.testing.assert_allclose(mu[None] + off[:, None, None, :], values, atol=1e-9)


def test_cbgpm_constant_style_offset_recovers_a_hidden_cell_exactly():
    T = 8
    values, _ = offset_styles(T=T)
    X, y, s, g, phase = grid_table(values, T)
    hide = (s == "s0") & (y == "c0")
    model = CBGPM(n_components=6, phase_bins=T).fit(X[~hide], y[~hide], s[~hide], phase[~hide])
    # Bin centres of 8 bins over 8 frames sit at the frames' own phases only at the middle;
    # compare at the bin centres, where the templates live.
    centres = (np.arange(T) + 0.5) / T
    got = model.synthesize("s0", "c0", centres)
    np.testing.assert_allclose(got, values[0, 0], atol=1e-6)


def test_cbgpm_meets_its_constraints_on_observed_cells():
    rng = np.random.default_rng(2)
    T = 6
    values, _ = offset_styles(T=T, seed=4)
    values = values + 0.3 * rng.normal(size=values.shape)          # a pose-dependent style on top
    X, y, s, g, phase = grid_table(values, T)
    model = CBGPM(n_components=6, phase_bins=3, jitter=1e-8).fit(X, y, s, phase)
    _, _, means, observed, _ = phase_bins(X, s, y, phase, 3)
    centres = (np.arange(3) + 0.5) / 3
    for i in range(4):
        for j in range(5):
            np.testing.assert_allclose(model.synthesize(f"s{i}", f"c{j}", centres), means[i, j], atol=1e-5)
    assert (model.predict(X, s) == y).mean() > 0.9


# ------------------------------------------------------------------ cross-validation
def test_precision_vs_rank_runs_both_gp_models_and_clips_the_mgpm_rank():
    T = 8
    values, _ = offset_styles(S=3, C=4, T=T, seed=5)
    rng = np.random.default_rng(0)
    rows = []
    for k in range(3):                                                 # three clips per cell
        X, y, s, g, ph = grid_table(values + 0.05 * rng.normal(size=values.shape), T)
        rows.append(pd.DataFrame({"y": y, "s": s, "g": [f"{c}-{k}" for c in g], "ph": ph}).join(
            pd.DataFrame(X)))
    t = pd.concat(rows, ignore_index=True)
    X = t[list(range(6))].to_numpy()
    table = precision_vs_rank(X, t["y"].to_numpy(), t["g"].to_numpy(), t["s"].to_numpy(),
                              methods=["mgpm", "cbgpm"], ranks=[2, 6], n_splits=3, seed=0,
                              phase=t["ph"].to_numpy(), gp_params={"phase_bins": 2, "max_iter": 30})
    used = table.groupby(["method", "rank"])["rank_used"].first().to_dict()
    assert max_rank("mgpm", 6, 3, 4) == 4
    assert used == {("cbgpm", 2): 2, ("cbgpm", 6): 6, ("mgpm", 2): 2, ("mgpm", 6): 4}
    assert table.loc[(table["method"] == "mgpm") & (table["rank"] == 6), "note"].str.startswith(
        "clipped from 6 to 4").all()
    mean = table.groupby(["method", "rank"])["precision"].mean()
    assert mean[("cbgpm", 6)] > 0.9 and mean[("mgpm", 6)] > 0.9, mean
    with pytest.raises(ValueError, match="gp_params"):
        precision_vs_rank(X, t["y"].to_numpy(), t["g"].to_numpy(), t["s"].to_numpy(), methods=["mgpm"],
                          ranks=[2], n_splits=3, gp_params={"bins": 2})


# ------------------------------------------------------------------ bad input
def test_estimators_reject_a_rank_above_their_limit_and_a_subsample_larger_than_the_data():
    values, _ = offset_styles(S=3, C=4, T=5)
    X, y, s, g, ph = grid_table(values, 5)
    with pytest.raises(ValueError, match=r"n_components=5 exceeds the MGPM's limit .* max\(3, 4\) = 4"):
        MGPM(n_components=5).fit(X, y, s, ph)
    with pytest.raises(ValueError, match="n_components=7 exceeds the CBGPM's limit"):
        CBGPM(n_components=7).fit(X, y, s, ph)                     # d = 6 features
    for model in (MGPM(n_components=2, phase_bins=6), CBGPM(n_components=2, phase_bins=6)):
        with pytest.raises(ValueError, match=r"phase_bins=6 exceeds the frames of the smallest .*\(5\)"):
            model.fit(X, y, s, ph)
    with pytest.raises(ValueError, match="needs phase"):
        MGPM(n_components=2).fit(X, y, s)


def _contract_table(S=2, C=3, clips=2, T=6):
    rng = np.random.default_rng(0)
    rows = [[f"ch{i}-m{j}-{k}", f, f"ch{i}", f"m{j}", *rng.uniform(0.5, 3.0, 34)]
            for i in range(S) for j in range(C) for k in range(clips) for f in range(T)]
    return pd.DataFrame(rows, columns=list(COLUMNS))


def test_translation_gp_params_name_the_field():
    table = _contract_table()
    ok = {"translation": {"gp_rank": 3, "gp_phase_bins": 6, "gp_max_iter": 10}}
    assert translation_gp_params(ok, table) == {"rank": 3, "phase_bins": 6, "max_iter": 10}
    with pytest.raises(InputError, match=r"^params.yaml: translation.gp_rank: expected a rank of at most "
                                         r"max\(styles, contents\) = max\(2, 3\)"):
        translation_gp_params({"translation": {**ok["translation"], "gp_rank": 4}}, table)
    with pytest.raises(InputError, match=r"translation.gp_phase_bins: expected at most the frames of the "
                                         r"shortest clip \(6\)"):
        translation_gp_params({"translation": {**ok["translation"], "gp_phase_bins": 7}}, table)


@pytest.mark.parametrize("method", ["mgpm", "cbgpm"])
def test_gp_translate_synthesises_the_hidden_cell(method):
    T = 8
    values, _ = offset_styles(T=T, seed=7)
    X, y, s, g, ph = grid_table(values, T)
    hide = (s == "s1") & (y == "c2")
    model = fit_gp_translator(method, X[~hide], y[~hide], s[~hide], g[~hide], rank=4, phase_bins=4,
                              max_iter=60)
    src = (s == "s0") & (y == "c2")
    out = gp_translate(model, X[src], "s0", "s1", "c2")
    assert out.shape == (T, 6)
    # Constant offsets: source + (offset_1 - offset_0) is the answer, up to the model's fit.
    err = np.sqrt(np.mean((out - values[1, 2]) ** 2))
    copy = np.sqrt(np.mean((X[src] - values[1, 2]) ** 2))
    assert err < 0.2 * copy, (err, copy)


@pytest.mark.slow  # starts `nnsf evaluate` as a process
def test_evaluate_stage_exits_2_on_a_subsample_larger_than_the_data(tmp_path):
    table = _contract_table(S=2, C=2, clips=10, T=6)
    path = tmp_path / "data" / "features" / "features.csv"
    path.parent.mkdir(parents=True)
    table.to_csv(path, index=False)
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["evaluate"].update(ranks=[2], folds=2)
    params["evaluate"]["gp"]["phase_bins"] = 7
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    result = subprocess.run([sys.executable, "-m", "nnsf.cli", "evaluate"], cwd=tmp_path, env=env,
                            capture_output=True, text=True, timeout=120)
    lines = result.stderr.strip().splitlines()
    assert result.returncode == 2, result.stderr
    assert lines == ["error: params.yaml: evaluate.gp.phase_bins: expected at most the frames of the "
                     "shortest clip (6); the GP models' subsample cannot be larger than the data, got 7"]
    assert not (tmp_path / "reports").exists()


# ------------------------------------------------------------------ scikit-learn conventions
@pytest.mark.parametrize("Estimator", [MGPM, CBGPM])
def test_scikit_learn_conventions_that_do_not_need_fit_x_y(Estimator):
    """check_estimator as a whole cannot pass: fit needs each row's style and phase (or clip)
    besides X and y, and its checks call fit(X, y).  The checks of construction do apply."""
    from sklearn.base import clone
    from sklearn.utils.estimator_checks import (check_get_params_invariance,
                                                check_no_attributes_set_in_init,
                                                check_parameters_default_constructible)
    name = Estimator.__name__
    check_parameters_default_constructible(name, Estimator())
    check_no_attributes_set_in_init(name, Estimator())
    check_get_params_invariance(name, Estimator())
    est = Estimator(n_components=2, phase_bins=2)
    assert clone(est).get_params() == est.get_params()
    X, y, s, g, ph = grid_table(offset_styles(S=2, C=3, T=4)[0], 4)
    fitted = est.fit(X, y, s, ph)
    assert fitted is est and not hasattr(clone(est), "classes_")


def test_dvc_plots_show_every_method_of_the_precision_vs_rank_stage():
    """dvc.yaml's plots draw precision (and reconstruction error) vs rank for every method the
    evaluate stage runs by default, the GP models included."""
    dvc = yaml.safe_load((ROOT / "dvc.yaml").read_text())
    methods = yaml.safe_load((ROOT / "params.yaml").read_text())["evaluate"]["methods"]
    plots = {k: v for p in dvc["plots"] if isinstance(p, dict) for k, v in p.items()}
    for name, csv in (("precision_vs_rank", "reports/plots/precision_vs_rank.csv"),
                      ("recon_error_vs_rank", "reports/plots/recon_error_vs_rank.csv")):
        assert plots[name]["y"][csv] == methods, name
    assert {"mgpm", "cbgpm"} <= set(methods)
