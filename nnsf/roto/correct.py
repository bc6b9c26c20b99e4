"""The correction loop: tracked curves out to CVAT, corrected frames back in as keyframes.

* :func:`export_cvat` writes a clip's tracked curves as a "CVAT for video
  1.1" XML: one ``<track>`` per side curve (label ``l_forearm.a`` ...), one
  ``<polyline>`` per frame.  CVAT keeps only the shapes marked
  ``keyframe="1"`` when it imports a track (the interpolated ones are
  recomputed), so every tracked frame is written as a CVAT keyframe; the
  clip's own keyframes are marked by the shape attribute
  ``nnsf_keyframe="true"`` (declared in ``<meta>`` for every label, a
  checkbox in CVAT).  Coordinates are written with :data:`DECIMALS`
  decimals, as CVAT's own export does.
* :func:`read_corrections` reads such a file back after a user edited it in
  CVAT: a frame is **corrected** when one of its polylines differs from the
  exported one (beyond the stored precision); its curves become a new
  keyframe.  Bad input (a file of another clip, a frame outside the clip, a
  label the clip does not have, a changed vertex count) raises
  :class:`InputError` naming the file and the field.
* :func:`retrack` adds corrected frames as keyframes and re-solves only the
  keyframe intervals that contain one; every other frame keeps its values
  bit for bit.
* :func:`simulate_user` is the simulated user of the edit-ratio metric
  (the paper's Fig. 4a) running this same loop: in each round it corrects
  the worst frame of every interval that still has a control point more
  than ``tol`` px from the truth (only those points are moved, onto the
  true curve), then re-tracks.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.frames.clips import read_clip
from nnsf.frames.cvat import task_meta, parse_points
from nnsf.frames.clips import read_index
from nnsf.roto.tracks import TRACKS, read_tracks
from nnsf.io import atomic_path, read_bytes, read_npz, write_npz
from nnsf.names import inside
from nnsf.roto.curves import project_to_polyline
from nnsf.roto.solve import ClipTracker, TrackOptions, plan
from nnsf.roto.options import method as _method
from nnsf.roto.options import track_options

DECIMALS = 2
#: Largest corrections file read (bytes), as for CVAT imports (nnsf.frames.cvat).
MAX_CVAT_BYTES = 256_000_000
KEYFRAME_ATTRIBUTE = "nnsf_keyframe"


# --------------------------------------------------------------------------- export
def _fmt(pts: np.ndarray) -> str:
    return ";".join(f"{x:.{DECIMALS}f},{y:.{DECIMALS}f}" for x, y in pts)


def cvat_xml(control: np.ndarray, names: list[str], n_points, keyframes, clip: str,
             image_size: tuple[int, int]) -> str:
    """The CVAT for video 1.1 XML text of a clip's tracked curves.

    control : (T, N, P, 2) px (pixel centres at integers, as the tracker);
    names : the N side-curve names; n_points : (N,) control points per curve;
    keyframes : the clip's keyframe indices; image_size : (width, height).
    Rows without a finite estimate are written as ``outside="1"`` shapes.
    """
    control = np.asarray(control, np.float64)
    T = control.shape[0]
    keys = {int(k) for k in keyframes}
    root = ET.Element("annotations")
    ET.SubElement(root, "version").text = "1.1"
    task = ET.SubElement(ET.SubElement(root, "meta"), "task")
    ET.SubElement(task, "name").text = clip
    ET.SubElement(task, "size").text = str(T)
    ET.SubElement(task, "mode").text = "interpolation"
    ET.SubElement(task, "start_frame").text = "0"
    ET.SubElement(task, "stop_frame").text = str(T - 1)
    labels = ET.SubElement(task, "labels")
    for n in names:
        lab = ET.SubElement(labels, "label")
        ET.SubElement(lab, "name").text = n
        ET.SubElement(lab, "type").text = "polyline"
        at = ET.SubElement(ET.SubElement(lab, "attributes"), "attribute")
        for k, v in (("name", KEYFRAME_ATTRIBUTE), ("mutable", "True"), ("input_type", "checkbox"),
                     ("default_value", "false"), ("values", "false")):
            ET.SubElement(at, k).text = v
    size = ET.SubElement(task, "original_size")
    ET.SubElement(size, "width").text = str(int(image_size[0]))
    ET.SubElement(size, "height").text = str(int(image_size[1]))
    for i, n in enumerate(names):
        tr = ET.SubElement(root, "track", id=str(i), label=n, source="auto")
        C = int(n_points[i])
        last = None
        for t in range(T):
            pts = control[t, i, :C]
            ok = bool(np.isfinite(pts).all())
            if not ok and last is None:
                continue
            shape = ET.SubElement(tr, "polyline", frame=str(t), outside="0" if ok else "1",
                                  occluded="0", keyframe="1",
                                  points=_fmt(pts if ok else last), z_order="0")
            ET.SubElement(shape, "attribute", name=KEYFRAME_ATTRIBUTE).text = \
                "true" if t in keys else "false"
            if ok:
                last = pts
    ET.indent(root)
    return '<?xml version="1.0" encoding="utf-8"?>\n' + ET.tostring(root, encoding="unicode") + "\n"


def export_cvat(path, control, names, n_points, keyframes, clip: str, image_size) -> Path:
    """Write :func:`cvat_xml` to ``path`` atomically; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    text = cvat_xml(control, names, n_points, keyframes, clip, image_size)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


