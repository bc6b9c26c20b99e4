"""Which BVH joints make the 17 key points, per skeleton family.

A key point is a :class:`PointRule`: an affine combination of node positions
(one joint, the midpoint of two, an End Site, or a point extrapolated past a
joint along a bone), or a *virtual site* — a point fixed in one joint's local
frame, ``factor`` times that joint's own OFFSET along the bone, so that it
nods with the joint (used where the file has no usable head End Site).

Built-in families, auto-detected from joint names (a ``namespace:`` prefix
such as ``mixamorig:`` and letter case are ignored):

=============  ==========================================================
family         files
=============  ==========================================================
bandai-namco   Bandai-Namco-Research-Motiondataset-1 (``joint_Root``,
               ``Hips``, ``UpperLeg_L`` …; six channels on every joint; cm)
cmu            CMU mocap as converted to BVH (``LHipJoint``, ``LeftHip``,
               ``lowerback``, ``Chest2``, ``lowerneck`` …)
mixamo         Mixamo-style names with four spine joints (``Spine`` ..
               ``Spine3``, ``LeftUpLeg``, ``LeftForeArm`` …); the FAIR
               AnimatedDrawings clips (Z-up)
rokoko         Rokoko Studio export (``Spine`` .. ``Spine2``,
               ``LeftInHandIndex`` …; cm)
=============  ==========================================================

Choices behind the table (``FAMILIES``): the pelvis is the midpoint of the
two hip joints in every family, so that it sits level with the hips as in the
template; ``thorax`` is the joint at the base of the neck; ``neck`` (the
Human3.6M neck/nose point) is the head joint; ``head_top`` is the head's End
Site where it points along the head (CMU, Mixamo), and otherwise a point
placed about 15-20 cm above the head joint (Bandai-Namco's head End Site has
a zero offset; Rokoko's head End Site points sideways).
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Mapping

import numpy as np

from nnsf.errors import InputError
from nnsf.skeleton.layout import JOINTS

__all__ = [
    "PointRule", "SkeletonFamily", "FAMILIES", "joint", "mid", "end", "beyond", "local",
    "parse_rule", "family_from_mapping", "detect_family", "resolve", "keypoints_3d",
]


@dataclass(frozen=True)
class PointRule:
    """How one key point is made from BVH nodes.

    ``weights`` pairs node names with weights summing to 1 (an affine
    combination of world positions).  If ``site`` is set instead, the point
    is ``p_site + G_site (factor * offset_site)``: a virtual End Site at
    ``factor`` times the joint's own OFFSET, in the joint's rotated frame.
    """

    weights: tuple[tuple[str, float], ...] = ()
    site: str | None = None
    factor: float = 1.0
    text: str = ""

    def names(self) -> tuple[str, ...]:
        return (self.site,) if self.site is not None else tuple(n for n, _ in self.weights)

    def __str__(self) -> str:
        return self.text


def joint(name: str) -> PointRule:
    """The joint's own position."""
    return PointRule(((name, 1.0),), text=name)


def mid(a: str, b: str) -> PointRule:
    """Midpoint of two nodes."""
    return PointRule(((a, 0.5), (b, 0.5)), text=f"mid({a}, {b})")


def end(name: str) -> PointRule:
    """The End Site below joint ``name`` (node ``<name>_end``)."""
    return PointRule(((f"{name}_end", 1.0),), text=f"end({name})")


def beyond(a: str, b: str, factor: float) -> PointRule:
    """``b + factor (b - a)``: past b along the bone a->b."""
    return PointRule(((b, 1.0 + factor), (a, -factor)), text=f"beyond({a}, {b}, {factor:g})")


def local(name: str, factor: float) -> PointRule:
    """Virtual site ``factor`` x the joint's OFFSET past it, in its own frame."""
    return PointRule(site=name, factor=float(factor), text=f"local({name}, {factor:g})")


_RULE = re.compile(r"^\s*(\w+)\s*\((.*)\)\s*$")


def parse_rule(text: str) -> PointRule:
    """Parse ``"Hips"``, ``"mid(A, B)"``, ``"end(Head)"``, ``"beyond(A, B, 1.5)"``
    or ``"local(Head, 3)"`` (the forms ``str(rule)`` prints)."""
    m = _RULE.match(text)
    if m is None:
        name = text.strip()
        if not name:
            raise ValueError("empty joint name")
        return joint(name)
    kind, args = m.group(1).lower(), [a.strip() for a in m.group(2).split(",")]
    try:
        if kind == "mid" and len(args) == 2:
            return mid(*args)
        if kind == "end" and len(args) == 1:
            return end(args[0])
        if kind == "beyond" and len(args) == 3:
            return beyond(args[0], args[1], float(args[2]))
        if kind == "local" and len(args) == 2:
            return local(args[0], float(args[1]))
    except ValueError:
        pass
    raise ValueError(f"cannot read key-point rule {text!r}: use NAME, mid(A, B), end(A), "
                     "beyond(A, B, f) or local(A, f)")


