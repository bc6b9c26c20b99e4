"""Pipeline stages of the frames source: render clips, and key points from tracked curves.

``render_frames`` writes ``data/frames/<clip>/`` (frames, ``truth.npz``,
``annotation.json``) and ``data/frames/index.csv``; the tracker (another
stage) writes ``data/tracks/<clip>/curves.npz`` (format in
``.helpers/TRACKS.md`` and :func:`read_tracks`); ``keypoints_from_tracks``
turns those into the feature-matrix contract table ``keypoints.csv`` plus
``characters.json``, as the ``data`` stage does for the synthetic source.

Both fan out over clips through ``mapper``; a clip that fails on bad input is
reported by name and left out, the other clips are written, and the stage
then raises one :class:`InputError` naming the failed clips.  A failed clip
leaves no folder behind, and outputs are swapped in only when complete.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.io import atomic_dir, read_npz, write_csv, write_json
from nnsf.params import require, source_of

FRAMES_DIR = Path("data/frames")
TRACKS_DIR = Path("data/tracks")
RAW_DIR = Path("data/raw")
INDEX_COLUMNS = ("clip", "character", "motion", "folder", "frames")
#: Tracked keyframe curves may differ from the annotation by at most this (px).
KEYFRAME_TOL_PX = 0.5


def _map(mapper, fn, items) -> list:
    return list(map(fn, items)) if mapper is None else list(mapper(fn, items))


def _failures(failed: dict) -> str:
    """Failed clip names, then each clip's full error (InputError shortens ``got``)."""
    return ", ".join(failed) + ". " + " | ".join(f"{c}: {e}" for c, e in failed.items())


def _int_param(params, key, lo, hi=None) -> int:
    v = require(params, key)
    if not isinstance(v, int) or isinstance(v, bool) or v < lo or (hi is not None and v > hi):
        rng = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
        raise InputError(source_of(params), key, rng, v)
    return v


def frames_params(params: dict) -> dict:
    """The checked ``frames`` section plus ``seed`` (InputError naming the field otherwise)."""
    from nnsf.datasets.synthetic import CHARACTERS, MOTIONS

    motions = require(params, "frames.motions")
    if isinstance(motions, int) and not isinstance(motions, bool):
        if not 1 <= motions <= len(MOTIONS):
            raise InputError(source_of(params), "frames.motions",
                             f"a count in [1, {len(MOTIONS)}] or a list of motion names", motions)
        motions = list(MOTIONS[:motions])
    elif (not isinstance(motions, list) or not motions or len(set(map(str, motions))) != len(motions)
          or any(m not in MOTIONS for m in motions)):
        raise InputError(source_of(params), "frames.motions",
                         "a count or a list of distinct motion names from " + ", ".join(MOTIONS), motions)
    return {
        "seed": _int_param(params, "seed", 0),
        "characters": [c.name for c in CHARACTERS[: _int_param(params, "frames.characters", 1,
                                                               len(CHARACTERS))]],
        "motions": list(motions),
        "clips_per_cell": _int_param(params, "frames.clips_per_cell", 1),
        "frames": _int_param(params, "frames.frames", 2),
        "size": _int_param(params, "frames.size", 64, 4096),
        "keyframe_every": _int_param(params, "frames.keyframe_every", 0),
        "control_points": _int_param(params, "frames.control_points", 2, 32),
    }


# --------------------------------------------------------------------------- render_frames

def _render_item(item: dict) -> dict:
    """Render one clip (module-level, picklable for any task runner)."""
    from nnsf.frames.render import render_clip

    folder = Path(item["folder"])
    try:
        summary = render_clip(folder, item["character"], item["motion"], item["frames"],
                              variation=item["variation"], seed=item["seed"], size=item["size"],
                              keyframe_every=item["keyframe_every"],
                              control_points=item["control_points"], clip=item["clip"])
        return {"ok": True, **summary}
    except (InputError, ValueError) as exc:
        shutil.rmtree(folder, ignore_errors=True)      # no half-written clip left behind
        return {"ok": False, "clip": item["clip"], "error": str(exc)}


