"""The dense-flow initialisation of the space-time solver (roto.init: flow)."""
from __future__ import annotations

import numpy as np

from nnsf.roto.metrics import project_to_polyline
from nnsf.roto.solve import dense_flows, flow_init, linear_init, track_clip
from nnsf.roto.toy import draw_polygons, rect, segment_controls


def _clip(T=9):
    t = np.arange(T)
    ys = 96 - 40 * np.sin(t / (T - 1) * np.pi)                 # a jump: up and down again
    polys = [rect(96, y, 50, 60) for y in ys]
    frames = np.stack([draw_polygons((192, 192), [p], [(200, 60, 50)]) for p in polys])
    truth = np.stack([segment_controls(p[1], p[2], 64) for p in polys])   # the right edge
    return frames, polys, truth


def test_flow_init_follows_a_motion_interpolation_misses_and_meets_both_keyframes():
    frames, polys, truth = _clip()
    T = len(frames)
    gray = frames.mean(-1).astype(np.uint8)
    fwd, bwd = dense_flows(gray)
    assert fwd.shape == (T - 1, 192, 192, 2)
    P = np.zeros((1, T, 4, 2))
    P[0, 0] = segment_controls(polys[0][1], polys[0][2], 4)
    P[0, -1] = segment_controls(polys[-1][1], polys[-1][2], 4)
    fixed = np.zeros((1, T, 4), bool)
    fixed[:, [0, -1]] = True
    flow = flow_init(fwd, bwd, P, fixed, np.array([0]))
    lin = linear_init(P, fixed)
    np.testing.assert_array_equal(flow[0, [0, -1]], P[0, [0, -1]])
    d_flow = project_to_polyline(flow[0], truth)[0]
    d_lin = project_to_polyline(lin[0], truth)[0]
    # the keyframes are the same box position: interpolation stays put, 40 px off at the top
    assert d_lin.max() > 35 and d_flow.max() < 3.0


def test_init_flow_tracks_the_jump():
    frames, polys, truth = _clip()
    T = len(frames)
    ann = {"keyframes": [{"frame": k, "curves": {"l_forearm.a": segment_controls(polys[k][1], polys[k][2], 4)}}
                         for k in (0, T - 1)]}
    control = track_clip(frames, ann, "ours", init="flow", max_nfev=10)
    d = project_to_polyline(control[:, 0], truth)[0]
    assert d.max() < 2.0
