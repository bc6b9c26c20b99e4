"""Layered mesh (segments, straight cuts, collars, underlay) and driving a character from a motion."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nnsf.errors import InputError
from nnsf.reshape import metrics
from nnsf.reshape.character import stick_figure
from nnsf.reshape.drive import TORSO, read_motion, retarget
from nnsf.reshape.layers import build_mesh, joint_cuts
from nnsf.reshape.mesh import triangle_adjacency, triangle_areas
from nnsf.reshape.parts import COLLARS, SEGMENTS
from nnsf.reshape.rig import Rig
from nnsf.skeleton import BONES, JOINT_INDEX as J, JOINTS, rest_pose
from nnsf.skeleton.layout import FEATURE_COLUMNS


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=360)


@pytest.fixture(scope="module")
def layered(figure):
    return Rig.build(figure, n_vertices=500, split="layered", propagation="limb-frame")


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (p - c) @ R.T + c


def _bend_elbow(kp, deg):
    out = kp.copy()
    out[J["l_wrist"]] = _rot(kp[J["l_wrist"]], kp[J["l_elbow"]], deg)
    return out


# --------------------------------------------------------------------------- mesh

def test_layered_mesh_pieces_are_connected_segments_with_collars(figure, layered):
    m = layered.mesh
    assert m.piece_names == SEGMENTS and set(np.unique(m.pieces)) == set(range(len(SEGMENTS)))
    core = m.core_triangles
    # joint tabs (the collars of the puppet mesh) are the vertices after the solved core, name the
    # part they hide under, and are textured from their own layer
    assert m.tabs and np.all(m.triangles[~core] >= m.core) and np.all(m.collar[~core] >= 0)
    assert np.all(m.layer[~core] >= 3) and np.all(m.collar[core] == -1)
    for pc in range(len(SEGMENTS)):  # every piece's solved triangles are one edge-connected group (else ARAP is singular)
        tri = m.triangles[(m.pieces == pc) & core]
        a, b = triangle_adjacency(tri)
        from scipy.sparse import coo_matrix
        from scipy.sparse.csgraph import connected_components
        n = len(tri)
        assert connected_components(coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)[0] == 1
    # every vertex belongs to exactly one piece; collar copies name a parent part
    vp = np.full(m.n_vertices, -1)
    for k, pc in enumerate(m.pieces):
        assert np.all((vp[m.triangles[k]] == -1) | (vp[m.triangles[k]] == pc))
        vp[m.triangles[k]] = pc
    assert (m.collar >= 0).sum() > 0 and np.all(m.parts[m.collar >= 0] != m.collar[m.collar >= 0])
    assert np.all(triangle_areas(m.vertices, m.triangles) > 0)


def test_cuts_cross_each_joint_inside_the_mask(figure):
    cuts = joint_cuts(figure.mask, figure.keypoints)
    assert len(cuts) == len(COLLARS)
    for c in cuts:
        j = figure.keypoints[c["joint"]]
        d = c["q"] - c["p"]
        # the joint lies on the cut segment, and the cut is perpendicular to its normal
        t = np.dot(j - c["p"], d) / np.dot(d, d)
        assert 0 <= t <= 1 and np.linalg.norm(c["p"] + t * d - j) < 1e-6
        assert abs(np.dot(d, c["normal"])) < 1e-6 * np.linalg.norm(d)


def test_drive_carries_moved_pivots_with_the_torso(figure, layered):
    """Rig.drive on a pose whose torso is the rest torso turned by 25° and moved, with one arm
    and one leg turned: each moved pivot is the rest pivot under that rigid motion, the point
    after it keeps the motion's direction and the rest length from the pivot, points further down
    move with it, and the torso's key points are untouched."""
    rig = layered
    assert rig.moved and len(rig._pivots) >= 2
    rest0, rest1 = figure.keypoints, rig.rest_keypoints
    a = np.radians(25.0)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    t = np.array([14.0, -9.0])
    kp = rest0 @ R.T + t
    kp[[J["l_elbow"], J["l_wrist"]]] = _rot(kp[[J["l_elbow"], J["l_wrist"]]], kp[J["l_shoulder"]], 35.0)
    kp[[J["r_knee"], J["r_ankle"]]] = _rot(kp[[J["r_knee"], J["r_ankle"]]], kp[J["r_hip"]], -20.0)
    out = rig.drive(kp)
    np.testing.assert_array_equal(rig.drive(kp[None])[0], out)
    down = {J["l_shoulder"]: (J["l_elbow"], J["l_wrist"]), J["r_shoulder"]: (J["r_elbow"], J["r_wrist"]),
            J["l_hip"]: (J["l_knee"], J["l_ankle"]), J["r_hip"]: (J["r_knee"], J["r_ankle"]),
            J["neck"]: (J["head_top"],)}
    moved = [j for j in down if not np.allclose(rest0[j], rest1[j])]
    assert sorted(moved) == sorted(rig._pivots.tolist())
    for j in moved:
        nxt = down[j][0]
        np.testing.assert_allclose(out[j], rest1[j] @ R.T + t, atol=1e-9)
        d_in, d_out = kp[nxt] - kp[j], out[nxt] - out[j]
        assert abs(d_in[0] * d_out[1] - d_in[1] * d_out[0]) < 1e-9 * np.linalg.norm(d_in) * np.linalg.norm(d_out)
        assert d_in @ d_out > 0
        assert np.linalg.norm(d_out) == pytest.approx(np.linalg.norm(rest1[nxt] - rest1[j]), rel=1e-12)
        for q in down[j][1:]:
            np.testing.assert_allclose(out[q] - kp[q], out[nxt] - kp[nxt], atol=1e-9)
    still = [k for k in range(len(kp)) if k not in moved and all(k not in v for j, v in down.items() if j in moved)]
    np.testing.assert_array_equal(out[still], kp[still])


