"""Pipeline stages of contour tracking: track every clip, and evaluate the trackers.

``track_clips`` reads ``<frames_dir>/index.csv`` and each clip's frames and
``annotation.json`` (written by the render stage, or by hand for real
frames) and writes ``<out_dir>/<clip>/curves.npz`` in the TRACKS format
(``control (T, C, P, 2)``, ``curve_names``, ``n_points``, plus
``keyframes``).  ``evaluate_tracking`` runs the three trackers on the clips
that have ground truth (``truth.npz``) and writes ``reports/tracking.json``,
``reports/tracking.csv`` and ``reports/figures/tracking_overlay.png``.

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
from nnsf.io import atomic_dir, read_npz, write_csv, write_json, write_npz
from nnsf.params import checked, require

FRAMES_DIR = Path("data/frames")
TRACKS_DIR = Path("data/tracks")
REPORTS = Path("reports")
TRACKERS = ("ours", "agarwala", "lk")

#: params.yaml ``track.<key>`` -> (TrackOptions field, kind, lower bound)
OPTION_PARAMS: dict[str, tuple[str, str, float]] = {
    "w_velocity": ("velocity", "num", 0.0),
    "w_length": ("length", "num", 0.0),
    "w_length_anchor": ("length_anchor", "num", 0.0),
    "w_curvature": ("curvature", "num", 0.0),
    "w_edge": ("edge", "num", 0.0),
    "w_sketch": ("sketch", "num", 0.0),
    "w_colour": ("colour", "num", 0.0),
    "window": ("K", "int", 1),
    "samples": ("n_samples", "int", 3),
    "levels": ("levels", "int", 1),
    "max_iter": ("max_nfev", "int", 1),
}
#: the same for keys that may be absent (then 0: the term is off, as before they existed)
OPTIONAL_PARAMS: dict[str, tuple[str, str, float]] = {
    "w_slide": ("slide", "num", 0.0),
    "edge_gate": ("edge_gate", "num", 0.0),
}


def _map(mapper, fn, items) -> list:
    return list(map(fn, items)) if mapper is None else list(mapper(fn, items))


def track_options(params: dict) -> dict:
    """TrackOptions keyword arguments from the ``track`` section (InputError naming the field).

    Each value is checked by :func:`nnsf.params.require` against the params
    schema, the ranges ``nnsf check`` applies.
    """
    out = {name: require(params, f"track.{key}") for key, (name, _, _) in OPTION_PARAMS.items()}
    out["init"] = require(params, "track.init")
    out["lk_end"] = require(params, "track.lk_end")
    for key, (name, _, _) in OPTIONAL_PARAMS.items():     # absent in older params files: off
        out[name] = checked(params, f"track.{key}", 0.0)
    return out


def _method(params: dict) -> str:
    return require(params, "track.method")  # one of TRACKERS (the params schema)


def _failures(failed: dict) -> str:
    return ", ".join(failed) + ". " + " | ".join(f"{c}: {e}" for c, e in failed.items())


def _load(item: dict):
    """(annotation, frames) of one indexed clip; InputError on bad input."""
    from nnsf.frames.annotation import read_annotation
    from nnsf.frames.clips import read_clip

    folder = Path(item["frames_dir"]) / item["folder"]
    ann = read_annotation(folder / "annotation.json")
    if ann.clip != item["clip"]:
        raise InputError(ann.source, "clip", f"the clip id {item['clip']!r} of index.csv", ann.clip)
    return ann, read_clip(folder, ann)


# --------------------------------------------------------------------------- track_clips
def _track_item(item: dict) -> dict:
    """Track one clip and write its curves.npz (module-level, picklable)."""
    from nnsf.track.solve import keyframe_curves, track_clip

    clip = item["clip"]
    out = Path(item["out"]) / clip
    try:
        ann, frames = _load(item)
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

    Reads ``track.method`` and the ``track`` options (:func:`track_options`).
    Writes ``<out_dir>/<clip>/curves.npz`` (TRACKS format) for every clip that
    succeeds (the folder is swapped in complete); failed clips are listed in
    ``<out_dir>/failed.json`` and named in the InputError raised at the end.
    """
    from nnsf.frames.stage import read_index
    from nnsf.stages import StageResult

    method = _method(params)
    options = track_options(params)
    frames_dir, out_dir = Path(frames_dir), Path(out_dir)
    index = read_index(frames_dir)
    with atomic_dir(out_dir) as tmp:
        items = [{"clip": r.clip, "folder": r.folder, "frames_dir": str(frames_dir),
                  "out": str(tmp), "method": method, "options": options}
                 for r in index.itertuples()]
        results = _map(mapper, _track_item, items)
        failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
        if failed:
            write_json(tmp / "failed.json", failed)
    ok = [r for r in results if r["ok"]]
    if failed:
        raise InputError(frames_dir, "clips", f"every clip tracked; {len(failed)} failed (the other "
                         f"{len(ok)} were written to {out_dir}): " + _failures(failed))
    return StageResult(
        params={"track_method": method, **{f"track_{k}": v for k, v in options.items()}},
        metrics={"clips": len(ok), "frames": int(sum(r["frames"] for r in ok)),
                 "rows_without_estimate": int(sum(r["rows_without_estimate"] for r in ok))})