# --------------------------------------------------------------------------- import
def _parse(path: Path):
    """The XML root of a corrections file: bounded in size, no DOCTYPE or ENTITY, well-formed."""
    if not path.is_file():
        raise InputError(path, "file", "an existing CVAT XML file (CVAT for video 1.1)")
    data = read_bytes(path, MAX_CVAT_BYTES, "a readable CVAT XML file")
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise InputError(path, "file", "CVAT XML without DOCTYPE or ENTITY declarations")
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise InputError(path, f"line {exc.position[0]}", "well-formed XML", str(exc)) from None


def read_cvat_curves(path, clip: str, names: list[str], n_points, n_frames: int
                     ) -> tuple[dict[int, dict[str, np.ndarray]], set[int]]:
    """Per-frame polylines of a CVAT for video 1.1 file written for ``clip``.

    Returns ``({frame: {curve: (C, 2) array}}, frames marked nnsf_keyframe)``;
    only shapes with ``outside="0"`` are read (every such shape, whatever its
    ``keyframe`` flag: CVAT exports the frames it interpolates as well).
    InputError naming ``path`` and the field for a file of another clip
    (``<meta><task><name>``), another export format ("CVAT for images"), no
    ``<track>``, a frame outside 0..n_frames-1, a label that is not one of
    ``names`` or that two tracks share, a track without polylines or with
    other shapes, no shape inside the frame, a vertex count other than the
    curve's, malformed points or XML: nothing in the file is dropped silently.
    """
    path = Path(path)
    root = _parse(path)
    if root.tag != "annotations" or (root.findtext("version") or "").strip() != "1.1":
        raise InputError(path, "<version>", '"1.1" under <annotations> (CVAT for video 1.1)',
                         (root.findtext("version") or "").strip() or root.tag)
    if root.find("image") is not None:
        raise InputError(path, "<image>", "a CVAT for video 1.1 export (<track> elements); this is a "
                         '"CVAT for images" export: export the task again as CVAT for video 1.1')
    meta = task_meta(root)
    if meta.get("name") != clip:
        raise InputError(path, "<meta><task><name>", f"the clip {clip!r} (corrections of that clip)",
                         meta.get("name"))
    tracks = root.findall("track")
    if not tracks:
        raise InputError(path, "<track>", "at least one <track> of the clip's curves (CVAT for video 1.1)")
    count = {n: int(c) for n, c in zip(names, n_points)}
    out: dict[int, dict[str, np.ndarray]] = {}
    marked: set[int] = set()
    seen: dict[str, str] = {}      # label -> id of the track that has it
    for track in tracks:
        tid, label = track.get("id", "?"), track.get("label", "")
        if label not in count:
            raise InputError(path, f"track id={tid} label", "one of the clip's curves ("
                             + ", ".join(names[:3]) + (", ..." if len(names) > 3 else "") + ")",
                             label)
        if label in seen:
            raise InputError(path, f"track id={tid} label", f"each curve in one track; track id={seen[label]} "
                             "has this label too (merge the two tracks in CVAT)", label)
        seen[label] = tid
        other = [shape.tag for shape in track if shape.tag != "polyline"]
        if other or track.find("polyline") is None:
            raise InputError(path, f"track id={tid} label={label!r}", "<polyline> shapes (the curve's "
                             "control points)", f"<{other[0]}>" if other else "no shape")
        for shape in track.findall("polyline"):
            fr = shape.get("frame", "")
            where = f"track id={tid} label={label!r} frame"
            if not fr.strip().isdigit() or int(fr) >= n_frames:
                raise InputError(path, where, f"a frame of the clip, 0..{n_frames - 1}", fr)
            if shape.get("outside", "0") != "0":
                continue
            f = int(fr)
            pts = parse_points(shape.get("points"), path, f"track id={tid} frame={f}",
                                n=count[label])
            out.setdefault(f, {})[label] = np.array(pts, np.float64)
            for a in shape.findall("attribute"):
                if a.get("name") == KEYFRAME_ATTRIBUTE and (a.text or "").strip().lower() == "true":
                    marked.add(f)
    if not out:
        raise InputError(path, "<polyline>", 'at least one polyline inside the frame (outside="0")',
                         "every shape is outside")
    return dict(sorted(out.items())), marked


