"""The 17-point layout and template unification (docs/method.md §4, Eq. 4)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nnsf.datasets import contract
from nnsf.datasets.synthetic import generate
from nnsf.skeleton import (
    BONES, JOINTS, LIMBS, PARENTS, TEMPLATE_BONE_LENGTHS, Unifier, bone_lengths, character_scale,
    difference_operator, rest_pose, to_features, to_points,
)


def test_layout_is_a_tree_in_human36m_order():
    assert len(JOINTS) == 17 and JOINTS[0] == "pelvis" and JOINTS[10] == "head_top"
    assert PARENTS[0] == -1 and all(0 <= PARENTS[j] < j for j in range(1, 17))
    assert len(BONES) == 16 and len(LIMBS) == 8
    D = difference_operator()
    assert np.linalg.matrix_rank(D) == 17


def test_rest_pose_has_template_bone_lengths():
    np.testing.assert_allclose(bone_lengths(rest_pose()), TEMPLATE_BONE_LENGTHS, rtol=1e-12)


def _synthetic_points(**kw):
    table = generate(**kw)
    return to_points(contract.features(table)), table["character"].to_numpy()


def test_unification_round_trip_and_non_negative():
    P, chars = _synthetic_points(characters=9, clips_per_cell=1, frames=16)
    unifier = Unifier(margin=0.5).fit(P, chars)
    X = unifier.transform(P, chars)
    assert X.shape == (len(P), 34)
    assert X.min() >= 0.5 - 1e-12
    for c in np.unique(chars):
        back = unifier.inverse_transform(X[chars == c], c)
        np.testing.assert_allclose(back, P[chars == c], atol=1e-9, rtol=0)
    again = Unifier.from_dict(unifier.to_dict())
    np.testing.assert_array_equal(again.transform(P, chars), X)


def test_unified_bones_have_template_median_lengths():
    """After unification every character's median bone length is the template's."""
    P, chars = _synthetic_points(characters=5, clips_per_cell=1, frames=12)
    X = Unifier().fit(P, chars).transform(P, chars)
    for c in np.unique(chars):
        med = np.median(bone_lengths(to_points(X[chars == c])), axis=0)
        np.testing.assert_allclose(med, TEMPLATE_BONE_LENGTHS, rtol=1e-9)


def test_matrix_form_matches_bone_scaling():
    """W = D⁻¹RD scales each bone vector and the root, nothing else."""
    rng = np.random.default_rng(0)
    P = rng.random((4, 17, 2)) * 100
    sc = character_scale(P)
    X = np.einsum("ij,njc->nic", sc.matrix(), P)
    bones_in = P[:, [c for _, c in BONES]] - P[:, [p for p, _ in BONES]]
    bones_out = X[:, [c for _, c in BONES]] - X[:, [p for p, _ in BONES]]
    np.testing.assert_allclose(bones_out, bones_in * sc.bone_ratio[None, :, None], rtol=1e-12)
    np.testing.assert_allclose(X[:, 0], P[:, 0] * sc.root_scale, rtol=1e-12)
    np.testing.assert_allclose(sc.matrix() @ sc.inverse_matrix(), np.eye(17), atol=1e-12)


def test_root_position_does_not_encode_body_size():
    """Characters standing at different canvas spots and sizes share one unified root position."""
    base = rest_pose((0, 0))
    small = (base * 40 + [60, 200])[None].repeat(3, 0)
    big = (base * 90 + [150, 120])[None].repeat(3, 0)
    P = np.concatenate([small, big])
    chars = np.array(["small"] * 3 + ["big"] * 3)
    X = Unifier().fit(P, chars).transform(P, chars)
    np.testing.assert_allclose(X[0], X[3], atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), scale=st.floats(0.2, 20), n=st.integers(2, 30))
def test_round_trip_property(seed, scale, n):
    rng = np.random.default_rng(seed)
    P = (rest_pose((3, 4))[None] + rng.normal(scale=0.1, size=(n, 17, 2))) * scale
    chars = np.where(np.arange(n) % 2 == 0, "a", "b")
    u = Unifier(margin=1.0).fit(P, chars)
    X = u.transform(P, chars)
    assert X.min() >= 1.0 - 1e-9
    for c in ("a", "b"):
        np.testing.assert_allclose(u.inverse_transform(X[chars == c], c), P[chars == c],
                                   atol=1e-9 * max(1.0, scale))


def test_transform_rejects_unknown_character_and_out_of_range():
    P = rest_pose((5, 5))[None].repeat(2, 0) * 10
    u = Unifier().fit(P, ["a", "a"])
    with pytest.raises(ValueError, match="unknown character"):
        u.transform(P, ["z", "z"])
    with pytest.raises(ValueError, match="< 0"):
        u.transform(P - 1000, ["a", "a"])


def test_features_points_round_trip():
    P = np.arange(2 * 17 * 2, dtype=float).reshape(2, 17, 2)
    np.testing.assert_array_equal(to_points(to_features(P)), P)
    assert to_features(P)[0, :4].tolist() == [0, 1, 2, 3]  # x1, y1, x2, y2
