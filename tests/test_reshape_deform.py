"""Two-step ARAP against oracles, the deformation measures, and the paper's deformation of a character's
one connected mesh: rest is rest, rigid is rigid, a bent limb bends smoothly and nothing comes apart."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from nnsf.reshape import metrics
from nnsf.reshape.animator import Animator
from nnsf.reshape.arap import Handles, TwoStepARAP, barycentric
from stick_figure import stick_figure
from nnsf.reshape.deform import Deformer, keypoint_handles
from nnsf.reshape.mesh import triangle_areas
from nnsf.skeleton import JOINT_INDEX as J

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
rng = np.random.default_rng(3)


def _rotation(deg):
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=300)


@pytest.fixture(scope="module")
def rig(figure):
    """The character's pipeline (the fixture keeps its old name: ``rig.mesh``, ``rig.deformer``)."""
    a = Animator(figure, n_vertices=400)
    a.handles, a.deformer_ = a.deformer.handles, a.deformer
    return a


def _scale(v):
    return np.abs(v).max()


# --------------------------------------------------------------------------- handles

def test_barycentric_handles_reproduce_points(figure, rig):
    m = rig.mesh
    bary, tri = barycentric(m.vertices, m.triangles, figure.keypoints)
    assert np.all(bary.sum(1) == pytest.approx(1.0))
    H = keypoint_handles(m, rig.rig, 3.0)
    np.testing.assert_allclose(H.positions(m.vertices), figure.keypoints, atol=1e-9)
    assert np.all(H.weights == 3.0) and len(H) == 17
    both = H + Handles.at_vertices(m.n_vertices, [0, 5], 2.0)
    np.testing.assert_allclose(both.positions(m.vertices)[17:], m.vertices[[0, 5]])
    frames = np.stack([m.vertices, m.vertices + 1.0])
    np.testing.assert_allclose(both.positions(frames)[1], both.positions(m.vertices) + 1.0, atol=1e-12)


# --------------------------------------------------------------------------- ARAP oracles

@pytest.mark.parametrize("method", ["ours", "keypoints"])
def test_rest_handles_give_the_rest_mesh(figure, rig, method):
    d = Deformer(rig.mesh, rig.rig, figure.mask, method)
    rest_targets = d.handles.positions(rig.mesh.vertices)
    for steps in (1, 2):
        np.testing.assert_allclose(d.arap.deform(rest_targets, steps=steps), rig.mesh.vertices,
                                   atol=1e-9 * _scale(rig.mesh.vertices), rtol=0)
    # Through the whole pipeline: a clip that stays at rest.
    clip = np.repeat(figure.keypoints[None], 3, 0)
    np.testing.assert_allclose(d.run(clip), np.broadcast_to(rig.mesh.vertices, (3,) + rig.mesh.vertices.shape),
                               atol=1e-9 * _scale(rig.mesh.vertices), rtol=0)


def test_rigid_motion_of_all_handles_moves_the_mesh_rigidly(rig):
    d, V, T = rig.deformer.arap, rig.mesh.vertices, rig.mesh.triangles
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
    small = Animator(figure, n_vertices=150)   # dense SVD least squares is O(n³)
    d = small.deformer.arap
    g = d.handles.positions(small.mesh.vertices) + rng.normal(size=(len(d.handles), 2)) * 15
    n = d.n_vertices
    v1 = d.deform(g, steps=1)
    M, r = d.similarity_system(g)
    with threadpool_limits(1):   # threaded LAPACK crawls on a busy 2-core machine
        z = np.linalg.lstsq(M.toarray(), r, rcond=None)[0]
    np.testing.assert_allclose(v1, np.column_stack([z[:n], z[n:]]), atol=1e-9 * _scale(v1), rtol=0)
    v2 = d.deform(g)   # step 2 from the step-1 result v1
    M2, R2 = d.scale_system(v1, g)
    with threadpool_limits(1):
        z2 = np.linalg.lstsq(M2.toarray(), R2, rcond=None)[0]
    np.testing.assert_allclose(v2, z2, atol=1e-9 * _scale(v2), rtol=0)
    # A clip solved in one go equals frame-by-frame solves.
    G = np.stack([g, g * 0.9, g + 3.0])
    clip = d.deform(G)
    for f in range(3):
        np.testing.assert_allclose(clip[f], d.deform(G[f]), atol=1e-10 * _scale(v2), rtol=0)
    np.testing.assert_allclose(d.deform(G, steps=1)[1], d.deform(G[1], steps=1), atol=1e-10 * _scale(v2), rtol=0)