def stored(a: np.ndarray) -> np.ndarray:
    """``a`` as the XML stores it: each value through the ``.{DECIMALS}f`` format."""
    a = np.asarray(a, np.float64)
    return np.vectorize(lambda v: float(f"{v:.{DECIMALS}f}") if math.isfinite(v) else v)(a)


def read_corrections(path, clip: str, names: list[str], n_points, control: np.ndarray,
                     keyframes) -> dict[int, dict[str, np.ndarray]]:
    """Frames a user corrected in an exported CVAT file, as new keyframe curves.

    control : (T, N, P, 2) the tracked curves the file was exported from.
    A frame counts as corrected when one of its polylines differs from the
    stored (rounded) tracked one by more than half the last decimal, or when
    the user ticked ``nnsf_keyframe`` on a frame that was not a keyframe.
    A corrected frame takes every curve: the file's polyline where the user
    changed it, else the tracked curve at full precision.  Returns ``{frame: {curve: (C, 2)}}``.
    """
    T = control.shape[0]
    polys, marked = read_cvat_curves(path, clip, names, n_points, T)
    keys = {int(k) for k in keyframes}
    half = 0.5 * 10.0 ** -DECIMALS
    out = {}
    for f, curves in polys.items():
        changed = f in marked and f not in keys
        edited = set()
        for n, pts in curves.items():
            i = names.index(n)
            ref = stored(control[f, i, : len(pts)])
            if not np.isfinite(ref).all() or (np.abs(pts - ref) > half + 1e-9).any():
                edited.add(n)
        if changed or edited:
            full = {}
            for i, n in enumerate(names):
                c = curves.get(n) if n in edited else None
                if c is None:
                    c = control[f, i, : int(n_points[i])]
                    if not np.isfinite(c).all():
                        raise InputError(path, f"frame={f} label={n!r}",
                                         "a polyline on a corrected frame where the curve has no track")
                full[n] = np.asarray(c, np.float64)
            out[f] = full
    return out


# --------------------------------------------------------------------------- re-solve
def intervals(keys) -> list[tuple[int, int]]:
    """Consecutive keyframe pairs (k0, k1) of sorted ``keys``."""
    k = sorted(int(v) for v in keys)
    return list(zip(k[:-1], k[1:]))


def solve_intervals(tracker, names: list[str], kfs: dict, control: np.ndarray,
                    only: set[tuple[int, int]] | None = None) -> np.ndarray:
    """Track the (interval, curve) problems of keyframes ``kfs`` into a copy of ``control``.

    tracker : a :class:`nnsf.roto.solve.ClipTracker`; kfs : ``{frame: {curve: (C, 2)}}``;
    control : (T, N, P, 2); only : the intervals (k0, k1) to solve (default all).
    Keyframe rows are set from ``kfs``; rows outside the solved intervals are
    left as they are in ``control``.
    """
    out = np.array(control, np.float64, copy=True)
    _, _, batches = plan({"keyframes": [{"frame": f, "curves": c} for f, c in kfs.items()]})
    for b in batches:
        sel = np.array([only is None or (k0, k1) in only for k0, k1, _ in b.jobs], bool)
        if not sel.any():
            continue
        P = tracker.solve(b.P[sel], b.fixed[sel], b.frame0[sel],
                          names=[n for (_, _, n), s in zip(b.jobs, sel) if s])
        C = P.shape[2]
        for g, (k0, k1, name) in enumerate(j for j, s in zip(b.jobs, sel) if s):
            out[k0:k1 + 1, names.index(name), :C] = P[g]
    for f, curves in kfs.items():
        for n, c in curves.items():
            out[f, names.index(n), : len(c)] = c
    return out