# --------------------------------------------------------------------------- evaluate_tracking
def _evaluate_item(item: dict) -> dict:
    """All metrics of one (clip, tracker) pair (module-level, picklable)."""
    from nnsf.frames.keypoints import fit_keypoint_model, keypoints_from_curves
    from nnsf.skeleton import JOINT_INDEX
    from nnsf.track.metrics import curve_errors, edit_ratio, length_ratio, pck, reverse_errors

    clip, method = item["clip"], item["method"]
    try:
        ann, frames = _load(item)
        truth = read_npz(Path(item["frames_dir"]) / item["folder"] / "truth.npz")
        side_names = [str(n) for n in truth["side_names"]]
        res = edit_ratio(frames, ann, truth["sides"], side_names, method, tol=item["tol"],
                         max_edits=item["max_edits"], **item["options"])
        names, control = res["names"], res["tracked"]
        idx = [side_names.index(n) for n in names]
        inb = np.ones(len(frames), bool)
        inb[ann.keyframe_indices] = False
        err, vis = curve_errors(control[inb], truth["sides"][inb][:, idx],
                                visible=truth["visible"][inb][:, idx])
        rev = reverse_errors(control[inb], truth["sides"][inb][:, idx])
        model = fit_keypoint_model(ann)
        kp = keypoints_from_curves(control, names, model)
        tk = truth["keypoints"]
        torso = np.linalg.norm(tk[:, JOINT_INDEX["thorax"]] - tk[:, JOINT_INDEX["pelvis"]], axis=-1)
        score = pck(kp[inb], tk[inb], torso[inb], 0.05)
        return {"ok": True, "clip": clip, "method": method, "errors": err[np.isfinite(err)],
                "errors_visible": err[np.isfinite(err) & vis], "errors_rev": rev[np.isfinite(rev)],
                "length_ratio": length_ratio(control, ann.keyframe_indices), "pck": score,
                "edit_ratio": res["edit_ratio"], "edits": res["edits"],
                "control_points": res["control_points"], "capped_curves": res["capped_curves"],
                "corrected_frames": res["corrected_frames"], "rounds": res["rounds"],
                "control": control if item["keep"] else None, "names": names}
    except InputError as exc:
        return {"ok": False, "clip": clip, "method": method, "error": str(exc)}


