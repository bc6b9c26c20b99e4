"""Which BVH joints make the 17 key points: skeleton families, found by their joint names.

A key point is a :class:`PointRule`: an affine combination of node positions
(one joint, the midpoint of two, an End Site, or a point extrapolated past a
joint along a bone), or a *virtual site* — a point fixed in one joint's local
frame, ``factor`` times that joint's own OFFSET along the bone, so that it
nods with the joint (used where the file has no usable head End Site).  A
family may give a key point several rules; the first whose joints the file
has is used (a spine chain of two or four joints, a head with or without an
End Site).

Built-in families (:data:`FAMILIES`; the table in docs/formats.md §3.2):

==================  ============================================================
family              names it writes
==================  ============================================================
bandai-namco        ``joint_Root``, ``UpperLeg_L``, ``LowerArm_R`` … (cm)
cmu-motionbuilder   CMU, "MotionBuilder-friendly" BVH release (``LHipJoint``,
                    ``LeftUpLeg``, ``LowerBack``, ``Spine1``, ``Neck1`` …)
cmu-asf             CMU with the ASF skeleton's spine names (``LHipJoint``,
                    ``LeftHip``, ``lowerback``, ``Chest2``, ``lowerneck``, ``lhand``)
3dsmax              3ds Max Biped / Biovision naming, also CMU's
                    "3dsMax-friendly" release (``Chest``…``Chest4`` or ``Ab``,
                    ``LeftCollar``, ``LeftHip``, ``LeftKnee``, ``LeftAnkle``)
daz                 Daz / Poser naming, also CMU's "Daz-friendly" release
                    (``hip``, ``abdomen``, ``lCollar``, ``lShldr``, ``lThigh``)
mixamo              Adobe Mixamo (``mixamorig:`` prefix, ``Spine2``, ``HeadTop_End``)
animated-drawings   the AnimatedDrawings example clips (``Spine3``,
                    ``LeftHandEnd``; Z-up)
rokoko              Rokoko Studio (``LeftInHandIndex`` …; cm)
iclone              iClone / Character Creator (``CC_Base_Hip``,
                    ``CC_Base_L_Thigh``, ``CC_Base_NeckTwist01``; twist and
                    share bones ignored)
==================  ============================================================

Detection by these names is :mod:`nnsf.datasets.bvh_detect`.

Matching ignores letter case, a ``namespace:`` prefix (``mixamorig:``) and a
prefix that every joint name shares (``Character1_``, ``Bip01 ``), so one
family reads the renamed exports of the same rig.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from typing import Iterable, Mapping, Sequence

import numpy as np

from nnsf.errors import InputError
from nnsf.skeleton.layout import BONES, JOINTS

__all__ = [
    "PointRule", "SkeletonFamily", "FAMILIES", "JointNames", "first_rule",
    "joint", "mid", "end", "beyond", "local", "parse_rule", "rule_from_value", "family_from_mapping",
    "unmapped", "resolve", "mapping_text", "keypoints_3d", "check_bones",
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
    or ``"local(Head, 3)"`` (the forms ``str(rule)`` prints); ``ValueError`` otherwise."""
    m = _RULE.match(text)
    if m is None:
        name = text.strip()
        if not name or "(" in name or ")" in name:
            raise ValueError(f"cannot read key-point rule {text!r}: use NAME, mid(A, B), end(A), "
                             "beyond(A, B, f) or local(A, f)")
        return joint(name)
    kind, args = m.group(1).lower(), [a.strip() for a in m.group(2).split(",")]
    try:
        if all(args[:2]):
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
    """A joint-naming family: rules for the 17 key points and the names it writes.

    ``rules`` maps each key point to one or more :class:`PointRule` (the first
    whose nodes exist is used).  ``names`` is the family's signature: the
    joints its exporter always writes.  ``extra`` holds regular expressions
    (matched against lower-case names) of joints it may also write: fingers,
    toes, eyes, twist bones.  A user mapping has neither, and ``source``
    names the joint map it came from.
    """

    name: str
    description: str
    rules: Mapping[str, tuple[PointRule, ...]]
    names: tuple[str, ...] = ()
    extra: tuple[str, ...] = ()
    source: str = ""
    _extra_re: re.Pattern | None = field(default=None, compare=False, repr=False)

    def __post_init__(self):
        if self.extra:
            object.__setattr__(self, "_extra_re", re.compile("|".join(f"(?:{p})" for p in self.extra)))

    def writes(self, canonical: str) -> bool:
        """Whether the family writes a joint of this lower-case name."""
        return canonical in self.signature or (
            self._extra_re is not None and self._extra_re.fullmatch(canonical) is not None)

    @property
    def signature(self) -> frozenset[str]:
        return frozenset(n.lower() for n in self.names)

    def required(self) -> dict[str, list[str]]:
        """Node name -> the key points whose first rule needs it."""
        out: dict[str, list[str]] = {}
        for kp in JOINTS:
            for n in self.rules[kp][0].names():
                out.setdefault(n, []).append(kp)
        return out

    def table(self) -> list[tuple[str, str]]:
        """(key point, rule texts joined by ``|``) in key-point order, for documentation."""
        return [(kp, " | ".join(str(r) for r in self.rules[kp])) for kp in JOINTS]