def retrack(tracker, names: list[str], kfs: dict, control: np.ndarray, corrections: dict
            ) -> tuple[np.ndarray, dict, list[tuple[int, int]]]:
    """Add corrected frames as keyframes and re-solve only the intervals they touch.

    kfs : the current keyframes ``{frame: {curve: (C, 2)}}``; control : (T, N, P, 2)
    the current tracks; corrections : ``{frame: {curve: (C, 2)}}``.  An old
    interval (k0, k1) is touched when a corrected frame lies inside it or on
    one of its ends; it is split at the corrected frames and the parts are
    tracked afresh (cold start, coarse to fine, as the first track).
    Returns (new control, new keyframes, the re-solved intervals).
    """
    old = intervals(kfs)
    new_kfs = dict(kfs)
    for f, c in corrections.items():
        new_kfs[int(f)] = {n: np.asarray(v, np.float64) for n, v in c.items()}
    new_kfs = dict(sorted(new_kfs.items()))
    fr = sorted(int(f) for f in corrections)
    touched = [(a, b) for a, b in old if any(a <= f <= b for f in fr)]
    todo = {(a, b) for a, b in intervals(new_kfs)
            if any(ta <= a and b <= tb for ta, tb in touched)}
    out = solve_intervals(tracker, names, new_kfs, control, only=todo)
    return out, new_kfs, sorted(todo)


# --------------------------------------------------------------------------- simulated user
def simulate_user(tracker, names: list[str], kfs: dict, truth: np.ndarray, n_points,
                  tol: float = 2.0, max_rounds: int = 20, control: np.ndarray | None = None
                  ) -> dict:
    """The simulated user of the edit ratio, running the correction loop to the end.

    truth : (T, N, S, 2) dense true side curves in ``names`` order.  The
    curves are tracked (unless ``control`` is given); then in each round,
    in every keyframe interval that still has an in-between control point
    more than ``tol`` px from its true curve, the frame with the worst such
    point is corrected (each of its points further than ``tol`` is moved to
    the nearest true point and counted as one edit) and becomes a keyframe;
    :func:`retrack` re-solves the touched intervals.  Every round adds a
    keyframe to a shrinking interval, so the loop ends after at most the
    number of in-between frames; ``max_rounds`` caps it (points still off
    then count one edit each).
    Returns ``{"edits", "corrected_frames", "rounds", "left" (control
    points still off at the cap), "left_curves" (curves with such points),
    "control", "tracked", "keyframes"}``.
    """
    T = truth.shape[0]
    P = max(int(c) for c in n_points)
    if control is None:
        control = solve_intervals(tracker, names, kfs, np.full((T, len(names), P, 2), np.nan))
    tracked = control.copy()
    lo, hi = min(kfs), max(kfs)
    span = np.zeros(T, bool)
    span[lo:hi + 1] = True
    mask = np.arange(P)[None, :] < np.asarray(n_points)[:, None]        # (N, P)

    def off_dist(ctrl, keys):
        d, near = project_to_polyline(np.nan_to_num(ctrl), truth)     # (T, N, P)
        ok = span[:, None, None] & mask[None] & np.isfinite(ctrl).all(-1)
        ok[sorted(keys)] = False
        return np.where(ok, d, 0.0), near

    edits = corrected = rounds = 0
    while True:
        dist, near = off_dist(control, kfs)
        if not (dist > tol).any() or rounds >= max_rounds:
            break
        fixes = {}
        for a, b in intervals(kfs):
            if b - a < 2:
                continue
            worst = dist[a + 1:b].reshape(b - a - 1, -1).max(1)
            if worst.max() <= tol:
                continue
            f = a + 1 + int(worst.argmax())
            new = {}
            for i, n in enumerate(names):
                C = int(n_points[i])
                c = control[f, i, :C].copy()
                if not np.isfinite(c).all():      # not tracked in this interval
                    continue
                bad = dist[f, i, :C] > tol
                c[bad] = near[f, i, :C][bad]
                edits += int(bad.sum())
                new[n] = c
            fixes[f] = new
        corrected += len(fixes)
        rounds += 1
        control, kfs, _ = retrack(tracker, names, kfs, control, fixes)
    dist, _ = off_dist(control, kfs)
    left = int((dist > tol).sum())
    left_curves = int((dist > tol).any(axis=(0, 2)).sum())
    return {"edits": edits + left, "corrected_frames": corrected, "rounds": rounds, "left": left,
            "left_curves": left_curves,
            "control": control, "tracked": tracked, "keyframes": sorted(kfs)}


