"""The NNSF estimator against oracles: scikit-learn's NMF, analytic cases, invariants."""
from __future__ import annotations

import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from sklearn.decomposition import non_negative_factorization
from sklearn.linear_model import LogisticRegression
from sklearn.model_selection import GridSearchCV
from sklearn.pipeline import Pipeline
from sklearn.utils.estimator_checks import check_estimator

from nnsf import NNSF
from nnsf.factor.updates import weights_for_basis


def _random_basis(rng, k, d):
    U = rng.random((k, d))
    return U / np.linalg.norm(U, axis=1, keepdims=True)


@pytest.mark.parametrize("alpha", [0.0, 0.05, 0.7])
@pytest.mark.parametrize("k", [1, 7, 34])
def test_weight_update_equals_sklearn_mu(alpha, k):
    """docs/method.md §6.4's oracle: the same weights as non_negative_factorization, bit for bit."""
    rng = np.random.default_rng(k)
    X = rng.random((800, 34)) * 3
    U = _random_basis(rng, k, 34)
    T = 40
    ours = weights_for_basis(X, U, alpha=alpha, max_iter=T, tol=0)
    theirs, _, n_iter = non_negative_factorization(
        X, H=U.copy(), n_components=k, update_H=False, solver="mu", beta_loss="frobenius",
        alpha_W=alpha / 34, alpha_H=0.0, l1_ratio=1.0, tol=0, max_iter=T,
    )
    assert n_iter == T
    np.testing.assert_allclose(ours, theirs, rtol=1e-12, atol=0)


def test_transform_is_the_oracle_update():
    rng = np.random.default_rng(3)
    X = rng.random((300, 12))
    model = NNSF(5, alpha=0.1, max_iter=25, tol=0, random_state=0).fit(X)
    theirs, _, _ = non_negative_factorization(
        X, H=model.components_.copy(), n_components=5, update_H=False, solver="mu",
        alpha_W=0.1 / 12, alpha_H=0.0, l1_ratio=1.0, tol=0, max_iter=25,
    )
    np.testing.assert_allclose(model.transform(X), theirs, rtol=1e-12, atol=0)


@settings(max_examples=25, deadline=None)
@given(
    n=st.integers(5, 120), d=st.integers(2, 20), k_frac=st.floats(0.1, 1.0),
    alpha=st.sampled_from([0.0, 0.01, 0.5]), seed=st.integers(0, 2**16),
    init=st.sampled_from(["random", "nndsvda", "nndsvd"]),
)
def test_objective_never_increases_without_class_term(n, d, k_frac, alpha, seed, init):
    rng = np.random.default_rng(seed)
    X = rng.random((n, d)) ** 2
    k = max(1, min(d, n, int(round(k_frac * d))))
    model = NNSF(k, alpha=alpha, beta=0.0, max_iter=60, tol=0, init=init, random_state=seed)
    V = model.fit_weights(X)
    hist = model.objective_
    assert np.all(np.diff(hist) <= 1e-10 * np.abs(hist[:-1]) + 1e-12)
    assert np.all(model.components_ >= 0) and np.all(V >= 0)
    np.testing.assert_allclose(np.linalg.norm(model.components_, axis=1), 1.0, rtol=1e-12)
    # The recorded objective is the real one, not only its Gram-matrix shortcut.
    direct = 0.5 * np.linalg.norm(X - V @ model.components_) ** 2 + alpha * V.sum()
    np.testing.assert_allclose(hist[-1], direct, rtol=1e-8, atol=1e-10)


def test_class_term_objective_is_the_stated_one():
    rng = np.random.default_rng(5)
    X = rng.random((400, 10))
    y = rng.integers(0, 3, 400)
    model = NNSF(4, alpha=0.02, beta=3.0, max_iter=1, tol=0, random_state=0)
    V = model.fit_weights(X, y)
    # After one iteration the class map used in the objective is W*(V_before);
    # refit it on the final V and the stated objective can only be lower.
    Y = np.eye(3)[y]
    W = np.linalg.lstsq(V, Y, rcond=None)[0]
    C = (0.5 * np.linalg.norm(X - V @ model.components_) ** 2 + 0.02 * V.sum()
         + 1.5 * np.linalg.norm(V @ W - Y) ** 2)
    assert C <= model.objective_[-1] * (1 + 1e-9)


def test_exact_factorization_is_recovered():
    """Analytic case: X = V U with a well separated non-negative U is fitted to ~0 error."""
    rng = np.random.default_rng(11)
    U = np.zeros((3, 9))
    U[0, :3] = U[1, 3:6] = U[2, 6:] = 1 / np.sqrt(3)
    V = rng.random((500, 3)) + 0.1
    X = V @ U
    model = NNSF(3, alpha=0.0, max_iter=2000, tol=1e-12, random_state=0).fit(X)
    # Multiplicative updates converge slowly near the optimum; 2,000 steps
    # bring this case to ~1e-3 relative error.
    assert model.reconstruction_err_ / np.linalg.norm(X) < 2e-3
    # Every true atom is found (up to order).
    cos = model.components_ @ U.T
    assert np.all(cos.max(axis=0) > 0.98)


