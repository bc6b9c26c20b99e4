"""The embedded synthetic cartoon dataset: determinism, geometry, style, contract."""
from __future__ import annotations

import dataclasses
import json
import re
import time

import numpy as np
import pytest
from sklearn.discriminant_analysis import LinearDiscriminantAnalysis
from sklearn.model_selection import GroupKFold, StratifiedKFold, cross_val_score
from sklearn.neighbors import KNeighborsClassifier

from nnsf.datasets import contract
from nnsf.datasets import synthetic as S
from nnsf.datasets.synthetic_motions import interpolate
from nnsf.skeleton import (
    BONES, FEATURE_COLUMNS, JOINT_INDEX, JOINTS, TEMPLATE_BONE_LENGTHS, Unifier, bone_lengths, to_points,
)


# --- helpers -------------------------------------------------------------------------------

def _points(table):
    return to_points(table.loc[:, list(FEATURE_COLUMNS)].to_numpy())


def _unified(table):
    """Unified points ``(n, 17, 2)`` of a contract table (template units)."""
    chars = table["character"].to_numpy()
    unifier = Unifier().fit(_points(table), chars)
    return to_points(unifier.transform(_points(table), chars)), unifier


def _style_features(table):
    """Per-frame features ``(n, 33)`` and per-clip mean+std ``(clips, 66)`` with labels.

    Pose relative to the pelvis plus the pelvis's vertical motion about its
    clip mean.  The absolute pelvis position is left out on purpose: the
    unifier scales it by body size, so it would name the character by its
    proportions, and these tests are about style.
    """
    Q, _ = _unified(table)
    clips = table["clip"].to_numpy()
    _, inv, counts = np.unique(clips, return_inverse=True, return_counts=True)

    def clip_mean(F):
        return np.stack([np.bincount(inv, F[:, k]) for k in range(F.shape[1])], 1) / counts[:, None]

    root_y = Q[:, 0, 1:2]
    frame = np.hstack([(Q[:, 1:] - Q[:, :1]).reshape(len(Q), -1),
                       root_y - clip_mean(root_y)[inv]])
    mean = clip_mean(frame)
    std = np.sqrt(np.maximum(clip_mean(frame ** 2) - mean ** 2, 0.0))
    first = np.array([np.flatnonzero(inv == i)[0] for i in range(len(counts))])
    labels = {k: table[k].to_numpy() for k in ("character", "motion", "clip")}
    return frame, np.hstack([mean, std]), labels, first


@pytest.fixture(scope="module")
def default_table():
    return S.generate()


# --- definitions ---------------------------------------------------------------------------

def test_catalogue():
    assert S.CANVAS == (256, 256)
    assert len(S.CHARACTERS) >= 12
    assert len({c.name for c in S.CHARACTERS}) == len(S.CHARACTERS)
    assert len(S.MOTIONS) == 15 and len(set(S.MOTIONS)) == 15
    for c in S.CHARACTERS:
        assert S.character(c.name) is c
        assert S.character(c) is c
        assert c.description and re.fullmatch(r"[a-z]+", c.name)
        for colour in dataclasses.astuple(c.palette):
            assert len(colour) == 3 and all(isinstance(v, int) and 0 <= v <= 255 for v in colour)
        assert c.proportions.height > 90 and c.proportions.head_radius > 0


@pytest.mark.parametrize("call", [
    lambda: S.character("nobody"),
    lambda: S.clip_points("nobody", "walk", 8),
    lambda: S.clip_points("pip", "moonwalk", 8),
    lambda: S.generate(characters=["pip", "nobody"], clips_per_cell=1, frames=4),
    lambda: S.generate(motions=["walk", "moonwalk"], clips_per_cell=1, frames=4),
])
def test_unknown_names_list_the_valid_ones(call):
    with pytest.raises(ValueError) as err:
        call()
    message = str(err.value)
    assert ("bruno" in message and "tilly" in message) or ("walk" in message and "stretch" in message)