def render_frames(params: dict, out_dir=FRAMES_DIR, mapper=None):
    """Render the synthetic characters × motions as cartoon clips into ``out_dir``.

    Reads ``seed`` and ``frames.{characters, motions, clips_per_cell, frames,
    size, keyframe_every, control_points}``.  Writes ``<out_dir>/<clip>/``
    (``frame_0000.png`` …, ``truth.npz``, ``annotation.json``; see
    :func:`nnsf.frames.render.render_clip`) and ``<out_dir>/index.csv``
    (clip, character, motion, folder, frames).
    """
    from nnsf.stages import StageResult

    p = frames_params(params)
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        items = [{"clip": f"{c}-{m}-{v:02d}", "character": c, "motion": m, "variation": v,
                  "seed": p["seed"], "frames": p["frames"], "size": p["size"],
                  "keyframe_every": p["keyframe_every"], "control_points": p["control_points"],
                  "folder": str(tmp / f"{c}-{m}-{v:02d}")}
                 for c in p["characters"] for m in p["motions"] for v in range(p["clips_per_cell"])]
        results = _map(mapper, _render_item, items)
        ok = [r for r in results if r["ok"]]
        failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
        index = pd.DataFrame({"clip": [r["clip"] for r in ok], "character": [r["character"] for r in ok],
                              "motion": [r["motion"] for r in ok], "folder": [r["clip"] for r in ok],
                              "frames": [r["frames"] for r in ok]}, columns=list(INDEX_COLUMNS))
        write_csv(tmp / "index.csv", index)
        if failed:
            write_json(tmp / "failed.json", failed)
    if failed:
        raise InputError(out_dir, "clips", "every clip rendered; failed: " + _failures(failed))
    fit = max((r["max_fit_error_px"] for r in ok), default=0.0)
    return StageResult(
        params={f"frames_{k}": (",".join(v) if isinstance(v, list) else v) for k, v in p.items()},
        metrics={"clips": len(ok), "frames": int(index["frames"].sum()),
                 "max_control_fit_error_px": fit},
    )


# --------------------------------------------------------------------------- tracks -> key points

def read_index(frames_dir) -> pd.DataFrame:
    """``<frames_dir>/index.csv`` checked: columns, unique clips, folders inside ``frames_dir``."""
    from nnsf.frames.annotation import check_relative

    path = Path(frames_dir) / "index.csv"
    if not path.is_file():
        raise InputError(path, "file", "the frame-set index written by the render_frames stage")
    try:
        index = pd.read_csv(path, dtype=str, keep_default_na=False)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, OSError) as exc:
        raise InputError(path, "file", "a readable CSV table", reason=str(exc)) from None
    missing = [c for c in ("clip", "folder") if c not in index.columns]
    if missing:
        raise InputError(path, missing[0], "columns " + ", ".join(INDEX_COLUMNS))
    if index.empty:
        raise InputError(path, "rows", "at least one clip")
    dup = index["clip"].duplicated()
    if dup.any():
        raise InputError(path, "clip", "each clip once", index["clip"][dup].iloc[0])
    for i, f in enumerate(index["folder"]):
        check_relative(f, path, f"folder (row {i + 1})")
    return index


