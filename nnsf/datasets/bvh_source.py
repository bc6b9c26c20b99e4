"""A folder of BVH clips -> the feature-matrix contract table, with labels.

Each clip goes BVH -> forward kinematics -> the 17 key points in 3D
(:mod:`~nnsf.datasets.bvh_skeletons`) -> resampled to ``fps`` -> projected to
2D (:func:`nnsf.datasets.projection.project`).  Rows are ``clip, frame, character,
motion, x1, y1 … x17, y17`` with ``clip`` = file stem, ``character`` = the
style and ``motion`` = the content (styles play the paper's characters).
Coordinates are in the BVH's own units times ``scale`` (Bandai-Namco:
centimetres), image axes x right, y down, origin at the root's (smoothed)
ground position when ``center`` is on; the template unifier normalises body
size and makes them non-negative later.

Labels come from a JSON label file beside the clip (``<stem>.json``) when
there is one, else from the file name ``{dataset}_{motion}_{style}_{id}.bvh``.
A JSON label holds ``content`` and ``style`` (or ``motion`` and
``character``), each a name or a 0-based index into the label lists
``cfg/content_label.txt`` / ``cfg/style_label.txt`` found in the folder or
its parent (entries like ``dataset-1_walk`` lose their ``dataset-1_``
prefix).  It may name its motion file with ``"bvh": "relative/path.bvh"``;
such paths must stay inside the folder given.

Problems never stop the whole folder: a bad or unlabelled clip, a label file
that cannot be read or whose BVH is missing, two label files that give one
clip different labels (the clip is left out), a link leading out of the
folder, a byte-identical copy of another clip (read once) or a style seen in
only one motion each become a line of the returned ``report`` and the rest is
read.
"""
from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets.bvh import MAX_BVH_BYTES, forward_kinematics, read_bvh
from nnsf.datasets.projection import detect_up_axis, project, resample, up_rotation
from nnsf.datasets.bvh_detect import detect_family
from nnsf.datasets.bvh_skeletons import FAMILIES, SkeletonFamily, check_bones, keypoints_3d
from nnsf.datasets.contract import validate
from nnsf.datasets.joint_map import check_joint_map
from nnsf.errors import InputError
from nnsf.io import parse_json, read_bytes, read_text
from nnsf.names import EXPECTED as NAME_EXPECTED, is_safe_name, real
from nnsf.skeleton.layout import FEATURE_COLUMNS, JOINT_INDEX, N_JOINTS

__all__ = [
    "NAME_PATTERN", "DEPTH_COLUMNS", "FACING_PAIRS", "BVHClip", "ClipLabels", "LabelLists",
    "load_clip", "label_lists", "labels_from_name", "labels_from_json", "read_folder",
]

#: ``{dataset}_{motion}_{style}_{id}``; motions and styles may contain '-' but not '_'.
NAME_PATTERN = re.compile(r"^(?P<dataset>[^_]+)_(?P<motion>[^_]+)_(?P<style>[^_]+)_(?P<id>\d+)$")

#: Depth columns added by ``read_folder(..., depth=True)`` (outside the contract).
DEPTH_COLUMNS: tuple[str, ...] = tuple(f"z{j + 1}" for j in range(N_JOINTS))

#: Left/right key-point pairs whose (left - right) x up gives the facing
#: direction for facing normalisation: the hips and the shoulders.
FACING_PAIRS = (JOINT_INDEX["l_hip"], JOINT_INDEX["r_hip"],
                JOINT_INDEX["l_shoulder"], JOINT_INDEX["r_shoulder"])


@dataclass
class ClipLabels:
    """Labels of one clip: ``motion`` (content) and ``style`` (the character)."""

    motion: str
    style: str
    origin: str  # "name" or the JSON file it came from


@dataclass
class BVHClip:
    """One projected clip.

    points : ``(F, 17, 2)`` image coordinates (x right, y down), BVH units x scale.
    depth : ``(F, 17)`` camera-space depth, larger is farther (same units).
    points3d : ``(F, 17, 3)`` key points in Y-up world axes before projection.
    fps : frame rate of the rows; ``source_fps``: the file's.
    family : skeleton family used; ``up``: the file's detected up axis.
    notes : what the reader tolerated (a header frame count off by a row), one line each.
    """

    name: str
    path: Path
    points: np.ndarray
    depth: np.ndarray
    points3d: np.ndarray
    fps: float
    source_fps: float
    family: str
    up: str
    yaw: np.ndarray = field(repr=False, default=None)
    notes: list = field(default_factory=list)