@dataclass(frozen=True)
class SkeletonFamily:
    """A joint-naming family and its rule for each of the 17 key points."""

    name: str
    description: str
    rules: Mapping[str, PointRule]

    def required(self) -> dict[str, list[str]]:
        """Node name -> the key points that need it."""
        out: dict[str, list[str]] = {}
        for kp in JOINTS:
            for n in self.rules[kp].names():
                out.setdefault(n, []).append(kp)
        return out

    def table(self) -> list[tuple[str, str]]:
        """(key point, rule text) in key-point order, for documentation."""
        return [(kp, str(self.rules[kp])) for kp in JOINTS]


def _family(name: str, description: str, **rules) -> SkeletonFamily:
    missing = [k for k in JOINTS if k not in rules]
    if missing:  # pragma: no cover - a programming error in this module
        raise ValueError(f"family {name} lacks {missing}")
    return SkeletonFamily(name, description, {k: rules[k] for k in JOINTS})


def _limbs(hip: str, knee: str, ankle: str, shoulder: str, elbow: str, wrist: str,
           left="Left{}", right="Right{}"):
    """Rules for the eight limb key points from name templates."""
    out = {}
    for side, tmpl in (("l", left), ("r", right)):
        out[f"{side}_hip"] = joint(tmpl.format(hip))
        out[f"{side}_knee"] = joint(tmpl.format(knee))
        out[f"{side}_ankle"] = joint(tmpl.format(ankle))
        out[f"{side}_shoulder"] = joint(tmpl.format(shoulder))
        out[f"{side}_elbow"] = joint(tmpl.format(elbow))
        out[f"{side}_wrist"] = joint(tmpl.format(wrist))
    return out