def _family(name: str, description: str, names: Iterable[str], extra: Sequence[str] = (),
            **rules) -> SkeletonFamily:
    missing = [k for k in JOINTS if k not in rules]
    if missing:  # pragma: no cover - a programming error in this module
        raise ValueError(f"family {name} lacks {missing}")
    as_tuple = {k: (rules[k] if isinstance(rules[k], tuple) else (rules[k],)) for k in JOINTS}
    return SkeletonFamily(name, description, as_tuple, tuple(names), tuple(extra))


def _limbs(hip: str, knee: str, ankle: str, shoulder: str, elbow: str, wrist: str,
           left="Left{}", right="Right{}"):
    """Rules for the twelve limb key points from name templates."""
    out = {}
    for side, tmpl in (("l", left), ("r", right)):
        out[f"{side}_hip"] = joint(tmpl.format(hip))
        out[f"{side}_knee"] = joint(tmpl.format(knee))
        out[f"{side}_ankle"] = joint(tmpl.format(ankle))
        out[f"{side}_shoulder"] = joint(tmpl.format(shoulder))
        out[f"{side}_elbow"] = joint(tmpl.format(elbow))
        out[f"{side}_wrist"] = joint(tmpl.format(wrist))
    return out


def _sided(parts: str, left="Left{}", right="Right{}") -> list[str]:
    """``"UpLeg Leg"`` -> LeftUpLeg, RightUpLeg, LeftLeg, RightLeg."""
    return [t.format(p) for p in parts.split() for t in (left, right)]


#: Finger joints as most exporters name them (lower case): LeftHandIndex1, RightHandThumb3, ...
_HAND_FINGERS = r"(left|right)hand(thumb|index|middle|ring|pinky)\d(_end)?"

