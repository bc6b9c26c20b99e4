"""What a turned joint's tab draws beside the pieces, and the paper it leaves at the joint.

Turns both elbows or both knees of the AnimatedDrawings characters by ±15,
±30 and ±45 degrees from the rest pose (the parent stays where it is, the
forearm or shin turns about the joint key point), renders each pose with the
default layered mesh and counts:

- **beside**: opaque pixels more than 2 px outside both the rest drawing and
  the turned child segment (its rest pixels turned rigidly about the joint),
  and farther from the joint than the drawing's thickness there.  A tab's rim
  that swings out beside the parent's outline shows here, with the new stroke
  along its edge: a second line beside the drawn one.
- **gap**: paper pixels in the joint's disc (radius 0.8 × the thickness,
  :func:`nnsf.reshape.artefacts.joint_gaps`): what a tab must still fill.

Needs ../shared/data.  Run: ``python benchmarks/tab_doubles.py`` (per
character and joint, summed over the six angles and both sides).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.reshape import artefacts, depth
from nnsf.reshape.character import load_animated_drawings
from nnsf.reshape.cuts import SEGMENT_NAMES
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import build_rig
from nnsf.skeleton import JOINT_INDEX as J

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CHARACTERS = ("char1", "char2", "char3", "char4")
JOINTS = (("elbow", "wrist", "forearm"), ("knee", "ankle", "shin"))
DEGREES = (-45, -30, -15, 15, 30, 45)


def _rotation(deg: float) -> np.ndarray:
    a = np.radians(deg)
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def main() -> None:
    order = depth.default_order()
    grand = {"beside": 0, "gap": 0}
    for name in CHARACTERS:
        folder = DATA / "animated-drawings" / "characters" / name
        if not folder.is_dir():
            continue
        ch = load_animated_drawings(folder)
        rig = build_rig(ch, "ours", "layered", 800, 4)
        r = MeshRenderer.for_mesh(rig.mesh, ch)
        mask = np.asarray(ch.mask, bool)
        H, W = mask.shape
        thick = cv2.distanceTransform(np.pad(mask.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        labels = rig.mesh.labels
        for joint, end, seg in JOINTS:
            beside = gap = 0
            for deg in DEGREES:
                kp = ch.keypoints.copy()
                allowed = mask.copy()
                discs = []
                for side, sgn in (("l_", 1.0), ("r_", -1.0)):
                    c = kp[J[side + joint]]
                    kp[J[side + end]] = (kp[J[side + end]] - c) @ _rotation(sgn * deg).T + c
                    M = cv2.getRotationMatrix2D((float(c[0]), float(c[1])), -sgn * deg, 1.0)
                    child = (labels == SEGMENT_NAMES.index(side + seg)).astype(np.uint8)
                    allowed |= cv2.warpAffine(child, M, (W, H), flags=cv2.INTER_NEAREST).astype(bool)
                    i, j = np.clip(np.rint(c).astype(int), 0, [W - 1, H - 1])
                    discs.append((c, float(thick[j, i])))
                V = rig.animate(kp[None])[0]
                solid = r.render(V, order)[..., 3] > 127
                near = cv2.dilate(allowed.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
                yy, xx = np.mgrid[:H, :W]
                for c, rad in discs:
                    near |= np.hypot(xx - c[0], yy - c[1]) <= rad
                beside += int((solid & ~near).sum())
                gap += artefacts.joint_gaps(solid, np.array([d[0] for d in discs]),
                                            0.8 * np.array([d[1] for d in discs]))
            grand["beside"] += beside
            grand["gap"] += gap
            print(f"  {name} {joint:6s} beside {beside:6d} px   gap {gap:4d} px")
    print(f"all, {len(DEGREES)} angles x 2 sides: beside {grand['beside']} px, joint-disc gap {grand['gap']} px")


if __name__ == "__main__":
    main()
