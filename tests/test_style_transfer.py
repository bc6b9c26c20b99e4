"""Posture and swing carried onto a clip of any action (docs/method.md §8.4), and the spectral baseline."""
from __future__ import annotations

import numpy as np
import pytest
from sklearn.utils._param_validation import InvalidParameterError

from nnsf.datasets.synthetic import generate
from nnsf.evaluate.content_baselines import mean_pose_offset, offset_transfer, spectral_transfer
from nnsf.evaluate.content_out import lean_degrees
from nnsf.factor import style_transfer as st
from nnsf.factor.translate import StyleTranslator
from nnsf.skeleton import Unifier, to_points


# --------------------------------------------------------------------------- the spectral baseline
def test_spectral_baseline_matches_a_hand_computation_on_two_frequencies():
    """Input a·cos(4 cycles) + b·cos(8 cycles) over 64 frames.  The source style's clips swing those
    components with amplitudes (p1, p2), the target's with (q1, q2); both at the same length, so no
    interpolation and no leakage: the result is a·(q1/p1)·cos4 + b·clip(q2/p2)·cos8 + mean + offset."""
    n = 64
    t = np.arange(n)
    c4, c8 = np.cos(2 * np.pi * 4 * t / n), np.cos(2 * np.pi * 8 * t / n)
    a, b = 0.3, 0.2
    R = np.stack([a * c4 + b * c8 + 1.0, 0.5 * c4 - 2.0], axis=1)           # two coordinates
    p1, p2, q1, q2 = 0.1, 0.05, 0.25, 0.5                                  # q2/p2 = 10 -> clipped to 4

    def clip(u, v, shift):
        return np.stack([u * c4 + v * c8 + shift, u * c4 + shift], axis=1)

    source = {"walk": [clip(p1, p2, 0.0)], "wave": [clip(p1, p2, 1.0), clip(p1, p2, 3.0)]}
    target = {"walk": [clip(q1, q2, 0.5)], "wave": [clip(q1, q2, 2.5)], "only_target": [clip(9, 9, 9)]}
    got = spectral_transfer(R, target, source)
    offset = np.mean([0.5 - 0.0, 2.5 - 2.0])                               # per content, then over them
    want_x = a * (q1 / p1) * c4 + b * 4.0 * c8 + 1.0 + offset
    want_y = 0.5 * (q1 / p1) * c4 - 2.0 + offset                          # c8 absent in source: ratio 1
    np.testing.assert_allclose(got[:, 0], want_x, atol=1e-12)
    np.testing.assert_allclose(got[:, 1], want_y, atol=1e-12)
    np.testing.assert_allclose(mean_pose_offset(target, source), [offset, offset], atol=1e-15)
    np.testing.assert_allclose(offset_transfer(R, target, source), R + offset, atol=1e-15)
    with pytest.raises(ValueError, match="share no content"):
        spectral_transfer(R, {"x": [R]}, {"y": [R]})


def test_spectral_baseline_interpolates_spectra_of_other_lengths():
    """A training clip twice as long has the same sinusoid at half the bin index: interpolated onto the
    input's grid its magnitude per frame is the same, so the ratio is still q/p."""
    n = 40
    t = np.arange(n)
    R = np.cos(2 * np.pi * 5 * t / n)[:, None]
    long = lambda u: u * np.cos(2 * np.pi * 10 * np.arange(2 * n) / (2 * n))[:, None]  # noqa: E731
    got = spectral_transfer(R, {"c": [long(0.6)]}, {"c": [long(0.3)]})
    np.testing.assert_allclose(got, 2.0 * R, atol=1e-9)


