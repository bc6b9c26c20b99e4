"""The body's parts, the pieces a split mesh is cut into, and the segments of a layered one.

Tables only: part ids (:data:`PARTS`: torso, head, then the limbs in
:data:`nnsf.skeleton.LIMBS` order) with the bones each is nearest to, the
pieces of a split mesh with the key points that pin each, and the ten
segments of a layered mesh (body, eight limb segments, head) with their
joint collars.  :mod:`nnsf.reshape.mesh` assigns triangles to parts,
:mod:`nnsf.reshape.layers` cuts the layered mesh along them.
"""
from __future__ import annotations

import numpy as np

from nnsf.skeleton import JOINT_INDEX, LIMBS

#: Part names; ids index this tuple.  Limb parts follow ``nnsf.skeleton.LIMBS``
#: order, so part ``2 + i`` is limb ``i``.
PARTS: tuple[str, ...] = ("torso", "head") + tuple(LIMBS)


PART_INDEX = {name: i for i, name in enumerate(PARTS)}

#: Part pairs a joint joins ``((ancestor, part), ...)``: the torso with the head and with each limb
#: segment (a lower segment meets the torso where its upper one is drawn hidden, AnimatedDrawings'
#: char1), each upper segment with its lower one.  Two limbs, or a limb and the head, are not joined.
JOINED_PARTS: tuple[tuple[int, int], ...] = ((0, 1),) + tuple((0, i) for i in range(2, len(PARTS))) + tuple(
    (i - 1, i) for i, name in enumerate(PARTS) if i >= 2 and not ("upper" in name or "thigh" in name))


def _bones_of_parts() -> list[tuple[int, int, int]]:
    """(parent key point, child key point, part id) for every bone used to label parts."""
    J = JOINT_INDEX
    torso = [("pelvis", "spine"), ("spine", "thorax"), ("pelvis", "r_hip"), ("pelvis", "l_hip"),
             ("thorax", "l_shoulder"), ("thorax", "r_shoulder")]
    head = [("thorax", "neck"), ("neck", "head_top")]
    out = [(J[a], J[b], PART_INDEX["torso"]) for a, b in torso]
    out += [(J[a], J[b], PART_INDEX["head"]) for a, b in head]
    out += [(a, b, PART_INDEX[name]) for name, (a, b) in LIMBS.items()]
    return out


PART_BONES = _bones_of_parts()


#: Pieces of a split mesh: the body (torso and head) and each whole limb.
PIECES: tuple[str, ...] = ("body", "l_arm", "r_arm", "l_leg", "r_leg")


#: Piece of each part, ``(10,)``, indexed by part id.
PART_PIECE = np.array([0, 0] + [PIECES.index(f"{name[0]}_{'arm' if 'arm' in name else 'leg'}")
                                for name in LIMBS], dtype=np.int64)


#: Key points that pin each piece: the body holds every point of the torso
#: and head, including the shoulders and hips where the limbs attach.
PIECE_KEYPOINTS: dict[str, tuple[int, ...]] = {
    "body": tuple(JOINT_INDEX[j] for j in ("pelvis", "r_hip", "l_hip", "spine", "thorax", "neck",
                                           "head_top", "l_shoulder", "r_shoulder")),
    "l_arm": tuple(JOINT_INDEX[j] for j in ("l_shoulder", "l_elbow", "l_wrist")),
    "r_arm": tuple(JOINT_INDEX[j] for j in ("r_shoulder", "r_elbow", "r_wrist")),
    "l_leg": tuple(JOINT_INDEX[j] for j in ("l_hip", "l_knee", "l_ankle")),
    "r_leg": tuple(JOINT_INDEX[j] for j in ("r_hip", "r_knee", "r_ankle")),
}


#: Pieces of a layered mesh (:func:`layer_pieces`): the body (torso), every
#: limb segment and the head, each on its own, so no joint can fold.
SEGMENTS: tuple[str, ...] = ("body",) + tuple(LIMBS) + ("head",)


#: Segment piece of each part, ``(10,)``, and the part of each segment, ``(10,)``.
PART_SEGMENT = np.array([0, len(SEGMENTS) - 1] + list(range(1, 1 + len(LIMBS))), dtype=np.int64)


SEGMENT_PART = np.array([0] + list(range(2, 2 + len(LIMBS))) + [1], dtype=np.int64)


SEGMENT_KEYPOINTS: tuple[tuple[int, ...], ...] = (
    (tuple(JOINT_INDEX[j] for j in ("pelvis", "r_hip", "l_hip", "spine", "thorax", "neck", "l_shoulder",
                                    "r_shoulder")),)
    + tuple((int(a), int(b)) for a, b in LIMBS.values())
    + ((JOINT_INDEX["neck"], JOINT_INDEX["head_top"]),))


#: Joints where a child piece overlaps its parent (:func:`layer_pieces`):
#: (joint, parent piece, child piece, collar scale), indices into ``JOINTS`` /
#: ``SEGMENTS``.  The scale is the cap's depth into the parent as a fraction
#: of half the cut: 0.6 covers the wedge of bends up to ~40° while a strongly
#: bent joint's cap pokes out less (at 1.0 the caps showed as grey bumps in a
#: run); the neck's is smaller: a drawn head is much wider than its neck.
COLLARS: tuple[tuple[int, int, int, float], ...] = tuple(
    (JOINT_INDEX[j], SEGMENTS.index(parent), SEGMENTS.index(child), scale) for j, parent, child, scale in (
        ("l_shoulder", "body", "l_upper_arm", 0.6), ("l_elbow", "l_upper_arm", "l_forearm", 0.6),
        ("r_shoulder", "body", "r_upper_arm", 0.6), ("r_elbow", "r_upper_arm", "r_forearm", 0.6),
        ("l_hip", "body", "l_thigh", 0.6), ("l_knee", "l_thigh", "l_shin", 0.6),
        ("r_hip", "body", "r_thigh", 0.6), ("r_knee", "r_thigh", "r_shin", 0.6),
        ("neck", "body", "head", 0.4)))


#: Pieces of a whole-limb mesh (``split="limbs"``, :func:`layer_pieces` with
#: ``whole_limbs=True``): the body, each whole limb (upper and lower segment
#: one deformable piece, bending at the elbow or knee) and the head.  Cut and
#: capped like the layered mesh at the shoulders, hips and neck only.
LIMB_PIECES: tuple[str, ...] = ("body", "l_arm", "r_arm", "l_leg", "r_leg", "head")


#: Whole-limb piece of each segment piece, ``(10,)``, indexed like :data:`SEGMENTS`.
SEGMENT_LIMB_PIECE = np.array([0] + [LIMB_PIECES.index(f"{n[0]}_{'arm' if 'arm' in n else 'leg'}")
                                     for n in LIMBS] + [len(LIMB_PIECES) - 1], dtype=np.int64)


LIMB_PIECE_KEYPOINTS: tuple[tuple[int, ...], ...] = (
    (SEGMENT_KEYPOINTS[0],) + tuple(PIECE_KEYPOINTS[n] for n in LIMB_PIECES[1:-1]) + (SEGMENT_KEYPOINTS[-1],))


#: The torso polygon (key points, in order) under which limb triangles get an underlay.
TORSO_POLYGON = tuple(JOINT_INDEX[j] for j in ("l_hip", "pelvis", "r_hip", "r_shoulder", "thorax", "l_shoulder"))
