"""The 17 key points (Human3.6M order), their tree, bones and limbs.

Coordinates everywhere are arrays of shape ``(..., 17, 2)`` holding ``(x, y)``
per key point; a feature row flattens one frame to ``x1, y1, ..., x17, y17``.
"""
from __future__ import annotations

import numpy as np

#: Key-point names in feature order (docs/method.md §1).
JOINTS: tuple[str, ...] = (
    "pelvis", "r_hip", "r_knee", "r_ankle", "l_hip", "l_knee", "l_ankle",
    "spine", "thorax", "neck", "head_top",
    "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
)
N_JOINTS = len(JOINTS)
N_FEATURES = 2 * N_JOINTS
JOINT_INDEX = {name: i for i, name in enumerate(JOINTS)}

#: Parent of each key point; the pelvis is the root (-1).  Parents come
#: before children, so a single forward pass visits the tree top-down.
PARENTS: tuple[int, ...] = (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 9, 8, 11, 12, 8, 14, 15)

#: Bones as (parent, child) index pairs, one per non-root key point; bone b
#: ends at key point ``b + 1``.
BONES: tuple[tuple[int, int], ...] = tuple((p, j) for j, p in enumerate(PARENTS) if p >= 0)
BONE_NAMES: tuple[str, ...] = tuple(f"{JOINTS[p]}-{JOINTS[c]}" for p, c in BONES)

#: The eight limbs of the paper's limb model, each two key points (p_j, p_j+1).
LIMBS: dict[str, tuple[int, int]] = {
    "l_upper_arm": (11, 12), "l_forearm": (12, 13),
    "r_upper_arm": (14, 15), "r_forearm": (15, 16),
    "l_thigh": (4, 5), "l_shin": (5, 6),
    "r_thigh": (1, 2), "r_shin": (2, 3),
}

#: Feature column names of the contract: x1, y1, ..., x17, y17 (1-based).
FEATURE_COLUMNS: tuple[str, ...] = tuple(
    f"{axis}{j + 1}" for j in range(N_JOINTS) for axis in ("x", "y")
)

assert all(PARENTS[j] < j for j in range(1, N_JOINTS))


def bone_vectors(points: np.ndarray) -> np.ndarray:
    """Child minus parent for every bone: ``(..., 17, 2)`` -> ``(..., 16, 2)``."""
    points = np.asarray(points, dtype=float)
    parents = np.array([p for p, _ in BONES])
    children = np.array([c for _, c in BONES])
    return points[..., children, :] - points[..., parents, :]


def bone_lengths(points: np.ndarray) -> np.ndarray:
    """Euclidean bone lengths: ``(..., 17, 2)`` -> ``(..., 16)``, in the points' units."""
    return np.linalg.norm(bone_vectors(points), axis=-1)


def to_points(features: np.ndarray) -> np.ndarray:
    """Feature rows ``(n, 34)`` -> points ``(n, 17, 2)`` (a view when possible)."""
    features = np.asarray(features, dtype=float)
    if features.shape[-1] != N_FEATURES:
        raise ValueError(f"expected {N_FEATURES} feature columns, got {features.shape[-1]}")
    return features.reshape(features.shape[:-1] + (N_JOINTS, 2))


def to_features(points: np.ndarray) -> np.ndarray:
    """Points ``(n, 17, 2)`` -> feature rows ``(n, 34)``."""
    points = np.asarray(points, dtype=float)
    return points.reshape(points.shape[:-2] + (N_FEATURES,))