def read_tracks(path, annotation) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Read and check a tracker's ``curves.npz`` against the clip's annotation.

    Returns ``control (T, C, P, 2)``, ``curve_names`` and ``n_points (C,)``.
    InputError (naming ``path``) for a missing file, missing arrays, wrong
    shapes, unknown or repeated curve names, a frame count other than the
    annotation's, or keyframe rows that differ from the annotated curves by
    more than :data:`KEYFRAME_TOL_PX`.
    """
    from nnsf.frames.curves import SIDE_INDEX

    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "the tracker's curves.npz for this clip (run the tracker)")
    z = read_npz(path)
    for key in ("control", "curve_names"):
        if key not in z:
            raise InputError(path, key, "an array of that name (see TRACKS format)")
    control, names = z["control"], z["curve_names"]
    T = len(annotation.frames)
    if control.ndim != 4 or control.shape[3] != 2 or control.shape[0] != T or control.shape[2] < 2:
        raise InputError(path, "control", f"a float array (T={T} frames, C, P>=2, 2)",
                         f"shape {control.shape}")
    if not np.issubdtype(control.dtype, np.floating):
        raise InputError(path, "control", "a float array", str(control.dtype))
    if names.ndim != 1 or names.dtype.kind != "U" or len(names) != control.shape[1]:
        raise InputError(path, "curve_names", f"{control.shape[1]} curve names (unicode array)",
                         f"{names.dtype} array of shape {names.shape}")
    names = [str(n) for n in names]
    for n in names:
        if n not in SIDE_INDEX:
            raise InputError(path, "curve_names", "side-curve names like l_forearm.a", n)
    if len(set(names)) != len(names):
        raise InputError(path, "curve_names", "each curve once", names)
    P = control.shape[2]
    if "n_points" in z:
        n_points = np.asarray(z["n_points"])
        if (n_points.shape != (len(names),) or n_points.dtype.kind not in "iu"
                or (n_points < 2).any() or (n_points > P).any()):
            raise InputError(path, "n_points", f"{len(names)} integers in [2, {P}]", n_points.tolist())
    else:
        finite = np.isfinite(control).all(-1).any(0)
        n_points = np.where(finite.all(1), P, np.argmin(finite, axis=1))
    n_points = n_points.astype(np.int64)
    for k in annotation.keyframes:
        for c, n in enumerate(names):
            if n in k.curves:
                want = k.curves[n]
                got = control[k.frame, c, : n_points[c]]
                if got.shape != want.shape or not (np.abs(got - want) <= KEYFRAME_TOL_PX).all():
                    raise InputError(path, f"control[{k.frame}, {c}] ({n})",
                                     f"the annotated keyframe curve (within {KEYFRAME_TOL_PX} px)",
                                     np.round(got, 2).tolist())
    return control.astype(np.float64), names, n_points


def _keypoints_item(item: dict) -> dict:
    """Key points of one clip from its tracks (module-level, picklable)."""
    from nnsf.frames.annotation import read_annotation
    from nnsf.frames.keypoints import fit_keypoint_model, keypoints_from_curves

    clip = item["clip"]
    try:
        ann = read_annotation(Path(item["frames_dir"]) / item["folder"] / "annotation.json")
        if ann.clip != clip:
            raise InputError(ann.source, "clip", f"the clip id {clip!r} of index.csv", ann.clip)
        control, names, n_points = read_tracks(Path(item["tracks_dir"]) / clip / "curves.npz", ann)
        model = fit_keypoint_model(ann)
        kp = keypoints_from_curves(control, names, model, n_points)
        good = np.isfinite(kp).all(axis=(1, 2))
        if not good.any():
            missing = [j for j in range(kp.shape[1]) if not np.isfinite(kp[:, j]).any()]
            from nnsf.skeleton import JOINTS

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
    from nnsf.datasets import contract
    from nnsf.skeleton import FEATURE_COLUMNS
    from nnsf.stages import StageResult

    frames_dir, tracks_dir, out_dir = Path(frames_dir), Path(tracks_dir), Path(out_dir)
    index = read_index(frames_dir)
    items = [{"clip": r.clip, "folder": r.folder, "frames_dir": str(frames_dir),
              "tracks_dir": str(tracks_dir)} for r in index.itertuples()]
    results = _map(mapper, _keypoints_item, items)
    ok = [r for r in results if r["ok"]]
    failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
    if not ok:
        raise InputError(tracks_dir, "clips", "at least one clip with usable tracks; failed: "
                         + _failures(failed))
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
                         f"(the other {len(ok)} were written to {out_dir}): " + _failures(failed))
    return StageResult(
        params={"frames_dir": str(frames_dir), "tracks_dir": str(tracks_dir)},
        metrics={"clips": len(ok), "frames": len(table),
                 "dropped_frames": int(sum(r["dropped"] for r in ok)),
                 "characters": table["character"].nunique(), "motions": table["motion"].nunique()},
    )
