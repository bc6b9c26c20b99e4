"""Keyframe annotations of a clip: format ``nnsf.annotation`` version 1.

One JSON file per clip (UTF-8)::

    {"format": "nnsf.annotation", "version": 1,
     "clip": "bruno-walk-00", "character": "bruno", "motion": "walk",
     "frames": ["frame_0000.png", ...],      # relative to the clip's image folder
     "image_size": [256, 256],                # [width, height] px
     "keyframes": [
       {"frame": 0,                           # index into "frames"
        "curves": {"l_forearm.a": [[x, y], ...], ...},    # >= 2 control points each
        "calibration": {"l_forearm": [p1, p2, p3, p4], ...},
        "keypoints": {"pelvis": [x, y], ..., "r_wrist": [x, y]}},   # optional, all 17
       ...]}

Curve names are ``<group>.a`` / ``<group>.b`` for the ten groups of
:data:`nnsf.frames.curves.GROUPS`; the control points are interpolated by the
Catmull-Rom spline of :mod:`nnsf.frames.curves`.  Calibration points are the
ends of a group's two side curves: p1 = a[0], p2 = b[0], p3 = a[-1],
p4 = b[-1]; they may be left out (then they are taken from the curve ends) and
must agree with the curve ends within :data:`CALIBRATION_TOL_PX` when given.

Rules checked by :func:`read_annotation` (each violation is an
:class:`~nnsf.errors.InputError` naming the file and the JSON path, e.g.
``keyframes[1].curves["l_forearm.a"]``): format and version; non-empty
``clip``/``character``/``motion``; frame paths relative, without ``..``, each
once; ``image_size`` two positive integers; keyframe indices inside
``frames`` and each frame keyed once; known curve and key-point names;
>= 2 finite control points per curve; calibration consistent with the curve
ends; every keyframe annotates the same curves with the same number of
control points (the tracker's unknowns between two keyframes are those
control points); key points, when given, all 17 and finite.  Keyframes are
returned sorted by frame.
"""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import numpy as np

from nnsf.errors import InputError
from nnsf.frames.curves import GROUPS, SIDE_INDEX, SIDE_NAMES
from nnsf.io import atomic_path, read_json
from nnsf.skeleton.layout import JOINT_INDEX, JOINTS, N_JOINTS
from nnsf.io import round_floats

FORMAT = "nnsf.annotation"
VERSION = 1
#: Largest allowed distance (px) between a calibration point and its curve end.
CALIBRATION_TOL_PX = 1.0


@dataclass
class Keyframe:
    """One annotated frame.

    frame : index into :attr:`Annotation.frames`.
    curves : side-curve name -> control points ``(P, 2)`` float64 px, P >= 2.
    calibration : group -> ``(4, 2)`` p1..p4 (px); filled for every group whose
        two side curves are both given.
    keypoints : ``(17, 2)`` px in :data:`nnsf.skeleton.JOINTS` order, or None.
    """

    frame: int
    curves: dict[str, np.ndarray]
    calibration: dict[str, np.ndarray] = field(default_factory=dict)
    keypoints: np.ndarray | None = None


@dataclass
class Annotation:
    """A clip's keyframe annotation (see the module docstring)."""

    clip: str
    character: str
    motion: str
    frames: list[str]
    image_size: tuple[int, int]
    keyframes: list[Keyframe]
    source: str = "<memory>"

    @property
    def curve_names(self) -> list[str]:
        """Annotated side curves, in :data:`SIDE_NAMES` order."""
        return sorted(self.keyframes[0].curves, key=SIDE_INDEX.__getitem__) if self.keyframes else []

    @property
    def groups(self) -> list[str]:
        """Groups with both side curves annotated, in :data:`GROUPS` order."""
        names = set(self.curve_names)
        return [g for g in GROUPS if f"{g}.a" in names and f"{g}.b" in names]

    @property
    def keyframe_indices(self) -> list[int]:
        return [k.frame for k in self.keyframes]

    def to_dict(self) -> dict:
        """JSON-ready dict in the file format (numbers as Python floats)."""
        def pts(a):
            return [[float(x), float(y)] for x, y in np.asarray(a, dtype=float)]

        kfs = []
        for k in self.keyframes:
            d = {"frame": int(k.frame),
                 "curves": {n: pts(c) for n, c in k.curves.items()},
                 "calibration": {g: pts(c) for g, c in k.calibration.items()}}
            if k.keypoints is not None:
                d["keypoints"] = {j: [float(x), float(y)] for j, (x, y) in zip(JOINTS, k.keypoints)}
            kfs.append(d)
        return {"format": FORMAT, "version": VERSION, "clip": self.clip,
                "character": self.character, "motion": self.motion,
                "frames": list(self.frames), "image_size": [int(v) for v in self.image_size],
                "keyframes": kfs}


# --------------------------------------------------------------------------- validation

