"""Kenney's "Toon Characters" as drawings: key-point files and the ``idle`` frame.

For each character the ``idle`` frame is the drawing (texture = its RGBA
image, mask = alpha > 0, key points from the hand annotation
``tests/data/kenney/<character>.keypoints.json``, format ``nnsf.keypoints``
v1, :func:`read_keypoint_file`).  :mod:`nnsf.reshape.kenney_check` deforms
it to the annotated walk frames and scores the silhouettes.

Annotated idle key points that fall just off the silhouette (a wrist on
the outline) are moved to the nearest silhouette pixel, and the move is
reported (``snapped_px``).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.errors import InputError
from nnsf.io import read_json
from nnsf.reshape.character import Character
from nnsf.skeleton import JOINTS, N_JOINTS

CHARACTERS = ("female_adventurer", "female_person", "male_adventurer", "male_person", "robot", "zombie")
WALK = tuple(f"walk{i}" for i in range(8))


def read_keypoint_file(path) -> dict[str, np.ndarray]:
    """``{image name: (17, 2) key points}`` from an ``nnsf.keypoints`` v1 file."""
    path = Path(path)
    obj = read_json(path)
    if obj.get("format") != "nnsf.keypoints" or obj.get("version") != 1:
        raise InputError(path, "format", "'nnsf.keypoints' version 1",
                         f"{obj.get('format')!r} version {obj.get('version')!r}")
    frames = obj.get("frames")
    if not isinstance(frames, dict) or not frames:
        raise InputError(path, "frames", "an object mapping image names to key points")
    out = {}
    for name, kps in frames.items():
        if Path(name).is_absolute() or ".." in Path(name).parts:
            raise InputError(path, f"frames.{name}", "an image name inside the character's folder", name)
        if not isinstance(kps, dict):
            raise InputError(path, f"frames.{name}", "an object of 17 key points")
        arr = np.full((N_JOINTS, 2), np.nan)
        for j, jn in enumerate(JOINTS):
            v = kps.get(jn)
            if (not isinstance(v, list) or len(v) != 2
                    or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in v)):
                raise InputError(path, f"frames.{name}.{jn}", "[x, y] in pixels", v)
            arr[j] = v
        out[name] = arr
    return out


def _frame(folder: Path, names: dict, suffix: str, source) -> tuple[str, np.ndarray]:
    hits = [n for n in names if n.endswith(f"_{suffix}.png")]
    if len(hits) != 1:
        raise InputError(source, "frames", f"one annotated '*_{suffix}.png' frame", hits)
    img = cv2.imread(str(folder / hits[0]), cv2.IMREAD_UNCHANGED)
    if img is None or img.ndim != 3 or img.shape[2] != 4:
        raise InputError(folder / hits[0], "image", "an RGBA PNG")
    return hits[0], cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)


def snap_inside(mask: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Move points ``(k, 2)`` off the mask to the nearest mask pixel centre; returns (points, moves px)."""
    ys, xs = np.nonzero(mask)
    fg = np.column_stack([xs, ys]).astype(np.float64)
    pts = np.asarray(points, dtype=np.float64).copy()
    ij = np.rint(pts).astype(int)
    H, W = mask.shape
    ok = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
    inside = np.zeros(len(pts), bool)
    inside[ok] = mask[ij[ok, 1], ij[ok, 0]]
    moves = np.zeros(len(pts))
    for k in np.flatnonzero(~inside):
        d = np.linalg.norm(fg - pts[k], axis=1)
        moves[k] = d.min()
        pts[k] = fg[np.argmin(d)]
    return pts, moves


def kenney_character(name: str, image_root, annotation_dir) -> tuple[Character, np.ndarray]:
    """The ``idle`` drawing of a Kenney character with its hand-annotated key points, and the snap moves (px)."""
    ann = Path(annotation_dir) / f"{name}.keypoints.json"
    folder = Path(image_root) / name
    if not ann.is_file():
        raise InputError(ann, "file", "a hand key-point annotation (nnsf.keypoints v1)")
    if not folder.is_dir():
        raise InputError(folder, "folder", "the character's Kenney frames")
    kps = read_keypoint_file(ann)
    idle_name, idle = _frame(folder, kps, "idle", ann)
    mask = idle[..., 3] > 0
    rest, moves = snap_inside(mask, kps[idle_name])
    return Character(name=name, texture=idle, mask=mask, keypoints=rest, source=str(folder / idle_name)), moves
