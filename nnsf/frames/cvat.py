"""Import keyframes from CVAT's "CVAT for video 1.1" XML export.

The export holds one ``<track id=... label=...>`` per annotated object, and
inside it one shape element per frame::

    <annotations>
      <version>1.1</version>
      <meta><task><name>...</name><size>48</size>
            <original_size><width>256</width><height>256</height></original_size>
      </task></meta>
      <track id="0" label="l_forearm.a" source="manual">
        <polyline frame="0" outside="0" occluded="0" keyframe="1"
                  points="10.0,20.0;12.5,30.0;15.0,41.0" z_order="0"/>
        ...
      </track>
      <track id="7" label="l_elbow" source="manual">
        <points frame="0" outside="0" occluded="0" keyframe="1" points="55.0,60.0" z_order="0"/>
      </track>
    </annotations>

Mapping to :mod:`nnsf.frames.annotation`:

* a ``<polyline>`` track's label is a side-curve name (``l_forearm.a``); its
  vertices become the curve's control points;
* a ``<points>`` track's label is a key-point name (``l_elbow``) with one point;
* only shapes with ``keyframe="1"`` and ``outside="0"`` are used (CVAT also
  writes the interpolated in-betweens, and ``outside`` marks where an object
  left the view); ``occluded`` is ignored (a hidden joint is still annotated
  at its best guess);
* a frame with curve keyframes is a keyframe; every curve must be keyframed
  on every keyframe, and key points, when a frame has any, must be all 17;
* ``<meta><task>`` (or ``<meta><job>``, as newer CVAT writes) gives the
  number of frames (``size``), the image size (``original_size``) and the
  default clip name (``name``); arguments override them.  Frame files are
  named by ``frame_pattern`` (CVAT's own export uses ``frame_{:06d}.png``).

Anything else (an unknown label, a label on the wrong shape type, a box or
polygon, malformed points) raises :class:`InputError` naming the file, the
track id and the label.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

from nnsf.errors import InputError
from nnsf.frames.annotation import Annotation, from_dict, write_annotation
from nnsf.frames.curves import SIDE_INDEX, SIDE_NAMES
from nnsf.skeleton.layout import JOINT_INDEX, JOINTS
from nnsf.io import read_bytes

SHAPES = ("polyline", "points")
CVAT_FRAME_PATTERN = "frame_{:06d}.png"


def parse_points(text, path, where: str, n: int | None = None) -> list[list[float]]:
    pts = []
    try:
        for pair in (text or "").strip().split(";"):
            x, y = (float(v) for v in pair.split(","))
            if not (math.isfinite(x) and math.isfinite(y)):
                raise ValueError
            pts.append([x, y])
    except ValueError:
        raise InputError(path, f"{where} points", '"x1,y1;x2,y2;..." with finite numbers',
                         text) from None
    if n is not None and len(pts) != n:
        raise InputError(path, f"{where} points", f"exactly {n} point(s)", text)
    return pts


def task_meta(root) -> dict:
    out = {}
    meta = root.find("meta")
    node = None
    if meta is not None:
        node = meta.find("task")
        if node is None:
            node = meta.find("job")
    if node is not None:
        size = node.findtext("size")
        if size is not None and size.strip().isdigit():
            out["size"] = int(size)
        name = node.findtext("name")
        if name and name.strip():
            out["name"] = name.strip()
        w, h = node.findtext("original_size/width"), node.findtext("original_size/height")
        if w and h and w.strip().isdigit() and h.strip().isdigit():
            out["image_size"] = [int(w), int(h)]
    return out


def read_cvat_video(path, clip: str | None = None, character: str = "unknown",
                    motion: str = "unknown", frame_pattern: str = CVAT_FRAME_PATTERN,
                    n_frames: int | None = None,
                    image_size: tuple[int, int] | None = None) -> Annotation:
    """Read a "CVAT for video 1.1" XML export into an :class:`Annotation` (validated).

    ``clip`` defaults to the task name, ``n_frames`` to the task size (else the
    last keyframe + 1), ``image_size`` ``(width, height)`` to the task's
    ``original_size`` (required from one of the two).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing CVAT XML export")

    data = read_bytes(path, 256_000_000, "a readable CVAT XML export")
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        # CVAT never writes these; refusing them rules out entity-expansion tricks.
        raise InputError(path, "file", "CVAT XML without DOCTYPE or ENTITY declarations")
    try:
        root = ET.fromstring(data)
    except ET.ParseError as exc:
        raise InputError(path, f"line {exc.position[0]}", "well-formed XML", reason=str(exc)) from None
    if root.tag != "annotations":
        raise InputError(path, "root element", "<annotations> (a CVAT XML export)", root.tag)
    version = (root.findtext("version") or "").strip()
    if version != "1.1":
        raise InputError(path, "<version>", '"1.1" (export format "CVAT for video 1.1")', version)
    meta = task_meta(root)

    curves: dict[int, dict[str, list]] = {}          # frame -> curve name -> points
    joints: dict[int, dict[str, list]] = {}          # frame -> joint name -> [x, y]
    where_curve: dict[str, str] = {}                 # curve name -> track description
    tracks = root.findall("track")
    if not tracks:
        raise InputError(path, "<track>", "at least one track (export as CVAT for video 1.1)")
    seen: dict[str, str] = {}      # label -> id of the track that has it
    for track in tracks:
        tid, label = track.get("id", "?"), track.get("label", "")
        where = f"track id={tid} label={label!r}"
        if label in seen:
            raise InputError(path, f"track id={tid} label", f"each label in one track; track id={seen[label]} "
                             "has this label too (merge the two tracks in CVAT)", label)
        seen[label] = tid
        if label in SIDE_INDEX:
            kind, target = "polyline", curves
        elif label in JOINT_INDEX:
            kind, target = "points", joints
        else:
            raise InputError(path, f"track id={tid}", "a label naming a side curve (" + ", ".join(
                SIDE_NAMES[:2]) + ", ...) or a key point (" + ", ".join(JOINTS[:3]) + ", ...)",
                label)
        used = 0
        for shape in track:
            if shape.tag not in SHAPES and shape.tag != "attribute":
                raise InputError(path, where, "polyline shapes for curves and points shapes for "
                                 "key points", f"<{shape.tag}>")
            if shape.tag == "attribute":
                continue
            if shape.tag != kind:
                raise InputError(path, where, f"<{kind}> shapes for label {label!r}", f"<{shape.tag}>")
            fr = shape.get("frame", "")
            if not fr.strip().isdigit():
                raise InputError(path, f"{where} frame", "a frame number >= 0", fr)
            if shape.get("keyframe", "0") != "1" or shape.get("outside", "0") != "0":
                continue
            f = int(fr)
            pts = parse_points(shape.get("points"), path, f"{where} frame={f}",
                                n=1 if kind == "points" else None)
            slot = target.setdefault(f, {})
            if label in slot:
                raise InputError(path, f"{where} frame={f}", f"one keyframe of {label!r} per frame",
                                 "two tracks with this label")
            slot[label] = pts if kind == "polyline" else pts[0]
            used += 1
            if kind == "polyline":
                where_curve.setdefault(label, where)
        if not used:   # a track none of whose shapes is a keyframe would vanish from the annotation
            raise InputError(path, where, f'at least one <{kind}> with keyframe="1" and outside="0" '
                             "(mark the annotated frames as keyframes in CVAT)", "none")
    if not curves:
        raise InputError(path, "<polyline>", 'at least one polyline shape with keyframe="1" '
                         'and outside="0"')
    keyframes = sorted(curves)
    names = sorted(set().union(*curves.values()), key=SIDE_INDEX.__getitem__)
    for f in keyframes:
        missing = [n for n in names if n not in curves[f]]
        if missing:
            raise InputError(path, where_curve[missing[0]], f"a keyframe at frame {f}, where other "
                             "curves have one (every curve is keyframed on every keyframe)")
    for f, kp in joints.items():
        if f not in curves:
            raise InputError(path, f"points at frame {f}", "key points only on frames with curve "
                             f"keyframes ({', '.join(map(str, keyframes))})")
        missing = [j for j in JOINTS if j not in kp]
        if missing:
            raise InputError(path, f"points at frame {f}", "all 17 key points on a frame that has any",
                             "missing " + ", ".join(missing))

    n = n_frames if n_frames is not None else meta.get("size", keyframes[-1] + 1)
    size = list(image_size) if image_size is not None else meta.get("image_size")
    if size is None:
        raise InputError(path, "<meta><task><original_size>", "the frame size (or pass image_size)")
    obj = {
        "format": "nnsf.annotation", "version": 1,
        "clip": clip or meta.get("name") or path.stem, "character": character, "motion": motion,
        "frames": [frame_pattern.format(i) for i in range(int(n))],
        "image_size": [int(v) for v in size],
        "keyframes": [{"frame": f, "curves": curves[f],
                       **({"keypoints": joints[f]} if f in joints else {})} for f in keyframes],
    }
    return from_dict(obj, source=path)


def import_cvat(xml_path, out_path, **kwargs) -> Annotation:
    """Read a CVAT video export and write it as an annotation JSON (atomically)."""
    ann = read_cvat_video(xml_path, **kwargs)
    write_annotation(ann, out_path)
    return ann
