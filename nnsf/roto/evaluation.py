"""The ``roto_eval`` stage: ours, Agarwala's and Lucas-Kanade tracking scored against the rendered ground truth (docs/method.md §15.6).

:func:`evaluate_tracking` runs the three trackers on the clips that have
ground truth (``truth.npz``) and writes ``reports/roto_eval.json``,
``reports/roto_eval.csv`` and ``reports/figures/roto_overlay.png``
(the paper's Fig. 5): point-to-curve error, PCK of the key points derived
from the tracked curves (Eq. 2-3), the simulated user's edit ratio (Fig. 4a).
It fans out over (clip, tracker) pairs through ``mapper``; ``roto_eval``
publishes the files as one set.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.frames.clips import read_clip, read_index, read_truth
from nnsf.io import write_csv, write_json
from nnsf.params import TRACKERS, require
from nnsf.pipeline import FRAMES_DIR, REPORTS, StageResult, failures, map_items
from nnsf.publish import publish_stage
from nnsf.skeleton import JOINT_INDEX
from nnsf.roto.figures import roto_overlay
from nnsf.roto.keypoints import fit_keypoint_model, keypoints_from_curves
from nnsf.roto.metrics import curve_errors, edit_ratio, error_summary, length_ratio, pck, reverse_errors, symmetric_summary
from nnsf.roto.options import track_options
from nnsf.roto.stage import load_clip

def _evaluate_item(item: dict) -> dict:
    """All metrics of one (clip, tracker) pair (module-level, picklable)."""
    clip, method = item["clip"], item["method"]
    try:
        ann, frames = load_clip(item)
        truth = read_truth(Path(item["frames_dir"]) / item["folder"])
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

    Reads ``track`` options, ``roto.eval_clips`` (how many clips, in index
    order, that have a ``truth.npz``), ``roto.edit_tol_px`` and
    ``roto.max_edits``.  Writes ``<reports>/roto_eval.json`` (per tracker:
    mean_px, p95_px (tracked -> truth), mean_px_rev, p95_px_rev (truth ->
    tracked), mean_px_sym, p95_px_sym (both; see
    :func:`nnsf.roto.metrics.symmetric_summary`), mean_px_visible,
    p95_px_visible, length_ratio (in-between over keyframe curve length,
    mean over clips), pck, edit_ratio, clips),
    ``<reports>/roto_eval.csv`` (per clip × tracker) and
    ``<reports>/figures/roto_overlay.png`` (first evaluated clip).
    """
    options = track_options(params)
    n_clips = require(params, "roto.eval_clips")      # each checked by the params schema
    tol = require(params, "roto.edit_tol_px")
    max_edits = require(params, "roto.max_edits")
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
    results = map_items(mapper, _evaluate_item, items)
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
    figure = reports / "figures" / "roto_overlay.png"
    keep = [r for r in ok if r["control"] is not None]
    artifacts = []
    if keep:
        first = rows[0]

        folder = frames_dir / first.folder
        ann = read_annotation(folder / "annotation.json")
        frames = read_clip(folder, ann)
        truth = read_truth(folder)
        side_names = [str(n) for n in truth["side_names"]]
        names = keep[0]["names"]
        true_sides = truth["sides"][:, [side_names.index(n) for n in names]]
        show = _frames_to_show(len(frames), ann.keyframe_indices)
        roto_overlay(frames, {r["method"]: r["control"] for r in keep}, true_sides, show,
                         figure, title=f"{first.clip}: tracked side contours between keyframes "
                         f"{ann.keyframe_indices}")
        artifacts.append(figure)
    write_json(reports / "roto_eval.json", {"trackers": summary, "failed": failed,
                                           "clips": [r.clip for r in rows],
                                           "edit_tol_px": float(tol), "max_edits": max_edits})
    write_csv(reports / "roto_eval.csv", pd.DataFrame(table))
    if failed:
        raise InputError(frames_dir, "clips", f"every clip evaluated; {len(failed)} failed: "
                         + failures(failed))
    metrics = {f"{m}_{k}": v for m, s in summary.items() for k, v in s.items() if k != "clips"}
    return StageResult(params={"track_eval_clips": n_clips, "track_edit_tol_px": tol,
                               "track_max_edits": max_edits},
                       metrics=metrics, artifacts=[reports / "roto_eval.json",
                                                   reports / "roto_eval.csv", *artifacts])


def _frames_to_show(T: int, keyframes: list[int], n: int = 4) -> list[int]:
    """``n`` in-between frames spread over the clip, each far from keyframes (mid-interval)."""
    keys = sorted(keyframes)
    mids = [(a + b) // 2 for a, b in zip(keys[:-1], keys[1:]) if b - a >= 2]
    if not mids:
        return list(np.linspace(0, T - 1, n).round().astype(int))
    pick = np.linspace(0, len(mids) - 1, min(n, len(mids))).round().astype(int)
    return [mids[i] for i in dict.fromkeys(pick)]


def roto_eval(params: dict, frames_dir=FRAMES_DIR, reports=REPORTS, mapper=None) -> StageResult:
    """Score ours, Agarwala's and Lucas-Kanade tracking against the rendered ground truth (docs/method.md §15.6).

    See :func:`evaluate_tracking`: ``reports/roto_eval.json``,
    ``reports/roto_eval.csv``, ``reports/figures/roto_overlay.png``.
    """
    return publish_stage("roto_eval", reports, "roto_eval.json",
                         lambda out: evaluate_tracking(params, frames_dir=frames_dir, reports=out, mapper=mapper))
