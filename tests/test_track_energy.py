"""Space-time energy: analytic Jacobian, normal equations and the solvers (nnsf.roto.energy)."""
import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from nnsf.roto.energy import SpaceTimeProblem, Weights, build_pyramid
from nnsf.roto.lm import levenberg_marquardt, solve_block_tridiagonal


def _problem(image_terms=True, seed=0, gated=False):
    rng = np.random.default_rng(seed)
    T, H, W = 5, 64, 64
    frames = np.zeros((T, H, W, 3), np.uint8)
    frames[:] = (230, 230, 230)
    for t in range(T):
        cv2.circle(frames[t], (30 + 2 * t, 32), 15, (200, 50, 40), -1)
        cv2.circle(frames[t], (30 + 2 * t, 32), 15, (20, 20, 20), 2)
    lev = build_pyramid(frames, 1, colour_sigma=1.5)[0]
    # float64 images so that finite differences are accurate
    lev.colour = lev.colour.astype(np.float64)
    lev.edge = lev.edge.astype(np.float64)
    P = np.array([[15, 20], [20, 30], [25, 40], [30, 46]], float)[None, None].repeat(T, 1)
    P = P.repeat(2, 0) + rng.normal(0, 1, (2, T, 4, 2))
    fixed = np.zeros((2, T, 4), bool)
    fixed[0, 2, 1] = True                     # an extra hard constraint (a user's edit)
    extra = {}
    if gated:      # edge gate, slide anchor to a start with a confidence per frame
        extra = dict(edge_gate=1.5, slide=50.0, motion_prior=P + rng.normal(0, 0.5, P.shape),
                     prior_confidence=rng.uniform(0.2, 1.0, (2, T)), velocity_trust=True)
    prob = SpaceTimeProblem(lev, P, fixed, Weights(), n_samples=9, K=2,
                            use_image_terms=image_terms, **extra)
    if gated:
        assert 0 < prob.on_edge.sum() < prob.on_edge.size       # the gate keeps some samples
    return prob, prob.x0() + rng.normal(0, 0.3, prob.n_unknowns)


@pytest.mark.parametrize("image_terms,gated", [(True, False), (False, False), (True, True)])
def test_jacobian_matches_finite_differences(image_terms, gated):
    prob, x = _problem(image_terms, gated=gated)
    J = prob.jacobian(x).toarray()
    eps = 1e-6
    Jn = np.empty_like(J)
    for k in range(len(x)):
        e = np.zeros_like(x)
        e[k] = eps
        Jn[:, k] = (prob.residuals(x + e) - prob.residuals(x - e)) / (2 * eps)
    assert np.abs(J - Jn).max() < 1e-5 * max(1.0, np.abs(Jn).max())


@pytest.mark.parametrize("gated", [False, True])
def test_normal_equations_equal_jtj_of_the_sparse_jacobian(gated):
    prob, x = _problem(gated=gated)
    r = prob.residuals(x)
    J = prob.jacobian(x).toarray()
    cost, g, Hd, Ho = prob.normal_equations(x)
    assert cost.sum() == pytest.approx(0.5 * r @ r, rel=1e-10)
    G, T, k = g.shape
    H = np.zeros((G * T * k, G * T * k))
    for gi in range(G):
        for t in range(T):
            o = (gi * T + t) * k
            H[o:o + k, o:o + k] = Hd[gi, t]
            if t < T - 1:
                H[o:o + k, o + k:o + 2 * k] = Ho[gi, t]
                H[o + k:o + 2 * k, o:o + k] = Ho[gi, t].T
    free = prob.free.reshape(-1)
    np.testing.assert_allclose(H[np.ix_(free, free)], J.T @ J, atol=1e-9)
    np.testing.assert_allclose(g.reshape(-1)[free], J.T @ r, atol=1e-9)