# --------------------------------------------------------------------------- bands
def test_band_amplitudes_share_out_the_variance_and_land_in_the_right_octave():
    fps, n = 30.0, 300
    t = np.arange(n) / fps
    rng = np.random.default_rng(0)
    R = np.stack([np.sin(2 * np.pi * 1.3 * t), rng.normal(size=n), 3 + 0 * t], axis=1)
    A = st.band_amplitudes(R, fps)
    assert A.shape == (st.N_BANDS, 3)
    # Parseval: the squares over the bands are the variance (of the mirrored clip, i.e. of the clip).
    np.testing.assert_allclose((A ** 2).sum(axis=0), R.var(axis=0), rtol=1e-10, atol=1e-20)
    band = int(np.searchsorted(st.BAND_EDGES, 1.3) - 1)        # 1.3 Hz lies in (1, 2]
    assert band == 2
    assert A[band, 0] ** 2 > 0.95 * R[:, 0].var()
    assert A[:, 2].max() == 0.0


def test_filter_bands_is_exact_for_flat_gains_and_scales_a_band():
    fps, n = 30.0, 150
    t = np.arange(n) / fps
    R = np.stack([0.2 * np.sin(2 * np.pi * 0.7 * t) + 0.05 * t, np.cos(2 * np.pi * 3.1 * t) + 1.0], axis=1)
    ones = np.ones((st.N_BANDS, 2))
    np.testing.assert_allclose(st.filter_bands(R, fps, ones), R, atol=1e-12)
    np.testing.assert_allclose(st.filter_bands(R, fps, 2.5 * ones), R.mean(0) + 2.5 * (R - R.mean(0)), atol=1e-12)
    # The mirror extension: a clip that drifts (does not end where it starts) is not bent at its ends.
    out = st.filter_bands(R, fps, ones * 1.0)
    assert abs(out[0, 0] - R[0, 0]) < 1e-12 and abs(out[-1, 0] - R[-1, 0]) < 1e-12


def test_swing_gains_weighted_ratio_and_clip():
    t = np.full((2, st.N_BANDS, 3), 2.0)
    r = np.ones((2, st.N_BANDS, 3))
    t[1, :, 1] = 40.0                                     # a content where the target moves 40x
    r[:, :, 2] = 0.0                                      # a coordinate the reference never moves
    swing = st.SWING_BANDS
    assert list(swing) == [False, True, True, True, True, False]      # 0.5-8 Hz only
    g = st.swing_gains(t, r, [1.0, 0.0])
    np.testing.assert_allclose(g[swing, 0], 2.0)
    np.testing.assert_allclose(g[~swing], 1.0)            # drift and noise bands are kept as they are
    np.testing.assert_allclose(g[:, 2], 1.0)
    np.testing.assert_allclose(st.swing_gains(t, r, [0.5, 0.5])[swing, 1], 4.0)     # 21 clipped to 4
    # a band one content could not measure (NaN: its takes were too short) comes from the other
    t2, r2 = t.copy(), r.copy()
    t2[0, 1, 0] = r2[0, 1, 0] = np.nan
    np.testing.assert_allclose(st.swing_gains(t2, r2, [0.5, 0.5])[1, 0], 2.0)
    assert list(st.resolved_bands(20, 30.0)) == [False, True, True, True, True, True]   # 20 frames: no drift
    w = st.content_weights(np.zeros(3), np.array([[0.0, 0, 0], [1.0, 0, 0], [10.0, 0, 0]]))
    assert w.sum() == pytest.approx(1.0) and w[0] > w[1] > w[2]


