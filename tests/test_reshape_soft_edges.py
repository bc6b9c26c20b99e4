"""A sprite with soft (anti-aliased) alpha edges cut into a layered mesh: the Kenney robot.

Its claws touch its legs through faint edge pixels; cut and labelled on the
whole mask (alpha > 0), a claw's inner prong went to the thigh beside it and
the left hip's cut ran along the claw, leaving the left thigh without a pixel.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nnsf.skeleton import JOINT_INDEX as J

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
KENNEY_ANN = Path(__file__).resolve().parent / "data" / "kenney"
needs_robot = pytest.mark.skipif(not (SHARED / "kenney-toon" / "robot").is_dir(),
                                 reason="../shared/data/kenney-toon/robot not present")


@pytest.fixture(scope="module")
def robot():
    from nnsf.reshape.kenney import kenney_character

    ch, _ = kenney_character("robot", SHARED / "kenney-toon", KENNEY_ANN)
    return ch


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (np.asarray(p, float) - c) @ R.T + c


@needs_robot
def test_every_piece_of_the_robot_owns_pixels(robot):
    from nnsf.reshape.layers import build_mesh
    from nnsf.reshape.parts import SEGMENTS

    mesh = build_mesh(robot.mask, robot.keypoints, 300, split="layered", texture=robot.texture)
    owned = [name for i, name in enumerate(SEGMENTS) if (mesh.labels == i).any()]
    assert owned == list(SEGMENTS)
    # Each limb segment is a piece of some size, not a sliver.
    counts = np.bincount(mesh.labels[mesh.labels >= 0], minlength=len(SEGMENTS))
    assert counts.min() >= 40


@needs_robot
def test_soft_edge_pixels_go_with_the_solid_shape_they_border(robot):
    from nnsf.reshape.pieces import solid_mask

    solid = solid_mask(robot.mask, robot.texture)
    np.testing.assert_array_equal(solid, robot.mask & (robot.texture[..., 3] >= 128))
    # Without alpha, or on a drawing of soft strokes, the mask itself.
    np.testing.assert_array_equal(solid_mask(robot.mask, robot.texture[..., :3]), robot.mask)
    faint = robot.texture.copy()
    faint[..., 3] = np.where(robot.mask, 100, 0)
    np.testing.assert_array_equal(solid_mask(robot.mask, faint), robot.mask)


@needs_robot
@pytest.mark.parametrize("side,deg", [("l", 60.0), ("r", -60.0)])
def test_a_raised_arm_carries_its_whole_claw(robot, side, deg):
    """Turn one arm rigidly about its shoulder: every opaque claw pixel is drawn at its turned
    place, and none stays at its rest place."""
    from scipy.ndimage import binary_dilation

    from nnsf.reshape.render import MeshRenderer
    from nnsf.reshape.stage import build_rig

    tex = robot.texture
    kp = robot.keypoints
    wrist = kp[J[f"{side}_wrist"]]
    H, W = robot.mask.shape
    yy, xx = np.mgrid[:H, :W]
    # The claw, found without the method: opaque pale pixels below the wrist and near it.
    claw = ((tex[..., 3] >= 128) & (tex[..., :3].min(axis=2) >= 140)
            & (yy > wrist[1]) & (np.hypot(xx - wrist[0], yy - wrist[1]) <= 16))
    assert claw.sum() >= 40
    rig = build_rig(robot, "ours", "layered", 300, 4)
    pose = kp.copy()
    arm = [J[f"{side}_elbow"], J[f"{side}_wrist"]]
    pivot = kp[J[f"{side}_shoulder"]]
    pose[arm] = _rot(kp[arm], pivot, deg)
    V = rig.animate(np.stack([kp, pose]))
    out = MeshRenderer.for_mesh(rig.mesh, robot).render(V[1])
    ys, xs = np.nonzero(claw)
    new = np.rint(_rot(np.column_stack([xs, ys]), pivot, deg)).astype(int)
    ok = (new[:, 0] >= 0) & (new[:, 0] < W) & (new[:, 1] >= 0) & (new[:, 1] < H)
    assert ok.all()

    def pale(img):
        return (img[..., 3] >= 128) & (img[..., :3].min(axis=-1) >= 140)

    # At its new place (within a pixel: the arm's ARAP fit is nearly rigid), the claw is drawn.
    drawn = pale(out)
    near = np.zeros_like(drawn)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            near |= np.roll(np.roll(drawn, dy, 0), dx, 1)
    assert near[new[:, 1], new[:, 0]].mean() >= 0.95
    # At its rest place, away from where the turned arm now lies, nothing pale is left.
    moved = np.zeros((H, W), bool)
    moved[new[:, 1], new[:, 0]] = True
    left_behind = claw & drawn & ~binary_dilation(moved, iterations=2)
    assert left_behind.sum() <= 2


@needs_robot
def test_the_drawn_crotch_gap_stays_open_at_rest(robot):
    """The robot's legs are drawn 2 px apart: the sealed rest frame keeps the gap (it is no crack
    between joined parts)."""
    from nnsf.reshape.render import MeshRenderer
    from nnsf.reshape.stage import build_rig

    rig = build_rig(robot, "ours", "layered", 300, 4)
    V = rig.animate(robot.keypoints[None])
    out = MeshRenderer.for_mesh(rig.mesh, robot).render(V[0])
    # The gap: columns where the drawing is clear between the two legs, below the hips.
    hip_y = int(np.ceil(robot.keypoints[[J["l_hip"], J["r_hip"]], 1].max())) + 2
    x0 = int(np.floor(robot.keypoints[J["r_hip"], 0]))
    x1 = int(np.ceil(robot.keypoints[J["l_hip"], 0]))
    clear = robot.texture[hip_y:, x0:x1, 3] == 0
    assert clear.sum() >= 20
    assert (out[hip_y:, x0:x1, 3][clear] < 64).mean() >= 0.9