@dataclass
class LabelLists:
    """Index -> name lists from ``cfg/content_label.txt`` and ``cfg/style_label.txt``."""

    contents: list[str]
    styles: list[str]
    source: str = ""


def _strip_dataset(label: str) -> str:
    # "dataset-1_walk-back" -> "walk-back"
    return label.split("_", 1)[1] if "_" in label else label


def label_lists(folder) -> LabelLists | None:
    """The label lists of a dataset folder (its ``cfg/`` or its parent's), or None."""
    folder = Path(folder)
    for base in (folder, folder.parent):
        c, s = base / "cfg" / "content_label.txt", base / "cfg" / "style_label.txt"
        if c.is_file() and s.is_file():
            read = lambda p: [_strip_dataset(l.strip())
                              for l in read_text(p, 10_000_000, "a label list").splitlines() if l.strip()]
            return LabelLists(read(c), read(s), str(base / "cfg"))
    return None


def labels_from_name(path) -> ClipLabels:
    """Labels from ``{dataset}_{motion}_{style}_{id}.bvh``; InputError otherwise."""
    path = Path(path)
    m = NAME_PATTERN.match(path.stem)
    if m is None:
        raise InputError(path, "file name", "{dataset}_{motion}_{style}_{id}.bvh (e.g. "
                         "dataset-1_walk_happy_001.bvh) or a <stem>.json label beside it", path.name)
    return ClipLabels(_label(m.group("motion"), path, "file name (motion)"),
                      _label(m.group("style"), path, "file name (style)"), "name")


def _label(value: str, source, field: str) -> str:
    """A content or style label: an id, so a safe name (:mod:`nnsf.names`): it names the model's
    styles, is printed in messages and may become a file name."""
    if not is_safe_name(value):
        raise InputError(source, field, "a label that is " + NAME_EXPECTED, value)
    return value


def _inside(root: Path, p: Path) -> bool:
    try:
        real(p).relative_to(real(root))
        return True
    except ValueError:
        return False


def labels_from_json(path, root, lists: LabelLists | None) -> tuple[ClipLabels, Path]:
    """Labels and motion file of a JSON label; InputError names file and field.

    The motion file is ``"bvh"`` (or ``"file"``) relative to the JSON's folder,
    else ``<stem>.bvh``; it must lie inside ``root``.
    """
    path = Path(path)
    if not _inside(root, path):
        raise InputError(path, "file", f"a label file inside the dataset folder {root} "
                         "(symbolic links included)")
    obj = parse_json(read_text(path, 10_000_000, "a JSON label file"), path)
    if not isinstance(obj, dict):
        raise InputError(path, "top level", "a JSON object", type(obj).__name__)

    def pick(keys, names, what):
        key = next((k for k in keys if k in obj), None)
        if key is None:
            raise InputError(path, "/".join(keys), f"a {what} label")
        v = obj[key]
        if isinstance(v, bool):
            raise InputError(path, key, f"a {what} name or index", v)
        if isinstance(v, int):
            if names is None:
                raise InputError(path, key, f"a {what} name (no cfg/ label lists found to look "
                                 "up an index)", v)
            if not 0 <= v < len(names):
                raise InputError(path, key, f"an index 0..{len(names) - 1} into the {what} list", v)
            return _label(names[v], lists.source, f"{what} label {v}")
        if isinstance(v, str) and v.strip():
            return _label(_strip_dataset(v.strip()) if v.startswith("dataset-") else v.strip(), path, key)
        raise InputError(path, key, f"a {what} name or index", v)

    motion = pick(("content", "motion"), lists.contents if lists else None, "content/motion")
    style = pick(("style", "character"), lists.styles if lists else None, "style/character")
    ref = obj.get("bvh", obj.get("file"))
    if ref is None:
        bvh = path.with_suffix(".bvh")
    else:
        if not isinstance(ref, str) or not ref.strip():
            raise InputError(path, "bvh", "a relative path to the clip's .bvh file", ref)
        bvh = path.parent / ref
        if Path(ref).is_absolute() or not _inside(root, bvh):
            raise InputError(path, "bvh", f"a path inside the dataset folder {root}", ref)
    return ClipLabels(motion, style, str(path)), bvh