# --------------------------------------------------------------------------- the track command
def _clip_tracks(frames_dir: Path, tracks_dir: Path, row):
    ann = read_annotation(frames_dir / row.folder / "annotation.json")
    path = inside(tracks_dir, row.clip, "curves.npz", source=frames_dir / "index.csv", field="clip")
    control, names, n_points = read_tracks(path, ann)

    z = read_npz(path, TRACKS, what="file of tracked curves")
    keys = [int(k) for k in z["keyframes"]] if "keyframes" in z else ann.keyframe_indices
    return ann, path, control, names, n_points, keys


def export_clips(frames_dir, tracks_dir, out_dir) -> list[Path]:
    """Write ``<out_dir>/<clip>.xml`` (CVAT for video 1.1) for every tracked clip of the index."""
    frames_dir, tracks_dir, out_dir = Path(frames_dir), Path(tracks_dir), Path(out_dir)
    written = []
    for row in read_index(frames_dir).itertuples():
        ann, _, control, names, n_points, keys = _clip_tracks(frames_dir, tracks_dir, row)
        target = inside(out_dir, f"{row.clip}.xml", source=frames_dir / "index.csv", field="clip")
        written.append(export_cvat(target, control, names, n_points, keys,
                                   row.clip, ann.image_size))
    return written


def apply_corrections(params: dict, xml_path, frames_dir, tracks_dir, clip: str | None = None
                      ) -> dict:
    """``nnsf roto --corrections FILE.xml``: corrected frames become keyframes, touched intervals re-tracked.

    The clip is ``clip`` or the file's task name; it must be in
    ``<frames_dir>/index.csv`` and tracked in ``<tracks_dir>``.  Rewrites
    ``<tracks_dir>/<clip>/curves.npz`` (atomically) with the re-solved
    curves and the enlarged keyframe list.  Returns a summary (clip,
    corrected frames, re-solved intervals, keyframes).
    """
    xml_path, frames_dir, tracks_dir = Path(xml_path), Path(frames_dir), Path(tracks_dir)
    index = read_index(frames_dir)
    if clip is None:
        clip = task_meta(_parse(xml_path)).get("name")
    rows = [r for r in index.itertuples() if r.clip == clip]
    if not rows:
        raise InputError(xml_path, "<meta><task><name>", "a clip of " + str(frames_dir / "index.csv")
                         + " (" + ", ".join(list(index["clip"])[:3]) + ", ...)", clip)
    ann, path, control, names, n_points, keys = _clip_tracks(frames_dir, tracks_dir, rows[0])
    fixes = read_corrections(xml_path, clip, names, n_points, control, keys)
    kfs = {}
    for k in keys:
        kfs[k] = {n: control[k, i, : int(n_points[i])] for i, n in enumerate(names)
                  if np.isfinite(control[k, i, : int(n_points[i])]).all()}
    method = _method(params)
    opts = TrackOptions.from_kwargs(**track_options(params))
    if fixes:
        tracker = ClipTracker(read_clip(frames_dir / rows[0].folder, ann), method, opts, keyframes=kfs)
        control, kfs, todo = retrack(tracker, names, kfs, control, fixes)
    else:
        todo = []
    write_npz(path, control=control,
              curve_names=np.array(names, dtype=f"<U{max(len(n) for n in names)}"),
              n_points=np.asarray(n_points, np.int64), keyframes=np.array(sorted(kfs), np.int64))
    return {"clip": clip, "corrected_frames": sorted(fixes), "resolved_intervals": todo,
            "keyframes": sorted(kfs), "curves": str(path)}