def test_class_term_separates_training_weights():
    rng = np.random.default_rng(2)
    X = rng.random((600, 20))
    y = rng.integers(0, 3, 600)
    X[np.arange(600), y] += 0.4  # a weak class signal
    plain = NNSF(6, beta=0.0, max_iter=150, random_state=0).fit(X, y)
    sep = NNSF(6, beta=20.0, max_iter=150, random_state=0)
    Vs = sep.fit_weights(X, y)
    Vp = plain.fit_weights(X, y)
    Y = np.eye(3)[y]
    acc_s = np.mean(np.argmax(Vs @ np.linalg.lstsq(Vs, Y, rcond=None)[0], axis=1) == y)
    acc_p = np.mean(np.argmax(Vp @ np.linalg.lstsq(Vp, Y, rcond=None)[0], axis=1) == y)
    assert acc_s > acc_p


def test_predict_and_attributes():
    rng = np.random.default_rng(0)
    X = rng.random((200, 8))
    y = np.where(X[:, 0] > 0.5, "a", "b")
    model = NNSF(4, beta=1.0, max_iter=50, random_state=0).fit(X, y)
    assert model.components_.shape == (4, 8)
    assert model.class_map_.shape == (4, 2)
    assert list(model.classes_) == ["a", "b"]
    assert set(model.predict(X)) <= {"a", "b"}
    assert model.n_iter_ == len(model.objective_) - 1 <= 50
    assert model.inverse_transform(model.transform(X)).shape == X.shape
    unlabeled = NNSF(4, max_iter=5).fit(X)
    with pytest.raises(ValueError, match="without class labels"):
        unlabeled.predict(X)


@pytest.mark.parametrize("bad, message", [
    (np.nan, "NaN"), (np.inf, "infinity"), (-1.0, "Negative values"),
])
def test_rejects_bad_values(bad, message):
    X = np.ones((10, 4))
    X[3, 2] = bad
    with pytest.raises(ValueError, match=message):
        NNSF(2).fit(X)
    good = NNSF(2, max_iter=3).fit(np.ones((10, 4)) + np.arange(4))
    with pytest.raises(ValueError, match=message):
        good.transform(X)


@pytest.mark.parametrize("params, message", [
    ({"n_components": 0}, "n_components"), ({"alpha": -1}, "alpha"), ({"beta": "x"}, "beta"),
    ({"init": "svd"}, "init"), ({"max_iter": 0}, "max_iter"), ({"tol": -1}, "tol"),
    ({"class_in_loop": "yes"}, "class_in_loop"), ({"v_update": "other"}, "v_update"),
])
def test_rejects_bad_parameters(params, message):
    with pytest.raises(ValueError, match=message):
        NNSF(**params).fit(np.ones((10, 4)))


def test_rank_above_feature_count_is_an_error():
    with pytest.raises(ValueError, match="larger than the number of features"):
        NNSF(35).fit(np.ones((50, 34)))


def test_passes_check_estimator():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        results = check_estimator(NNSF(), on_fail=None)
    failed = [r["check_name"] for r in results if r["status"] == "failed"]
    assert not failed, failed


def test_pipeline_and_grid_search():
    rng = np.random.default_rng(4)
    centers = rng.random((3, 10)) * 3
    y = rng.integers(0, 3, 300)
    X = centers[y] + rng.random((300, 10)) * 0.3
    pipe = Pipeline([("nnsf", NNSF(max_iter=60, random_state=0)),
                     ("clf", LogisticRegression(max_iter=500))])
    grid = GridSearchCV(pipe, {"nnsf__n_components": [2, 5], "nnsf__beta": [0.0, 1.0]}, cv=3)
    grid.fit(X, y)
    assert grid.best_score_ > 0.9
    assert grid.best_estimator_.predict(X).shape == (300,)


def test_float32_is_preserved():
    X = np.random.default_rng(0).random((100, 6)).astype(np.float32)
    model = NNSF(3, max_iter=20).fit(X)
    assert model.components_.dtype == np.float32
    assert model.transform(X).dtype == np.float32


def test_deterministic_given_seed():
    X = np.random.default_rng(0).random((200, 10))
    y = np.arange(200) % 4
    a = NNSF(5, beta=2.0, init="random", random_state=7, max_iter=30).fit(X, y)
    b = NNSF(5, beta=2.0, init="random", random_state=7, max_iter=30).fit(X, y)
    np.testing.assert_array_equal(a.components_, b.components_)
    np.testing.assert_array_equal(a.class_map_, b.class_map_)