def test_block_tridiagonal_solve_matches_dense_solve():
    rng = np.random.default_rng(1)
    G, T, k = 3, 7, 4
    A = rng.normal(size=(G, T, k, k))
    Hd = A @ np.swapaxes(A, -1, -2) + 4 * np.eye(k)
    Ho = 0.3 * rng.normal(size=(G, T - 1, k, k))
    b = rng.normal(size=(G, T, k))
    x = solve_block_tridiagonal(Hd, Ho, b)
    for g in range(G):
        M = np.zeros((T * k, T * k))
        for t in range(T):
            M[t * k:(t + 1) * k, t * k:(t + 1) * k] = Hd[g, t]
            if t < T - 1:
                M[t * k:(t + 1) * k, (t + 1) * k:(t + 2) * k] = Ho[g, t]
                M[(t + 1) * k:(t + 2) * k, t * k:(t + 1) * k] = Ho[g, t].T
        np.testing.assert_allclose(x[g].ravel(), np.linalg.solve(M, b[g].ravel()), atol=1e-10)


def test_levenberg_marquardt_reaches_the_cost_scipy_reaches():
    prob, x = _problem()
    x_lm, info = levenberg_marquardt(prob, x, max_iter=100, ftol=1e-10)
    ref = least_squares(prob.residuals, x, jac=prob.jacobian, method="trf", tr_solver="lsmr",
                        ftol=1e-12, xtol=1e-12, gtol=1e-12, max_nfev=400)
    start = prob.cost(x).sum()
    assert info["cost"] < start
    # both find the same local minimum of a smooth problem (within 1 % of the decrease)
    assert info["cost"] == pytest.approx(ref.cost, abs=0.01 * (start - ref.cost))
    # fixed entries never move
    np.testing.assert_array_equal(prob.controls(x_lm)[prob.fixed], prob.P0[prob.fixed])


def test_length_residuals_are_px_of_curve_length_and_anchored_to_the_keyframes():
    # straight 2-point curves traverse at constant speed: (n-1)|c'| equals the length exactly
    T, n = 5, 9
    frames = np.full((T, 32, 96, 3), 230, np.uint8)
    lev = build_pyramid(frames, 1)[0]
    P = np.zeros((1, T, 2, 2))
    P[0, :, 1, 0] = 40.0                                          # 40 px long in every frame
    fixed = np.zeros((1, T, 2), bool)
    w = Weights(velocity=0.0, length=2.0, curvature=0.0, edge=0.0, sketch=0.0, colour=0.0)
    prob = SpaceTimeProblem(lev, P, fixed, w, n_samples=n, K=1, use_image_terms=False,
                            length_anchor=4.0)
    assert prob.cost(prob.x0()).sum() == pytest.approx(0.0, abs=1e-12)
    # shrink the middle frame to 30 px: adjacent pairs (2 of them) and the anchor (1 frame)
    Q = P.copy()
    Q[0, 2, 1, 0] = 30.0
    x = Q[prob.free]
    expected = 0.5 * n * (2.0 * 2 * 10.0 ** 2 + 2.0 * 4.0 * 10.0 ** 2)
    assert prob.cost(x).sum() == pytest.approx(expected, rel=1e-9)
    # a curve 10x smaller shrunk by the same fraction: 1/100 of the cost (residuals in px)
    small = SpaceTimeProblem(lev, P / 10, fixed, w, n_samples=n, K=1, use_image_terms=False)
    assert small.cost((Q / 10)[small.free]).sum() == pytest.approx(expected / 100, rel=1e-9)
    # without the anchor only the adjacent-frame differences remain
    loose = SpaceTimeProblem(lev, P, fixed, w, n_samples=n, K=1, use_image_terms=False,
                             length_anchor=0.0)
    assert loose.cost(x).sum() == pytest.approx(0.5 * n * 2.0 * 2 * 10.0 ** 2, rel=1e-9)


