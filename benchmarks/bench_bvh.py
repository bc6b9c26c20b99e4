"""Time the BVH source on every Bandai-Namco clip: parse, FK, key points, projection.

Runs the same steps as :func:`nnsf.datasets.bvh_source.load_clip` (at the
files' own 30 fps, front view, facing normalised, root centred), each timed
on its own, then the whole :func:`~nnsf.datasets.bvh_source.read_folder`
end to end (labels, table and contract validation included).  Each pass is
repeated and the fastest kept; the file cache is warmed first, so the parse
time is CPU time, not disk.

    .venv/bin/python benchmarks/bench_bvh.py [--data ../shared/data/bandai-namco-1] [--repeat 3]

Target (the project's issue): <= 10 s for all clips on 2 cores.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from nnsf.datasets.bvh import forward_kinematics, read_bvh
from nnsf.datasets.projection import detect_up_axis, project
from nnsf.datasets.bvh_skeletons import detect_family, keypoints_3d
from nnsf.datasets.bvh_source import FACING_PAIRS, read_folder
from nnsf.skeleton.layout import JOINT_INDEX

DEFAULT = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco-1"


def stages(files):
    """Seconds per stage over all files, and the frame count."""
    t = dict(parse=0.0, fk=0.0, keypoints=0.0, project=0.0)
    frames = 0
    for f in files:
        t0 = time.perf_counter()
        bvh = read_bvh(f)
        t1 = time.perf_counter()
        P, G = forward_kinematics(bvh, return_rotations=True)
        t2 = time.perf_counter()
        K = keypoints_3d(bvh, P, G, detect_family(bvh.names, f))
        up = detect_up_axis(K, JOINT_INDEX["head_top"], (JOINT_INDEX["l_ankle"], JOINT_INDEX["r_ankle"]))
        t3 = time.perf_counter()
        project(K, up=up, facing="normalise", across=FACING_PAIRS, root=JOINT_INDEX["pelvis"],
                center=True, window=int(round(bvh.fps)))
        t4 = time.perf_counter()
        t["parse"] += t1 - t0
        t["fk"] += t2 - t1
        t["keypoints"] += t3 - t2
        t["project"] += t4 - t3
        frames += bvh.n_frames
    return t, frames


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DEFAULT)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    folder = args.data / "data" if (args.data / "data").is_dir() else args.data
    files = sorted(folder.glob("*.bvh"))
    if not files:
        raise SystemExit(f"no .bvh files in {folder}")
    for f in files:                      # warm the OS file cache
        f.read_bytes()

    best = None
    for _ in range(args.repeat):
        t, frames = stages(files)
        if best is None or sum(t.values()) < sum(best.values()):
            best = t
    total = sum(best.values())
    print(f"{len(files)} clips, {frames} frames ({folder})")
    print(f"parse+FK+project: {total:.2f} s, {frames / total:,.0f} frames/s")
    for k, v in best.items():
        print(f"  {k:<10} {v:6.2f} s  {100 * v / total:5.1f} %  {1e6 * v / frames:7.1f} us/frame")

    ends = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        table, report = read_folder(args.data)
        ends.append(time.perf_counter() - t0)
    print(f"read_folder end to end: {min(ends):.2f} s ({len(table)} rows, "
          f"{table['clip'].nunique()} clips, {len(report)} report line(s))")


if __name__ == "__main__":
    main()
