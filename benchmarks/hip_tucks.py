"""A thigh drawn in front of the body: how much of it lies over the body at the hip, and what the
hip tucks cost per frame.

Turns both legs of each AnimatedDrawings character about their hips by ±15, ±30 and ±45 degrees
(the body stays where it is), renders each pose with the default layered mesh, the body first in
the order (both thighs in front of it), and counts thigh pixels inside the body's own rest region
(7 px in from its edge): the straight top edge of a turned thigh laid over the belly.  Each pose is
rendered with the hip tucks (docs/method.md §13.1, "Hips tucked under the body") and without them
(the renderer's tucks emptied), alternated, and the median render time of each is printed.

Needs ../shared/data.  Run: ``python benchmarks/hip_tucks.py``.
"""
from __future__ import annotations

import time
from pathlib import Path

import cv2
import numpy as np

from nnsf.reshape.formats import read_character
from nnsf.reshape.parts import PART_INDEX, PARTS
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import build_rig
from nnsf.skeleton import JOINT_INDEX as J

ROOT = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters"
TORSO = PART_INDEX["torso"]
THIGHS = (PART_INDEX["l_thigh"], PART_INDEX["r_thigh"])


def legs_turned(kp: np.ndarray, deg: float) -> np.ndarray:
    """Key points ``(17, 2)`` with both legs turned ``deg`` degrees about their hips (mirrored)."""
    out = kp.copy()
    for side, sgn in (("l", 1.0), ("r", -1.0)):
        c, a = kp[J[f"{side}_hip"]], np.radians(sgn * deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        for j in ("knee", "ankle"):
            out[J[f"{side}_{j}"]] = (kp[J[f"{side}_{j}"]] - c) @ R.T + c
    return out


def main() -> None:
    if not ROOT.is_dir():
        raise SystemExit(f"needs {ROOT}")
    order = [TORSO] + [p for p in range(len(PARTS)) if p != TORSO]
    print("character | thigh px over the body: tucked / not | render ms: tucked / not")
    total = np.zeros(2)
    times = [[], []]
    for name in ("char1", "char2", "char3", "char4", "char5"):
        ch = read_character(str(ROOT / name))
        rig = build_rig(ch, "ours", "layered", 800, 4)
        body = cv2.erode((rig.mesh.labels == 0).astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
        plain = MeshRenderer.for_mesh(rig.mesh, ch)
        tucked = MeshRenderer.for_mesh(rig.mesh, ch)
        plain._tucked = {}
        over = np.zeros(2)
        ms = [[], []]
        for deg in (-45.0, -30.0, -15.0, 15.0, 30.0, 45.0):
            V = rig.animate(legs_turned(ch.keypoints, deg)[None])[0]
            for _ in range(3):
                for i, r in enumerate((tucked, plain)):
                    t0 = time.perf_counter()
                    _, lab = r.render_labelled(V, order, labels=True)
                    ms[i].append(1e3 * (time.perf_counter() - t0))
            for i, r in enumerate((tucked, plain)):
                _, lab = r.render_labelled(V, order, labels=True)
                over[i] += int((np.isin(lab, THIGHS) & body).sum())
        total += over
        for i in range(2):
            times[i] += ms[i]
        print(f"{name} | {over[0]:,.0f} / {over[1]:,.0f} | {np.median(ms[0]):.1f} / {np.median(ms[1]):.1f}")
    print(f"all | {total[0]:,.0f} / {total[1]:,.0f} | {np.median(times[0]):.1f} / {np.median(times[1]):.1f} "
          f"(ratio {np.median(times[0]) / np.median(times[1]):.3f})")


if __name__ == "__main__":
    main()