# --------------------------------------------------------------------------- the translator's public path
@pytest.fixture(scope="module")
def styled():
    """Two styles made from one character's clips: "base", and "wide" whose every root-relative
    coordinate swings twice as far about its clip mean and whose whole body is turned by 20° (its
    lean, the pelvis-to-neck line against the vertical, is 20° lower)."""
    tab = generate(characters=["bruno"], clips_per_cell=2, frames=48, noise_px=0.0, seed=0,
                   motions=["walk", "jump", "wave", "bow"])
    P = to_points(tab.loc[:, "x1":].to_numpy(float))
    X = Unifier().fit(P, tab["character"].to_numpy()).transform(P, tab["character"].to_numpy())
    mo, cl = tab["motion"].to_numpy(), tab["clip"].to_numpy()
    Pw = to_points(X).copy()
    th = np.deg2rad(20.0)
    rot = np.array([[np.cos(th), np.sin(th)], [-np.sin(th), np.cos(th)]])     # lean -20° (y down)
    for q in np.unique(cl):
        r = cl == q
        rel = Pw[r] - Pw[r][:, :1]
        m = rel.mean(axis=0)
        Pw[r] = Pw[r][:, :1] + (m + 2.0 * (rel - m)) @ rot.T
    W = Pw.reshape(len(X), 34)
    lift = 1.0 + max(0.0, -W.min())
    Xt = np.concatenate([X + lift, W + lift])
    cht = np.repeat(["base", "wide"], len(X))
    clt = np.concatenate([np.char.add("b-", cl.astype(str)), np.char.add("w-", cl.astype(str))])
    t = StyleTranslator(n_components=8, max_iter=60, align_iter=30, transfer="offset_swing",
                        neutral="base").fit(Xt, np.concatenate([mo, mo]), cht, clt, fps=24.0)
    return t, X + lift, cl


def test_offset_swing_carries_the_swing_and_lean_and_starts_in_the_clips_own_pose(styled):
    t, Xb, cl = styled
    Xq = Xb[cl == "bruno-walk-00"]
    out = t.translate_clip(Xq, "wide")                    # read as the neutral style, "base"
    assert out.shape == Xq.shape
    lean_in, lean_out = lean_degrees(to_points(Xq)), lean_degrees(to_points(out))
    # the first frame keeps the input's lean (the change eases in) ...
    assert abs(lean_out[0] - lean_in[0]) < 3.0
    # ... and after the onset the body leans like "wide" (20° lower)
    onset = int(round(st.ONSET_SECONDS * 24.0))
    assert -28.0 < np.mean(lean_out[onset:] - lean_in[onset:]) < -12.0
    # the swing about the clip mean grows (every band's gain is 2 in this pair of styles)
    rel = lambda X: st.root_relative(X)[0][onset:]                            # noqa: E731
    assert rel(out).std(axis=0).sum() > 1.6 * rel(Xq).std(axis=0).sum()
    # a clip read as the target style itself is returned unchanged
    np.testing.assert_array_equal(t.translate_clip(Xq, "base"), Xq)


def test_default_transfer_starts_in_the_input_lean_and_other_rates_are_resampled(styled):
    t, Xb, cl = styled
    Xq = Xb[cl == "bruno-wave-01"]
    t.set_params(transfer="recombine_swing")
    try:
        out = t.translate_clip(Xq, "wide")
        slow = t.translate_clip(Xq, "wide", fps=12.0)      # the clip at half the model's rate
    finally:
        t.set_params(transfer="offset_swing")
    assert abs(lean_degrees(to_points(out[:1]))[0] - lean_degrees(to_points(Xq[:1]))[0]) < 3.0
    assert slow.shape == Xq.shape and np.isfinite(slow).all()


def test_translator_parameters_are_declared_and_checked_in_fit(styled):
    t, Xb, cl = styled
    X = np.abs(np.random.default_rng(0).random((40, 34)))
    lab = np.repeat(["a", "b"], 20)
    with pytest.raises(InvalidParameterError, match="transfer"):
        StyleTranslator(transfer="sideways").fit(X, lab, lab)
    with pytest.raises(InvalidParameterError, match="n_components"):
        StyleTranslator(n_components=0).fit(X, lab, lab)
    with pytest.raises(ValueError, match="neutral style 'nobody'"):
        StyleTranslator(neutral="nobody", n_components=2, max_iter=5, align_iter=2).fit(X, lab, lab)
    assert len(StyleTranslator().get_params()) == len(StyleTranslator._parameter_constraints) == 15