def check_relative(rel, source, field_name: str) -> str:
    """Return ``rel`` if it is a non-empty relative path that cannot leave its folder."""
    if not isinstance(rel, str) or not rel:
        raise InputError(source, field_name, "a non-empty relative file path", rel)
    parts = PurePosixPath(rel.replace("\\", "/")).parts
    if rel.startswith(("/", "\\", "~")) or Path(rel).is_absolute() or re.match(r"^[A-Za-z]:", rel):
        raise InputError(source, field_name, "a path relative to the clip's folder (not absolute)", rel)
    if ".." in parts:
        raise InputError(source, field_name, "a path that stays inside the clip's folder (no '..')", rel)
    return rel


def _is_num(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _points(v, source, path: str, min_points: int = 1, exact: int | None = None) -> np.ndarray:
    what = (f"exactly {exact} [x, y] points" if exact else f"a list of at least {min_points} "
            "[x, y] points") + " with finite numbers (px)"
    if not isinstance(v, list):
        raise InputError(source, path, what, v)
    if exact is not None and len(v) != exact or len(v) < min_points:
        raise InputError(source, path, what, f"{len(v)} point(s)")
    for i, p in enumerate(v):
        if not (isinstance(p, list) and len(p) == 2 and all(_is_num(c) for c in p)):
            raise InputError(source, f"{path}[{i}]", "[x, y] with finite numbers (px)", p)
    return np.asarray(v, dtype=np.float64).reshape(-1, 2)


def _point(v, source, path: str) -> np.ndarray:
    if not (isinstance(v, list) and len(v) == 2 and all(_is_num(c) for c in v)):
        raise InputError(source, path, "[x, y] with finite numbers (px)", v)
    return np.asarray(v, dtype=np.float64)


def _label(obj, key, source) -> str:
    v = obj.get(key)
    if not isinstance(v, str) or not v:
        raise InputError(source, key, "a non-empty string", v)
    return v


def from_dict(obj: dict, source="<memory>") -> Annotation:
    """Validate a parsed annotation (see the module docstring) and build it."""
    if not isinstance(obj, dict):
        raise InputError(source, "top level", "a JSON object", type(obj).__name__)
    if obj.get("format") != FORMAT:
        raise InputError(source, "format", repr(FORMAT), obj.get("format"))
    if obj.get("version") != VERSION:
        raise InputError(source, "version", str(VERSION), obj.get("version"))
    clip, character, motion = (_label(obj, k, source) for k in ("clip", "character", "motion"))
    frames = obj.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError(source, "frames", "a non-empty list of frame image paths", frames)
    seen: dict[str, int] = {}
    for i, f in enumerate(frames):
        check_relative(f, source, f"frames[{i}]")
        if f in seen:
            raise InputError(source, f"frames[{i}]", "each frame file once",
                             f"{f!r} also at frames[{seen[f]}]")
        seen[f] = i
    size = obj.get("image_size")
    if not (isinstance(size, list) and len(size) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) and v > 0 for v in size)):
        raise InputError(source, "image_size", "[width, height], two positive integers (px)", size)
    kfs_raw = obj.get("keyframes")
    if not isinstance(kfs_raw, list) or not kfs_raw:
        raise InputError(source, "keyframes", "a non-empty list of keyframes", kfs_raw)
    keyframes: list[Keyframe] = []
    by_frame: dict[int, int] = {}
    for i, k in enumerate(kfs_raw):
        keyframes.append(_keyframe(k, i, len(frames), source))
        f = keyframes[-1].frame
        if f in by_frame:
            raise InputError(source, f"keyframes[{i}].frame", "each frame annotated once",
                             f"frame {f} also in keyframes[{by_frame[f]}]")
        by_frame[f] = i
    # The tracker's unknowns between two keyframes are one curve's control
    # points, so every keyframe must annotate the same curves, equally long.
    ref = {n: len(c) for n, c in keyframes[0].curves.items()}
    for i, k in enumerate(keyframes[1:], start=1):
        got = {n: len(c) for n, c in k.curves.items()}
        if set(got) != set(ref):
            diff = sorted(set(got) ^ set(ref), key=SIDE_INDEX.__getitem__)
            raise InputError(source, f"keyframes[{i}].curves",
                             "the same curves as keyframes[0]", "differs in " + ", ".join(diff))
        for n in ref:
            if got[n] != ref[n]:
                raise InputError(source, f'keyframes[{i}].curves["{n}"]',
                                 f"{ref[n]} control points, as in keyframes[0]", f"{got[n]} points")
    keyframes.sort(key=lambda k: k.frame)
    return Annotation(clip=clip, character=character, motion=motion, frames=list(frames),
                      image_size=(int(size[0]), int(size[1])), keyframes=keyframes, source=str(source))