#: Frames a clip may have once resampled (about 5.5 hours at 30 fps; each frame's 17 points
#: and their projections take a few kB): ``Frame Time`` x ``Frames`` is checked against it
#: before any resampled array is made.
MAX_RESAMPLED_FRAMES = 600_000


def family_for(bvh, family=None, source=None) -> SkeletonFamily:
    """The skeleton family of a parsed file: detected (``None``), a built-in name, or given."""
    source = bvh.source if source is None else source
    if family is None:
        return detect_family(bvh.names, source, bvh.site_kinds)
    if isinstance(family, SkeletonFamily):
        check_joint_map(family, bvh.names, source, bvh.site_kinds)
        return family
    if family not in FAMILIES:
        raise InputError(source, "family", f"one of {', '.join(FAMILIES)}", family)
    return FAMILIES[family]


def check_duration(bvh, fps: float | None, source=None) -> int:
    """Frames of the clip at ``fps`` (None: its own rate); :class:`InputError` above
    :data:`MAX_RESAMPLED_FRAMES`, naming ``Frame Time`` (checked before any allocation)."""
    source = bvh.source if source is None else source
    duration = max(bvh.n_frames - 1, 0) / bvh.fps          # as resample_times measures it, s
    rate = bvh.fps if fps is None else float(fps)
    n = float(np.floor(duration * rate + 0.5)) + 1.0       # a float: a huge Frame Time must not overflow
    if not n <= MAX_RESAMPLED_FRAMES:
        raise InputError(source, "Frame Time", f"a clip of at most {MAX_RESAMPLED_FRAMES} frames at "
                         f"{rate:g} fps (Frame Time x Frames = {duration:.6g} s would make {n:.3g})",
                         bvh.frame_time)
    return int(n)


#: Node-frames (nodes x frames) of one block of forward kinematics: each holds about 60
#: float64 of rotations, positions and their temporaries, so a block takes about 120 MB.
FK_BLOCK = 250_000


