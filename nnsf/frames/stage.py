"""The ``frames`` stage: render clips with their ground truth, and read a frame set's index.

``render_frames`` writes ``data/frames/<clip>/`` (frames, ``truth.npz``,
``annotation.json``) and ``data/frames/index.csv`` (:func:`read_index`).
The tracker (:mod:`nnsf.roto.stage`) reads them, writes
``data/tracks/<clip>/curves.npz`` and derives the key points (Eq. 2-3).

The stage fans out over clips through ``mapper``; a clip that fails on bad input is
reported by name and left out, the other clips are written, and the stage
then raises one :class:`InputError` naming the failed clips.  A failed clip
leaves no folder behind, and outputs are swapped in only when complete.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import pandas as pd

from nnsf.errors import InputError
from nnsf.io import atomic_dir, write_csv, write_json
from nnsf.params import require, source_of
from nnsf.pipeline import FRAMES_DIR, StageResult, failures, map_items
from nnsf.datasets.synthetic import CHARACTERS, MOTIONS
from nnsf.frames.render import render_clip
from nnsf.frames.clips import INDEX_COLUMNS


def _int_param(params, key, lo, hi=None) -> int:
    v = require(params, key)
    if not isinstance(v, int) or isinstance(v, bool) or v < lo or (hi is not None and v > hi):
        rng = f"an integer in [{lo}, {hi}]" if hi is not None else f"an integer >= {lo}"
        raise InputError(source_of(params), key, rng, v)
    return v


def frames_params(params: dict) -> dict:
    """The checked ``frames`` section plus ``seed`` (InputError naming the field otherwise)."""
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
    p = frames_params(params)
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        items = [{"clip": f"{c}-{m}-{v:02d}", "character": c, "motion": m, "variation": v,
                  "seed": p["seed"], "frames": p["frames"], "size": p["size"],
                  "keyframe_every": p["keyframe_every"], "control_points": p["control_points"],
                  "folder": str(tmp / f"{c}-{m}-{v:02d}")}
                 for c in p["characters"] for m in p["motions"] for v in range(p["clips_per_cell"])]
        results = map_items(mapper, _render_item, items)
        ok = [r for r in results if r["ok"]]
        failed = {r["clip"]: r["error"] for r in results if not r["ok"]}
        index = pd.DataFrame({"clip": [r["clip"] for r in ok], "character": [r["character"] for r in ok],
                              "motion": [r["motion"] for r in ok], "folder": [r["clip"] for r in ok],
                              "frames": [r["frames"] for r in ok]}, columns=list(INDEX_COLUMNS))
        write_csv(tmp / "index.csv", index)
        if failed:
            write_json(tmp / "failed.json", failed)
    if failed:
        raise InputError(out_dir, "clips", "every clip rendered; failed: " + failures(failed))
    fit = max((r["max_fit_error_px"] for r in ok), default=0.0)
    return StageResult(
        params={f"frames_{k}": (",".join(v) if isinstance(v, list) else v) for k, v in p.items()},
        metrics={"clips": len(ok), "frames": int(index["frames"].sum()),
                 "max_control_fit_error_px": fit},
    )


