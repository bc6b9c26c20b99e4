"""``legs: torso``: a figure drawn without legs, or cut off at the waist, keeps its drawn lower body."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import yaml

from nnsf.datasets import synthetic
from nnsf.errors import InputError
from nnsf.reshape.animator import Animator
from nnsf.reshape.drive import retarget
from nnsf.reshape.formats import read_character
from nnsf.skeleton import JOINT_INDEX as J, JOINTS
from stick_figure import stick_figure

LEG_POINTS = [J[j] for j in ("r_knee", "r_ankle", "l_knee", "l_ankle")]
BODY = [J[j] for j in ("pelvis", "thorax", "l_hip", "r_hip")]


def _pairwise(kp: np.ndarray, a, b) -> np.ndarray:
    """Distances ``(T, len(a), len(b))`` between two sets of key points of a clip ``(T, 17, 2)``."""
    return np.linalg.norm(kp[:, a, None] - kp[:, None, b], axis=-1)


@pytest.fixture(scope="module")
def figure():
    return stick_figure(height=300)


def test_legs_torso_carries_the_drawn_legs_with_the_torso(figure):
    """Walking, the motion's legs swing; with ``legs="torso"`` the knees and ankles keep their drawn
    distances to the pelvis, thorax and hips in every frame (they move as one rigid body with the
    torso), and everything else is as with ``legs="motion"``."""
    walk = synthetic.clip_points("bruno", "walk", 24)
    free = retarget(walk, figure.keypoints)
    held = retarget(walk, figure.keypoints, legs="torso")
    rest = _pairwise(figure.keypoints[None], LEG_POINTS, BODY)[0]
    np.testing.assert_allclose(_pairwise(held, LEG_POINTS, BODY), np.broadcast_to(rest, (len(walk),) + rest.shape),
                               atol=1e-6)
    assert np.abs(_pairwise(free, LEG_POINTS, BODY) - rest).max() > 0.05 * np.ptp(figure.keypoints[:, 1])
    others = np.setdiff1d(np.arange(len(JOINTS)), LEG_POINTS)
    np.testing.assert_allclose(held[:, others], free[:, others])


def _bust_yaml(folder, figure, legs):
    """``folder/bust.yaml`` beside ``bust.png``: the figure's joints and ``legs``."""
    folder.mkdir()
    assert cv2.imwrite(str(folder / "bust.png"), cv2.cvtColor(figure.texture, cv2.COLOR_RGBA2BGRA))
    doc = {"joints": {j: [float(x), float(y)] for j, (x, y) in zip(JOINTS, figure.keypoints)}, "legs": legs}
    (folder / "bust.yaml").write_text(yaml.safe_dump(doc))
    return folder / "bust.yaml"


def test_a_character_yaml_says_legs_torso_and_the_animator_follows_it(tmp_path, figure):
    ch = read_character(_bust_yaml(tmp_path / "c", figure, "torso"))
    assert ch.legs == "torso" and any("legs torso" in n for n in ch.notes)
    walk = synthetic.clip_points("bruno", "walk", 12)
    kp = Animator(ch, n_vertices=300).retarget(walk)
    np.testing.assert_allclose(kp, retarget(walk, ch.keypoints, legs="torso"))


def test_a_bad_legs_choice_names_the_file_and_field(tmp_path, figure):
    with pytest.raises(InputError, match=r"bust\.yaml: legs: expected motion or torso"):
        read_character(_bust_yaml(tmp_path / "c", figure, "still"))
    with pytest.raises(InputError, match=r"legs"):
        retarget(synthetic.clip_points("bruno", "walk", 4), figure.keypoints, legs="still")
