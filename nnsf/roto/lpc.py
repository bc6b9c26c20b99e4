"""Tracking on pixel art: the LPC body sprite sheets' walk rows, scored against alpha silhouettes.

The sheets (832×1344 RGBA, 64×64 tiles) stay in the shared data folder; the
keyframe annotations are hand-made files ``<body>.annotation.json`` (format
v1) in ``tests/data/lpc/``, whose frame names ``r<row>c<col>.png`` name the
sheet tiles (row 10 = walk facing down, columns 0-8).  Tiles are composited
over white and tracked, and scored as the Kenney frames are
(:mod:`nnsf.roto.real`: outline samples within ``tol`` px of the
silhouette, coverage, length ratio).  The annotations only hold limb sides
that lie on the silhouette (the outer sides of the arms, both sides of the
legs below the crotch): on 64×64 pixel art the inner arm sides lie over the
torso, where the silhouette says nothing.
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
from nnsf.roto.real import REPORTED, score_trackers, write_silhouette_report

#: px from the silhouette that count as on it.  Why not Kenney's 1.5: the annotated control
#: points sit on the centres of outline pixels, 0.5 px inside the alpha boundary (0.7 on a
#: diagonal), and the limbs of these 64-px sprites move 1-2 px a frame, so a curve left a
#: whole pixel off its outline (1.5 px from the boundary) still counted at 1.5 px: the
#: keyframes interpolated with no tracking scored 0.915.  At 1.0 px a sample counts only on
#: the right outline pixel; the keyframes themselves still score 1.0.
TOL = 1.0
BODIES = ("male", "female", "male_orc", "female_orc", "male_skeleton")
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


def track_lpc(data_root, annotations_dir, methods=TRACKERS, bodies=BODIES,
              tol: float = 1.5, **options) -> tuple[pd.DataFrame, dict]:
    """Run the trackers on the annotated walk rows; the table and tracks as :func:`nnsf.roto.real.track_kenney`."""
    rows, tracked = [], {}
    for body in bodies:
        path = Path(annotations_dir) / f"{body}.annotation.json"
        if not path.is_file():
            continue
        ann = read_annotation(path)
        frames, alpha = read_tiles(Path(data_root) / f"{body}.png", ann.frames)
        score_trackers(body, ann, frames, alpha, methods, tol, options, rows, tracked)
    return pd.DataFrame(rows), tracked


def lpc_report(data_root, annotations_dir, out_dir, tol: float = TOL, **options) -> dict:
    """Track the LPC walk rows with the three trackers and write the report files.

    Writes ``<out_dir>/roto_lpc.csv``, ``<out_dir>/roto_lpc.json``
    (the layout of ``roto_kenney.json``) and
    ``<out_dir>/figures/roto_lpc.png`` (the first body, four in-between
    frames, enlarged ×6).  Returns the JSON summary.
    """
    data_root, out_dir = Path(data_root), Path(out_dir)
    if not data_root.is_dir():
        raise InputError(data_root, "folder", "the lpc-bodies folder of the shared data")
    table, tracked = track_lpc(data_root, annotations_dir, methods=REPORTED, tol=tol, **options)
    return write_silhouette_report(
        table, tracked, tol, annotations_dir, out_dir, "roto_lpc",
        "at least one <body>.annotation.json for a sheet in " + str(data_root),
        lambda name, ann: read_tiles(data_root / f"{name}.png", ann.frames)[0], "LPC, walk row", upscale=6)
