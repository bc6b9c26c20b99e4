"""Tracking metrics (nnsf.roto.metrics): point-to-curve error, PCK, simulated-user edit ratio."""
import numpy as np
import pytest

from nnsf.roto import curves
from nnsf.roto.metrics import (
    curve_errors, edit_ratio, error_summary, length_ratio, pck, polygon_lengths,
    project_to_polyline, reverse_errors, symmetric_summary,
)
from nnsf.roto.toy import draw_polygons, rect, segment_controls


def test_projection_matches_dense_brute_force():
    rng = np.random.default_rng(0)
    poly = np.cumsum(rng.normal(0, 3, (40, 2)), axis=0)
    pts = rng.uniform(poly.min(0) - 5, poly.max(0) + 5, (200, 2))
    d, near = project_to_polyline(pts, poly)
    # oracle: the polyline resampled at 0.001 of each segment
    u = np.linspace(0, 1, 1001)[:, None]
    dense = np.concatenate([(1 - u) * a + u * b for a, b in zip(poly[:-1], poly[1:])])
    brute = np.linalg.norm(pts[:, None] - dense[None], axis=-1).min(1)
    np.testing.assert_allclose(d, brute, atol=2e-3)
    np.testing.assert_allclose(np.linalg.norm(pts - near, axis=-1), d, atol=1e-9)


def test_curve_errors_zero_on_truth_and_equal_to_an_offset():
    P = np.array([[10.0, 10.0], [30.0, 14.0], [50.0, 10.0]])
    truth = curves.dense(P, 0.05)[None, None]                 # (1, 1, S, 2)
    S = truth.shape[2]
    assert np.nanmax(curve_errors(P[None, None], truth)) < 1e-3
    straight = np.array([[0.0, 0.0], [0.0, 40.0]])
    truth = curves.sample(straight, S)[None, None]
    shifted = (straight + [1.5, 0.0])[None, None]
    np.testing.assert_allclose(curve_errors(shifted, truth), 1.5, atol=1e-9)
    # NaN-padded control rows: a 2-point curve stored with P = 3
    padded = np.concatenate([shifted, np.full((1, 1, 1, 2), np.nan)], axis=2)
    np.testing.assert_allclose(curve_errors(padded, truth), 1.5, atol=1e-9)
    assert error_summary(np.array([1.0, 2.0, np.nan]))["mean_px"] == 1.5


def test_symmetric_error_penalises_a_curve_shrunk_onto_the_truth():
    # truth: the segment x = 0, y in [0, 40]; tracked: its upper half, lying on it
    truth = curves.sample(np.array([[0.0, 0.0], [0.0, 40.0]]), 4001)[None, None]
    half = np.array([[0.0, 0.0], [0.0, 20.0]])[None, None]
    fwd = curve_errors(half, truth)
    rev = reverse_errors(half, truth)
    assert np.nanmax(fwd) < 1e-9                        # one-sided: a perfect score
    # truth -> tracked: 0 on the covered half, y - 20 on the other: mean 20² / 2 / 40 = 5
    assert np.nanmean(rev) == pytest.approx(5.0, abs=0.01)
    s = symmetric_summary(fwd, rev)
    assert s["mean_px"] < 1e-9 and s["mean_px_rev"] == pytest.approx(5.0, abs=0.01)
    assert s["mean_px_sym"] == pytest.approx(2.5, abs=0.01)
    assert s["p95_px_sym"] == pytest.approx(s["p95_px_rev"])
    assert s["p95_px_rev"] == pytest.approx(18.0, abs=0.02)
    # the full curve and a 1.5 px offset copy: both directions agree
    full = np.array([[0.0, 0.0], [0.0, 40.0]])[None, None]
    np.testing.assert_allclose(reverse_errors(full + [1.5, 0.0], truth), 1.5, atol=1e-9)
    # NaN rows (no estimate) stay NaN
    assert np.isnan(reverse_errors(np.full((1, 1, 2, 2), np.nan), truth)).all()


def test_length_ratio_of_shrunk_and_padded_curves():
    c = np.full((5, 2, 3, 2), np.nan)
    seg = np.array([[0.0, 0.0], [0.0, 10.0], [0.0, 20.0]])
    c[:, 0] = seg
    c[:, 1, :2] = seg[:2] * 2                                     # a 2-point curve, NaN-padded
    np.testing.assert_allclose(polygon_lengths(c[0]), [20.0, 20.0])
    assert length_ratio(c, [0, 4]) == pytest.approx(1.0)
    c[1:4] = c[1:4] * 0.5
    assert length_ratio(c, [0, 4]) == pytest.approx(0.5)
    # frames outside the keyframes are not in-between frames
    c[0] = np.nan
    # (keyframe 1 is a shrunk one: keyframe mean 15 px, in-between mean 10 px)
    assert length_ratio(c, [1, 4]) == pytest.approx(10.0 / 15.0)


def test_pck_counts_points_within_the_threshold():
    truth = np.zeros((2, 3, 2))
    pred = truth + np.array([[0.4, 0, 0], [0.6, np.nan, 0.5]])[..., None] * [1, 0]
    assert pck(pred, truth, np.array([10.0, 10.0]), 0.05) == pytest.approx(4 / 6)


def _moving_box(T=10):
    xs = 80 + 24 * (np.arange(T) / (T - 1)) ** 2
    polys = [rect(x, 96, 50, 70) for x in xs]
    frames = np.stack([draw_polygons((192, 192), [p], [(200, 60, 50)]) for p in polys])
    ann = {"keyframes": [{"frame": t, "curves": {"box.a": segment_controls(polys[t][1], polys[t][2], 4)}}
                         for t in (0, T - 1)]}
    truth = np.stack([segment_controls(p[1], p[2], 64) for p in polys])[:, None]
    return frames, ann, truth


def test_edit_ratio_zero_when_tracking_is_right_and_edits_fix_a_bad_tracker():
    frames, ann, truth = _moving_box()
    good = edit_ratio(frames, ann, truth, ["box.a"], "ours", tol=2.0)
    assert good["edits"] == 0 and good["edit_ratio"] == 0.0
    assert good["control_points"] == 4 * 8
    # a blind tracker (every image term off, so it stays at the linear guess) needs edits,
    # and after them every control point is within tolerance
    blind = edit_ratio(frames, ann, truth, ["box.a"], "agarwala", tol=2.0, edge=0.0)
    assert 0 < blind["edits"] <= blind["control_points"]
    assert blind["capped_curves"] == 0
    d, _ = project_to_polyline(blind["control"][:, 0], truth[:, 0])
    assert d.max() <= 2.0 + 1e-9
    # the un-edited result is what the tracker produced
    assert np.nanmax(curve_errors(blind["tracked"], truth)) > 2.0
    # no round allowed: every control point off in the tracker's result counts one edit
    capped = edit_ratio(frames, ann, truth, ["box.a"], "agarwala", tol=2.0, edge=0.0, max_edits=0)
    d0, _ = project_to_polyline(capped["tracked"][1:-1, 0], truth[1:-1, 0])
    assert capped["capped_curves"] == 1 and capped["rounds"] == 0
    assert capped["edits"] == int((d0 > 2.0).sum()) >= 2