def test_fast_frame_equals_the_dense_normal_equations(figure, monkeypatch):
    """The per-frame path (step 1 through the precomputed M₁ = H⁻¹CᵀW², step 2 as one two-column
    back-solve) against both steps' dense normal equations, on a character's cut mesh with strained,
    non-rigid targets; and step 1 through M₁ against step 1 by back-solve."""
    import nnsf.reshape.arap as arap

    small = Animator(figure, n_vertices=300)
    d = small.deformer.arap
    kp = np.repeat(figure.keypoints[None], 3, 0)
    arm = [J["l_elbow"], J["l_wrist"]]
    kp[1, arm] = (kp[1, arm] - kp[1, J["l_shoulder"]]) @ _rotation(50).T + kp[1, J["l_shoulder"]]
    G = small.deformer.targets(kp) + rng.normal(size=(3, len(d.handles), 2)) * 4.0
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
        rig.deformer.arap.deform(np.zeros((3, 2)))


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
    assert metrics.driving_failures(V, frames, T).mean() == pytest.approx(1 / 3)
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


def test_jitter_bending_and_report(figure, rig):
    m = rig.mesh
    steady = m.vertices[None] + np.arange(5)[:, None, None] * np.array([1.0, 2.0])
    assert metrics.temporal_jitter(steady) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(metrics.limb_bending(np.tile([0.5, 0.0], (8, 1))), 0.0)
    clip = np.repeat(figure.keypoints[None], 4, 0)
    V = rig.deformer.run(clip)
    om = rig.deformer.rest_omega
    rep = metrics.deformation_report(m, V, clip, figure.keypoints, om)
    assert rep["flipped_triangles"] == 0 and rep["driving_failure_ratio"] == 0.0
    assert rep["arap_energy_max"] < 1e-12 and rep["limb_bending_change"] < 1e-9


# --------------------------------------------------------------------------- the character


def _raise_arm(kp, degrees, T, elbow=0.0):
    """Frames that swing the left arm (shoulder fixed) by ``degrees`` in ``T`` steps, the forearm bending
    a further ``elbow`` degrees at the elbow."""
    out = np.repeat(kp[None], T, 0)
    for t in range(T):
        f = (t + 1) / T
        sh = kp[J["l_shoulder"]]
        out[t, [J["l_elbow"], J["l_wrist"]]] = (kp[[J["l_elbow"], J["l_wrist"]]] - sh) @ _rotation(-degrees * f).T + sh
        el = out[t, J["l_elbow"]]
        out[t, J["l_wrist"]] = (out[t, J["l_wrist"]] - el) @ _rotation(-elbow * f).T + el
    return out


def test_a_bent_elbow_bends_the_limb_smoothly_and_subkeys_keep_it_in_shape(figure, rig):
    clip = _raise_arm(figure.keypoints, 40, 8, elbow=60)
    m = rig.mesh
    V = rig.deformer.run(clip)
    base = Deformer(m, rig.rig, figure.mask, "keypoints")
    Vb = base.run(clip)
    fans = sum(len(f[3]) for f in rig.deformer.fans)
    assert len(base.handles) == 17 and len(rig.deformer.handles) == 17 + len(rig.deformer.subkeys) + fans
    for out in (V, Vb):   # the inside of a bent elbow may fold a few triangles, no more
        assert metrics.flipped(m.vertices, out, m.triangles).max() <= 0.02 * len(m.triangles)
    om = rig.deformer.rest_omega
    ours = metrics.deformation_report(m, V, clip, figure.keypoints, om)
    keys = metrics.deformation_report(m, Vb, clip, figure.keypoints, om)
    # The limbs bend with the motion (the measure moves), and less than with key points alone.
    assert ours["limb_bending_change"] > 1e-4
    assert ours["limb_bending_change"] < keys["limb_bending_change"]
    # The forearm's middle follows its bone within a fraction of its length.
    fore = np.unique(m.triangles[(m.parts == 3) & (m.layer == 0)])   # part 3 = l_forearm
    sh, el, wr = clip[-1, J["l_shoulder"]], clip[-1, J["l_elbow"]], clip[-1, J["l_wrist"]]
    d = wr - el
    u = ((V[-1, fore] - el) @ d) / (d @ d)
    mid = (u > 0.3) & (u < 0.7)
    rel = V[-1, fore][mid] - el
    off = np.abs(d[0] * rel[:, 1] - d[1] * rel[:, 0]) / np.linalg.norm(d)
    assert off.max() < 0.2 * np.linalg.norm(figure.keypoints[J["l_wrist"]] - figure.keypoints[J["l_elbow"]]) + 0.09 * 300


