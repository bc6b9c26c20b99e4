"""The template body every character is unified to.

Lengths are in *template units*: the template's torso (pelvis to thorax) is
1.0 long, so an error in template units reads directly as a fraction of the
torso.  The rest pose stands upright, facing the viewer, in image axes
(x to the right, y down).
"""
from __future__ import annotations

import numpy as np

from nnsf.skeleton.layout import BONES, JOINT_INDEX, N_JOINTS, PARENTS

# Rest-pose offsets of each key point from its parent, (dx, dy), template
# units.  Proportions follow an adult of about 7.5 heads.
_REST_OFFSETS: dict[str, tuple[float, float]] = {
    "r_hip": (-0.22, 0.0), "r_knee": (0.0, 0.98), "r_ankle": (0.0, 0.95),
    "l_hip": (0.22, 0.0), "l_knee": (0.0, 0.98), "l_ankle": (0.0, 0.95),
    "spine": (0.0, -0.5), "thorax": (0.0, -0.5), "neck": (0.0, -0.22),
    "head_top": (0.0, -0.38),
    "l_shoulder": (0.36, 0.02), "l_elbow": (0.0, 0.62), "l_wrist": (0.0, 0.55),
    "r_shoulder": (-0.36, 0.02), "r_elbow": (0.0, 0.62), "r_wrist": (0.0, 0.55),
}


def rest_pose(root=(0.0, 0.0)) -> np.ndarray:
    """Template rest pose, ``(17, 2)``, with the pelvis at ``root``."""
    pts = np.zeros((N_JOINTS, 2))
    pts[0] = root
    for j in range(1, N_JOINTS):
        pts[j] = pts[PARENTS[j]] + _REST_OFFSETS[_name(j)]
    return pts


def _name(j: int) -> str:
    for name, i in JOINT_INDEX.items():
        if i == j:
            return name
    raise KeyError(j)


#: Template bone lengths ``(16,)`` in bone order (see ``layout.BONES``).
TEMPLATE_BONE_LENGTHS: np.ndarray = np.array(
    [float(np.hypot(*_REST_OFFSETS[_name(c)])) for _, c in BONES]
)

#: Torso length of the template (pelvis-spine-thorax), the unit of error.
TEMPLATE_TORSO = 1.0

#: Height of the template standing (head top to ankles), template units.
TEMPLATE_HEIGHT = float(np.ptp(rest_pose()[:, 1]))