def test_rigid_motion_is_reproduced_exactly(figure, layered):
    kp = _rot(figure.keypoints, np.array([100.0, 80.0]), 27.0) + [13.0, -4.0]
    V = layered.animate(kp[None])[0]
    ref = _rot(layered.mesh.vertices, np.array([100.0, 80.0]), 27.0) + [13.0, -4.0]
    assert np.abs(V - ref).max() < 1e-6


@pytest.mark.parametrize("deg", [60.0, 120.0, 150.0])
def test_a_strong_elbow_bend_folds_the_connected_mesh_but_not_the_layered_one(figure, layered, deg):
    kp = np.stack([_bend_elbow(figure.keypoints, d) for d in np.linspace(0, deg, 6)])
    V = layered.animate(kp)
    m = layered.mesh
    assert metrics.flipped(m.vertices, V, m.triangles).max() == 0
    # every piece moves rigidly: each triangle's map is a rotation (σ1 = σ2 = 1)
    assert metrics.stretch_ratio(m.vertices, V, m.triangles).max() < 1.0 + 1e-6
    assert metrics.driving_failure_ratio(m.vertices, V, m.triangles, pieces=m.pieces) == 0.0
    if deg >= 120:
        whole = Rig.build(figure, n_vertices=500)
        W = whole.animate(kp)
        assert metrics.driving_failures(whole.mesh.vertices, W, whole.mesh.triangles)[-1]


# --------------------------------------------------------------------------- driving

def _motion(frames=8, scale=3.0, shift=(40.0, 10.0)):
    """The template rest pose, scaled and shifted, with the left arm waving (any units)."""
    kp = rest_pose() * scale + shift
    out = np.repeat(kp[None], frames, 0)
    for t in range(frames):
        ang = 50 * np.sin(2 * np.pi * t / frames)
        out[t, [J["l_elbow"], J["l_wrist"]]] = _rot(kp[[J["l_elbow"], J["l_wrist"]]], kp[J["l_shoulder"]], ang)
    return out


