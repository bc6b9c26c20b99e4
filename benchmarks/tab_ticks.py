"""Paper-coloured ticks across the drawn lines where a joint turns a little (char1, layered mesh).

Turns both elbows, both knees or the neck of AnimatedDrawings' char1 by ±2,
±5 and ±10 degrees from the rest pose, renders each pose and counts the
joint-tab pixels that show the paper's colour inside the drawn lines (in the
morphological closing, 7 × 7 px, of the frame's dark pixels).  A tab that
shows the limb's fill through a sliver cuts the line with such a tick.
Needs ../shared/data.  Run: ``python benchmarks/tab_ticks.py`` (prints the
count per pose and the total).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.reshape import depth
from nnsf.reshape.character import load_animated_drawings
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import build_rig
from nnsf.skeleton import JOINT_INDEX as J

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
POSES = (("elbow", "wrist"), ("knee", "ankle"), ("neck", "head_top"))
DEGREES = (-10, -5, -2, 2, 5, 10)


def _turned(kp: np.ndarray, joint: str, end: str, deg: float) -> np.ndarray:
    """Key points ``(17, 2)`` with ``end`` turned about ``joint`` by ``deg`` (mirrored on the right side)."""
    out = kp.copy()
    sides = (("l_", 1.0), ("r_", -1.0)) if joint != "neck" else (("", 1.0),)
    for side, sgn in sides:
        a = np.radians(sgn * deg)
        rot = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        c = out[J[side + joint]]
        out[J[side + end]] = (out[J[side + end]] - c) @ rot.T + c
    return out


def main() -> None:
    ch = load_animated_drawings(DATA / "animated-drawings" / "characters" / "char1")
    rig = build_rig(ch, "ours", "layered", 800, 4)
    r = MeshRenderer.for_mesh(rig.mesh, ch)
    order = depth.default_order()
    total = 0
    for joint, end in POSES:
        counts = []
        for deg in DEGREES:
            V = rig.animate(_turned(ch.keypoints, joint, end, deg)[None])[0]
            img = r.render(V, order, background=(255, 255, 255))
            solid = r.render(V, order)[..., 3] > 127
            _, _, ids = r.maps(V, order)
            tab = solid & (ids >= 0) & (rig.mesh.layer[np.maximum(ids, 0)] >= 3)
            lum = img.astype(float) @ np.array([0.299, 0.587, 0.114])
            lines = cv2.morphologyEx((lum < 110).astype(np.uint8), cv2.MORPH_CLOSE,
                                     np.ones((7, 7), np.uint8)).astype(bool)
            counts.append(int((tab & (lum > 110) & lines).sum()))
        total += sum(counts)
        print(f"  {joint:6s} " + "  ".join(f"{d:+d}°: {c:3d}" for d, c in zip(DEGREES, counts)))
    print(f"char1, tab pixels of paper colour inside the drawn lines, {len(POSES) * len(DEGREES)} poses: {total}")


if __name__ == "__main__":
    main()