def _keyframe(k, i: int, n_frames: int, source) -> Keyframe:
    at = f"keyframes[{i}]"
    if not isinstance(k, dict):
        raise InputError(source, at, "an object with frame, curves, calibration, keypoints", k)
    unknown = sorted(set(k) - {"frame", "curves", "calibration", "keypoints"})
    if unknown:
        raise InputError(source, f"{at}.{unknown[0]}", "only the keys frame, curves, calibration, "
                         "keypoints")
    f = k.get("frame")
    if not isinstance(f, int) or isinstance(f, bool) or not 0 <= f < n_frames:
        raise InputError(source, f"{at}.frame",
                         f"an index into frames, 0 to {n_frames - 1} (the clip has {n_frames} frames)", f)
    curves_raw = k.get("curves")
    if not isinstance(curves_raw, dict) or not curves_raw:
        raise InputError(source, f"{at}.curves", "an object of curve name -> control points", curves_raw)
    curves: dict[str, np.ndarray] = {}
    for name, pts in curves_raw.items():
        path = f'{at}.curves["{name}"]'
        if name not in SIDE_INDEX:
            raise InputError(source, path, "a curve name <group>.a or <group>.b with group one of "
                             + ", ".join(GROUPS))
        curves[name] = _points(pts, source, path, min_points=2)
    calib_raw = k.get("calibration", {})
    if not isinstance(calib_raw, dict):
        raise InputError(source, f"{at}.calibration", "an object of group -> [p1, p2, p3, p4]", calib_raw)
    calibration: dict[str, np.ndarray] = {}
    for g, pts in calib_raw.items():
        path = f'{at}.calibration["{g}"]'
        if g not in GROUPS:
            raise InputError(source, path, "a curve group, one of " + ", ".join(GROUPS))
        p = _points(pts, source, path, exact=4)
        if f"{g}.a" not in curves or f"{g}.b" not in curves:
            raise InputError(source, path, f"calibration only for groups with both curves "
                             f"{g}.a and {g}.b annotated in this keyframe")
        ends = _ends(curves[f"{g}.a"], curves[f"{g}.b"])
        dist = np.linalg.norm(p - ends, axis=1)
        if dist.max() > CALIBRATION_TOL_PX:
            j = int(np.argmax(dist))
            raise InputError(source, f"{path}[{j}]",
                             f"p{j + 1} within {CALIBRATION_TOL_PX:g} px of its curve end "
                             f"{ends[j].round(3).tolist()} (p1=a[0], p2=b[0], p3=a[-1], p4=b[-1])",
                             f"{p[j].tolist()}, {dist[j]:.3g} px away")
        calibration[g] = p
    for g in GROUPS:
        if g not in calibration and f"{g}.a" in curves and f"{g}.b" in curves:
            calibration[g] = _ends(curves[f"{g}.a"], curves[f"{g}.b"])
    keypoints = None
    if "keypoints" in k and k["keypoints"] is not None:
        kp_raw = k["keypoints"]
        if not isinstance(kp_raw, dict):
            raise InputError(source, f"{at}.keypoints", "an object of key-point name -> [x, y]", kp_raw)
        unknown = [n for n in kp_raw if n not in JOINT_INDEX]
        if unknown:
            raise InputError(source, f'{at}.keypoints["{unknown[0]}"]',
                             "a key-point name, one of " + ", ".join(JOINTS))
        missing = [n for n in JOINTS if n not in kp_raw]
        if missing:
            raise InputError(source, f"{at}.keypoints", f"all {N_JOINTS} key points",
                             "missing " + ", ".join(missing))
        keypoints = np.stack([_point(kp_raw[n], source, f'{at}.keypoints["{n}"]') for n in JOINTS])
    return Keyframe(frame=f, curves=curves, calibration=calibration, keypoints=keypoints)


def _ends(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Calibration points p1..p4 ``(4, 2)`` from side curves a, b ``(P, 2)``."""
    return np.stack([a[0], b[0], a[-1], b[-1]])


# --------------------------------------------------------------------------- files

def read_annotation(path) -> Annotation:
    """Read and validate an annotation file; errors name ``path`` and the JSON path."""
    path = Path(path)
    return from_dict(read_json(path), source=path)


def dumps(ann: Annotation) -> str:
    """The file text: sorted keys, 2-space indent, every [x, y] pair on one line.

    Numbers are rounded like every other output (``nnsf.io.DIGITS`` significant digits).
    """
    text = json.dumps(round_floats(ann.to_dict()), indent=2, sort_keys=True)
    # Put innermost number pairs on one line; the file stays diff-friendly.
    num = r"-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"
    return re.sub(rf"\[\s*({num}),\s*({num})\s*\]", r"[\1, \2]", text) + "\n"


def write_annotation(ann: Annotation, path) -> Path:
    """Validate ``ann`` and write it to ``path`` atomically (UTF-8 JSON). Returns ``path``."""
    path = Path(path)
    from_dict(ann.to_dict(), source=f"annotation for {path}")
    with atomic_path(path) as tmp:
        tmp.write_text(dumps(ann), encoding="utf-8")
    return path
