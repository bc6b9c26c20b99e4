"""Time reshaping per frame: deformation (subkey update + both ARAP steps) and rendering.

In one run, on AnimatedDrawings' char1 when ``../shared/data`` holds it (else
the built-in stick figure scaled to 512 px):

* deformation at about 800 and about 3,000 vertices, for the layered mesh
  (our default), the whole-limb one and the connected one, streaming frame by frame
  (:meth:`nnsf.reshape.Rig.step`: Eq. 12-14, right-hand sides, two
  back-solves against factors computed once), beside the **naive** baseline
  of the same frames: dense assembly of both least-squares systems and dense
  normal-equation solves every frame (float64);
* rendering one 512×512 frame (:class:`nnsf.reshape.render.MeshRenderer`:
  scanline runs, one ``cv2.remap``), beside a **naive** renderer: one
  ``cv2.warpAffine`` of the bounding box per triangle, composited in a loop.

Times are medians over frames of the fastest of ``--repeat`` runs; ratios are
naive / ours.  Targets (issue 5): ≤ 2 ms deformation at ~3,000 vertices,
≥ 30 frames/s rendering at 512×512 on 2 cores.

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_reshape.py [--frames 120] [--repeat 3]
"""
from __future__ import annotations

import argparse
import os
import time

import cv2
import numpy as np

from nnsf.reshape import Rig, load_animated_drawings, stick_figure
from nnsf.reshape.render import MeshRenderer
from nnsf.skeleton import JOINT_INDEX as J

# The script's own folder is on sys.path when it runs: one dense reference frame, one rotation
# and one data folder for both benchmarks.
from bench_arap import DATA, _rot, naive_frame


def clip(kp: np.ndarray, frames: int) -> np.ndarray:
    """Key points ``(frames, 17, 2)``: both arms wave ±40°, a leg swings ±20°, the forearm bends."""
    out = np.repeat(kp[None], frames, 0)
    for t in range(frames):
        s = np.sin(2 * np.pi * t / 48)
        for arm, sh, sg in (([J["l_elbow"], J["l_wrist"]], J["l_shoulder"], -1), ([J["r_elbow"], J["r_wrist"]],
                                                                                  J["r_shoulder"], 1)):
            out[t, arm] = _rot(kp[arm], kp[sh], sg * 40 * s)
        out[t, [J["l_wrist"]]] = _rot(out[t, [J["l_wrist"]]], out[t, J["l_elbow"]], 30 * s)
        leg = [J["r_knee"], J["r_ankle"]]
        out[t, leg] = _rot(kp[leg], kp[J["r_hip"]], 20 * s)
    return out


