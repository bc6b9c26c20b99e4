"""The snap step that ends "ours" (nnsf/roto/snap.py): analytic cases on synthetic frames."""
import numpy as np
import pytest

from nnsf.roto.energy import build_pyramid
from nnsf.roto.snap import STEP, edge_snap, gradient_strength, profile_snap
from nnsf.roto.solve import TrackOptions, track_clip

RED, BLUE = (220, 40, 40), (40, 40, 220)


def _two_colours(edges, size=(40, 48)):
    """Frames (T, H, W, 3) uint8: red left of x = edge + 0.5, blue right of it, per frame."""
    H, W = size
    x = np.arange(W)
    out = np.empty((len(edges), H, W, 3), np.uint8)
    for t, e in enumerate(edges):
        out[t] = np.where((x <= e)[None, :, None], RED, BLUE)
    return out


def _vertical(x, T, C=4):
    """(1, T, C, 2) control points of a vertical curve at x (px), y 8..32."""
    P = np.zeros((1, T, C, 2))
    P[..., 0] = x
    P[..., 1] = np.linspace(8.0, 32.0, C)
    return P


def test_spline_normals_at_the_control_points_are_the_central_differences():
    # the snap searches along curves.normals(P, C): with C samples of a C-point spline they sit
    # on the control points, where the tangent is (P_{i+1} - P_{i-1}) / 2 (P_1 - P_0 at the ends)
    from nnsf.roto import curves
    rng = np.random.default_rng(3)
    P = np.cumsum(rng.normal(0, 3, (5, 2)), 0)
    t = np.gradient(P, axis=0)
    want = curves.rot90(t / np.linalg.norm(t, axis=1, keepdims=True))
    np.testing.assert_allclose(curves.normals(P, 5), want, atol=1e-12)
    np.testing.assert_allclose(curves.sample(P, 5), P, atol=1e-12)


def test_profile_snap_finds_the_edge_where_the_keyframes_put_it():
    edges = [20, 22, 24, 26, 28]                     # the colour edge moves 2 px a frame
    colour = build_pyramid(_two_colours(edges), 1)[0].colour
    T = len(edges)
    P = _vertical(23.0, T)                           # a guess left at x = 23 in every frame
    P[:, 0, :, 0] = edges[0] + 0.5                   # keyframes on the edge
    P[:, -1, :, 0] = edges[-1] + 0.5
    fixed = np.zeros(P.shape[:3], bool)
    fixed[:, [0, -1]] = True
    out = profile_snap(colour, P, fixed, np.zeros(1, np.intp), radius=4.0, K=3)
    np.testing.assert_array_equal(out[:, [0, -1]], P[:, [0, -1]])      # keyframes stay
    want = np.broadcast_to(np.array(edges[1:-1], float)[:, None] + 0.5, (T - 2, 4))
    np.testing.assert_allclose(out[0, 1:-1, :, 0], want, atol=1e-9)
    np.testing.assert_array_equal(out[..., 1], P[..., 1])               # across the curve only
    # within 1 px only frame 1's edge (0.5 px away) is found; the others are out of reach
    near = profile_snap(colour, P, fixed, np.zeros(1, np.intp), radius=1.0, K=3)
    assert np.all(np.abs(near[0, 1:-1, :, 0] - 23.0) <= 1.0)
    np.testing.assert_allclose(near[0, 1, :, 0], 22.5, atol=1e-9)      # 0.5 px away: found


def test_edge_snap_moves_onto_the_strongest_edge_and_leaves_flat_areas():
    frames = _two_colours([20, 20, 20])
    strength = gradient_strength(build_pyramid(frames, 1)[0].colour)
    P = np.concatenate([_vertical(18.2, 3), _vertical(40.0, 3)])        # one near the edge, one far
    fixed = np.zeros(P.shape[:3], bool)
    fixed[:, 0] = True
    out = edge_snap(strength, P, fixed, np.zeros(2, np.intp), radius=3.0)
    # the smoothed step's gradient peaks between pixel 20 and 21; bilinear sampling makes the
    # peak a plateau [20, 21] and the pull takes its near end
    assert np.all((out[0, 1:, :, 0] >= 20.0) & (out[0, 1:, :, 0] <= 21.0))
    np.testing.assert_array_equal(out[1], P[1])                        # flat colour: stays
    np.testing.assert_array_equal(out[:, 0], P[:, 0])                  # fixed: stays
    np.testing.assert_array_equal(edge_snap(strength, P, fixed, np.zeros(2, np.intp), 0.0), P)


