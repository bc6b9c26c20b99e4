"""The 17 key points, bones, the template body and template unification."""
from nnsf.skeleton.layout import (
    BONE_NAMES, BONES, FEATURE_COLUMNS, JOINT_INDEX, JOINTS, LIMBS, N_FEATURES, N_JOINTS, PARENTS,
    bone_lengths, bone_vectors, to_features, to_points,
)
from nnsf.skeleton.template import TEMPLATE_BONE_LENGTHS, TEMPLATE_HEIGHT, TEMPLATE_TORSO, rest_pose
from nnsf.skeleton.unify import CharacterScale, Unifier, character_scale, difference_operator

__all__ = [
    "BONE_NAMES", "BONES", "FEATURE_COLUMNS", "JOINT_INDEX", "JOINTS", "LIMBS", "N_FEATURES",
    "N_JOINTS", "PARENTS", "bone_lengths", "bone_vectors", "to_features", "to_points",
    "TEMPLATE_BONE_LENGTHS", "TEMPLATE_HEIGHT", "TEMPLATE_TORSO", "rest_pose",
    "CharacterScale", "Unifier", "character_scale", "difference_operator",
]