def evaluate_tracking(params: dict, frames_dir=FRAMES_DIR, reports=REPORTS, mapper=None):
    """Compare the three trackers on the rendered clips with ground truth (docs/method.md §15.6).

    Reads ``track`` options, ``track.eval_clips`` (how many clips, in index
    order, that have a ``truth.npz``), ``track.edit_tol_px`` and
    ``track.max_edits``.  Writes ``<reports>/tracking.json`` (per tracker:
    mean_px, p95_px (tracked -> truth), mean_px_rev, p95_px_rev (truth ->
    tracked), mean_px_sym, p95_px_sym (both; see
    :func:`nnsf.track.metrics.symmetric_summary`), mean_px_visible,
    p95_px_visible, length_ratio (in-between over keyframe curve length,
    mean over clips), pck, edit_ratio, clips),
    ``<reports>/tracking.csv`` (per clip × tracker) and
    ``<reports>/figures/tracking_overlay.png`` (first evaluated clip).
    """
    from nnsf.frames.stage import read_index
    from nnsf.stages import StageResult
    from nnsf.track.figures import tracking_overlay
    from nnsf.track.metrics import error_summary, symmetric_summary

    options = track_options(params)
    n_clips = require(params, "track.eval_clips")      # each checked by the params schema
    tol = require(params, "track.edit_tol_px")
    max_edits = require(params, "track.max_edits")
    frames_dir, reports = Path(frames_dir), Path(reports)
    index = read_index(frames_dir)
    rows = [r for r in index.itertuples() if (frames_dir / r.folder / "truth.npz").is_file()]
    rows = rows[:n_clips]
    if not rows:
        raise InputError(frames_dir / "index.csv", "clips",
                         "at least one clip with ground truth (truth.npz) to evaluate tracking")
    items = [{"clip": r.clip, "folder": r.folder, "frames_dir": str(frames_dir), "method": m,
              "options": options, "tol": float(tol), "max_edits": max_edits, "keep": i == 0}
             for i, r in enumerate(rows) for m in TRACKERS]
    results = _map(mapper, _evaluate_item, items)
    ok = [r for r in results if r["ok"]]
    failed = {f"{r['clip']} ({r['method']})": r["error"] for r in results if not r["ok"]}
    table, summary = [], {}
    for m in TRACKERS:
        mine = [r for r in ok if r["method"] == m]
        for r in mine:
            table.append({"clip": r["clip"], "tracker": m,
                          **symmetric_summary(r["errors"], r["errors_rev"]),
                          **{k + "_visible": v for k, v in error_summary(r["errors_visible"]).items()},
                          "length_ratio": r["length_ratio"], "pck": r["pck"],
                          "edit_ratio": r["edit_ratio"], "edits": r["edits"],
                          "control_points": r["control_points"],
                          "capped_curves": r["capped_curves"],
                          "corrected_frames": r["corrected_frames"], "rounds": r["rounds"]})
        if not mine:
            continue
        allerr = np.concatenate([r["errors"] for r in mine])
        allvis = np.concatenate([r["errors_visible"] for r in mine])
        allrev = np.concatenate([r["errors_rev"] for r in mine])
        edits = sum(r["edits"] for r in mine)
        slots = sum(r["control_points"] for r in mine)
        summary[m] = {**symmetric_summary(allerr, allrev),
                      **{k + "_visible": v for k, v in error_summary(allvis).items()},
                      "length_ratio": float(np.mean([r["length_ratio"] for r in mine])),
                      "pck": float(np.mean([r["pck"] for r in mine])),
                      "edit_ratio": edits / slots if slots else float("nan"),
                      "edits": edits, "corrected_frames": sum(r["corrected_frames"] for r in mine),
                      "rounds": max(r["rounds"] for r in mine),
                      "clips": len(mine)}
    figure = reports / "figures" / "tracking_overlay.png"
    keep = [r for r in ok if r["control"] is not None]
    artifacts = []
    if keep:
        first = rows[0]
        from nnsf.frames.annotation import read_annotation
        from nnsf.frames.clips import read_clip

        folder = frames_dir / first.folder
        ann = read_annotation(folder / "annotation.json")
        frames = read_clip(folder, ann)
        truth = read_npz(folder / "truth.npz")
        side_names = [str(n) for n in truth["side_names"]]
        names = keep[0]["names"]
        true_sides = truth["sides"][:, [side_names.index(n) for n in names]]
        show = _frames_to_show(len(frames), ann.keyframe_indices)
        tracking_overlay(frames, {r["method"]: r["control"] for r in keep}, true_sides, show,
                         figure, title=f"{first.clip}: tracked side contours between keyframes "
                         f"{ann.keyframe_indices}")
        artifacts.append(figure)
    write_json(reports / "tracking.json", {"trackers": summary, "failed": failed,
                                           "clips": [r.clip for r in rows],
                                           "edit_tol_px": float(tol), "max_edits": max_edits})
    write_csv(reports / "tracking.csv", pd.DataFrame(table))
    if failed:
        raise InputError(frames_dir, "clips", f"every clip evaluated; {len(failed)} failed: "
                         + _failures(failed))
    metrics = {f"{m}_{k}": v for m, s in summary.items() for k, v in s.items() if k != "clips"}
    return StageResult(params={"track_eval_clips": n_clips, "track_edit_tol_px": tol,
                               "track_max_edits": max_edits},
                       metrics=metrics, artifacts=[reports / "tracking.json",
                                                   reports / "tracking.csv", *artifacts])


def _frames_to_show(T: int, keyframes: list[int], n: int = 4) -> list[int]:
    """``n`` in-between frames spread over the clip, each far from keyframes (mid-interval)."""
    keys = sorted(keyframes)
    mids = [(a + b) // 2 for a, b in zip(keys[:-1], keys[1:]) if b - a >= 2]
    if not mids:
        return list(np.linspace(0, T - 1, n).round().astype(int))
    pick = np.linspace(0, len(mids) - 1, min(n, len(mids))).round().astype(int)
    return [mids[i] for i in dict.fromkeys(pick)]