def test_bad_sizes_raise():
    with pytest.raises(ValueError):
        S.clip_points("pip", "walk", 0)
    with pytest.raises(ValueError):
        S.clip_points("pip", "walk", 8, noise_px=-1.0)
    with pytest.raises(ValueError):
        S.generate(characters=len(S.CHARACTERS) + 1)


# --- determinism ---------------------------------------------------------------------------

def test_clip_points_deterministic():
    a = S.clip_points("olga", "kick", 40, variation=2, seed=3, noise_px=0.5)
    b = S.clip_points(S.character("olga"), "kick", 40, variation=2, seed=3, noise_px=0.5)
    assert a.shape == (40, 17, 2)
    np.testing.assert_array_equal(a, b)
    for other in (dict(variation=3, seed=3), dict(variation=2, seed=4)):
        c = S.clip_points("olga", "kick", 40, noise_px=0.5, **other)
        assert np.abs(a - c).max() > 1.0


def test_generate_deterministic_and_seeded():
    a = S.generate(characters=3, clips_per_cell=2, frames=12, seed=5)
    b = S.generate(characters=3, clips_per_cell=2, frames=12, seed=5)
    c = S.generate(characters=3, clips_per_cell=2, frames=12, seed=6)
    assert a.equals(b)
    assert np.abs(_points(a) - _points(c)).max() > 1.0


def test_noise_is_gaussian_jitter_of_the_clean_clip():
    clean = S.clip_points("rex", "walk", 200, variation=1)
    noisy = S.clip_points("rex", "walk", 200, variation=1, noise_px=0.8)
    residual = (noisy - clean).ravel()
    assert abs(residual.mean()) < 0.05
    assert residual.std() == pytest.approx(0.8, rel=0.05)


def test_generate_rows_are_clip_points(default_table):
    for clip in ("bruno-walk-00", "tilly-throw-03", "mimi-kick-01"):
        char, motion, variation = clip.split("-")
        rows = default_table[default_table["clip"] == clip]
        expected = S.clip_points(char, motion, 32, int(variation), seed=0, noise_px=0.4)
        np.testing.assert_array_equal(_points(rows), expected)


def test_clip_content_shared_across_characters():
    # The same variation of a motion has the same random changes whoever performs it.
    assert S.clip_variation("jump", 3, seed=1) == S.clip_variation("jump", 3, seed=1)
    assert S.clip_variation("jump", 3, seed=1) != S.clip_variation("jump", 4, seed=1)


# --- geometry ------------------------------------------------------------------------------

def test_every_point_inside_the_canvas():
    """All characters x all motions x several variations, long enough for whole loops."""
    lo, hi = S.MARGIN, S.CANVAS[0] - S.MARGIN
    for char in S.CHARACTERS:
        for motion in S.MOTIONS:
            channels = S.pose_channels(char, motion, 72, variation=range(6))
            pts = S.forward_kinematics(char.proportions, channels.reshape(-1, len(S.CHANNELS)))
            assert np.isfinite(pts).all()
            assert pts.min() >= lo and pts.max() <= hi, (char.name, motion, pts.min(), pts.max())


def test_bones_keep_the_characters_lengths():
    for char in S.CHARACTERS:
        P = char.proportions
        expected = {
            "r_hip": P.hip_width, "r_knee": P.thigh, "r_ankle": P.shin, "l_hip": P.hip_width,
            "l_knee": P.thigh, "l_ankle": P.shin, "spine": P.spine, "thorax": P.chest,
            "neck": P.neck, "head_top": P.head, "l_shoulder": P.shoulder_width,
            "l_elbow": P.upper_arm, "l_wrist": P.forearm, "r_shoulder": P.shoulder_width,
            "r_elbow": P.upper_arm, "r_wrist": P.forearm,
        }
        want = np.array([expected[JOINTS[c]] for _, c in BONES])
        pts = S.clip_points(char, "spin_arms", 30, variation=1)
        np.testing.assert_allclose(bone_lengths(pts), np.broadcast_to(want, (30, 16)), atol=1e-9)