def naive_render(renderer: MeshRenderer, V: np.ndarray) -> np.ndarray:
    """Per-triangle ``cv2.warpAffine`` of its bounding box, masked and composited in part order."""
    H, W = renderer.size
    tex = renderer._tex8
    out = np.zeros((H, W, 4), np.uint8)
    for tri in np.concatenate(renderer._order):
        src = renderer.uv[renderer.triangles[tri]].astype(np.float32)
        src[:, 0] += renderer._shift[tri]
        dst = V[renderer.triangles[tri]].astype(np.float32)
        x0, y0 = np.floor(dst.min(0)).astype(int)
        x1, y1 = np.ceil(dst.max(0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
        if x1 <= x0 or y1 <= y0:
            continue
        M = cv2.getAffineTransform(src, dst - np.float32([x0, y0]))
        patch = cv2.warpAffine(tex, M, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR)
        m = np.zeros((y1 - y0, x1 - x0), np.uint8)
        cv2.fillConvexPoly(m, np.rint(dst - [x0, y0]).astype(np.int32), 1)
        region = out[y0:y1, x0:x1]
        region[m > 0] = patch[m > 0]
    return out


def best_median(fn, frames, repeat):
    best = None
    for _ in range(repeat):
        times = np.empty(len(frames))
        for k, f in enumerate(frames):
            t0 = time.perf_counter()
            fn(f)
            times[k] = time.perf_counter() - t0
        best = times if best is None else np.minimum(best, times)
    return float(np.median(best))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=120)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--naive-frames", type=int, default=1,
                    help="frames solved densely for the comparison (at least 1)")
    ap.add_argument("--sizes", type=int, nargs="+", default=[800, 3000])
    args = ap.parse_args(argv)
    if args.naive_frames < 1:
        ap.error("--naive-frames: expected 1 or more (the comparison needs one dense frame)")
    if DATA.is_dir():
        ch, what = load_animated_drawings(DATA), "char1 (AnimatedDrawings, 508x602)"
    else:
        ch, what = stick_figure(height=512), "stick figure (char1 not found)"
    kp = clip(ch.keypoints, args.frames)
    print(f"character: {what}; {args.frames} frames; load average {os.getloadavg()[0]:.1f} on "
          f"{os.cpu_count()} cores; float64")
    print(f"{'mesh':>9} {'vertices':>8} {'handles':>7} {'build ms':>9} {'frame ms':>9} {'naive ms':>9} "
          f"{'naive/ours':>10} {'max |diff| px':>13}")
    rigs = {}
    for split in ("layered", "limbs", "connected"):
        for n in args.sizes:
            t0 = time.perf_counter()
            # A layered mesh duplicates its seam, cut and collar vertices
            # (~30 %; ~15 % for whole-limb pieces): ask for fewer so the
            # meshes end near the same size.
            rig = Rig.build(ch, n_vertices=int(n / {"layered": 1.3, "limbs": 1.15}.get(split, 1.0)),
                            split=split if split != "connected" else False, propagation="limb-frame")
            build = time.perf_counter() - t0

            def step(f, rig=rig):
                rig.step(f)

            rig.reset()
            ours = best_median(lambda f: step(f), list(kp), args.repeat)
            targets = rig.targets(kp[: args.naive_frames])
            fast = rig.deformer.deform(targets)
            naive_t, slow = [], None
            for f in range(args.naive_frames):
                t0 = time.perf_counter()
                slow = naive_frame(rig, targets[f])
                naive_t.append(time.perf_counter() - t0)
            naive = float(np.median(naive_t))
            diff = float(np.abs(slow - fast[-1]).max())
            print(f"{split:>9} {rig.mesh.n_vertices:>8} {len(rig.handles):>7} {build * 1e3:>9.1f} "
                  f"{ours * 1e3:>9.3f} {naive * 1e3:>9.1f} {naive / ours:>10.0f} {diff:>13.2e}")
            rigs[(split, n)] = rig
    # Rendering at 512x512: the character scaled so its longer side is 512 px.
    print(f"\n{'render 512x512':>15} {'triangles':>9} {'ours ms':>8} {'fps':>6} {'naive ms':>9} {'naive/ours':>10}")
    s = 512.0 / max(ch.shape)
    small = type(ch)(name=ch.name, texture=cv2.resize(ch.texture, None, fx=s, fy=s, interpolation=cv2.INTER_AREA),
                     mask=cv2.resize(ch.mask.astype(np.uint8), None, fx=s, fy=s,
                                     interpolation=cv2.INTER_NEAREST) > 0,
                     keypoints=ch.keypoints * s, source="scaled")
    for n in args.sizes:
        rig = Rig.build(small, n_vertices=n, split="layered")
        V = rig.animate(kp * s)
        r = MeshRenderer.for_mesh(rig.mesh, small, size=(512, 512))
        ours = best_median(lambda v: r.render(v, background=(255, 255, 255)), list(V[: min(len(V), 60)]),
                           args.repeat)
        naive = best_median(lambda v: naive_render(r, v), list(V[:3]), 1)
        print(f"{'layered':>15} {len(rig.mesh.triangles):>9} {ours * 1e3:>8.2f} {1 / ours:>6.0f} "
              f"{naive * 1e3:>9.1f} {naive / ours:>10.0f}")


if __name__ == "__main__":
    main()
