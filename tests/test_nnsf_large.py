"""NNSF on inputs too large for n × d temporaries: the lean initialisation, memory, dtype."""
from __future__ import annotations

import tracemalloc

import numpy as np
import pytest
from sklearn.decomposition._nmf import _initialize_nmf

from nnsf import NNSF
from nnsf.factor import nnsf as nnsf_module
from nnsf.factor.nnsf import LARGE_INIT_ROWS, _initialize_nndsvd_lean
from nnsf.factor.updates import residual_norm, _weight_pass, weight_step


def _exact_rank(n, d, k, seed=0):
    """A non-negative matrix of exact rank k with well separated singular values."""
    rng = np.random.default_rng(seed)
    A = rng.random((n, k)) * np.geomspace(4.0, 1.0, k)
    return A @ rng.random((k, d))


@pytest.mark.parametrize("init", ["nndsvd", "nndsvda"])
def test_lean_nndsvd_is_scikit_learns_when_the_svd_is_exact(init):
    # On an exactly rank-k matrix the randomized SVD is exact too, so both
    # constructions must agree to rounding.
    X = _exact_rank(3000, 34, 6)
    W, H = _initialize_nmf(X, 6, init=init, random_state=0)
    V, U = _initialize_nndsvd_lean(X, 6, fill=init == "nndsvda")
    np.testing.assert_allclose(V, W, rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(U, H, rtol=1e-7, atol=1e-9)


def test_blocked_weight_pass_is_the_plain_update_with_its_grams():
    rng = np.random.default_rng(1)
    X, U = rng.random((5000, 34)), rng.random((7, 34))
    V0 = rng.random((5000, 7))
    plain = V0.copy()
    weight_step(X, plain, U, 0.05)
    blocked = V0.copy()
    VtV, VtX, v_sum = _weight_pass(X, blocked, U, 0.05, chunk=999)  # a ragged last block
    np.testing.assert_allclose(blocked, plain, rtol=1e-13, atol=0)
    np.testing.assert_allclose(VtV, plain.T @ plain, rtol=1e-12)
    np.testing.assert_allclose(VtX, plain.T @ X, rtol=1e-12)
    assert v_sum == pytest.approx(plain.sum(), rel=1e-12)
    assert residual_norm(X, plain, U, chunk=999) == pytest.approx(np.linalg.norm(X - plain @ U), rel=1e-12)


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_fit_on_a_large_input_peaks_below_three_times_the_input(dtype):
    n = LARGE_INIT_ROWS
    rng = np.random.default_rng(2)
    X = (rng.random((n, 8)) @ rng.random((8, 34)) + 0.05 * rng.random((n, 34))).astype(dtype)
    tracemalloc.start()
    try:
        model = NNSF(20, max_iter=3, tol=0.0, random_state=0, dtype=dtype).fit(X)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert model.components_.dtype == np.dtype(dtype)
    assert peak <= 3 * X.nbytes, peak / X.nbytes
    assert np.isfinite(model.objective_).all() and model.objective_[-1] <= model.objective_[0]


def test_dtype_option_casts_and_keeps_sklearn_conventions():
    X = np.random.default_rng(3).random((200, 10))
    model = NNSF(4, max_iter=20, random_state=0, dtype="float32").fit(X)
    assert model.components_.dtype == np.float32
    assert model.transform(X).dtype == np.float32
    assert NNSF(4, max_iter=20, random_state=0).fit(X.astype(np.float32)).components_.dtype == np.float32
    ref = NNSF(4, max_iter=20, random_state=0).fit(X)
    np.testing.assert_allclose(model.components_, ref.components_, rtol=2e-3, atol=2e-4)
    with pytest.raises(ValueError, match="dtype"):
        NNSF(4, dtype="float16").fit(X)
    assert nnsf_module.NNSF().get_params()["dtype"] is None
