"""The limb model (Eq. 9-10) and subkey points (Eq. 11-14), against analytic oracles."""
from __future__ import annotations

import numpy as np
import pytest

from stick_figure import stick_figure
from nnsf.reshape.limbs import (
    LIMB_PAIRS, STRAIGHT, bezier, control_from_omega, endpoints, fit_omega, limb_curves,
    omega_from_control, rot90,
)
from nnsf.reshape.mesh import triangulate
from nnsf.reshape.subkeys import SubkeyTracker, closest_on_bezier, init_subkeys, propagate

rng = np.random.default_rng(7)


def _rotation(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


# --------------------------------------------------------------------------- Eq. 9-10

def test_bezier_endpoints_midpoint_and_omega_round_trip():
    p0, p1 = rng.normal(size=(50, 2)) * 100, rng.normal(size=(50, 2)) * 100
    omega = rng.normal(size=(50, 2))
    pc = control_from_omega(p0, p1, omega)
    B = bezier(p0, pc, p1, np.array([0.0, 0.5, 1.0]))  # (50, 3, 2)
    np.testing.assert_allclose(B[:, 0], p0, atol=1e-12)
    np.testing.assert_allclose(B[:, 2], p1, atol=1e-12)
    np.testing.assert_allclose(B[:, 1], 0.25 * p0 + 0.5 * pc + 0.25 * p1, atol=1e-12)
    np.testing.assert_allclose(omega_from_control(p0, p1, pc), omega, atol=1e-12)
    # R90 is +90° in (x, y) axes, and ω is invariant to similarity transforms of the limb.
    np.testing.assert_array_equal(rot90(np.array([1.0, 0.0])), [0.0, 1.0])
    S = 2.5 * _rotation(33)
    t = np.array([10.0, -4.0])
    np.testing.assert_allclose(omega_from_control(p0 @ S.T + t, p1 @ S.T + t, pc @ S.T + t), omega, atol=1e-10)
    # The straight ω parameterises the bone uniformly.
    lam = np.linspace(0, 1, 7)
    np.testing.assert_allclose(bezier(p0, control_from_omega(p0, p1, STRAIGHT), p1, lam),
                               p0[:, None] + lam[:, None] * (p1 - p0)[:, None], atol=1e-12)


def test_limb_functions_broadcast_over_frames():
    fig = stick_figure(height=200)
    kp = np.stack([fig.keypoints, fig.keypoints + 5.0, fig.keypoints * 1.1])  # (3, 17, 2)
    om = np.tile(STRAIGHT, (3, 8, 1))
    assert control_from_omega(*endpoints(kp), om).shape == (3, 8, 2)
    curves = limb_curves(kp, om, np.linspace(0, 1, 5))
    assert curves.shape == (3, 8, 5, 2)
    np.testing.assert_allclose(curves[:, :, 0], kp[:, LIMB_PAIRS[:, 0]])
    np.testing.assert_allclose(curves[:, :, -1], kp[:, LIMB_PAIRS[:, 1]])


def test_fit_omega_recovers_a_bent_limb():
    import cv2
    p0, p1 = np.array([60.0, 100.0]), np.array([260.0, 100.0])
    truth = np.array([0.5, 0.2])
    pc = control_from_omega(p0, p1, truth)
    curve = bezier(p0, pc, p1, np.linspace(0, 1, 200))
    mask = np.zeros((200, 320), np.uint8)
    cv2.polylines(mask, [np.rint(curve).astype(np.int32)], False, 1, 21)
    kp = np.zeros((17, 2))
    kp[:] = p0
    kp[LIMB_PAIRS[0, 0]], kp[LIMB_PAIRS[0, 1]] = p0, p1   # l_upper_arm
    kp[LIMB_PAIRS[1, 1]] = p1 + [1.0, 0.0]               # l_forearm: too short to fit, stays straight
    om = fit_omega(mask.astype(bool), kp)
    assert om[0, 0] == pytest.approx(0.5)
    assert om[0, 1] == pytest.approx(truth[1], abs=0.01)
    np.testing.assert_array_equal(om[1], STRAIGHT)


# --------------------------------------------------------------------------- Eq. 13-14

def _brute_force(p0, pc, p1, q, n=200001):
    lam = np.linspace(0, 1, n)
    B = bezier(p0, pc, p1, lam)  # (..., n, 2)
    d = ((B - q[..., None, :]) ** 2).sum(-1)
    i = np.argmin(d, axis=-1)
    return lam[i], np.sqrt(d.min(-1))


def test_cubic_closest_point_matches_dense_sampling():
    N = 300
    p0, p1 = rng.normal(size=(N, 2)) * 50, rng.normal(size=(N, 2)) * 50
    pc = control_from_omega(p0, p1, rng.normal(size=(N, 2)) * 0.6)
    q = rng.normal(size=(N, 2)) * 80
    lam, pt = closest_on_bezier(p0, pc, p1, q)
    assert lam.shape == (N,) and pt.shape == (N, 2)
    np.testing.assert_allclose(pt, bezier(p0, pc, p1, lam[:, None])[np.arange(N), 0], atol=1e-9)
    for k in range(0, N, 30):   # dense sampling is heavy: check a subset against it
        _, dist = _brute_force(p0[k], pc[k], p1[k], q[k])
        assert np.linalg.norm(pt[k] - q[k]) <= dist + 1e-6
    # Never worse than any sample of the curve, on all queries (coarse grid).
    B = bezier(p0, pc, p1, np.linspace(0, 1, 2001))
    coarse = np.sqrt(((B - q[:, None]) ** 2).sum(-1).min(-1))
    assert np.all(np.linalg.norm(pt - q, axis=1) <= coarse + 1e-9)


def test_closest_point_linear_case_and_ends():
    p0, p1 = np.array([0.0, 0.0]), np.array([10.0, 0.0])
    pc = control_from_omega(p0, p1, STRAIGHT)       # A = 0: the cubic is linear
    q = np.array([[3.0, 4.0], [-5.0, 1.0], [12.0, -2.0], [10.0, 0.0]])
    lam, pt = closest_on_bezier(p0, pc, p1, q)
    np.testing.assert_allclose(lam, [0.3, 0.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(pt, [[3, 0], [0, 0], [10, 0], [10, 0]], atol=1e-12)
    # Nearly straight (A tiny but non-zero) behaves the same.
    pc2 = control_from_omega(p0, p1, [0.5, 1e-9])
    np.testing.assert_allclose(closest_on_bezier(p0, pc2, p1, q)[0], [0.3, 0.0, 1.0, 1.0], atol=1e-7)


# --------------------------------------------------------------------------- Eq. 12

def test_propagation_under_translation_and_rotation():
    p0, p1 = np.array([10.0, 20.0]), np.array([110.0, 60.0])
    s = np.linspace(0.05, 0.95, 9)[:, None]
    q = p0 + s * (p1 - p0)                     # subkeys on the limb
    off = q + rng.normal(size=q.shape) * 5     # and near it
    shift = np.array([-7.5, 13.0])
    np.testing.assert_allclose(propagate(q, p0, p1, p0 + shift, p1 + shift), q + shift, atol=1e-12)
    np.testing.assert_allclose(propagate(off, p0, p1, p0 + shift, p1 + shift), off + shift, atol=1e-12)
    R = _rotation(50)
    c = np.array([30.0, -10.0])
    n0, n1 = (p0 - c) @ R.T + c, (p1 - c) @ R.T + c
    moved = propagate(q, p0, p1, n0, n1)
    np.testing.assert_allclose(moved, (q - c) @ R.T + c, atol=1e-10)   # same fraction along the limb
    u, v = moved - n0, n1 - n0
    np.testing.assert_allclose(u[:, 0] * v[1] - u[:, 1] * v[0], 0, atol=1e-9)


def test_tracker_keeps_subkeys_on_the_limb_through_a_clip():
    fig = stick_figure(height=300)
    V, _, h = triangulate(fig.mask, 400)
    mesh = type("Mesh", (), {"vertices": V, "spacing": h})
    om = fit_omega(fig.mask, fig.keypoints)
    sk = init_subkeys(mesh.vertices, fig.keypoints, om, per_limb=4)
    assert len(sk) > 8 and len(np.unique(sk.vertex)) == len(sk)
    # Eq. 11: each subkey is the vertex nearest its curve sample, so near the curve.
    p0, p1 = endpoints(fig.keypoints)
    pc = control_from_omega(p0, p1, om)
    _, on = closest_on_bezier(p0[sk.limb], pc[sk.limb], p1[sk.limb], mesh.vertices[sk.vertex])
    assert np.linalg.norm(mesh.vertices[sk.vertex] - on, axis=1).max() < mesh.spacing
    # A clip: the whole body turns and moves, one forearm swings.
    T = 12
    kp = np.repeat(fig.keypoints[None], T, 0)
    centre = fig.keypoints.mean(0)
    for t in range(T):
        kp[t] = (fig.keypoints - centre) @ _rotation(4 * (t + 1)).T + centre + [2.0 * t, -1.0 * t]
        kp[t, 13] = kp[t, 12] + (kp[t, 13] - kp[t, 12]) @ _rotation(-6 * (t + 1)).T
    for keep in (False, True):
        tr = SubkeyTracker(sk, fig.keypoints, om, keep_offset=keep)
        out = tr.track(kp, om)
        assert out.shape == (T, len(sk), 2)
        a0, a1 = endpoints(kp)
        ac = control_from_omega(a0, a1, om)
        _, near = closest_on_bezier(a0[:, sk.limb], ac[:, sk.limb], a1[:, sk.limb], out)
        dist = np.linalg.norm(out - near, axis=-1)
        if keep:   # a curve point plus the rest offset (under one mesh spacing)
            assert np.all(dist <= np.linalg.norm(sk.offset, axis=1) + 1e-9)
        else:      # the paper's positions lie on the curve
            assert dist.max() < 1e-9
    # At rest the tracked subkeys are exactly their vertices.
    tr = SubkeyTracker(sk, fig.keypoints, om)
    np.testing.assert_allclose(tr.track(fig.keypoints[None], om)[0], mesh.vertices[sk.vertex], atol=1e-9)
    # Under a pure translation the tracked subkeys translate.
    shift = np.array([15.0, -8.0])
    np.testing.assert_allclose(tr.track(fig.keypoints[None] + shift, om)[0],
                               mesh.vertices[sk.vertex] + shift, atol=1e-9)


def test_limb_frame_propagation_does_not_slide_along_a_bent_limb():
    from nnsf.reshape.subkeys import Subkeys
    kp = stick_figure(height=300).keypoints
    om = np.tile([0.5, 0.25], (8, 1))                       # strongly bent limbs
    p0, p1 = endpoints(kp)
    pc = control_from_omega(p0, p1, om)
    lam = np.tile([0.2, 0.4, 0.6, 0.8], 8)
    limb = np.repeat(np.arange(8), 4)
    on = bezier(p0[limb], pc[limb], p1[limb], lam[:, None])[np.arange(32), 0]
    sk = Subkeys(limb=limb, vertex=np.arange(32), lam=lam, offset=np.zeros((32, 2)))
    T = 12
    c = kp.mean(0)
    clip = np.stack([(kp - c) @ _rotation(5 * (t + 1)).T + c for t in range(T)])
    rigid = (on - c) @ _rotation(5 * T).T + c
    frame = SubkeyTracker(sk, kp, om, propagation="limb-frame").track(clip, om)[-1]
    np.testing.assert_allclose(frame, rigid, atol=1e-9)
    paper = SubkeyTracker(sk, kp, om, propagation="eq12").track(clip, om)[-1]
    a0, a1 = endpoints(clip[-1])
    ac = control_from_omega(a0, a1, om)
    assert np.abs(closest_on_bezier(a0[limb], ac[limb], a1[limb], paper)[1] - paper).max() < 1e-9  # on the curve
    assert np.abs(paper - rigid).max() > 0.1   # but slid along it: Eq. 12 is exact on straight bones only
    with pytest.raises(ValueError, match="propagation"):
        SubkeyTracker(sk, kp, om, propagation="nope")