def test_edge_gate_and_slide_anchor_residuals_against_their_definitions():
    from nnsf.roto import curves
    from nnsf.roto.energy import bilinear
    base, x = _problem()
    rng = np.random.default_rng(5)
    T = base.T
    prior = base.P0 + rng.normal(0, 0.5, base.P0.shape)
    conf = rng.uniform(0.2, 1.0, (2, T))
    prob = SpaceTimeProblem(base.images, base.P0, base.fixed, Weights(), n_samples=9, K=2,
                            edge_gate=1.5, slide=50.0, motion_prior=prior, prior_confidence=conf)
    P = prob.controls(x)
    B0, B1, _ = curves.basis(prob.C, prob.n)
    # slide: the offset from the start along the start's unit tangent, times sqrt(w·c)
    S, Sp = np.einsum("nc,gtcd->gtnd", B0, P), np.einsum("nc,gtcd->gtnd", B0, prior)
    D1p = np.einsum("nc,gtcd->gtnd", B1, prior)
    tp = D1p / np.linalg.norm(D1p, axis=-1, keepdims=True)
    want = np.sqrt(50.0 * conf[:, 1:-1])[..., None] * ((S - Sp) * tp).sum(-1)[:, 1:-1]
    plain = [b.r for b in base.blocks(x, jacobian=False)]
    extra = [b.r for b in prob.blocks(x, jacobian=False)]
    assert len(extra) == len(plain) + 1
    assert any(r.shape == want.shape and np.allclose(r, want) for r in extra)
    # edge gate: samples off an edge (> 1.5 px) in either keyframe carry no edge residual
    Sk = np.einsum("nc,gtcd->gtnd", B0, prob.P0[:, [0, -1]])
    ek = bilinear(prob.images.edge, prob._t([0, T - 1], 1), Sk, grad=False)[..., 0]
    on = ek.max(1) <= 1.5
    np.testing.assert_array_equal(prob.on_edge, on)
    # off the edges the residuals are scaled by 1 - the start's mean in-between confidence
    keep = np.where(on, 1.0, 1.0 - conf[:, 1:-1].mean(1)[:, None])
    e = bilinear(prob.images.edge, prob._t(np.arange(1, T - 1), 1), S[:, 1:-1], grad=False)[..., 0]
    assert any(r.shape == e.shape and np.allclose(r, keep[:, None] * e) for r in extra)
    assert 0 < on.sum() < on.size


def test_velocity_trust_scales_the_velocity_term_by_the_start_confidence():
    # velocity_trust: r = sqrt(w_v (c_t + c_{t+1}) / 2) ((c_t - c_{t+1}) - (c̃_t - c̃_{t+1})),
    # c the start's confidence (docs/method.md §2.2); off, or without a confidence: full weight
    from nnsf.roto import curves
    base, x = _problem()
    rng = np.random.default_rng(7)
    T = base.T
    prior = base.P0 + rng.normal(0, 0.5, base.P0.shape)
    conf = rng.uniform(0.0, 1.0, (2, T))
    B0 = curves.basis(base.C, base.n)[0]
    P = base.controls(x)
    S, Sp = np.einsum("nc,gtcd->gtnd", B0, P), np.einsum("nc,gtcd->gtnd", B0, prior)
    dv = ((S[:, :-1] - S[:, 1:]) - (Sp[:, :-1] - Sp[:, 1:])).reshape(2, T - 1, -1)
    w = Weights()
    trusted = np.sqrt(0.5 * (conf[:, :-1] + conf[:, 1:]))[..., None]
    for c, on, scale in ((conf, True, trusted), (conf, False, 1.0), (None, True, 1.0)):
        prob = SpaceTimeProblem(base.images, base.P0, base.fixed, w, n_samples=9, K=2,
                                motion_prior=prior, prior_confidence=c, velocity_trust=on)
        r = prob.blocks(x, jacobian=False)[0].r
        np.testing.assert_allclose(r, np.sqrt(w.velocity) * scale * dv, rtol=1e-10, atol=1e-12)
