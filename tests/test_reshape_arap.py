"""Two-step ARAP, the deformation metrics and the assembled rig."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from nnsf.reshape import metrics
from nnsf.reshape.arap import Handles, TwoStepARAP, barycentric
from nnsf.reshape.character import load_animated_drawings, stick_figure
from nnsf.reshape.mesh import triangle_areas
from nnsf.reshape.rig import Rig
from nnsf.skeleton import JOINT_INDEX as J

CHARACTERS = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters"
rng = np.random.default_rng(3)


def _rotation(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=300)


@pytest.fixture(scope="module")
def rig(figure):
    return Rig.build(figure, n_vertices=400)


def _scale(v):
    return np.abs(v).max()


# --------------------------------------------------------------------------- handles

def test_barycentric_handles_reproduce_points(figure, rig):
    m = rig.mesh
    bary, tri = barycentric(m.vertices, m.triangles, figure.keypoints)
    assert np.all(bary.sum(1) == pytest.approx(1.0))
    H = Handles.at_points(m.vertices, m.triangles, figure.keypoints, 3.0)
    np.testing.assert_allclose(H.positions(m.vertices), figure.keypoints, atol=1e-9)
    assert np.all(H.weights == 3.0) and len(H) == 17
    both = H + Handles.at_vertices(m.n_vertices, [0, 5], 2.0)
    np.testing.assert_allclose(both.positions(m.vertices)[17:], m.vertices[[0, 5]])
    frames = np.stack([m.vertices, m.vertices + 1.0])
    np.testing.assert_allclose(both.positions(frames)[1], both.positions(m.vertices) + 1.0, atol=1e-12)


# --------------------------------------------------------------------------- ARAP oracles

@pytest.mark.parametrize("handle_set", ["subkeys", "keypoints"])
def test_rest_handles_give_the_rest_mesh(figure, rig, handle_set):
    r = rig if handle_set == "subkeys" else Rig.build(figure, mesh=rig.mesh, handle_set="keypoints")
    d = r.deformer
    rest_targets = r.handles.positions(r.mesh.vertices)
    for steps in (1, 2):
        np.testing.assert_allclose(d.deform(rest_targets, steps=steps), r.mesh.vertices,
                                   atol=1e-9 * _scale(r.mesh.vertices), rtol=0)
    # Through the whole rig: a clip that stays at rest.
    clip = np.repeat(figure.keypoints[None], 3, 0)
    np.testing.assert_allclose(r.animate(clip), np.broadcast_to(r.mesh.vertices, (3,) + r.mesh.vertices.shape),
                               atol=1e-9 * _scale(r.mesh.vertices), rtol=0)


def test_rigid_motion_of_all_handles_moves_the_mesh_rigidly(rig):
    d, V, T = rig.deformer, rig.mesh.vertices, rig.mesh.triangles
    g = rig.handles.positions(V)
    R, t = _rotation(37), np.array([25.0, -40.0])
    for moved_targets, moved in ((g + t, V + t), (g @ R.T + t, V @ R.T + t)):
        out = d.deform(moved_targets)
        np.testing.assert_allclose(out, moved, atol=1e-9 * _scale(V), rtol=0)
        assert metrics.arap_energy(V, out, T) < 1e-16 * triangle_areas(V, T).sum()
        assert metrics.flipped(V, out, T) == 0
    # Step 1 is similarity invariant: a uniform scale is reproduced exactly.
    np.testing.assert_allclose(d.deform(1.7 * g @ R.T, steps=1), 1.7 * V @ R.T, atol=1e-9 * _scale(V), rtol=0)


def test_prefactorised_solves_equal_dense_least_squares(figure):
    small = Rig.build(figure, n_vertices=150)   # dense SVD least squares is O(n³)
    d = small.deformer
    g = small.handles.positions(small.mesh.vertices) + rng.normal(size=(len(small.handles), 2)) * 15
    n = d.n_vertices
    v1 = d.similarity_step(g)
    M, r = d.similarity_system(g)
    with threadpool_limits(1):   # threaded LAPACK crawls on a busy 2-core machine
        z = np.linalg.lstsq(M.toarray(), r, rcond=None)[0]
    np.testing.assert_allclose(v1, np.column_stack([z[:n], z[n:]]), atol=1e-9 * _scale(v1), rtol=0)
    v2 = d.scale_step(v1, g)
    M2, R2 = d.scale_system(v1, g)
    with threadpool_limits(1):
        z2 = np.linalg.lstsq(M2.toarray(), R2, rcond=None)[0]
    np.testing.assert_allclose(v2, z2, atol=1e-9 * _scale(v2), rtol=0)
    np.testing.assert_allclose(d.deform(g), v2, atol=1e-12 * _scale(v2), rtol=0)
    # A clip solved in one go equals frame-by-frame solves.
    G = np.stack([g, g * 0.9, g + 3.0])
    clip = d.deform(G)
    for f in range(3):
        np.testing.assert_allclose(clip[f], d.deform(G[f]), atol=1e-10 * _scale(v2), rtol=0)
    np.testing.assert_allclose(d.similarity_step(G)[1], d.similarity_step(G[1]), atol=1e-10 * _scale(v2), rtol=0)


def test_fast_frame_on_a_layered_mesh_equals_the_dense_normal_equations(figure, monkeypatch):
    """The per-frame path (step 1 as one complex Hermitian system through the precomputed
    M₁ = H⁻¹CᵀW², step 2 as one two-column back-solve) against both steps' dense normal equations,
    on the stage's pieced mesh with strained, non-rigid targets; and step 1 through M₁ against
    step 1 by back-solve."""
    import nnsf.reshape.arap as arap

    small = Rig.build(figure, n_vertices=300, split="layered", propagation="limb-frame")
    d = small.deformer
    kp = np.repeat(figure.keypoints[None], 3, 0)
    arm = [J["l_elbow"], J["l_wrist"]]
    kp[1, arm] = (kp[1, arm] - kp[1, J["l_shoulder"]]) @ _rotation(50).T + kp[1, J["l_shoulder"]]
    G = small.targets(kp) + rng.normal(size=(3, len(small.handles), 2)) * 4.0
    fast = d.deform(G)
    n = d.n_vertices
    for f in range(3):
        M, r = d.similarity_system(G[f])
        with threadpool_limits(1):
            A = M.toarray()
            z = np.linalg.solve(A.T @ A, A.T @ r)
            M2, R2 = d.scale_system(np.column_stack([z[:n], z[n:]]), G[f])
            B = M2.toarray()
            slow = np.linalg.solve(B.T @ B, B.T @ R2)
        np.testing.assert_allclose(fast[f], slow, atol=1e-9 * _scale(slow), rtol=0)
    assert d._M1 is not None
    monkeypatch.setattr(arap, "DENSE_STEP1_MAX", 0)
    solved = TwoStepARAP(d.vertices, d.triangles, d.handles)
    assert solved._M1 is None
    for steps in (1, 2):
        np.testing.assert_allclose(solved.deform(G, steps=steps), d.deform(G, steps=steps),
                                   atol=1e-10 * _scale(fast), rtol=0)


def test_handles_that_do_not_pin_the_mesh_are_refused(rig):
    V, T = rig.mesh.vertices, rig.mesh.triangles
    with pytest.raises(ValueError, match="singular"):
        TwoStepARAP(V, T, Handles.at_vertices(len(V), [0]))
    with pytest.raises(ValueError, match=r"expected handle targets"):
        rig.deformer.deform(np.zeros((3, 2)))


# --------------------------------------------------------------------------- metrics

def test_singular_values_and_affine_stretch(rig):
    J_ = rng.normal(size=(200, 2, 2))
    s1, s2, det = metrics.singular_values(J_)
    ref = np.linalg.svd(J_, compute_uv=False)
    np.testing.assert_allclose(np.column_stack([s1, s2]), ref, atol=1e-12)
    np.testing.assert_allclose(det, np.linalg.det(J_), atol=1e-12)
    V, T = rig.mesh.vertices, rig.mesh.triangles
    A = np.array([[2.0, 0.0], [0.0, 1.0]]) @ _rotation(20).T
    out = V @ A.T
    area = triangle_areas(V, T).sum()
    assert metrics.arap_energy(V, out, T) == pytest.approx(area, rel=1e-9)     # (2−1)² + (1−1)²
    np.testing.assert_allclose(metrics.stretch_ratio(V, out, T), 2.0, rtol=1e-9)
    assert metrics.flipped(V, out, T) == 0
    mirror = V * [-1.0, 1.0]
    assert metrics.flipped(V, mirror, T) == len(T)
    frames = np.stack([V, out, mirror])
    np.testing.assert_array_equal(metrics.flipped(V, frames, T), [0, 0, len(T)])
    np.testing.assert_array_equal(metrics.driving_failures(V, frames, T), [False, False, True])
    assert metrics.driving_failure_ratio(V, frames, T) == pytest.approx(1 / 3)
    assert metrics.driving_failures(V, V[None] @ np.diag([3.5, 1.0]), T)[0]   # σ1/σ2 > 3


def test_outline_self_crossing_detects_a_fold():
    # A strip, 100 x 20 px; the right half is swung back over the left half.
    xs, ys = np.meshgrid(np.linspace(0, 100, 21), np.linspace(0, 20, 5))
    V = np.column_stack([xs.ravel(), ys.ravel()])
    idx = np.arange(V.shape[0]).reshape(5, 21)
    T = np.concatenate([np.column_stack([idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()]),
                        np.column_stack([idx[:-1, :-1].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()])])
    T[triangle_areas(V, T) < 0] = T[triangle_areas(V, T) < 0][:, [0, 2, 1]]
    assert metrics.outline_self_crossings(V, T) == 0
    folded = V.copy()
    right = V[:, 0] > 50
    folded[right] = (V[right] - [50, 10]) @ _rotation(150).T + [50, 10]
    assert metrics.outline_self_crossings(folded, T) > 0
    np.testing.assert_array_equal(metrics.outline_self_crossings(np.stack([V, folded]), T) > 0, [False, True])


def test_widths_jitter_and_report(figure, rig):
    m, kp, om = rig.mesh, figure.keypoints, rig.rest_omega
    w0 = metrics.limb_widths(m.vertices, m.triangles, m.parts, kp, om)
    assert w0.shape == (8,) and np.all(np.isfinite(w0))
    np.testing.assert_allclose(w0, 0.09 * 300, rtol=0.25)   # stick_figure draws limbs 0.09 x height wide
    R, t = _rotation(-25), np.array([4.0, 9.0])
    w1 = metrics.limb_widths(m.vertices @ R.T + t, m.triangles, m.parts, kp @ R.T + t, om)
    np.testing.assert_allclose(w1, w0, rtol=1e-9)
    np.testing.assert_allclose(metrics.width_drift(np.stack([w0, w1, 1.1 * w0])),
                               [np.zeros(8), np.zeros(8), np.full(8, 0.1)], atol=1e-9)
    steady = m.vertices[None] + np.arange(5)[:, None, None] * np.array([1.0, 2.0])
    assert metrics.temporal_jitter(steady) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(metrics.limb_bending(np.tile([0.5, 0.0], (8, 1))), 0.0)
    clip = np.repeat(kp[None], 4, 0)
    V = rig.animate(clip)
    rep = metrics.deformation_report(m.vertices, V, m.triangles, m.parts, clip, om, kp, om)
    assert rep["flipped_triangles"] == 0 and rep["driving_failure_ratio"] == 0.0
    assert rep["arap_energy_max"] < 1e-12 and rep["width_drift_max"] < 1e-9


# --------------------------------------------------------------------------- the rig

def _raise_arm(kp, degrees, T):
    """Frames that swing the left arm (shoulder fixed) up by ``degrees`` in ``T`` steps."""
    out = np.repeat(kp[None], T, 0)
    for t in range(T):
        R = _rotation(-degrees * (t + 1) / T)
        sh = kp[J["l_shoulder"]]
        out[t, [J["l_elbow"], J["l_wrist"]]] = (kp[[J["l_elbow"], J["l_wrist"]]] - sh) @ R.T + sh
    return out


def test_rig_streams_like_it_animates_and_keeps_the_arm_rigid(figure, rig):
    clip = _raise_arm(figure.keypoints, 40, 8)
    V = rig.animate(clip)
    rig.reset()
    streamed = np.stack([rig.step(k) for k in clip])
    np.testing.assert_allclose(streamed, V, atol=1e-9)
    base = Rig.build(figure, mesh=rig.mesh, handle_set="keypoints")
    assert len(base.handles) == 17 and len(rig.handles) == 17 + len(rig.subkeys)
    Vb = base.animate(clip)
    m = rig.mesh
    for out in (V, Vb):
        assert metrics.flipped(m.vertices, out, m.triangles).sum() == 0
    # The forearm turns rigidly with its key points: its vertices follow that rotation closely.
    fore = np.unique(m.triangles[m.parts == 2 + 1])   # part 3 = l_forearm
    R = _rotation(-40)
    sh = figure.keypoints[J["l_shoulder"]]
    expect = (m.vertices[fore] - sh) @ R.T + sh
    err_sub = np.linalg.norm(V[-1, fore] - expect, axis=1).mean()
    err_key = np.linalg.norm(Vb[-1, fore] - expect, axis=1).mean()
    assert err_sub < 0.1 * np.linalg.norm(figure.keypoints[J["l_wrist"]] - sh)
    assert err_sub <= err_key + 1e-9


def test_char1_arm_raise():
    if not (CHARACTERS / "char1").is_dir():
        pytest.skip(f"AnimatedDrawings example characters not found at {CHARACTERS}")
    ch = load_animated_drawings(CHARACTERS / "char1")
    rig = Rig.build(ch, n_vertices=800)
    clip = _raise_arm(ch.keypoints, 45, 10)
    V = rig.animate(clip)
    m = rig.mesh
    assert metrics.flipped(m.vertices, V, m.triangles).sum() == 0
    assert metrics.driving_failure_ratio(m.vertices, V, m.triangles) < 0.5
    g = rig.targets(clip)
    assert np.abs(rig.handles.positions(V) - g).max() < 2.0   # handles are met within 2 px


def test_split_rig_rest_and_rigid_and_per_piece_outline(figure):
    rig = Rig.build(figure, n_vertices=400, split=True)
    m = rig.mesh
    assert m.is_split and len(rig.handle_keypoints) == 17 + 4   # shoulders and hips on both sides
    clip = np.repeat(figure.keypoints[None], 2, 0)
    np.testing.assert_allclose(rig.animate(clip)[-1], m.vertices, atol=1e-9 * _scale(m.vertices), rtol=0)
    R, t = _rotation(-20), np.array([5.0, 7.0])
    g = rig.handles.positions(m.vertices)
    np.testing.assert_allclose(rig.deformer.deform(g @ R.T + t), m.vertices @ R.T + t,
                               atol=1e-9 * _scale(m.vertices), rtol=0)
    # Through the whole rig, with subkeys carried in their limb's frame (exact for rigid motion).
    framed = Rig.build(figure, mesh=m, propagation="limb-frame")
    moved = framed.animate((figure.keypoints @ R.T + t)[None])[0]
    np.testing.assert_allclose(moved, m.vertices @ R.T + t, atol=1e-9 * _scale(m.vertices), rtol=0)
    # Swing an arm across the chest: the pieces overlap, which is not a self-crossing of any piece.
    across = _raise_arm(figure.keypoints, -120, 12)
    V = rig.animate(across)
    assert metrics.flipped(m.vertices, V, m.triangles).sum() == 0
    assert metrics.outline_self_crossings(V[-1], m.triangles, m.pieces) == 0
    assert metrics.outline_self_crossings(V[-1], m.triangles) > 0
