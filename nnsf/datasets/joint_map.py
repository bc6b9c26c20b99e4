"""A user's joint map: which joints of a BVH skeleton make the 17 key points (docs/formats.md §3.3).

For a skeleton that no built-in family reads (:mod:`nnsf.datasets.bvh_skeletons`),
or reads wrongly, a small YAML names the joints::

    format: nnsf.joint_map        # optional
    version: 1                    # optional
    family: mixamo                # optional: key points left out keep this family's rules
    joints:
      pelvis: [LThigh, RThigh]    # the midpoint of two joints
      l_hip: LThigh
      head_top: end(Head)         # the End Site below Head

A key point is a joint name, a list of two joint names (their midpoint) or
one of the rule forms of :func:`~nnsf.datasets.bvh_skeletons.parse_rule`.
:func:`read_joint_map` checks the file alone; :func:`check_joint_map`
checks it against one BVH's joints, naming the map, the key point and the
nearest joint names of the file.
"""
from __future__ import annotations

import difflib
from pathlib import Path

from nnsf.datasets.bvh_skeletons import FAMILIES, SkeletonFamily, family_from_mapping, rule_from_value, unmapped
from nnsf.errors import InputError
from nnsf.safe_yaml import read_yaml
from nnsf.skeleton.layout import JOINTS

__all__ = ["FORMAT", "MAX_JOINT_MAP_BYTES", "read_joint_map", "check_joint_map"]

FORMAT = "nnsf.joint_map"
#: Largest joint map read (bytes): 17 lines of names fit in 2 KB.
MAX_JOINT_MAP_BYTES = 100_000
_KEYS = {"format", "version", "family", "joints"}


def read_joint_map(path) -> SkeletonFamily:
    """The skeleton family a joint-map YAML describes; :class:`InputError` names the file and field."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing joint-map YAML (docs/formats.md §3.3)")
    doc = read_yaml(path, MAX_JOINT_MAP_BYTES, "a joint-map YAML")
    if not isinstance(doc, dict):
        raise InputError(path, "top level", "a mapping with a 'joints' mapping", doc)
    extra = sorted(str(k) for k in doc if k not in _KEYS)
    if extra:
        raise InputError(path, extra[0], "only the keys " + ", ".join(sorted(_KEYS)), extra[0])
    if doc.get("format", FORMAT) != FORMAT:
        raise InputError(path, "format", repr(FORMAT), doc["format"])
    if doc.get("version", 1) != 1:
        raise InputError(path, "version", "1", doc["version"])
    base = None
    if doc.get("family") is not None:
        if doc["family"] not in FAMILIES:
            raise InputError(path, "family", "one of " + ", ".join(FAMILIES), doc["family"])
        base = FAMILIES[doc["family"]]
    joints = doc.get("joints")
    if not isinstance(joints, dict) or not joints:
        raise InputError(path, "joints", "a mapping of key points to joint names", joints)
    for kp in joints:
        if kp not in JOINTS:
            near = difflib.get_close_matches(str(kp), JOINTS, n=1)
            raise InputError(path, f"joints.{kp}", "one of the 17 key points " + ", ".join(JOINTS), kp,
                             reason=f"did you mean {near[0]}?" if near else None)
    if base is None:
        missing = [k for k in JOINTS if k not in joints]
        if missing:
            raise InputError(path, "joints", "all 17 key points (or a 'family' whose rules fill in the "
                             "rest)", reason="missing " + ", ".join(missing))
    for kp, value in joints.items():
        try:
            rule_from_value(value, kp)
        except ValueError as exc:
            raise InputError(path, f"joints.{kp}", "a joint name, a list of two joint names or a rule "
                             "such as end(Head)", value, reason=str(exc)) from None
    fam = family_from_mapping(joints, name=f"joint map {path.name}", base=base)
    return SkeletonFamily(fam.name, fam.description, fam.rules, source=str(path))


def check_joint_map(family: SkeletonFamily, names, bvh_source="<bvh>", end_sites=None) -> None:
    """:class:`InputError` naming the joint map, the key point and the missing joint (with the
    file's nearest names) if ``family`` (from :func:`read_joint_map`) needs a joint the BVH lacks."""
    if not family.source:
        return
    lacking = unmapped(family, names, end_sites)
    if not lacking:
        return
    kp = next(iter(lacking))
    name = lacking[kp][0]
    ends = end_sites if end_sites is not None else [False] * len(names)
    joints = [str(n) for n, e in zip(names, ends) if not e]
    near = difflib.get_close_matches(name.removesuffix("_end"), joints, n=3, cutoff=0.5)
    raise InputError(family.source, f"joints.{kp}", f"joints of {bvh_source}", name,
                     reason=("the nearest are " + ", ".join(near)) if near else
                     "its joints are " + ", ".join(joints[:12]) + (", ..." if len(joints) > 12 else ""))
