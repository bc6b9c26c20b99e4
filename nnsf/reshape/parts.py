"""The body's parts: the one table of part names, the bones that label them and the joints that join them.

Part ids index :data:`PARTS`: the torso, the head, then the limb segments in
:data:`nnsf.skeleton.LIMBS` order (part ``2 + i`` is limb ``i``).  Arms a skeleton has beyond the
two it drives get parts after these (:class:`nnsf.reshape.rig.Rig`).
"""
from __future__ import annotations

from nnsf.skeleton import JOINT_INDEX as J, LIMBS

PARTS: tuple[str, ...] = ("torso", "head") + tuple(LIMBS)
PART_INDEX = {name: i for i, name in enumerate(PARTS)}

#: ``(a, b, part)``: the key-point segments a part is made of.  The torso is its spine and the lines
#: out to the hips and shoulders; the head runs from the neck to its top.  Nothing stands for the
#: stretch between thorax and neck: drawings put the neck joint anywhere from the shoulders to the
#: face, so the drawing's own lines decide where the head ends (:meth:`nnsf.reshape.rig.Rig.segment`).
PART_BONES: tuple[tuple[int, int, int], ...] = tuple(
    [(J[a], J[b], 0) for a, b in (("pelvis", "spine"), ("spine", "thorax"), ("pelvis", "r_hip"),
                                  ("pelvis", "l_hip"), ("thorax", "l_shoulder"), ("thorax", "r_shoulder"))]
    + [(J["neck"], J["head_top"], 1)]
    + [(a, b, 2 + i) for i, (a, b) in enumerate(LIMBS.values())])

#: ``(parent part, child part, joint key point)``: where a part hangs from its parent.
JOINS: tuple[tuple[int, int, int], ...] = ((0, 1, J["neck"]),) + tuple(
    (0 if name.endswith(("upper_arm", "thigh")) else PART_INDEX[name] - 1, PART_INDEX[name], a)
    for name, (a, _) in LIMBS.items())