#: Built-in families (module docstring); ties between them are errors, not broken by order.
FAMILIES: dict[str, SkeletonFamily] = {f.name: f for f in (
    _family(
        "bandai-namco",
        "Bandai-Namco-Research-Motiondataset (joint_Root, Hips, Spine, Chest, Neck, Head, "
        "Shoulder_L, UpperArm_L, LowerArm_L, Hand_L, UpperLeg_L, LowerLeg_L, Foot_L, Toes_L); cm",
        ["joint_Root", "Hips", "Spine", "Chest", "Neck", "Head"]
        + _sided("Shoulder UpperArm LowerArm Hand UpperLeg LowerLeg Foot Toes", "{}_L", "{}_R"),
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
        "cmu-motionbuilder",
        "CMU motion capture, the 'MotionBuilder-friendly' BVH release (Hips, LHipJoint, LeftUpLeg, "
        "LeftLeg, LeftFoot, LowerBack, Spine, Spine1, Neck, Neck1, Head, LeftShoulder, LeftArm, "
        "LeftForeArm, LeftHand)",
        ["Hips", "LHipJoint", "RHipJoint", "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head",
         "LThumb", "RThumb"]
        + _sided("UpLeg Leg Foot ToeBase Shoulder Arm ForeArm Hand FingerBase"),
        extra=[r"(left|right)handindex1", r"[lr]fingers"],
        pelvis=mid("LeftUpLeg", "RightUpLeg"),
        spine=joint("Spine"),
        # Neck sits on Spine1 with a zero OFFSET (as do the shoulders); Neck1
        # is one neck bone higher: the base of the neck lies between them.
        thorax=mid("Neck", "Neck1"),
        neck=joint("Head"),
        # The head End Site; where it is missing or at zero OFFSET (retargeted copies of this
        # skeleton), the crown lies about one upper-neck bone above the head joint.
        head_top=(end("Head"), beyond("Neck1", "Head", 1.0)),
        **_limbs("UpLeg", "Leg", "Foot", "Arm", "ForeArm", "Hand"),
    ),
    _family(
        "cmu-asf",
        "CMU motion capture with the ASF skeleton's spine names (Hips, LHipJoint, LeftHip, LeftKnee, "
        "LeftAnkle, lowerback, Chest, Chest2, lowerneck, Neck, Head, LeftCollar, LeftShoulder, "
        "LeftElbow, LeftWrist, lhand)",
        ["Hips", "LHipJoint", "RHipJoint", "lowerback", "Chest", "Chest2", "lowerneck", "Neck", "Head",
         "lhand", "rhand", "LFingers", "RFingers", "LThumb", "RThumb"]
        + _sided("Hip Knee Ankle Toe Collar Shoulder Elbow Wrist"),
        pelvis=mid("LeftHip", "RightHip"),
        spine=joint("Chest"),
        # lowerneck sits at the top of the chest, Neck about one neck bone
        # higher; the shoulders lie between them.
        thorax=mid("lowerneck", "Neck"),
        neck=joint("Head"),
        head_top=(end("Head"), beyond("Neck", "Head", 1.0)),
        **_limbs("Hip", "Knee", "Ankle", "Shoulder", "Elbow", "Wrist"),
    ),
    _family(
        "3dsmax",
        "3ds Max Biped / Biovision naming, also CMU's '3dsMax-friendly' release (Hips, Chest, "
        "Chest2..Chest4 or Ab, Neck, Head, LeftCollar, LeftShoulder, LeftElbow, LeftWrist, LeftHip, "
        "LeftKnee, LeftAnkle, LeftToe)",
        ["Hips", "Chest", "Chest2", "Neck", "Head"]
        + _sided("Collar Shoulder Elbow Wrist Hip Knee Ankle Toe"),
        extra=[r"chest[3-9]", r"ab", r"(left|right)toes"],
        pelvis=mid("LeftHip", "RightHip"),
        # The chain between the hips and the neck has one to four joints in
        # the variants of this naming: its middle is the spine point.
        spine=mid("Hips", "Neck"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        head_top=(end("Head"), local("Head", 1.6)),
        **_limbs("Hip", "Knee", "Ankle", "Shoulder", "Elbow", "Wrist"),
    ),
    _family(
        "daz",
        "Daz / Poser naming, also CMU's 'Daz-friendly' release (hip, abdomen, chest, neck, head, "
        "lCollar, lShldr, lForeArm, lHand, lButtock, lThigh, lShin, lFoot)",
        ["hip", "abdomen", "chest", "neck", "head"]
        + _sided("Collar Shldr ForeArm Hand Buttock Thigh Shin Foot", "l{}", "r{}"),
        extra=[r"(left|right)eye", r"[lr](thumb|index|mid|ring|pinky)\d", r"[lr]toe"],
        pelvis=mid("lThigh", "rThigh"),
        spine=mid("abdomen", "chest"),
        thorax=joint("neck"),
        neck=joint("head"),
        # The head carries the eyes, no End Site: 2.5 head OFFSETs (the short
        # upper neck) up the head's own axis reach the crown.
        head_top=(end("head"), local("head", 2.5)),
        **_limbs("Thigh", "Shin", "Foot", "Shldr", "ForeArm", "Hand", left="l{}", right="r{}"),
    ),
    _family(
        "mixamo",
        "Adobe Mixamo (mixamorig:Hips, Spine, Spine1, Spine2, Neck, Head, HeadTop_End, LeftShoulder, "
        "LeftArm, LeftForeArm, LeftHand, LeftUpLeg, LeftLeg, LeftFoot, LeftToeBase)",
        ["Hips", "Spine", "Spine1", "Spine2", "Neck", "Head", "HeadTop_End"]
        + _sided("Shoulder Arm ForeArm Hand UpLeg Leg Foot ToeBase"),
        extra=[_HAND_FINGERS, r"(left|right)eye", r"(left|right)toe_end"],
        pelvis=mid("LeftUpLeg", "RightUpLeg"),
        spine=joint("Spine1"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        head_top=(joint("HeadTop_End"), end("Head"), beyond("Neck", "Head", 1.8)),
        **_limbs("UpLeg", "Leg", "Foot", "Arm", "ForeArm", "Hand"),
    ),
    _family(
        "animated-drawings",
        "the AnimatedDrawings example clips (Hips, Spine, Spine1, Spine2, Spine3, Neck, Head, "
        "LeftShoulder, LeftArm, LeftForeArm, LeftHand, LeftHandEnd, LeftUpLeg, LeftLeg, LeftFoot); "
        "Z-up",
        ["Hips", "Spine", "Spine1", "Spine2", "Spine3", "Neck", "Head"]
        + _sided("Shoulder Arm ForeArm Hand HandEnd HandThumb1 UpLeg Leg Foot ToeBase"),
        pelvis=mid("LeftUpLeg", "RightUpLeg"),
        spine=joint("Spine2"),
        thorax=joint("Neck"),
        neck=joint("Head"),
        head_top=(end("Head"), beyond("Neck", "Head", 1.2)),
        **_limbs("UpLeg", "Leg", "Foot", "Arm", "ForeArm", "Hand"),
    ),
    _family(
        "rokoko",
        "Rokoko Studio export (Hips, Spine, Spine1, Spine2, Neck, Head, LeftShoulder, LeftArm, "
        "LeftForeArm, LeftHand, LeftInHandIndex, LeftUpLeg, LeftLeg, LeftFoot); cm",
        ["Hips", "Spine", "Spine1", "Spine2", "Neck", "Head"]
        + _sided("Shoulder Arm ForeArm Hand UpLeg Leg Foot ToeBase InHandIndex InHandMiddle "
                 "InHandRing InHandPinky"),
        extra=[_HAND_FINGERS],
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
    _family(
        "iclone",
        "iClone / Character Creator (CC_Base_Hip, CC_Base_Pelvis, CC_Base_Waist, CC_Base_Spine01, "
        "CC_Base_Spine02, CC_Base_NeckTwist01, CC_Base_Head, CC_Base_L_Thigh, CC_Base_L_Calf, "
        "CC_Base_L_Foot, CC_Base_L_Clavicle, CC_Base_L_Upperarm, CC_Base_L_Forearm, CC_Base_L_Hand; "
        "twist and share bones ignored)",
        ["CC_Base_Hip", "CC_Base_Pelvis", "CC_Base_Waist", "CC_Base_Spine01", "CC_Base_Spine02",
         "CC_Base_NeckTwist01", "CC_Base_NeckTwist02", "CC_Base_Head"]
        + _sided("Thigh Calf Foot ToeBase Clavicle Upperarm Forearm Hand", "CC_Base_L_{}", "CC_Base_R_{}"),
        # Every other CC_Base_ bone (twist, share, facial, finger bones) and the rig's root.
        extra=[r"cc_base_.*", r"rl_.*"],
        pelvis=mid("CC_Base_L_Thigh", "CC_Base_R_Thigh"),
        spine=joint("CC_Base_Spine01"),
        thorax=joint("CC_Base_NeckTwist01"),
        neck=joint("CC_Base_Head"),
        # The head's children are facial bones, not an End Site: 1.8 neck
        # lengths above the head joint, as the crown sits in a Mixamo rig.
        head_top=beyond("CC_Base_NeckTwist01", "CC_Base_Head", 1.8),
        **_limbs("Thigh", "Calf", "Foot", "Upperarm", "Forearm", "Hand",
                 left="CC_Base_L_{}", right="CC_Base_R_{}"),
    ),
)}


# --------------------------------------------------------------------------- names

def _namespace_free(name: str) -> str:
    return name.rsplit(":", 1)[-1]


def _shared_prefix(names: Sequence[str]) -> str:
    """The prefix every name shares, up to its last separator (``Character1_``, ``Bip01 ``), or ''."""
    if len(names) < 2:
        return ""
    common = os.path.commonprefix(list(names))
    cut = max(common.rfind(c) for c in "_ .|") + 1
    if cut == 0 or any(len(n) <= cut for n in names):
        return ""
    return common[:cut]


class JointNames:
    """A file's node names for matching: each node's lower-case forms (whole, and without a shared prefix).

    ``end_sites`` gives each node's kind (:attr:`nnsf.datasets.bvh.BVH.site_kinds`: 0 a joint,
    1 an End Site, 2 an End Site at zero OFFSET, which no rule may use: it marks no point of its
    own); booleans (End Site or not) work too.

    ``has(name)`` and ``index(name)`` look a family's joint name up as the module docstring says.
    """

    def __init__(self, names: Sequence[str], end_sites: Sequence[int] | None = None):
        self.names = tuple(str(n) for n in names)
        kinds = [0] * len(self.names) if end_sites is None else [int(e) for e in end_sites]
        ends = [k > 0 for k in kinds]
        free = [_namespace_free(n) for n in self.names]
        prefix = _shared_prefix([f for f, e in zip(free, ends) if not e])
        self.forms: list[tuple[str, ...]] = [()] * len(free)
        self.lookup: dict[str, int] = {}
        for i, f in enumerate(free):
            if kinds[i] == 2:       # an End Site at zero OFFSET is its joint, not a point a rule may use
                continue
            whole = f.lower()
            forms = (whole,) if not prefix or not f.startswith(prefix) else (whole, f[len(prefix):].lower())
            self.forms[i] = forms
            for form in forms:
                self.lookup.setdefault(form, i)
        self.joints = [i for i, e in enumerate(ends) if not e]

    def has(self, name: str) -> bool:
        return _namespace_free(name).lower() in self.lookup

    def index(self, name: str) -> int:
        return self.lookup[_namespace_free(name).lower()]


def first_rule(family: SkeletonFamily, kp: str, names: JointNames) -> PointRule | None:
    """The first of the family's rules for ``kp`` whose nodes ``names`` has, or None."""
    for rule in family.rules[kp]:
        if all(names.has(n) for n in rule.names()):
            return rule
    return None


def rule_from_value(value, key: str = "key point") -> PointRule:
    """A joint map's value as a rule: a joint name or rule text (:func:`parse_rule`), or a
    list of two joint names (their midpoint); ``ValueError`` otherwise."""
    if isinstance(value, (list, tuple)):
        if len(value) != 2 or not all(isinstance(x, str) and x.strip() for x in value):
            raise ValueError(f"{key}: a list must hold two joint names (their midpoint), got {value!r}")
        return mid(value[0].strip(), value[1].strip())
    if isinstance(value, str):
        return parse_rule(value)
    raise ValueError(f"{key}: expected a joint name, a list of two joint names or a rule, got {value!r}")


def unmapped(family: SkeletonFamily, names, end_sites=None) -> dict[str, list[str]]:
    """Key point -> the joints its first rule needs that ``names`` lack, for the key points no rule maps."""
    nm = JointNames(names, end_sites)
    return {kp: [n for n in family.rules[kp][0].names() if not nm.has(n)]
            for kp in JOINTS if first_rule(family, kp, nm) is None}


def family_from_mapping(mapping: Mapping[str, object], name: str = "custom",
                        base: SkeletonFamily | None = None) -> SkeletonFamily:
    """A family from ``{key point: rule}`` (see :func:`parse_rule`; a list of two
    joint names is their midpoint).  Without ``base`` all 17 key points are
    needed; with it, key points left out keep ``base``'s rules.  ``ValueError``
    names what is missing or unreadable."""
    unknown = sorted(set(map(str, mapping)) - set(JOINTS))
    if unknown:
        raise ValueError(f"unknown key point(s) {unknown}; the 17 are {list(JOINTS)}")
    missing = [k for k in JOINTS if k not in mapping]
    if missing and base is None:
        raise ValueError(f"mapping lacks key point(s) {missing}")
    rules = {k: (rule_from_value(mapping[k], k),) if k in mapping else base.rules[k] for k in JOINTS}
    desc = "user mapping" + (f" over {base.name}" if base is not None else "")
    return SkeletonFamily(name, desc, rules)


# --------------------------------------------------------------------------- using a family

def resolve(family: SkeletonFamily, names, source="<bvh>",
            end_sites=None) -> list[tuple[np.ndarray, np.ndarray, int | None, float]]:
    """Node indices per key point: ``[(indices, weights, site, factor), ...]`` (17).

    Raises :class:`InputError` listing the joints the family needs that the file lacks.
    """
    nm = JointNames(names, end_sites)
    out = []
    missing: dict[str, list[str]] = {}
    for kp in JOINTS:
        r = first_rule(family, kp, nm)
        if r is None:
            for n in family.rules[kp][0].names():
                if not nm.has(n):
                    missing.setdefault(n, []).append(kp)
            continue
        if r.site is not None:
            out.append((np.zeros(0, dtype=np.int64), np.zeros(0), nm.index(r.site), r.factor))
        else:
            idx = np.array([nm.index(n) for n, _ in r.weights], dtype=np.int64)
            w = np.array([w for _, w in r.weights], dtype=np.float64)
            out.append((idx, w, None, 1.0))
    if missing:
        kps = sorted({k for v in missing.values() for k in v}, key=JOINTS.index)
        raise InputError(source, "joint names",
                         f"the joints that skeleton family {family.name} maps: "
                         f"{', '.join(sorted(missing))} (for key point(s) {', '.join(kps)})", "none of them")
    return out


def mapping_text(family: SkeletonFamily, names, end_sites=None) -> dict[str, str]:
    """Key point -> the rule used for this file (``"mid(LeftUpLeg, RightUpLeg)"``), or ``"-"``."""
    nm = JointNames(names, end_sites)
    out = {}
    for kp in JOINTS:
        r = first_rule(family, kp, nm)
        out[kp] = "-" if r is None else str(r)
    return out


def keypoints_3d(bvh, positions: np.ndarray, rotations: np.ndarray, family: SkeletonFamily) -> np.ndarray:
    """The 17 key points in 3D, ``(F, 17, 3)``, in the BVH's units and axes.

    ``positions`` ``(F, J, 3)`` and ``rotations`` ``(F, J, 3, 3)`` are the
    output of ``forward_kinematics(bvh, end_sites=True, return_rotations=True)``.
    """
    F = positions.shape[0]
    out = np.empty((F, len(JOINTS), 3))
    for k, (idx, w, site, factor) in enumerate(resolve(family, bvh.names, bvh.source, bvh.site_kinds)):
        if site is not None:
            out[:, k] = positions[:, site] + rotations[:, site] @ (factor * bvh.offsets[site])
        else:
            out[:, k] = np.tensordot(w, positions[:, idx], axes=([0], [1]))
    return out


#: A bone shorter than this share of the skeleton's summed bone lengths (its median over frames)
#: is taken as zero: it can only be two key points made from the same place, never a real bone.
ZERO_BONE = 1e-6


def check_bones(points: np.ndarray, family: SkeletonFamily, names, source="<bvh>", end_sites=None) -> None:
    """Raise :class:`InputError` if two connected key points coincide.

    ``points`` ``(F, 17, D)``.  A bone (of the 17-point tree) whose median
    length over the frames is below :data:`ZERO_BONE` times the summed median
    lengths is degenerate; the message names the two key points and the
    joints they were made from.
    """
    P = np.asarray(points, dtype=float)
    lengths = np.median(np.linalg.norm(np.diff(P[:, np.array(BONES)], axis=2)[:, :, 0], axis=-1), axis=0)
    total = float(lengths.sum())
    bad = np.flatnonzero(~(lengths > ZERO_BONE * total)) if total > 0 else np.arange(len(BONES))
    if bad.size == 0:
        return
    used = mapping_text(family, names, end_sites)
    parts = []
    for b in bad[:3]:
        p, c = BONES[b]
        parts.append(f"{JOINTS[p]} = {used[JOINTS[p]]} and {JOINTS[c]} = {used[JOINTS[c]]}")
    raise InputError(source, "skeleton",
                     f"key points at distinct places (skeleton family {family.name}); these coincide in "
                     f"most frames: " + "; ".join(parts),
                     reason="the file's joints do not separate them: map them to other joints with "
                     "--joint-map FILE.yaml (docs/formats.md §3.3)")