def test_retarget_takes_lengths_from_the_drawing_and_directions_from_the_motion(figure):
    P = _motion()
    Q = retarget(P, figure.keypoints)
    rest = figure.keypoints
    for b, (p, c) in enumerate(BONES):
        if c in TORSO:
            continue
        drawn = np.linalg.norm(rest[c] - rest[p])
        assert np.allclose(np.linalg.norm(Q[:, c] - Q[:, p], axis=1), drawn, rtol=1e-9)
        u = (P[:, c] - P[:, p]) / np.linalg.norm(P[:, c] - P[:, p], axis=1, keepdims=True)
        v = (Q[:, c] - Q[:, p]) / np.linalg.norm(Q[:, c] - Q[:, p], axis=1, keepdims=True)
        assert np.allclose(u, v, atol=1e-9)
    # the torso is the drawn torso, moved rigidly; the root stays at the drawn pelvis (the clip
    # does not travel), and a drawing retargeted onto itself is unchanged
    for t in range(len(Q)):
        d0 = rest[list(TORSO)] - rest[0]
        d1 = Q[t, list(TORSO)] - Q[t, 0]
        assert np.allclose(np.linalg.norm(d0, axis=1), np.linalg.norm(d1, axis=1), atol=1e-9)
    assert np.allclose(Q[:, 0], rest[0])
    assert np.allclose(retarget(np.repeat(rest[None], 3, 0), rest), rest[None], atol=1e-9)


def _arm_angles(Q, p, c):
    d = Q[..., c, :] - Q[..., p, :]
    return np.degrees(np.arctan2(d[..., 1], d[..., 0]))


def test_arms_from_the_drawing_swing_about_the_drawn_pose(figure):
    """``arms="drawing"``: a drawing whose left arm is spread sideways keeps it spread and swings it
    by exactly the motion's swing (±50° about the hanging arm, whose mean direction is the rest
    direction by symmetry); bone lengths stay the drawing's; every other key point is the
    ``arms="motion"`` one; a motion that holds its arms still gives the drawn arms exactly."""
    P = _motion(frames=24)
    rest = figure.keypoints.copy()
    sh, el, wr = J["l_shoulder"], J["l_elbow"], J["l_wrist"]
    rest[[el, wr]] = _rot(rest[[el, wr]], rest[sh], -80)           # the arm drawn spread
    drawn = _arm_angles(rest, sh, el)
    Q = retarget(P, rest, arms="drawing")
    Qm = retarget(P, rest)
    swing = 50 * np.sin(2 * np.pi * np.arange(24) / 24)
    got = (_arm_angles(Q, sh, el) - drawn + 180) % 360 - 180
    assert np.allclose(got, swing, atol=1e-6)
    # the elbow bend is the drawing's: the motion's forearm turns with its upper arm
    bend = lambda K: (_arm_angles(K, el, wr) - _arm_angles(K, sh, el) + 180) % 360 - 180
    assert np.allclose(bend(Q), bend(rest[None]), atol=1e-6)
    for p, c in ((sh, el), (el, wr)):
        assert np.allclose(np.linalg.norm(Q[:, c] - Q[:, p], axis=1), np.linalg.norm(rest[c] - rest[p]))
    arms = (el, wr, J["r_elbow"], J["r_wrist"])
    others = [j for j in range(len(JOINTS)) if j not in arms]
    assert np.allclose(Q[:, others], Qm[:, others], atol=1e-9)
    # the right arm does not swing in this motion: it stays as drawn, relative to its shoulder
    r = [J["r_shoulder"], J["r_elbow"], J["r_wrist"]]
    assert np.allclose(Q[:, r] - Q[:, r[:1]], (rest[r] - rest[r[:1]])[None], atol=1e-9)
    # under "motion" the same drawing's arm hangs and swings as the motion's does
    assert np.allclose(_arm_angles(Qm, sh, el), _arm_angles(P, sh, el), atol=1e-6)
    still = retarget(np.repeat(figure.keypoints[None], 4, 0), rest, arms="drawing")
    assert np.allclose(still, rest[None], atol=1e-9)
    with pytest.raises(InputError, match="arms.*motion, drawing"):
        retarget(P, rest, source="clip.csv", arms="sideways")