#: Built-in families, in the order detection prefers them on a tie.
FAMILIES: dict[str, SkeletonFamily] = {f.name: f for f in (
    _family(
        "bandai-namco",
        "Bandai-Namco-Research-Motiondataset (joint_Root, Hips, Spine, Chest, Neck, Head, "
        "Shoulder_L, UpperArm_L, LowerArm_L, Hand_L, UpperLeg_L, LowerLeg_L, Foot_L, Toes_L); cm",
        pelvis=mid("UpperLeg_L", "UpperLeg_R"),
        spine=mid("Spine", "Chest"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        # The head End Site has a zero OFFSET; the head joint sits at the top
        # of a 6.5 cm neck, its bone axis along the neck.  Three neck lengths
        # (about 19 cm) up the head's own axis reaches the crown.
        head_top=local("Head", 3.0),
        **_limbs("UpperLeg", "LowerLeg", "Foot", "UpperArm", "LowerArm", "Hand",
                 left="{}_L", right="{}_R"),
    ),
    _family(
        "cmu",
        "CMU motion capture converted to BVH (Hips, LHipJoint, LeftHip, LeftKnee, LeftAnkle, "
        "lowerback, Chest, Chest2, lowerneck, Neck, Head, LeftCollar, LeftShoulder, LeftElbow, "
        "LeftWrist); units as converted",
        pelvis=mid("LeftHip", "RightHip"),
        spine=joint("Chest"),
        # lowerneck sits at the top of the chest, Neck about one neck bone
        # higher; the shoulders lie between them.
        thorax=mid("lowerneck", "Neck"),
        neck=joint("Head"),
        head_top=end("Head"),
        **_limbs("Hip", "Knee", "Ankle", "Shoulder", "Elbow", "Wrist"),
    ),
    _family(
        "mixamo",
        "Mixamo-style names with four spine joints (Hips, Spine, Spine1, Spine2, Spine3, Neck, "
        "Head, LeftShoulder, LeftArm, LeftForeArm, LeftHand, LeftUpLeg, LeftLeg, LeftFoot); "
        "the FAIR AnimatedDrawings clips, Z-up",
        pelvis=mid("LeftUpLeg", "RightUpLeg"),
        spine=joint("Spine2"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        head_top=end("Head"),
        **_limbs("UpLeg", "Leg", "Foot", "Arm", "ForeArm", "Hand"),
    ),
    _family(
        "rokoko",
        "Rokoko Studio export (Hips, Spine, Spine1, Spine2, Neck, Head, LeftShoulder, LeftArm, "
        "LeftForeArm, LeftHand, LeftInHandIndex, LeftUpLeg, LeftLeg, LeftFoot); cm",
        pelvis=mid("LeftUpLeg", "RightUpLeg"),
        spine=joint("Spine1"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        # Rokoko's head End Site points sideways (the head joint carries a
        # -90 degree roll), so extend the neck bone instead: 1.4 neck bones
        # (about 15 cm) above the head joint.
        head_top=beyond("Neck", "Head", 1.4),
        **_limbs("UpLeg", "Leg", "Foot", "Arm", "ForeArm", "Hand"),
    ),
)}

# Names only one family uses; they break ties between families whose rules
# are all satisfiable (a Mixamo file also has every joint the Rokoko rules use).
_DISTINCTIVE: dict[str, tuple[str, ...]] = {
    "bandai-namco": ("joint_Root",),
    "cmu": ("LHipJoint", "lowerback"),
    "mixamo": ("Spine3",),
    "rokoko": ("LeftInHandIndex", "RightInHandIndex"),
}


def _canonical(name: str) -> str:
    return name.rsplit(":", 1)[-1].lower()


def family_from_mapping(mapping: Mapping[str, str], name: str = "custom") -> SkeletonFamily:
    """A family from ``{key point: rule text}`` covering all 17 key points
    (see :func:`parse_rule`); ``ValueError`` names what is missing or unknown."""
    unknown = sorted(set(mapping) - set(JOINTS))
    if unknown:
        raise ValueError(f"unknown key point(s) {unknown}; the 17 are {list(JOINTS)}")
    missing = [k for k in JOINTS if k not in mapping]
    if missing:
        raise ValueError(f"mapping lacks key point(s) {missing}")
    return SkeletonFamily(name, "user mapping", {k: parse_rule(str(mapping[k])) for k in JOINTS})


def _lookup(names) -> dict[str, int]:
    out: dict[str, int] = {}
    for i, n in enumerate(names):
        out.setdefault(_canonical(n), i)
    return out


def _missing(family: SkeletonFamily, lookup: Mapping[str, int]) -> dict[str, list[str]]:
    return {n: kps for n, kps in family.required().items() if _canonical(n) not in lookup}


def detect_family(names, source="<bvh>") -> SkeletonFamily:
    """The built-in family whose rules the node ``names`` satisfy.

    Among families whose required joints are all present, one with a
    distinctive joint name wins, then the first in :data:`FAMILIES`.
    Raises :class:`InputError` naming ``source``, the closest family, its
    missing joint names and the key points left unmapped.
    """
    lookup = _lookup(names)
    ok = [f for f in FAMILIES.values() if not _missing(f, lookup)]
    if ok:
        marked = [f for f in ok if any(_canonical(d) in lookup for d in _DISTINCTIVE.get(f.name, ()))]
        return (marked or ok)[0]
    # Closest family: the one with fewest unmapped key points.
    best, best_missing = None, None
    for f in FAMILIES.values():
        miss = _missing(f, lookup)
        kps = sorted({k for v in miss.values() for k in v}, key=JOINTS.index)
        if best is None or len(kps) < len(best_missing[1]):
            best, best_missing = f, (miss, kps)
    miss, kps = best_missing
    raise InputError(
        source, "joint names",
        f"a skeleton of a known family ({', '.join(FAMILIES)}); closest is {best.name}, which "
        f"needs {', '.join(sorted(miss))} for the unmapped key point(s) {', '.join(kps)}",
    )


def resolve(family: SkeletonFamily, names,
            source="<bvh>") -> list[tuple[np.ndarray, np.ndarray, int | None, float]]:
    """Node indices per key point: ``[(indices, weights, site, factor), ...]`` (17).

    Raises :class:`InputError` listing missing joints if ``family`` does not fit.
    """
    lookup = _lookup(names)
    miss = _missing(family, lookup)
    if miss:
        kps = sorted({k for v in miss.values() for k in v}, key=JOINTS.index)
        raise InputError(source, "joint names",
                         f"the joints skeleton family {family.name} maps: "
                         f"{', '.join(sorted(miss))} (for key point(s) {', '.join(kps)})", "none of them")
    out = []
    for kp in JOINTS:
        r = family.rules[kp]
        if r.site is not None:
            out.append((np.zeros(0, dtype=np.int64), np.zeros(0), lookup[_canonical(r.site)], r.factor))
        else:
            idx = np.array([lookup[_canonical(n)] for n, _ in r.weights], dtype=np.int64)
            w = np.array([w for _, w in r.weights], dtype=np.float64)
            out.append((idx, w, None, 1.0))
    return out


def keypoints_3d(bvh, positions: np.ndarray, rotations: np.ndarray, family: SkeletonFamily) -> np.ndarray:
    """The 17 key points in 3D, ``(F, 17, 3)``, in the BVH's units and axes.

    ``positions`` ``(F, J, 3)`` and ``rotations`` ``(F, J, 3, 3)`` are the
    output of ``forward_kinematics(bvh, end_sites=True, return_rotations=True)``.
    """
    F = positions.shape[0]
    out = np.empty((F, len(JOINTS), 3))
    for k, (idx, w, site, factor) in enumerate(resolve(family, bvh.names, bvh.source)):
        if site is not None:
            out[:, k] = positions[:, site] + rotations[:, site] @ (factor * bvh.offsets[site])
        else:
            out[:, k] = np.tensordot(w, positions[:, idx], axes=([0], [1]))
    return out