def keypoints_of(bvh, family: SkeletonFamily) -> np.ndarray:
    """The 17 key points in 3D ``(F, 17, 3)`` (:func:`keypoints_3d`), forward kinematics run over
    blocks of frames so that its ``(F, J, 3, 3)`` arrays never exceed :data:`FK_BLOCK` node-frames
    (a long clip of a large skeleton would otherwise need gigabytes)."""
    step = max(FK_BLOCK // max(len(bvh.names), 1), 1)
    out = np.empty((bvh.n_frames, N_JOINTS, 3))
    with np.errstate(over="ignore", invalid="ignore"):      # overflow is refused below, in one line
        for start in range(0, bvh.n_frames, step):
            P, G = forward_kinematics(bvh, end_sites=True, return_rotations=True,
                                      motion=bvh.motion[start:start + step])
            out[start:start + step] = keypoints_3d(bvh, P, G, family)
    if not np.isfinite(out).all():
        frame = int(np.flatnonzero(~np.isfinite(out).all(axis=(1, 2)))[0])
        raise InputError(bvh.source, "OFFSET", "offsets and motion values small enough for finite joint "
                         f"positions (overflow from frame {frame} on)")
    return out


#: A first frame whose pose lies farther from the second's than this many times the clip's own
#: 99th-percentile step between frames is the skeleton's bind pose (a T-pose that many exporters
#: put at frame 0), not motion: it is left out.  On the shared clips the CMU conversions' first
#: step is 24-43 times that percentile; every other clip's is at most 1.1 times it.
BIND_JUMP = 5.0


def bind_frame(points: np.ndarray) -> float:
    """How far the first pose of ``points`` ``(F, 17, 3)`` jumps to the second, in units of the clip's
    99th-percentile step (0 for a clip under 3 frames).  A pose is the key points less the pelvis; a
    step is the largest move of a key point from one frame to the next."""
    if len(points) < 3:
        return 0.0
    pose = points - points[:, JOINT_INDEX["pelvis"]][:, None]
    step = np.linalg.norm(np.diff(pose, axis=0), axis=2).max(axis=1)
    usual = float(np.percentile(step[1:], 99))
    return float(step[0] / usual) if usual > 0 else (np.inf if step[0] > 0 else 0.0)


def load_clip(path, fps: float | None = 30, azimuth: float = 0.0, elevation: float = 0.0,
              facing: str = "normalise", center: bool = True, up: str = "auto",
              family: str | SkeletonFamily | None = None, window: float = 1.0,
              scale: float = 1.0) -> BVHClip:
    """Read one BVH file and project its 17 key points (see :func:`read_folder`).

    Raises :class:`InputError` for a skeleton no family clearly fits, key
    points that coincide (:func:`~nnsf.datasets.bvh_skeletons.check_bones`)
    or a clip too long to resample (:func:`check_duration`).  A first frame
    that is the skeleton's bind pose (:func:`bind_frame`) is left out, with a note.
    """
    path = Path(path)
    bvh = read_bvh(path)
    fam = family_for(bvh, family, path)
    out_fps = bvh.fps if fps is None else float(fps)
    check_duration(bvh, fps, path)
    K = keypoints_of(bvh, fam)
    check_bones(K, fam, bvh.names, path, bvh.site_kinds)
    notes = list(bvh.notes)
    if (jump := bind_frame(K)) > BIND_JUMP:
        K = K[1:]
        how = f"by {jump:.0f} times the clip's usual largest step" if np.isfinite(jump) else "while the rest holds still"
        notes.append(f"{path}: frame 0 is the skeleton's bind pose (its pose jumps to frame 1 {how}): left out")
    if up == "auto":
        up = detect_up_axis(K, JOINT_INDEX["head_top"], (JOINT_INDEX["l_ankle"], JOINT_INDEX["r_ankle"]))
    K = resample(K, bvh.fps, out_fps) * float(scale)
    win = max(int(round(window * out_fps)), 1)
    proj = project(K, azimuth=azimuth, elevation=elevation, up=up, facing=facing,
                   across=FACING_PAIRS, root=JOINT_INDEX["pelvis"], center=center, window=win)
    return BVHClip(name=path.stem, path=path, points=proj.xy, depth=proj.depth,
                   points3d=K @ up_rotation(up).T, fps=out_fps, source_fps=bvh.fps,
                   family=fam.name, up=up, yaw=proj.yaw, notes=notes)


def _data_folder(folder: Path) -> Path:
    if any(folder.glob("*.bvh")) or any(folder.glob("*.json")):
        return folder
    if (folder / "data").is_dir():
        return folder / "data"
    return folder


def _clip_labels(p: Path, key: Path, folder: Path, from_json: list, report: list) -> ClipLabels:
    """The labels of clip ``p`` (resolved ``key``): its label file's, else its name's.

    Two label files that disagree leave the clip out (which is right cannot be
    told); a file name that disagrees with its label file is a warning.
    """
    if not _inside(folder, key):
        # The frame folders' rule: a file, or what a link in it points
        # to, must stay inside the folder given.
        raise InputError(p, "file", f"a .bvh file inside the dataset folder {folder} "
                         "(symbolic links included)", f"a link to {key}")
    labels = None
    if from_json:
        said = {(lab.motion, lab.style) for lab, _ in from_json}
        files = ", ".join(str(js) for _, js in from_json)
        if len(said) > 1:
            raise InputError(p, "labels", "one content/style from its label files",
                             reason=f"{files} say " + ", ".join(f"{lab.motion}/{lab.style}"
                                                               for lab, _ in from_json))
        if len(from_json) > 1:
            report.append(f"note: {p}: labels: {files} label it alike; read once")
        labels = from_json[0][0]
    by_name = None
    try:
        by_name = labels_from_name(p)
    except InputError:
        if labels is None:
            raise
    if labels is None:
        return by_name
    if by_name is not None and (by_name.motion, by_name.style) != (labels.motion, labels.style):
        report.append(f"warning: {p}: labels: file name says {by_name.motion}/{by_name.style}, "
                      f"label file says {labels.motion}/{labels.style}; using the label file")
    return labels


def _identical_files(keys: list[Path], clips: dict[Path, Path]) -> list[tuple[Path, list[Path]]]:
    """Groups of byte-identical files among ``keys``: ``[(first by name, [the copies])]``.

    Only files of equal size are hashed (SHA-256).
    """
    by_size: dict[int, list[Path]] = {}
    for k in keys:
        by_size.setdefault(k.stat().st_size, []).append(k)
    out = []
    for same_size in by_size.values():
        if len(same_size) < 2:
            continue
        by_hash: dict[str, list[Path]] = {}
        for k in sorted(same_size, key=lambda k: (k.stem, str(k))):
            digest = hashlib.sha256(read_bytes(clips[k], MAX_BVH_BYTES, "a readable .bvh file")).hexdigest()
            by_hash.setdefault(digest, []).append(k)
        out += [(group[0], group[1:]) for group in by_hash.values() if len(group) > 1]
    return sorted(out, key=lambda g: g[0].stem)


def read_folder(path, fps: float | None = 30, azimuth: float = 0.0, elevation: float = 0.0,
                facing: str = "normalise", center: bool = True, up: str = "auto",
                family: str | SkeletonFamily | None = None, window: float = 1.0,
                scale: float = 1.0, depth: bool = False) -> tuple[pd.DataFrame, list[str]]:
    """Read every labelled BVH clip of a folder into a contract table.

    Parameters
    ----------
    path : the folder with ``*.bvh`` (and optional ``*.json`` labels), or a
        dataset folder whose ``data/`` holds them (Bandai-Namco's layout).
    fps : output frame rate (linear resampling of 3D positions,
        :func:`nnsf.datasets.projection.resample`); None keeps each file's rate.
    azimuth, elevation : camera angles in degrees; ``0, 0`` is the front view.
    facing : ``"first"`` turns the whole clip once so that the body faces the
        camera at its start (a turn within the clip is kept), ``"normalise"``
        turns each frame about the vertical so the body
        faces the camera (heading smoothed over ``window`` seconds) or
        ``"none"`` keeps the world heading.
    center : remove the root's horizontal travel (smoothed over ``window``
        seconds, so sway within a stride stays), like the embedded dataset's
        treadmill motion; False keeps travel across the image.
    up : the world up axis (``"y"``, ``"z"``, …) or ``"auto"`` (per file, from
        head and feet).
    family : a built-in skeleton family name or a
        :class:`~nnsf.datasets.bvh_skeletons.SkeletonFamily`; None detects it
        per file.
    scale : factor applied to all coordinates (1.0 keeps the BVH's units).
    depth : also add columns ``z1..z17`` (camera depth; not part of the
        contract, ``validate`` drops them).

    Returns
    -------
    table : contract table (``clip, frame, character, motion, x1..y17``),
        sorted by clip and frame; ``character`` is the style.
    report : human-readable lines, one per skipped file or warning.

    Raises
    ------
    InputError
        If the folder is missing or no clip at all could be read.
    """
    folder = Path(path)
    if not folder.is_dir():
        raise InputError(folder, "folder", "an existing folder of .bvh clips")
    data = _data_folder(folder)
    lists = label_lists(data)
    report: list[str] = []

    # 1) label files and the clips they name
    labelled: dict[Path, list[tuple[ClipLabels, Path]]] = {}
    for js in sorted(data.glob("*.json")):
        try:
            labels, bvh_path = labels_from_json(js, folder, lists)
        except InputError as exc:
            report.append(f"skipped label: {exc}")
            continue
        if not bvh_path.is_file():
            report.append(f"skipped label: {js}: bvh: expected an existing motion file for "
                          f"{labels.motion}/{labels.style}, got {bvh_path.name!r} (missing)")
            continue
        labelled.setdefault(real(bvh_path), []).append((labels, js))

    # 2) every clip's labels: from its JSON, else from its name
    clips = {}
    for p in sorted(data.glob("*.bvh")):
        if p.is_file():
            clips[real(p)] = p
        else:   # a folder, a FIFO, a dangling link or a link loop named *.bvh
            report.append(f"skipped: {p}: file: expected a regular .bvh file")
    for p in labelled:
        clips.setdefault(p, p)
    chosen: dict[Path, ClipLabels] = {}
    stems: dict[str, Path] = {}
    for key in sorted(clips, key=lambda p: (p.stem, str(p))):
        p = clips[key]
        try:
            chosen[key] = _clip_labels(p, key, folder, labelled.get(key, []), report)
        except InputError as exc:
            report.append(f"skipped: {exc}")
            continue
        if p.stem in stems:  # a label file's "bvh" may name a clip of the same name elsewhere
            report.append(f"skipped: {p}: file name: expected a clip name of its own, got the name of "
                          f"{stems[p.stem]}")
            del chosen[key]
            continue
        stems[p.stem] = p

    # 3) a byte-identical copy is the same take twice: kept once, else it would sit on both
    #    sides of a cross-validation split (or, labelled differently, contradict itself)
    for first, copies in _identical_files(list(chosen), clips):
        names = ", ".join(str(clips[c]) for c in copies)
        same = all((chosen[c].motion, chosen[c].style) == (chosen[first].motion, chosen[first].style)
                   for c in copies)
        if same:
            report.append(f"skipped: {names}: file: expected a clip of its own, got a byte-identical copy "
                          f"of {clips[first]}; that one is kept")
        else:
            labels = "; ".join(f"{clips[c].name} {chosen[c].motion}/{chosen[c].style}" for c in [first, *copies])
            report.append(f"skipped: {clips[first]}, {names}: labels: expected one label for one take, got "
                          f"byte-identical files labelled differently ({labels}); all are left out")
            del chosen[first]
        for c in copies:
            del chosen[c]

    rows_xy, rows_depth, meta = [], [], []
    for key in sorted(chosen, key=lambda p: p.stem):
        p, labels = clips[key], chosen[key]
        try:
            clip = load_clip(p, fps=fps, azimuth=azimuth, elevation=elevation, facing=facing,
                             center=center, up=up, family=family, window=window, scale=scale)
        except InputError as exc:
            report.append(f"skipped: {exc}")
            continue
        report.extend(f"note: {n}" for n in clip.notes)
        rows_xy.append(clip.points.reshape(len(clip.points), -1))
        rows_depth.append(clip.depth)
        meta.append((clip.name, len(clip.points), labels.style, labels.motion))
    if not meta:
        raise InputError(folder, "clips", "at least one readable, labelled .bvh clip",
                         reason=f"none of {len(clips)} could be read; {len(report)} problem(s), "
                         f"the first: {report[0] if report else 'no .bvh files'}")

    # 3) a style seen in one motion only cannot be told apart from that motion
    styles: dict[str, set[str]] = {}
    for _, _, s, m in meta:
        styles.setdefault(s, set()).add(m)
    for s, ms in sorted(styles.items()):
        if len(ms) == 1:
            report.append(f"warning: style {s!r} appears in one motion only ({next(iter(ms))}); "
                          "its style cannot be separated from that content")

    n = np.array([m[1] for m in meta])
    table = pd.DataFrame({
        "clip": np.repeat([m[0] for m in meta], n),
        "frame": np.concatenate([np.arange(k) for k in n]),
        "character": np.repeat([m[2] for m in meta], n),
        "motion": np.repeat([m[3] for m in meta], n),
    })
    table = pd.concat([table, pd.DataFrame(np.concatenate(rows_xy), columns=list(FEATURE_COLUMNS))], axis=1)
    checked = validate(table, folder)
    if depth:
        d = pd.DataFrame(np.concatenate(rows_depth), columns=list(DEPTH_COLUMNS))
        # validate() sorts by (clip, frame) and drops extra columns: sort the
        # depth block the same way and put it back beside the contract columns.
        full = pd.concat([table[["clip", "frame"]], d], axis=1)
        full = full.sort_values(["clip", "frame"], kind="stable").reset_index(drop=True)
        checked = pd.concat([checked, full[list(DEPTH_COLUMNS)]], axis=1)
    return checked, report