def test_a_sharply_bent_elbow_stays_round_on_the_outside(figure, rig, monkeypatch):
    """Bent 150° from the drawn straight arm, the outside of the elbow is an arc about the joint (the
    elbow's fan, docs/method.md §13), not the chord two rigid triangles cut across it: the drawing
    reaches at least 0.7 of the arm's half-width from the elbow along the outer bisector (0.78
    measured), against 0.37 without the fan."""
    import nnsf.reshape.deform as deform
    from nnsf.reshape.animator import canvas
    from nnsf.reshape.artefacts import coverage

    clip = _raise_arm(figure.keypoints, 30, 1, elbow=150)
    el, sh, wr = clip[0, J["l_elbow"]], clip[0, J["l_shoulder"]], clip[0, J["l_wrist"]]
    inner = (sh - el) / np.linalg.norm(sh - el) + (wr - el) / np.linalg.norm(wr - el)
    out = -inner / np.linalg.norm(inner)
    half = rig.rig.radius[(rig.rig.bones[:, 2] == 3)][0]            # part 3 = l_forearm
    reach, fan = {}, deform.FAN_WEIGHT
    for weight in (fan, 0.0):
        monkeypatch.setattr(deform, "FAN_WEIGHT", weight)
        d = Deformer(rig.mesh, rig.rig, figure.mask, "ours")
        V = d.run(clip)
        offset, size = canvas(V, shape=figure.shape)
        cov = coverage(rig.renderer(size).render(V[0] + offset))
        steps = np.arange(0, 3 * half, 0.25)
        p = np.clip(np.rint(el + offset + steps[:, None] * out).astype(int), 0, [size[1] - 1, size[0] - 1])
        reach[weight] = steps[np.argmin(cov[p[:, 1], p[:, 0]])]
    assert reach[fan] >= 0.7 * half and reach[fan] > 1.6 * reach[0.0], (reach, half)


def test_nothing_comes_apart_through_a_motion(figure, rig):
    """Every frame rendered: no detached piece; at most a few pixels of page where the drawing's
    armpit notch (page at rest, outside the mask) is pinched shut as the arm comes down across the
    body's side, and a notch of a few pixels at a joint."""
    from nnsf.reshape.animator import canvas
    from nnsf.reshape.artefacts import FrameMeasures

    clip = np.concatenate([_raise_arm(figure.keypoints, a, 6, elbow=e) for a, e in ((70, 0), (-60, 80), (120, 40))])
    V = rig.deformer.run(clip)
    offset, size = canvas(V, shape=figure.shape)
    r = rig.renderer(size)
    measure = FrameMeasures(figure.texture, figure.mask, figure.keypoints)
    for v, kp in zip(V, clip):
        got = measure(r.render(v + offset), kp + offset)
        assert got["detached"] == 0 and got["crack_px"] <= 8, got
        # (the elbow bent 80° with the forearm across the body: its inner side is one sheet that
        # folds, a notch of about a dozen pixels)
        assert got["notch_beyond_rest"] <= 12, got


def test_char1_arm_raise():
    if not (DATA / "animated-drawings" / "characters" / "char1").is_dir():
        pytest.skip("AnimatedDrawings example characters not found")
    from nnsf.reshape.formats import read_character

    ch = read_character(DATA / "animated-drawings" / "characters" / "char1")
    a = Animator(ch, n_vertices=800)
    clip = _raise_arm(ch.keypoints, 45, 10)
    V = a.deformer.run(clip)
    g = a.deformer.targets(clip)
    assert np.abs(a.deformer.handles.positions(V) - g)[:, :17].max() < 2.0   # key points met within 2 px


def test_an_underlay_rides_with_its_parts_own_vertices_not_the_seam():
    """A body (x ≤ 20) and a limb (x ≥ 20) of a 10 px grid, joined along x = 20, with an underlay
    copied from the limb's first column into the body (its own vertices at x = 30).  The seam and
    the limb dragged 50 px away, the body's own vertices still: the underlay stays with the body.
    (Riding on the nearest body triangle's affine extension, whose corners on the seam had weights
    up to 2, it left 100 px with the limb.)  An affine motion of everything moves it affinely."""
    from nnsf.reshape.deform import underlay_riders
    from nnsf.reshape.mesh import Mesh

    x, y = np.meshgrid(np.arange(5) * 10.0, np.arange(5) * 10.0)
    grid = np.column_stack([x.ravel(), y.ravel()])
    i = np.arange(20).reshape(4, 5)[:, :4].ravel()
    quads = np.column_stack([i, i + 5, i + 6, i + 1])                          # counter-clockwise, y down
    tris = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    centre_x = grid[tris].mean(axis=1)[:, 0]
    limb = centre_x > 20
    first = limb & (centre_x < 30)
    copy = tris[first].copy()
    free = np.unique(copy[grid[copy][..., 0] > 25])
    new = {v: 25 + k for k, v in enumerate(free)}
    copy = np.vectorize(lambda v: new.get(v, v))(copy)
    mesh = Mesh(vertices=np.vstack([grid, grid[free]]), triangles=np.vstack([tris, copy]),
                parts=np.r_[limb.astype(np.int64) + 2 * limb, np.zeros(first.sum(), np.int64)],
                layer=np.r_[np.zeros(len(tris), np.int64), np.ones(first.sum(), np.int64)], spacing=10.0)
    riders, ride = underlay_riders(mesh)
    assert set(riders.tolist()) == set(new.values())
    V = mesh.vertices.copy()
    V[(mesh.vertices[:, 0] >= 20) & (np.arange(len(V)) < 25), 1] += 50.0
    assert np.abs(ride @ V - mesh.vertices[riders]).max() < 1e-9
    A, t = np.array([[1.2, 0.3], [-0.2, 0.9]]), np.array([5.0, -3.0])
    assert np.allclose(ride @ (mesh.vertices @ A.T + t), mesh.vertices[riders] @ A.T + t)
