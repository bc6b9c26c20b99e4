"""Key points from side curves (Eq. 2-3) against analytic cases and rendered ground truth."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import from_dict
from nnsf.roto.keypoints import fit_keypoint_model, keypoints_from_curves
from nnsf.frames.render import render_clip
from nnsf.io import read_npz
from nnsf.frames.annotation import read_annotation
from nnsf.skeleton import JOINT_INDEX, JOINTS


def _ann(kp_elbow, kp_wrist):
    kp = {j: [0.0, 0.0] for j in JOINTS}
    kp["l_elbow"], kp["l_wrist"] = kp_elbow, kp_wrist
    return from_dict({
        "format": "nnsf.annotation", "version": 1, "clip": "c", "character": "s", "motion": "m",
        "frames": ["a.png", "b.png"], "image_size": [100, 100],
        "keyframes": [{"frame": 0, "curves": {"l_forearm.a": [[0, 0], [0, 10]],
                                              "l_forearm.b": [[4, 0], [8, 10]]}, "keypoints": kp}]})


def test_omega_analytic():
    # elbow a quarter of the way from p2=(4,0) to p1=(0,0): omega = 0.75; wrist at p4 -> 0.
    ann = _ann([1.0, 0.0], [8.0, 10.0])
    m = fit_keypoint_model(ann)
    assert m.omega[("l_forearm", "start")] == pytest.approx(0.75)
    assert m.omega[("l_forearm", "end")] == pytest.approx(0.0)
    # Outside the pair: clipped to [0, 1].
    assert fit_keypoint_model(_ann([-3.0, 0.0], [9.0, 10.0])).omega[("l_forearm", "start")] == 1.0
    # Applied to a moved frame, and joints of absent groups are NaN.
    control = np.array([[[[10, 0], [10, 10]], [[14, 0], [18, 10]]]], float)
    kp = keypoints_from_curves(control, ["l_forearm.a", "l_forearm.b"], m)
    np.testing.assert_allclose(kp[0, JOINT_INDEX["l_elbow"]], [11.0, 0.0])
    np.testing.assert_allclose(kp[0, JOINT_INDEX["l_wrist"]], [18.0, 10.0])
    assert np.isnan(kp[0, JOINT_INDEX["pelvis"]]).all()


def test_needs_keypoints_on_a_keyframe():
    ann = _ann([1.0, 0.0], [8.0, 10.0])
    ann.keyframes[0].keypoints = None
    with pytest.raises(InputError, match="key points on at least one keyframe"):
        fit_keypoint_model(ann)


@pytest.mark.parametrize("character,motion", [("bruno", "walk"), ("mimi", "spin_arms")])
def test_recovers_rendered_truth(tmp_path, character, motion):
    """omega fitted on first/last keyframe, applied to the true curves of every frame."""
    render_clip(tmp_path, character, motion, 16, size=192, keyframe_every=0)
    ann = read_annotation(tmp_path / "annotation.json")
    tr = read_npz(tmp_path / "truth.npz")
    model = fit_keypoint_model(ann)
    kp = keypoints_from_curves(tr["control"], tr["side_names"], model)
    err = np.linalg.norm(kp - tr["keypoints"], axis=-1)
    assert err.max() < 0.2, err.max(0)           # all but the spine are exact up to rounding
    assert np.delete(err, JOINT_INDEX["spine"], axis=1).max() < 1e-3
    # Shared joints: the average of two equal estimates is the joint.
    assert model.omega[("l_upper_arm", "end")] == pytest.approx(0.5, abs=1e-4)