def test_snap_through_track_clip_and_off_by_default():
    edges = [16, 17, 20, 25, 29, 31]                 # uneven: the linear start is up to 2 px off
    frames = _two_colours(edges)
    T = len(edges)
    curve = lambda x: np.stack([np.full(4, x), np.linspace(8.0, 32.0, 4)], -1)
    ann = {"keyframes": [{"frame": 0, "curves": {"edge.a": curve(edges[0] + 0.5)}},
                         {"frame": T - 1, "curves": {"edge.a": curve(edges[-1] + 0.5)}}]}
    # image terms off, so that the solve leaves the linear start where it is and only the snap
    # can find the edge
    opts = dict(init="linear", max_nfev=3, levels=1, colour=0.0, sketch=0.0, edge=0.0)
    plain = track_clip(frames, ann, "ours", **opts)
    np.testing.assert_array_equal(plain, track_clip(frames, ann, "ours", snap=0.0, **opts))
    snapped = track_clip(frames, ann, "ours", snap=3.0, **opts)
    truth = np.broadcast_to(np.array(edges, float)[:, None] + 0.5, (T, 4))
    err_plain = np.abs(plain[:, 0, :, 0] - truth).max()
    err_snap = np.abs(snapped[:, 0, :, 0] - truth).max()
    assert err_snap <= STEP / 2 + 1e-9 < 1.0 < err_plain       # on the 0.25-px search grid
    # LK and Agarwala's tracker never snap
    ag = track_clip(frames, ann, "agarwala", **opts)
    np.testing.assert_array_equal(ag, track_clip(frames, ann, "agarwala", snap=3.0, **opts))


@pytest.mark.parametrize("bad", [{"snap": -1.0}, {"snap": float("inf")}, {"snap_to": "edges"}])
def test_bad_snap_options_raise(bad):
    with pytest.raises(ValueError, match="track option snap"):
        TrackOptions.from_kwargs(**bad)


def _stroke(xs, size=(40, 48), width=2):
    """Frames (T, H, W, 3) uint8: a dark vertical stroke ``width`` px wide centred at x + 0.5 on white."""
    H, W = size
    x = np.arange(W)
    out = np.full((len(xs), H, W, 3), 255, np.uint8)
    for t, c in enumerate(xs):
        on = np.abs(x - (c + 0.5)) < width / 2 + 1e-9
        out[t][:, on] = (30, 30, 60)
    return out


def test_stroke_share_tells_flat_colour_from_line_art():
    from nnsf.roto.snap import STROKED, auto_target, stroke_share
    curve = lambda x: {"s": np.stack([np.full(4, x), np.linspace(8.0, 32.0, 4)], -1)}
    flat = _two_colours([20, 24])                       # a boundary between two flat colours
    assert stroke_share(flat, {0: curve(20.5), 1: curve(24.5)}) == 0.0
    assert auto_target(flat, {0: curve(20.5)}) == ("edge", 0.0)
    lines = _stroke([20, 24])                           # a 2-px ink line, annotated on its centre
    assert stroke_share(lines, {0: curve(20.5), 1: curve(24.5)}) == 1.0
    assert auto_target(lines, {0: curve(20.5)}) == (None, 1.0)
    # half the points on the line, half beside it on white paper: not on a stroke there
    mixed = {0: {"s": np.array([[20.5, 8.0], [20.5, 16.0], [35.0, 24.0], [35.0, 32.0]])}}
    assert stroke_share(lines, mixed) == 0.5 >= STROKED
    assert stroke_share(lines, {}) == 0.0


def test_auto_snap_is_the_edge_snap_on_flat_colour_and_no_snap_on_line_art():
    edges = [16, 17, 20, 25, 29, 31]
    T = len(edges)
    curve = lambda x: np.stack([np.full(4, x), np.linspace(8.0, 32.0, 4)], -1)
    ann = {"keyframes": [{"frame": 0, "curves": {"edge.a": curve(edges[0] + 0.5)}},
                         {"frame": T - 1, "curves": {"edge.a": curve(edges[-1] + 0.5)}}]}
    opts = dict(init="linear", max_nfev=3, levels=1, colour=0.0, sketch=0.0, edge=0.0, snap=3.0)
    flat = _two_colours(edges)
    np.testing.assert_array_equal(track_clip(flat, ann, "ours", snap_to="auto", **opts),
                                  track_clip(flat, ann, "ours", snap_to="edge", **opts))
    lines = _stroke(edges)
    plain = track_clip(lines, ann, "ours", **{**opts, "snap": 0.0})
    np.testing.assert_array_equal(track_clip(lines, ann, "ours", snap_to="auto", **opts), plain)
    # the edge snap would have moved the line's points onto a side of the stroke
    assert not np.array_equal(track_clip(lines, ann, "ours", snap_to="edge", **opts), plain)
    from nnsf.roto.solve import ClipTracker
    with pytest.raises(ValueError, match="auto.*keyframes"):
        ClipTracker(flat, "ours", TrackOptions.from_kwargs(snap=3.0, snap_to="auto"))
    assert ClipTracker(flat, "lk", TrackOptions.from_kwargs(snap=3.0, snap_to="auto")).snap_target is None
