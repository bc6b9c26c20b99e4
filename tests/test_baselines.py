"""Baselines: the shared class map, NMF + class map, NNSC, and the bilinear model."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.factor.baselines import BilinearModel, NMFClassifier, class_map, make_nnsc, one_hot


# --------------------------------------------------------------------------- data
def separable(n_per_class=40, n_classes=4, d=16, noise=0.02, seed=0):
    """Each class lights up its own block of features: a rank-C non-negative problem.

    The class patterns are fixed; ``seed`` draws new frames (amplitudes, noise).
    """
    patterns = np.random.default_rng(12345).random((n_classes, d // n_classes))
    rng = np.random.default_rng(seed)
    block = d // n_classes
    X, y = [], []
    for c in range(n_classes):
        pattern = np.zeros(d)
        pattern[c * block:(c + 1) * block] = 1.0 + patterns[c]
        amp = 0.5 + rng.random((n_per_class, 1))
        X.append(amp * pattern + noise * rng.random((n_per_class, d)))
        y += [f"class{c}"] * n_per_class
    return np.vstack(X), np.array(y)


def bilinear_data(S=4, C=6, d=34, J=3, frames=5, noise=0.0, seed=0):
    """Frames of an exact rank-J asymmetric bilinear model y^{sc} = A^s b^c (+ noise).

    Returns X (n, d), content labels, style labels and the true A (S, d, J), B (J, C).
    """
    rng = np.random.default_rng(seed)
    A = rng.standard_normal((S, d, J))
    B = rng.standard_normal((J, C))
    X, y, s = [], [], []
    for i in range(S):
        for c in range(C):
            mean = A[i] @ B[:, c]
            jitter = noise * rng.standard_normal((frames, d))
            jitter -= jitter.mean(axis=0)      # the cell mean stays exactly A^s b^c
            X.append(mean + jitter)
            y += [f"c{c}"] * frames
            s += [f"s{i}"] * frames
    return np.vstack(X), np.array(y), np.array(s), A, B


# ------------------------------------------------------------------- class_map
def test_class_map_without_ridge_is_least_squares():
    rng = np.random.default_rng(1)
    V = rng.random((50, 6))
    _, Y = one_hot(rng.integers(0, 3, 50))
    W = class_map(V, Y, eps=0.0)
    assert W.shape == (6, 3)
    np.testing.assert_allclose(W, np.linalg.lstsq(V, Y, rcond=None)[0], rtol=1e-10, atol=1e-12)


def test_class_map_ridge_matches_augmented_least_squares():
    # min ‖VW − Y‖² + λ‖W‖²  ==  lstsq of [V; √λ I] W = [Y; 0], with λ = eps · trace(VᵀV)/k.
    rng = np.random.default_rng(2)
    V = rng.random((40, 5)) * 3.0
    _, Y = one_hot(rng.integers(0, 4, 40))
    eps = 0.3
    lam = eps * np.trace(V.T @ V) / 5
    A = np.vstack([V, np.sqrt(lam) * np.eye(5)])
    B = np.vstack([Y, np.zeros((5, Y.shape[1]))])
    np.testing.assert_allclose(class_map(V, Y, eps), np.linalg.lstsq(A, B, rcond=None)[0],
                               rtol=1e-9, atol=1e-12)


def test_class_map_is_unit_free_and_survives_a_dead_atom():
    rng = np.random.default_rng(3)
    V = rng.random((30, 4))
    V[:, 2] = 0.0                                   # a dead atom: VᵀV is singular
    _, Y = one_hot(rng.integers(0, 2, 30))
    W = class_map(V, Y, 1e-6)
    assert np.isfinite(W).all() and np.allclose(W[2], 0.0)
    # Scaling V by s scales W by 1/s exactly (the ridge is relative).
    np.testing.assert_allclose(class_map(10.0 * V, Y, 1e-6), W / 10.0, rtol=1e-9)


def test_class_map_rejects_bad_input():
    with pytest.raises(ValueError, match="same number of rows"):
        class_map(np.ones((5, 2)), np.ones((4, 2)))
    with pytest.raises(ValueError, match="eps"):
        class_map(np.ones((5, 2)), np.ones((5, 2)), eps=-1.0)


def test_one_hot():
    classes, Y = one_hot(np.array(["b", "a", "b"]))
    assert list(classes) == ["a", "b"]
    np.testing.assert_array_equal(Y, [[0, 1], [1, 0], [0, 1]])


# ------------------------------------------------------------------ NMFClassifier
def test_nmf_classifier_separates_block_classes_on_held_out_frames():
    X, y = separable(seed=0)
    Xt, yt = separable(n_per_class=20, seed=1)      # same classes, new frames
    model = NMFClassifier(n_components=4, max_iter=400, random_state=0).fit(X, y)
    assert list(model.classes_) == sorted(set(y))
    assert model.components_.shape == (4, 16) and model.class_map_.shape == (4, 4)
    np.testing.assert_allclose(np.linalg.norm(model.components_, axis=1), 1.0)
    assert np.mean(model.predict(Xt) == yt) == 1.0
    V = model.transform(Xt)
    assert V.shape == (80, 4) and (V >= 0).all()
    np.testing.assert_array_equal(model.predict(Xt), model.classes_[np.argmax(V @ model.class_map_, 1)])
    # Rescaling U's rows must not change the reconstruction sklearn's NMF gives.
    np.testing.assert_allclose(model.inverse_transform(V),
                               model.nmf_.transform(Xt) @ model.nmf_.components_, rtol=1e-10, atol=1e-12)
    rel = np.linalg.norm(Xt - model.inverse_transform(V)) / np.linalg.norm(Xt)
    assert rel < 0.05


def test_nmf_classifier_alpha_is_nnsf_l1_weight():
    # NNSF's α ΣV corresponds to sklearn's alpha_W = α / d with l1_ratio = 1 (docs/method.md §6.4).
    X, y = separable()
    model = NMFClassifier(n_components=3, alpha=0.5, max_iter=50, solver="mu").fit(X, y)
    assert model.nmf_.alpha_W == pytest.approx(0.5 / X.shape[1])
    assert model.nmf_.alpha_H == 0.0 and model.nmf_.l1_ratio == 1.0
    dense = NMFClassifier(n_components=3, alpha=0.0, max_iter=50, solver="mu").fit(X, y)
    assert model.transform(X).sum() < dense.transform(X).sum()     # the L1 term shrinks V


def test_nmf_classifier_validation():
    X, y = separable()
    with pytest.raises(ValueError, match="Negative"):
        NMFClassifier(2).fit(-X, y)
    with pytest.raises(ValueError, match="n_components"):
        NMFClassifier(0).fit(X, y)
    with pytest.raises(ValueError, match="solver"):
        NMFClassifier(2, solver="sgd").fit(X, y)
    with pytest.raises(ValueError, match="one label per row"):
        NMFClassifier(2).fit(X, y[:-1])
    unlabeled = NMFClassifier(2, max_iter=20).fit(X)
    with pytest.raises(ValueError, match="without labels"):
        unlabeled.predict(X)


# --------------------------------------------------------------------------- NNSC
def test_make_nnsc_is_nnsf_with_beta_zero():
    from nnsf.factor.nnsf import NNSF

    X, y = separable()
    nnsc = make_nnsc(n_components=4, alpha=0.01, max_iter=60, random_state=0)
    assert isinstance(nnsc, NNSF) and nnsc.beta == 0.0
    nnsc.fit(X, y)
    ref = NNSF(n_components=4, alpha=0.01, beta=0.0, max_iter=60, random_state=0).fit(X, y)
    np.testing.assert_array_equal(nnsc.components_, ref.components_)
    assert np.mean(nnsc.predict(X) == y) > 0.95
    with pytest.raises(ValueError, match="beta"):
        make_nnsc(n_components=4, beta=1.0)


# ----------------------------------------------------------------------- bilinear
def test_bilinear_full_rank_recovers_cell_means_and_classifies_perfectly():
    X, y, s, A, B = bilinear_data(noise=0.3, seed=4)
    model = BilinearModel(n_components=None).fit(X, y, s)
    assert model.n_components_ == 6                  # min(S·d, C) = C
    for i in range(4):
        for c in range(6):
            np.testing.assert_allclose(model.cell_template(f"s{i}", f"c{c}"), A[i] @ B[:, c],
                                       atol=1e-9)
    assert np.all(model.predict(X, s) == y)
    # reconstruct() is the cell template of the predicted content.
    np.testing.assert_allclose(model.reconstruct(X[:5], s[:5]),
                               np.tile(A[0] @ B[:, 0], (5, 1)), atol=1e-9)


def test_bilinear_rank_is_clipped_not_an_error():
    X, y, s, _, _ = bilinear_data(frames=2)
    assert BilinearModel(n_components=34).fit(X, y, s).n_components_ == 6
    assert BilinearModel(n_components=2).fit(X, y, s).n_components_ == 2


def test_bilinear_truncation_is_the_best_rank_J_fit_of_the_stacked_means():
    # Eckart–Young: ‖M − A B‖_F equals the root of the discarded squared singular values.
    X, y, s, _, _ = bilinear_data(J=6, noise=0.5, seed=5)
    model = BilinearModel(n_components=3).fit(X, y, s)
    M = np.concatenate([model.cell_means_[i].T for i in range(4)])     # (S·d, C)
    fit = np.concatenate([model.style_matrices_[f"s{i}"] for i in range(4)]) @ model.content_vectors_
    sigma = np.linalg.svd(M, compute_uv=False)
    assert np.linalg.norm(M - fit) == pytest.approx(np.sqrt((sigma[3:] ** 2).sum()), rel=1e-9)


def test_bilinear_imputes_a_missing_cell_from_low_rank_structure():
    X, y, s, A, B = bilinear_data(J=2, seed=6)
    hide = (s == "s1") & (y == "c3")
    model = BilinearModel(n_components=2, max_iter=5000, tol=1e-12).fit(X[~hide], y[~hide], s[~hide])
    assert not model.observed_[1, 3] and model.observed_.sum() == 4 * 6 - 1
    assert model.n_iter_ > 0
    np.testing.assert_allclose(model.cell_template("s1", "c3"), A[1] @ B[:, 3], atol=1e-5)


def test_bilinear_missing_content_everywhere_is_simply_absent():
    X, y, s, _, _ = bilinear_data(frames=2)
    keep = y != "c5"
    model = BilinearModel().fit(X[keep], y[keep], s[keep])
    assert "c5" not in model.classes_ and model.n_components_ == 5


def test_bilinear_adapt_style_from_observed_contents():
    X, y, s, A, B = bilinear_data(S=5, J=3, seed=7)
    train = s != "s4"
    model = BilinearModel(n_components=3).fit(X[train], y[train], s[train])
    # The new style is seen with 4 of the 6 contents (>= J, so A^s is determined).
    seen = (s == "s4") & np.isin(y, ["c0", "c1", "c2", "c3"])
    model.adapt_style(X[seen], y[seen], "s4")
    assert "s4" in model.styles_
    # Its unseen contents are synthesised: A^{s4} b^{c} equals the truth up to the
    # model's basis (the content vectors span the same space as the true B).
    for c in ("c4", "c5"):
        truth = A[4] @ B[:, int(c[1])]
        np.testing.assert_allclose(model.cell_template("s4", c), truth, atol=1e-8)
    unseen = (s == "s4") & ~seen
    assert np.all(model.predict(X[unseen], s[unseen]) == y[unseen])


def test_bilinear_transform_round_trip_and_style_inference():
    X, y, s, A, B = bilinear_data(J=3, seed=8)
    model = BilinearModel(n_components=3).fit(X, y, s)
    codes = model.transform(X, s)
    assert codes.shape == (len(X), 3)
    np.testing.assert_allclose(model.inverse_transform(codes, s), X, atol=1e-9)  # X lies in span(A^s)
    # Without styles, the nearest (style, content) template is searched.
    assert np.all(model.predict(X) == y)


def test_bilinear_validation():
    X, y, s, _, _ = bilinear_data(frames=2)
    model = BilinearModel(n_components=2).fit(X, y, s)
    with pytest.raises(ValueError, match="unknown"):
        model.predict(X[:3], np.array(["new"] * 3))
    with pytest.raises(ValueError, match="one style per row"):
        BilinearModel().fit(X, y, s[:-1])
    with pytest.raises(ValueError, match="n_components"):
        BilinearModel(n_components=0).fit(X, y, s)
    with pytest.raises(ValueError, match="not in the fitted model"):
        model.adapt_style(X[:2], np.array(["zzz", "zzz"]), "s9")