def test_motions_stay_in_place_on_the_ground():
    ground = S.CANVAS[1] - S.GROUND_MARGIN
    ankles = [JOINT_INDEX["r_ankle"], JOINT_INDEX["l_ankle"]]
    for char in ("bruno", "pip", "wendell"):
        leg = S.character(char).proportions.leg
        # Treadmill walk: the pelvis does not travel.
        walk = S.clip_points(char, "walk", 60)
        assert np.ptp(walk[:, 0, 0]) < 1e-9
        # Sitting down: no lift, no bounce, so the lower foot is on the ground.
        sit = S.clip_points(char, "sit_down", 60)
        np.testing.assert_allclose(sit[:, ankles, 1].max(axis=1), ground, atol=1e-9)
        # A jump leaves the ground and comes back down.
        jump = S.clip_points(char, "jump", 60)
        feet = jump[:, ankles, 1].max(axis=1)
        assert feet.min() < ground - 0.1 * leg
        assert np.isclose(feet, ground).sum() > 10


def test_canvas_argument_scales_the_scene():
    small = S.clip_points("max", "throw", 20, variation=1)
    large = S.clip_points("max", "throw", 20, variation=1, canvas=(512, 512))
    np.testing.assert_allclose(large, 2 * small, atol=1e-9)


def test_left_handed_character_kicks_with_the_left_leg():
    r, l = JOINT_INDEX["r_ankle"], JOINT_INDEX["l_ankle"]
    assert S.character("bruno").style.handedness == "right"
    assert S.character("mimi").style.handedness == "left"
    bruno = S.clip_points("bruno", "kick", 60)
    mimi = S.clip_points("mimi", "kick", 60)
    assert np.ptp(bruno[:, r, 0]) > 3 * np.ptp(bruno[:, l, 0])
    assert np.ptp(mimi[:, l, 0]) > 3 * np.ptp(mimi[:, r, 0])


def test_interpolation_passes_through_the_keys_and_winds():
    times = np.array([0.0, 0.3, 0.7])
    values = np.array([[0.0, 0.0], [10.0, 120.0], [-5.0, 240.0]])
    wind = np.array([0.0, 360.0])
    phase = np.repeat(np.r_[times, times + 1.0][:, None], 2, axis=1)
    for style in (dict(), dict(tension=0.5, overshoot=0.3), dict(snap=2.0, skew=0.3)):
        out = interpolate(times, values, wind, phase, **style)
        np.testing.assert_allclose(out[:3], values, atol=1e-9)
        np.testing.assert_allclose(out[3:], values + wind, atol=1e-9)
    # Continuous across the loop seam.
    seam = interpolate(times, values, wind, np.array([[1 - 1e-7] * 2, [1 + 1e-7] * 2]))
    assert np.abs(np.diff(seam, axis=0)).max() < 1e-3


# --- proportions and unification ------------------------------------------------------------

def test_characters_differ_in_proportions():
    # Bone lengths relative to the leg: scale-free shape of each body.
    shapes = []
    for char in S.CHARACTERS:
        lengths = bone_lengths(S.clip_points(char, "walk", 1))[0]
        shapes.append(lengths / char.proportions.leg)
    shapes = np.array(shapes)
    for i in range(len(shapes)):
        for j in range(i + 1, len(shapes)):
            rel = np.abs(shapes[i] - shapes[j]) / np.minimum(shapes[i], shapes[j])
            assert rel.max() > 0.08, (S.CHARACTERS[i].name, S.CHARACTERS[j].name)
    heights = [c.proportions.height for c in S.CHARACTERS]
    assert max(heights) / min(heights) > 1.4


def test_unified_features_are_non_negative_and_template_sized():
    table = S.generate(characters=12, clips_per_cell=2, frames=24, noise_px=0.0)
    Q, unifier = _unified(table)
    assert Q.min() >= unifier.margin - 1e-9
    contract.validate(
        table.assign(**dict(zip(FEATURE_COLUMNS, Q.reshape(len(Q), -1).T))), "unified",
        non_negative=True,
    )
    # Every character's bones now have the template's lengths.
    np.testing.assert_allclose(bone_lengths(Q), np.broadcast_to(TEMPLATE_BONE_LENGTHS, (len(Q), 16)),
                               atol=1e-9)


