"""What the elbow and knee caps (nnsf.reshape.tab_regions.cap_region) close, and what they cost.

For each character (AnimatedDrawings char1-char5, the six Kenney sprites), each
elbow and knee is folded 90°, 120° and 150° either way (the lower segment turned
about the joint, everything else at rest), and the page showing in the joint's
disc (nnsf.reshape.artefacts.joint_gaps, radius 0.8 × the drawing's thickness
there) beyond the rest pose's is summed over the 4 joints × 2 directions, with
the caps and without (``build_mesh(..., caps=False)``), the same rig otherwise.
Then the per-frame render time of char1's and male_adventurer's kick (first
60 frames, default mesh), with and without, alternated, each the fastest of three
passes.  Needs ../shared/data.  Run: ``python benchmarks/joint_caps.py``.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from nnsf.datasets.bvh_source import load_clip
from nnsf.reshape import artefacts as A
from nnsf.reshape import depth as D
from nnsf.reshape.formats import read_character
from nnsf.reshape.kenney import kenney_character
from nnsf.reshape.layers import build_mesh
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.stage import animate, build_rig, canvas
from nnsf.skeleton import JOINT_INDEX as J

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
ANN = Path(__file__).resolve().parents[1] / "tests" / "data" / "kenney"
KENNEY = ("female_adventurer", "female_person", "male_adventurer", "male_person", "robot", "zombie")
FOLDS = (("l_elbow", "l_wrist"), ("r_elbow", "r_wrist"), ("l_knee", "l_ankle"), ("r_knee", "r_ankle"))


def _character(name: str):
    if name.startswith("char"):
        return read_character(str(DATA / "animated-drawings" / "characters" / name)), 800
    return kenney_character(name, DATA / "kenney-toon", ANN)[0], 300


def _rig(ch, n: int, caps: bool):
    mesh = build_mesh(ch.mask, ch.keypoints, n, split="layered", texture=ch.texture,
                      extra_limbs=ch.extra_limbs, caps=caps)
    return build_rig(ch, "ours", "layered", n, 4, base_mesh=mesh)


def folded_gaps(ch, rig, degrees: float) -> int:
    """Page pixels in the folded joints' discs beyond the rest pose's, summed over the 8 folds."""
    r = MeshRenderer.for_mesh(rig.mesh, ch)
    joints = list(A.JOINTS_CHECKED)
    radii = A.joint_radii(ch.mask, ch.keypoints)
    rest = r.render(rig.mesh.vertices, D.default_order())[..., 3] >= 128
    _, e0 = A.joint_gaps(rest, ch.keypoints[joints], radii, per_joint=True)
    total = 0
    for sgn in (1.0, -1.0):
        a = np.radians(sgn * degrees)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        for joint, end in FOLDS:
            kp = ch.keypoints.copy()
            kp[J[end]] = (kp[J[end]] - kp[J[joint]]) @ R.T + kp[J[joint]]
            solid = r.render(rig.animate(kp[None])[0], D.default_order())[..., 3] >= 128
            _, each = A.joint_gaps(solid, kp[joints], radii, per_joint=True)
            k = joints.index(J[joint])
            total += max(int(each[k]) - int(e0[k]), 0)
    return total


def render_ms(ch, n: int, frames: int = 60, repeat: int = 3) -> tuple[float, float]:
    """Milliseconds per frame of the kick's first ``frames`` frames: (with caps, without)."""
    clip = load_clip(DATA / "bandai-namco-1" / "data" / "dataset-1_kick_normal_001.bvh", fps=30)
    setups = []
    for caps in (True, False):
        anim = animate(_rig(ch, n, caps), clip.points[:frames], clip.depth[:frames])
        off, size = canvas(ch, anim.frames.reshape(-1, 2))
        setups.append((MeshRenderer.for_mesh(anim.rig.mesh, ch, size=size), anim, off))
    best = [np.inf, np.inf]
    for _ in range(repeat):  # alternated, so both see the same load
        for i, (r, anim, off) in enumerate(setups):
            t0 = time.perf_counter()
            for t in range(frames):
                r.render(anim.frames[t] + off, anim.orders[t], background=(255, 255, 255))
            best[i] = min(best[i], (time.perf_counter() - t0) / frames * 1e3)
    return best[0], best[1]


def main() -> None:
    import os

    print(f"load average {os.getloadavg()[0]:.1f}")
    print("character          | folded 90° with / without | 120° | 150°")
    totals = np.zeros((3, 2))
    for name in ("char1", "char2", "char3", "char4", "char5") + KENNEY:
        ch, n = _character(name)
        rigs = (_rig(ch, n, True), _rig(ch, n, False))
        row = [[folded_gaps(ch, rig, d) for rig in rigs] for d in (90.0, 120.0, 150.0)]
        totals += np.array(row)
        print(f"{name:18s} | " + " | ".join(f"{a} / {b}" for a, b in row))
    print("all                | " + " | ".join(f"{a:.0f} / {b:.0f}" for a, b in totals))
    for name in ("char1", "male_adventurer"):
        ch, n = _character(name)
        with_, without = render_ms(ch, n)
        print(f"render, {name} kick: {with_:.2f} ms per frame with the caps, {without:.2f} without "
              f"({with_ / without:.3f}x)")


if __name__ == "__main__":
    main()
