"""Tracking on pixel art: LPC sprite sheets, scored against their alpha silhouettes.

An LPC sheet (the Liberated Pixel Cup layout: 64×64 tiles, one animation row
per direction) is one RGBA PNG per body, ``<data>/<body>.png``; the keyframe
annotations are hand-made files ``<annotations>/<body>.annotation.json``
(format v1) whose frame names ``r<row>c<col>.png`` name the sheet tiles, and
every annotated body is tracked.  Tiles are composited over white, tracked,
and scored as other real frames are (:mod:`nnsf.roto.real`: outline samples
within ``tol`` px of the silhouette, coverage, length ratio).  Annotations of
such small sprites hold only the limb sides that lie on the silhouette: the
inner sides of the arms lie over the torso, where the silhouette says nothing.
"""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.io import read_image
from nnsf.params import TRACKERS
from nnsf.roto.real import REPORTED, annotated_names, score_trackers, write_silhouette_report

#: px from the silhouette that count as on it.  Why less than the 1.5 of larger frames: the
#: annotated control points sit on the centres of outline pixels, 0.5 px inside the alpha
#: boundary (0.7 on a diagonal), and the limbs of 64-px sprites move 1-2 px a frame, so at
#: 1.5 px a curve left a whole pixel off its outline still counts as on it, and the keyframes
#: interpolated with no tracking score nearly as well as a tracker.  At 1.0 px a sample counts
#: only on the right outline pixel; the keyframes themselves still score 1.0.
TOL = 1.0
TILE = 64
_NAME = re.compile(r"^r(\d+)c(\d+)\.png$")


def read_tiles(sheet_path, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Tiles ``r<row>c<col>.png`` of a sprite sheet: RGB over white (T, 64, 64, 3) uint8, alpha (T, 64, 64)."""
    sheet_path = Path(sheet_path)
    img = read_image(sheet_path)
    if img.ndim != 3 or img.shape[2] != 4:
        raise InputError(sheet_path, "file", "a readable RGBA sprite sheet PNG")
    rgb, alpha = [], []
    for n in names:
        m = _NAME.match(n)
        if not m:
            raise InputError(sheet_path, f"frame {n!r}", "a tile name r<row>c<col>.png")
        r, c = int(m.group(1)), int(m.group(2))
        t = img[r * TILE:(r + 1) * TILE, c * TILE:(c + 1) * TILE]
        if t.shape[:2] != (TILE, TILE):
            raise InputError(sheet_path, f"frame {n!r}", f"a tile inside the {img.shape[1]}×"
                             f"{img.shape[0]} sheet")
        a = t[..., 3:4].astype(np.float32) / 255.0
        comp = np.rint(t[..., :3].astype(np.float32) * a + 255.0 * (1 - a)).astype(np.uint8)
        rgb.append(cv2.cvtColor(comp, cv2.COLOR_BGR2RGB))
        alpha.append(t[..., 3])
    return np.stack(rgb), np.stack(alpha)


def track_lpc(data_root, annotations_dir, methods=TRACKERS, names=None,
              tol: float = TOL, **options) -> tuple[pd.DataFrame, dict]:
    """Run the trackers on the annotated sheet rows (default: every annotated body); the table
    and tracks as :func:`nnsf.roto.real.track_frames`."""
    rows, tracked = [], {}
    for body in annotated_names(annotations_dir) if names is None else names:
        ann = read_annotation(Path(annotations_dir) / f"{body}.annotation.json")
        frames, alpha = read_tiles(Path(data_root) / f"{body}.png", ann.frames)
        score_trackers(body, ann, frames, alpha, methods, tol, options, rows, tracked)
    return pd.DataFrame(rows), tracked


def lpc_report(data_root, annotations_dir, out_dir, stem: str = "roto_lpc", tol: float = TOL,
               **options) -> dict:
    """Track the annotated sheet rows with the three trackers and write the report files.

    Writes ``<out_dir>/<stem>.csv``, ``<out_dir>/<stem>.json`` (the layout of
    :func:`nnsf.roto.real.frames_report`) and ``<out_dir>/figures/<stem>.png``
    (the first body, four in-between frames, enlarged ×6).  Returns the JSON
    summary.
    """
    data_root, out_dir = Path(data_root), Path(out_dir)
    if not data_root.is_dir():
        raise InputError(data_root, "folder", "a folder of LPC sprite sheets <body>.png")
    table, tracked = track_lpc(data_root, annotations_dir, methods=REPORTED, tol=tol, **options)
    return write_silhouette_report(
        table, tracked, tol, annotations_dir, out_dir, stem,
        "at least one <body>.annotation.json for a sheet in " + str(data_root),
        lambda name, ann: read_tiles(data_root / f"{name}.png", ann.frames)[0], "LPC, walk row", upscale=6)
