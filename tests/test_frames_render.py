"""Rendered cartoon clips: determinism, contour geometry, pictures agree with the truth."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.datasets.synthetic import clip_points
from nnsf.frames.annotation import read_annotation
from nnsf.frames.curves import GROUP_JOINTS, GROUPS, SIDE_NAMES, sample_curve
from nnsf.frames.render import (
    keyframe_indices, render_character, render_clip,
)
from nnsf.io import read_npz
from nnsf.reshape.formats import read_character, synthetic_character, write_character
from nnsf.skeleton import JOINT_INDEX

SIZE, T = 128, 6


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    folder = tmp_path_factory.mktemp("render") / "olga-kick-00"
    info = render_clip(folder, "olga", "kick", T, seed=3, size=SIZE, keyframe_every=2)
    return folder, info


def test_byte_identical_across_runs(clip, tmp_path):
    folder, _ = clip
    render_clip(tmp_path / "again", "olga", "kick", T, seed=3, size=SIZE, keyframe_every=2)
    for name in [f"frame_{t:04d}.png" for t in range(T)] + ["annotation.json", "truth.npz"]:
        assert (folder / name).read_bytes() == (tmp_path / "again" / name).read_bytes(), name


def test_truth_keypoints_are_the_generator(clip):
    folder, _ = clip
    tr = read_npz(folder / "truth.npz")
    want = clip_points("olga", "kick", T, seed=3, canvas=(SIZE, SIZE))
    # Stored to the outputs' 6 significant digits (nnsf.io.DIGITS), so the file is the same on every machine.
    np.testing.assert_allclose(tr["keypoints"], want, rtol=5.1e-6, atol=0)
    assert list(tr["side_names"]) == list(SIDE_NAMES)
    assert tr["sides"].shape[:2] == (T, 20)


def test_sides_bracket_the_bone_on_the_documented_sides(clip):
    folder, _ = clip
    tr = read_npz(folder / "truth.npz")
    kp, sides = tr["keypoints"], tr["sides"]
    for gi, g in enumerate(GROUPS):
        s, e = GROUP_JOINTS[g]
        d = kp[:, e] - kp[:, s]
        r90 = np.stack([-d[:, 1], d[:, 0]], -1)
        a, b = sides[:, 2 * gi], sides[:, 2 * gi + 1]
        mid = a.mean(1) - (a.mean(1) + b.mean(1)) / 2
        assert (np.einsum("ti,ti->t", mid, r90) > 0).all(), g       # a on the +R90 d side
        # End points sit symmetric about the joints (true omega = 0.5).
        # Files keep 6 significant digits (nnsf.io.DIGITS): 0.0005 px at 100-999 px, per value.
        np.testing.assert_allclose((a[:, 0] + b[:, 0]) / 2, kp[:, s], atol=1.01e-3)
        np.testing.assert_allclose((a[:, -1] + b[:, -1]) / 2, kp[:, e], atol=1.01e-3)
        # ... and run start -> end.
        assert (np.linalg.norm(a[:, 0] - kp[:, s], axis=1) < np.linalg.norm(a[:, 0] - kp[:, e], axis=1)).all()


def test_fitted_control_points_follow_the_truth(clip):
    folder, info = clip
    tr = read_npz(folder / "truth.npz")
    assert tr["control"].shape == (T, 20, 5, 2)
    assert info["max_fit_error_px"] < 0.5
    # Independent check: dense spline samples vs the dense truth (nearest-sample distance).
    dense = sample_curve(tr["control"], 400)
    d = np.linalg.norm(tr["sides"][..., :, None, :] - dense[..., None, :, :], axis=-1).min(-1)
    assert d.max() < 0.55


def test_outline_is_drawn_on_the_visible_contours(clip):
    """Where the truth says a contour sample is visible, the frame shows the dark outline."""
    import cv2

    folder, _ = clip
    tr = read_npz(folder / "truth.npz")
    from nnsf.datasets.synthetic import character

    ink = np.array(character("olga").palette.outline, float)
    frame = cv2.cvtColor(cv2.imread(str(folder / "frame_0002.png")), cv2.COLOR_BGR2RGB).astype(float)
    pts = np.rint(tr["sides"][2]).astype(int)                      # (20, S, 2)
    vis = tr["visible"][2]
    assert vis.mean() > 0.5
    colour = frame[pts[..., 1], pts[..., 0]]
    dist_ink = np.linalg.norm(colour - ink, axis=-1)
    bg = np.array([238, 234, 224], float)
    # Visible contour pixels are much nearer the ink than the background is.
    assert np.median(dist_ink[vis]) < 0.35 * np.linalg.norm(bg - ink)
    # Away from the figure, the frame is plain background.
    assert np.allclose(frame[2, 2], bg)


def test_annotation_keyframes_and_contents(clip):
    folder, _ = clip
    ann = read_annotation(folder / "annotation.json")
    assert ann.keyframe_indices == [0, 2, 4, 5] == keyframe_indices(T, 2)
    assert keyframe_indices(T, 0) == [0, T - 1]
    tr = read_npz(folder / "truth.npz")
    k = ann.keyframes[1]
    np.testing.assert_allclose(k.keypoints, tr["keypoints"][2], atol=1e-4)
    # Both files keep 6 significant digits, each rounded on its own: one unit of the 6th apart at most.
    np.testing.assert_allclose(k.curves["l_shin.b"], tr["control"][2, SIDE_NAMES.index("l_shin.b")],
                               atol=1.01e-3)
    assert ann.image_size == (SIZE, SIZE) and ann.character == "olga" and ann.motion == "kick"


def test_rest_character_is_a_valid_drawn_character(tmp_path):
    rgba, mask, kp = render_character("gus", 200)
    assert rgba.shape == (200, 200, 4) and mask.shape == (200, 200)
    assert ((rgba[..., 3] == 255) == mask).all()
    # Arms away from the body: wrists outside the torso's horizontal extent.
    J = JOINT_INDEX
    assert kp[J["l_wrist"], 0] > kp[J["l_shoulder"], 0] and kp[J["r_wrist"], 0] < kp[J["r_shoulder"], 0]
    path = write_character(synthetic_character("gus", 200), tmp_path / "gus.json")
    ch = read_character(path)                     # validates mask, key points inside it
    np.testing.assert_allclose(ch.keypoints, kp, rtol=5.1e-6)  # the JSON's 6 significant digits
    assert (ch.mask == mask).all() and (ch.texture == rgba).all()