def test_head_with_the_torso_keeps_its_drawn_angle_to_the_body(figure):
    """``head="torso"``: the head leans with the spine and keeps its drawn angle and length to it,
    whatever the motion's head does; every other key point is the ``head="motion"`` one."""
    P = _motion(frames=12)
    pel, tho, nk, top = J["pelvis"], J["thorax"], J["neck"], J["head_top"]
    for t in range(12):  # the performer leans and nods against the lean
        P[t] = _rot(P[t], P[t, pel], 20 * np.sin(2 * np.pi * t / 12))
        P[t, top] = _rot(P[t, top], P[t, nk], -35 * np.sin(2 * np.pi * t / 12))
    rest = figure.keypoints
    Q, Qm = retarget(P, rest, head="torso"), retarget(P, rest)
    wrap = lambda a: (a + 180) % 360 - 180
    lean = wrap(_arm_angles(Q, pel, tho) - _arm_angles(rest, pel, tho))
    assert np.abs(lean).max() > 15                       # the body does lean
    assert np.allclose(wrap(_arm_angles(Q, nk, top) - _arm_angles(rest, nk, top)), lean, atol=1e-6)
    assert np.allclose(np.linalg.norm(Q[:, top] - Q[:, nk], axis=1), np.linalg.norm(rest[top] - rest[nk]))
    # under "motion" the head nods as the performer's: up to 35° - 20° against the body
    nod = wrap(_arm_angles(Qm, nk, top) - _arm_angles(rest, nk, top)) - lean
    assert np.abs(nod).max() > 10
    others = [j for j in range(len(JOINTS)) if j != top]
    assert np.allclose(Q[:, others], Qm[:, others], atol=1e-9)
    with pytest.raises(InputError, match="head.*motion, torso"):
        retarget(P, rest, source="clip.csv", head="nod")


def test_nan_frames_are_refused_naming_the_frame(figure, tmp_path):
    P = _motion()
    P[5, J["r_knee"], 1] = np.nan
    with pytest.raises(InputError, match=r"frame 5.*r_knee"):
        retarget(P, figure.keypoints, source="clip.csv")
    rows = []
    for t, pts in enumerate(P):
        rows.append({"clip": "c0", "frame": t, "character": "x", "motion": "wave",
                     **dict(zip(FEATURE_COLUMNS, pts.ravel()))})
    path = tmp_path / "motion.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    with pytest.raises(InputError, match=r"clip c0.*frame 5"):
        read_motion(path)
    with pytest.raises(InputError, match="clip"):
        read_motion(path, "nope")


def test_read_motion_returns_the_clip_in_frame_order(tmp_path):
    P = _motion(frames=5)
    rows = [{"clip": c, "frame": t, "character": "x", "motion": "wave", **dict(zip(FEATURE_COLUMNS, (P[t] + k).ravel()))}
            for k, c in enumerate(("b", "a")) for t in (3, 1, 0, 4, 2)]
    path = tmp_path / "m.csv"
    pd.DataFrame(rows).to_csv(path, index=False)
    name, frames, pts = read_motion(path)
    assert name == "a" and frames.tolist() == [0, 1, 2, 3, 4]
    assert np.allclose(pts, P + 1)
    assert JOINTS[0] == "pelvis"


# --------------------------------------------------------------------------- extra arms (char5)

_CHAR5 = __import__("pathlib").Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters" / "char5"


@pytest.mark.skipif(not _CHAR5.is_dir(), reason="../shared/data (AnimatedDrawings char5) not present")
def test_extra_arms_turn_with_the_driven_arm_of_their_side():
    """char5 has three arms a side: the driven one and two followers.  Turning the right arm by 40°
    about its shoulder turns each right follower by 40° about its own pivot, and moves nothing
    else of the left side; at rest nothing moves."""
    from nnsf.animate.animation import read_character
    from nnsf.reshape.pieces import attach_tabs

    ch = read_character(_CHAR5)
    assert len(ch.extra_limbs) == 4 and {e["side"] for e in ch.extra_limbs} == {"l", "r"}
    rig = Rig.build(ch, n_vertices=500, split="layered", handle_set="keypoints")
    m = rig.mesh
    followers = [t for t in m.tabs if t.pivot is not None]
    assert len(followers) >= 4 and any(t.drawn for t in followers)
    V0 = rig.animate(ch.keypoints[None])[0]
    assert np.abs(V0 - m.vertices).max() < 1e-6
    kp = ch.keypoints.copy()
    for j in ("r_elbow", "r_wrist"):
        kp[J[j]] = _rot(kp[J[j]], kp[J["r_shoulder"]], 40.0)
    V = rig.animate(kp[None])[0]
    for t in followers:
        expect = _rot(m.vertices[t.vertices], t.pivot, 40.0 if t.bone[0] == J["r_shoulder"] else 0.0)
        assert np.abs(V[t.vertices] - expect).max() < 1e-6
