"""The ``track`` stage: track every clip's side contours (Eq. 1), then derive its key points (Eq. 2-3).

``track_clips`` reads ``<frames_dir>/index.csv`` and each clip's frames and
``annotation.json`` (written by the render stage, or by hand for real
frames) and writes ``<out_dir>/<clip>/curves.npz`` in the TRACKS format
(:mod:`nnsf.roto.tracks`).  ``keypoints_from_tracks`` turns those into the
feature-matrix contract table ``keypoints.csv`` plus ``characters.json``
(the ``frames`` source of the ``data`` stage).  The ``roto_eval`` stage that
scores the trackers is :mod:`nnsf.roto.evaluation`.

Both fan out over clips through ``mapper``; a clip failing on bad input is
reported by name, the others are kept, and the stage then raises one
:class:`InputError` naming the failed clips.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.io import atomic_dir, write_json, write_npz
from nnsf.names import inside
from nnsf.pipeline import FRAMES_DIR, RAW_DIR, TRACKED_DIR, TRACKS_DIR, StageResult, failures, map_items
from nnsf.datasets import contract
from nnsf.frames.annotation import read_annotation
from nnsf.frames.clips import read_clip
from nnsf.frames.clips import read_index
from nnsf.skeleton import FEATURE_COLUMNS, JOINTS
from nnsf.roto.keypoints import fit_keypoint_model, keypoints_from_curves
from nnsf.roto.options import method as _method
from nnsf.roto.options import track_options
from nnsf.roto.solve import keyframe_curves, track_clip
from nnsf.roto.tracks import read_tracks

def load_clip(item: dict):
    """(annotation, frames) of one indexed clip; InputError on bad input."""
    folder = Path(item["frames_dir"]) / item["folder"]
    ann = read_annotation(folder / "annotation.json")
    if ann.clip != item["clip"]:
        raise InputError(ann.source, "clip", f"the clip id {item['clip']!r} of index.csv", ann.clip)
    return ann, read_clip(folder, ann)


# --------------------------------------------------------------------------- track_clips
def _track_item(item: dict) -> dict:
    """Track one clip and write its curves.npz (module-level, picklable)."""
    clip = item["clip"]
    out = inside(item["out"], clip, source=Path(item["frames_dir"]) / "index.csv", field="clip")
    try:
        ann, frames = load_clip(item)
        names, _ = keyframe_curves(ann)
        if not names:
            raise InputError(ann.source, "keyframes[0].curves", "at least one curve to track")
        try:
            control = track_clip(frames, ann, item["method"], **item["options"])
        except ValueError as exc:     # e.g. control-point counts differing between keyframes
            raise InputError(ann.source, "keyframes", "curves trackable between keyframes",
                             reason=str(exc)) from None
        n_points = np.array([max(len(k.curves[n]) for k in ann.keyframes if n in k.curves)
                             for n in names], np.int64)
        out.mkdir(parents=True, exist_ok=True)
        write_npz(out / "curves.npz", control=control,
                  curve_names=np.array(names, dtype=f"<U{max(len(n) for n in names)}"),
                  n_points=n_points, keyframes=np.array(ann.keyframe_indices, np.int64))
        lost = int((~np.isfinite(control).all(axis=(2, 3))).sum())
        return {"ok": True, "clip": clip, "frames": len(frames), "curves": len(names),
                "rows_without_estimate": lost}
    except InputError as exc:
        shutil.rmtree(out, ignore_errors=True)
        return {"ok": False, "clip": clip, "error": str(exc)}


def track_clips(params: dict, frames_dir=FRAMES_DIR, out_dir=TRACKS_DIR, mapper=None):
    """Track the side curves of every clip listed in ``<frames_dir>/index.csv``.

    Reads ``roto.method`` and the ``track`` options (:func:`track_options`).
    Writes ``<out_dir>/<clip>/curves.npz`` (TRACKS format) for every clip that
    succeeds (the folder is swapped in complete); failed clips are listed in
    ``<out_dir>/failed.json`` and named in the InputError raised at the end.
    """
    method = _method(params)
    options = track_options(params)
    frames_dir, out_dir = Path(frames_dir), Path(out_dir)
    index = read_index(frames_dir)
    with atomic_dir(out_dir) as tmp:
        items = [{"clip": r.clip, "folder": r.folder, "frames_dir": str(frames_dir),
                  "out": str(tmp), "method": method, "options": options}
                 for r in index.itertuples()]
        results = map_items(mapper, _track_item, items)
        failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
        if failed:
            write_json(tmp / "failed.json", failed)
    ok = [r for r in results if r["ok"]]
    if failed:
        raise InputError(frames_dir, "clips", f"every clip tracked; {len(failed)} failed (the other "
                         f"{len(ok)} were written to {out_dir}): " + failures(failed))
    return StageResult(
        params={"track_method": method, **{f"track_{k}": v for k, v in options.items()}},
        metrics={"clips": len(ok), "frames": int(sum(r["frames"] for r in ok)),
                 "rows_without_estimate": int(sum(r["rows_without_estimate"] for r in ok))})


# --------------------------------------------------------------------------- evaluate_tracking


# --------------------------------------------------------------------------- tracks -> key points (Eq. 2-3)


def _keypoints_item(item: dict) -> dict:
    """Key points of one clip from its tracks (module-level, picklable)."""
    clip = item["clip"]
    try:
        ann = read_annotation(Path(item["frames_dir"]) / item["folder"] / "annotation.json")
        if ann.clip != clip:
            raise InputError(ann.source, "clip", f"the clip id {clip!r} of index.csv", ann.clip)
        control, names, n_points = read_tracks(inside(item["tracks_dir"], clip, "curves.npz",
                                                      source=ann.source, field="clip"), ann)
        model = fit_keypoint_model(ann)
        kp = keypoints_from_curves(control, names, model, n_points)
        good = np.isfinite(kp).all(axis=(1, 2))
        if not good.any():
            missing = [j for j in range(kp.shape[1]) if not np.isfinite(kp[:, j]).any()]

            raise InputError(Path(item["tracks_dir"]) / clip / "curves.npz", "curves",
                             "curves giving all 17 key points in at least one frame",
                             "never: " + ", ".join(JOINTS[j] for j in missing) if missing else None)
        return {"ok": True, "clip": clip, "character": ann.character, "motion": ann.motion,
                "frame": np.flatnonzero(good), "points": kp[good], "frames": len(ann.frames),
                "dropped": int((~good).sum()), "model": model.to_dict()}
    except InputError as exc:
        return {"ok": False, "clip": clip, "error": str(exc)}


def keypoints_from_tracks(params: dict, frames_dir=FRAMES_DIR, tracks_dir=TRACKS_DIR,
                          out_dir=RAW_DIR, mapper=None):
    """Key points of every clip from the tracked side curves (Eq. 2-3).

    Reads ``<frames_dir>/index.csv``, each clip's ``annotation.json`` (ω is
    fitted on its keyframes' key points) and ``<tracks_dir>/<clip>/curves.npz``.
    Writes ``<out_dir>/keypoints.csv`` (the feature-matrix contract, pixels;
    frames where some key point has no estimate are left out) and
    ``<out_dir>/characters.json`` (per clip: labels, frame counts, fitted ω).
    Reads no parameters (``params`` is only used to name the params file).
    """
    frames_dir, tracks_dir, out_dir = Path(frames_dir), Path(tracks_dir), Path(out_dir)
    index = read_index(frames_dir)
    items = [{"clip": r.clip, "folder": r.folder, "frames_dir": str(frames_dir),
              "tracks_dir": str(tracks_dir)} for r in index.itertuples()]
    results = map_items(mapper, _keypoints_item, items)
    ok = [r for r in results if r["ok"]]
    failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
    if not ok:
        raise InputError(tracks_dir, "clips", "at least one clip with usable tracks; failed: "
                         + failures(failed))
    blocks = []
    for r in ok:
        n = len(r["frame"])
        block = pd.DataFrame(r["points"].reshape(n, -1), columns=list(FEATURE_COLUMNS))
        block.insert(0, "motion", r["motion"])
        block.insert(0, "character", r["character"])
        block.insert(0, "frame", r["frame"].astype(np.int64))
        block.insert(0, "clip", r["clip"])
        blocks.append(block)
    table = contract.validate(pd.concat(blocks, ignore_index=True), "tracked key points")
    described = {
        "source": "frames",
        "frames_dir": str(frames_dir), "tracks_dir": str(tracks_dir),
        "clips": {r["clip"]: {"character": r["character"], "motion": r["motion"],
                              "frames": r["frames"], "dropped_frames": r["dropped"],
                              "keypoint_model": r["model"]} for r in ok},
        "failed": failed,
    }
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "keypoints.csv", table)
        write_json(tmp / "characters.json", described)
    if failed:
        raise InputError(tracks_dir, "clips", f"key points for every clip; {len(failed)} failed "
                         f"(the other {len(ok)} were written to {out_dir}): " + failures(failed))
    return StageResult(
        params={"frames_dir": str(frames_dir), "tracks_dir": str(tracks_dir)},
        metrics={"clips": len(ok), "frames": len(table),
                 "dropped_frames": int(sum(r["dropped"] for r in ok)),
                 "characters": table["character"].nunique(), "motions": table["motion"].nunique()},
    )


# --------------------------------------------------------------------------- the stages
def roto(params: dict, frames_dir=FRAMES_DIR, tracks_dir=TRACKS_DIR, tracked_dir=TRACKED_DIR,
          mapper=None) -> StageResult:
    """Track every clip's side contours, then derive its key points (the ``frames`` source).

    Writes ``<tracks_dir>/<clip>/curves.npz`` (:func:`track_clips`)
    and ``<tracked_dir>/keypoints.csv`` + ``characters.json`` in the
    feature-matrix contract, pixels (:func:`keypoints_from_tracks`),
    which the data stage reads with ``dataset.name: frames`` and
    ``dataset.path: data/tracked``.  ``mapper`` fans out over clips.
    """
    tracked = track_clips(params, frames_dir=frames_dir, out_dir=tracks_dir, mapper=mapper)
    points = keypoints_from_tracks(params, frames_dir=frames_dir, tracks_dir=tracks_dir,
                                   out_dir=tracked_dir, mapper=mapper)
    return StageResult(params=tracked.params,
                       metrics={**tracked.metrics, **{f"keypoints_{k}": v for k, v in points.metrics.items()}})