# --- style survives unification -------------------------------------------------------------
# Measured (seed 0, default size, 9 characters): per-clip LDA 0.996 character, 0.996 motion;
# per-frame 5-NN 0.948 motion, 0.951 character.  Seed 1: 1.000, 0.998, 0.940, 0.950.
# 12 characters: 0.956, 0.997, 0.948, 0.923.  All nine with one body: per-clip character 0.972.

def test_style_and_motion_survive_unification(default_table):
    frame, clip, labels, first = _style_features(default_table)
    cv = StratifiedKFold(4, shuffle=True, random_state=0)
    lda = LinearDiscriminantAnalysis()
    char_acc = cross_val_score(lda, clip, labels["character"][first], cv=cv).mean()
    motion_acc = cross_val_score(lda, clip, labels["motion"][first], cv=cv).mean()
    assert char_acc > 0.9, char_acc          # chance 1/9
    assert motion_acc > 0.9, motion_acc      # chance 1/15

    groups = GroupKFold(4)
    knn = KNeighborsClassifier(5, algorithm="brute")
    frame_motion = cross_val_score(knn, frame, labels["motion"], cv=groups,
                                   groups=labels["clip"]).mean()
    frame_char = cross_val_score(knn, frame, labels["character"], cv=groups,
                                 groups=labels["clip"]).mean()
    assert frame_motion > 0.85, frame_motion
    assert frame_char > 0.85, frame_char


def test_style_alone_tells_characters_apart():
    """Give every character the same body: only the way they move is left."""
    body = S.character("rex").proportions
    same_body = [dataclasses.replace(c, proportions=body) for c in S.CHARACTERS[:9]]
    table = S.generate(characters=same_body, clips_per_cell=4, frames=32)
    _, clip, labels, first = _style_features(table)
    cv = StratifiedKFold(4, shuffle=True, random_state=0)
    acc = cross_val_score(LinearDiscriminantAnalysis(), clip, labels["character"][first], cv=cv)
    assert acc.mean() > 0.9, acc.mean()


# --- contract and description ---------------------------------------------------------------

def test_generate_follows_the_contract(default_table):
    table = default_table
    assert list(table.columns) == list(contract.COLUMNS)
    assert len(table) == 9 * 15 * 4 * 32
    checked = contract.validate(table, "synthetic")
    assert len(checked) == len(table)
    assert set(table["character"]) == {c.name for c in S.CHARACTERS[:9]}
    assert set(table["motion"]) == set(S.MOTIONS)
    assert table["clip"].nunique() == 9 * 15 * 4
    assert all(re.fullmatch(r"[a-z]+-[a-z_]+-\d\d", c) for c in table["clip"].unique())
    assert (table.groupby("clip")["frame"].apply(list) == [list(range(32))] * 540).all()
    first = table.iloc[0]
    assert first["clip"] == f"{first['character']}-{first['motion']}-00"


def test_generate_is_fast():
    S.generate()
    timings = []
    for _ in range(3):
        start = time.perf_counter()
        S.generate()
        timings.append(time.perf_counter() - start)
    assert min(timings) < 1.0, timings


def test_describe_is_json_ground_truth():
    d = json.loads(json.dumps(S.describe(characters=5, clips_per_cell=2, frames=16, seed=3)))
    assert d["parameters"] == {"characters": 5, "clips_per_cell": 2, "frames": 16,
                               "noise_px": 0.4, "seed": 3}
    assert d["canvas"] == [256, 256]
    assert [c["name"] for c in d["characters"]] == [c.name for c in S.CHARACTERS[:5]]
    assert [m["name"] for m in d["motions"]] == list(S.MOTIONS)
    pip = d["characters"][1]
    assert pip["proportions"]["height"] == pytest.approx(S.character("pip").proportions.height)
    assert set(pip["style"]) >= {"tempo", "bounce", "lean", "asymmetry", "lag_arms", "amp_legs"}
    assert set(pip["palette"]) == {"body", "limbs", "head", "outline"}
