"""Write the LPC walk-row keyframe annotations of this folder from the hand-read landmarks below.

Run from the repository root:  python tests/data/lpc/make_annotations.py ../shared/data/lpc-bodies

The landmarks are ours, read by hand off ×9 views of each sheet's "walk, facing down" row
(row 10, frames 0 and 8) with a pixel grid: for every limb side, the rows where it starts,
bends (elbow, knee) and ends.  The script only reads, on each of four rows spread over a curve,
the x of the outline pixel of that side (the first opaque pixel scanning from the named
direction), so every control point sits on the centre of a drawn outline pixel.  Coordinates:
px of the 64×64 tile, pixel centres at integers (as the tracker).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import cv2
import numpy as np

ROW = 10                   # walk, facing down (the character faces the viewer: its right is image-left)
KEYFRAMES = (0, 8)
#: body -> frame -> landmarks (rows, px):
#:   arm: (top, elbow, bottom) of each arm's outer side, legs: (top, knee, bottom) of the outer
#:   sides, inner: first row of the gap between the legs, mid: an x inside that gap
LANDMARKS = {
    "male": {0: {"r_arm": (37, 42, 48), "l_arm": (37, 42, 48), "r_leg": (51, 55, 60),
                 "l_leg": (51, 55, 60), "inner": 52, "mid": 31},
             8: {"r_arm": (37, 42, 47), "l_arm": (37, 42, 49), "r_leg": (51, 56, 61),
                 "l_leg": (52, 55, 59), "inner": 52, "mid": 31}},
    "female": {0: {"r_arm": (39, 44, 49), "l_arm": (39, 44, 49), "r_leg": (51, 55, 60),
                   "l_leg": (51, 55, 60), "inner": 52, "mid": 31},
               8: {"r_arm": (39, 44, 48), "l_arm": (39, 44, 50), "r_leg": (51, 56, 61),
                   "l_leg": (52, 55, 59), "inner": 52, "mid": 31}},
    "male_orc": {0: {"r_arm": (37, 42, 49), "l_arm": (37, 42, 49), "r_leg": (51, 55, 60),
                     "l_leg": (51, 55, 60), "inner": 52, "mid": 31},
                 8: {"r_arm": (37, 42, 48), "l_arm": (37, 42, 50), "r_leg": (51, 56, 61),
                     "l_leg": (52, 55, 59), "inner": 52, "mid": 31}},
    "female_orc": {0: {"r_arm": (39, 44, 49), "l_arm": (39, 44, 49), "r_leg": (51, 55, 60),
                       "l_leg": (51, 55, 60), "inner": 52, "mid": 31},
                   8: {"r_arm": (39, 44, 48), "l_arm": (39, 44, 50), "r_leg": (51, 56, 61),
                       "l_leg": (52, 55, 59), "inner": 52, "mid": 31}},
    "male_skeleton": {0: {"r_arm": (37, 42, 48), "l_arm": (37, 42, 48), "r_leg": (51, 55, 60),
                          "l_leg": (51, 55, 60), "inner": 52, "mid": 31},
                      8: {"r_arm": (37, 42, 47), "l_arm": (37, 42, 49), "r_leg": (51, 56, 61),
                          "l_leg": (52, 55, 59), "inner": 52, "mid": 31}},
}


def tile(sheet: np.ndarray, col: int) -> np.ndarray:
    return sheet[ROW * 64:(ROW + 1) * 64, col * 64:(col + 1) * 64, 3]


def edge_x(alpha: np.ndarray, y: int, side: str, start: int) -> float:
    """x of the first opaque pixel on row y scanning from ``start`` leftwards or rightwards."""
    row = alpha[y] > 127
    if side == "right":          # scanning leftwards: the right-hand outline of a part
        xs = np.flatnonzero(row[: start + 1])
        return float(xs.max())
    xs = np.flatnonzero(row[start:]) + start
    return float(xs.min())


def curve(alpha, rows, side, start):
    ys = np.round(np.linspace(rows[0], rows[1], 4)).astype(int)
    return [[edge_x(alpha, int(y), side, start), float(y)] for y in ys]


def keyframe(alpha: np.ndarray, m: dict) -> dict:
    c = {}
    for g, lr in (("r", ("left", 0)), ("l", ("right", 63))):
        a, leg = m[f"{g}_arm"], m[f"{g}_leg"]
        c[f"{g}_upper_arm.a"] = curve(alpha, (a[0], a[1]), *lr)
        c[f"{g}_forearm.a"] = curve(alpha, (a[1], a[2]), *lr)
        c[f"{g}_thigh.a"] = curve(alpha, (leg[0], leg[1]), *lr)
        c[f"{g}_shin.a"] = curve(alpha, (leg[1], leg[2]), *lr)
        inner = ("right", m["mid"]) if g == "r" else ("left", m["mid"] + 1)
        c[f"{g}_thigh.b"] = curve(alpha, (m["inner"], leg[1]), *inner)
        c[f"{g}_shin.b"] = curve(alpha, (leg[1], leg[2]), *inner)
    return c


def main(root: Path) -> None:
    out = Path(__file__).resolve().parent
    for body, frames in LANDMARKS.items():
        sheet = cv2.imread(str(root / f"{body}.png"), cv2.IMREAD_UNCHANGED)
        ann = {"format": "nnsf.annotation", "version": 1, "clip": f"lpc_{body}_walk_down",
               "character": body, "motion": "walk",
               "frames": [f"r{ROW}c{c}.png" for c in range(9)], "image_size": [64, 64],
               "keyframes": [{"frame": f, "curves": keyframe(tile(sheet, f), frames[f])}
                             for f in KEYFRAMES]}
        (out / f"{body}.annotation.json").write_text(json.dumps(ann, indent=1) + "\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]))
