"""Question answered: how many of the artefacts the reshaping evaluation counts would an ideal figure show?

The evaluation (:mod:`nnsf.reshape.artefacts`) counts, per frame, thin enclosed background
(cracks), undrawn pixels in the joint discs beyond the drawing's own (notches) and outline points
turning more sharply than the drawing's outline ever does (spikes).  Issue 45 asks for 0 cracks in
every frame and notches and spikes no worse than at rest.  This asks what those counts are for a
figure that cannot tear, fold or be cut: for each drawing, a **figure of capsules** with the
drawing's rest key points and widths, posed in every frame at exactly the key points that drive the
drawing, and drawn with no mesh at all.

* Every bone is a capsule (a segment thickened by a radius, round at both ends); a limb's radius
  is half the drawing's median width across it at rest (:func:`~nnsf.reshape.artefacts.limb_widths`,
  the measure's own), or the drawing's half-width along the bone where a limb lies against
  something else all the way; the spine's bones get the drawing's half-width along them, the bone
  to the head (which ends at the head's centre) the neck's, the shoulder and hip bones those of the upper arm and thigh.  The
  head is a disc whose diameter runs from the neck to the head's top.
  The quadrilateral of shoulders and hips is filled.  Nothing else: no mesh, no texture, no depth.
* Drawn with OpenCV at 4× and area-averaged to the frame's pixels (anti-aliased, as a drawing is);
  coverage is alpha ≥ 128, as for the frames of the evaluation.
* Measured with the same :class:`~nnsf.reshape.artefacts.FrameMeasures`, against the capsule figure
  at rest, with the same thresholds the evaluation's rows use: a frame has cracks if it has more than
  at rest, a notch if its notch pixels beyond rest exceed 4, spikes if it has more than at rest.

The renderer, the mesh and the deformation are not used: only the character's key points and the
retargeting that turns a motion into the drawing's key points (``Animator.retarget``), which is the
input both figures share.

    python -m experiments.ideal_floor --data /work/shared/data /work/extra-drawings /work/extra-drawings-tuning --out reports

Writes ``OUT/reshape_ideal_floor.csv`` (one row per drawing × motion: the capsule figure's frames
with cracks, joint cracks, notches and spikes, beside the drawing's own rows from
``OUT/reshape_eval.csv`` when it is there), ``OUT/reshape_ideal_floor.json`` (totals per set) and
``OUT/figures/ideal_floor.png`` (the capsule frames with the most cracks and spikes).  A diagnostic,
not a measure: it changes nothing that is measured.
"""
from __future__ import annotations

import argparse
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from nnsf import params as params_mod
from nnsf.errors import InputError
from nnsf.io import atomic_path, write_csv, write_json
from nnsf.params import checked
from nnsf.reshape.animator import Animator
from nnsf.reshape.artefacts import FrameMeasures, coverage, cracks
from nnsf.reshape.evaluation import _character, _motion
from nnsf.skeleton import BONES, JOINT_INDEX, LIMBS

#: Supersampling of the capsule drawing.
SCALE = 4
#: Columns compared with ``reshape_eval.csv`` (its names).
COUNTS = ("frames_with_cracks", "frames_with_joint_cracks", "frames_notch_over_rest", "frames_spikes_over_rest")
J = JOINT_INDEX


def radii(mask: np.ndarray, keypoints: np.ndarray, rest_widths: np.ndarray) -> dict:
    """Radius (px) of each bone of :data:`nnsf.skeleton.BONES` ``{(a, b): r}`` and of the head (key ``"head"``)."""
    m = np.asarray(mask, np.uint8)
    dist = cv2.distanceTransform(np.pad(m, 1), cv2.DIST_L2, 5)[1:-1, 1:-1]
    H, W = m.shape
    kp = np.asarray(keypoints, float)

    def along(a, b, lo=0.3, hi=0.7):
        pts = kp[a] + np.linspace(lo, hi, 9)[:, None] * (kp[b] - kp[a])
        ij = np.clip(np.rint(pts).astype(int), 0, [W - 1, H - 1])
        return float(np.median(dist[ij[:, 1], ij[:, 0]]))

    out = {}
    for (a, b), w in zip(LIMBS.values(), rest_widths):
        ok = np.isfinite(w)
        out[(a, b)] = max(0.5 * float(np.median(w[ok])) if ok.any() else along(a, b), 1.0)
    limb = {a: out[(a, b)] for a, b in LIMBS.values()}
    for a, b in BONES:
        if (a, b) in out:
            continue
        if b in (J["l_shoulder"], J["r_shoulder"], J["l_hip"], J["r_hip"]):
            out[(a, b)] = limb[b]
        elif b == J["head_top"]:
            out[(a, b)] = out[(J["thorax"], a)]
        else:
            out[(a, b)] = max(along(a, b, 0.0, 1.0), 1.0)
    out["head"] = max(0.5 * float(np.linalg.norm(kp[J["head_top"]] - kp[J["neck"]])), 1.0)
    return out


def draw(keypoints: np.ndarray, r: dict, size: tuple[int, int]) -> np.ndarray:
    """The capsule figure at ``keypoints`` ``(17, 2)`` (canvas pixels): RGBA ``(H, W, 4)`` uint8, grey."""
    H, W = size
    S = SCALE
    big = np.zeros((H * S, W * S), np.uint8)
    kp = np.asarray(keypoints, float) * S + (S - 1) / 2.0   # pixel centres at 4× (area-average back)

    def pt(p):
        return tuple(int(v) for v in np.rint(p * 16))

    quad = kp[[J["l_shoulder"], J["r_shoulder"], J["r_hip"], J["l_hip"]]]
    cv2.fillPoly(big, [np.rint(quad * 16).astype(np.int32)], 255, cv2.LINE_8, 4)
    c = 0.5 * (kp[J["head_top"]] + kp[J["neck"]])
    for bone, rad in r.items():
        if bone == "head":
            continue
        a, b = bone
        ends = (kp[a], c if b == J["head_top"] else kp[b])
        # OpenCV draws a thick line with round ends: a capsule.
        cv2.line(big, pt(ends[0]), pt(ends[1]), 255, max(int(round(2 * rad * S)), 1), cv2.LINE_8, 4)
    cv2.circle(big, pt(c), int(round(r["head"] * S * 16)), 255, -1, cv2.LINE_8, 4)
    alpha = cv2.resize(big, (W, H), interpolation=cv2.INTER_AREA)
    rgba = np.full((H, W, 4), 128, np.uint8)
    rgba[..., 3] = alpha
    return rgba


def run_item(item: dict) -> dict:
    """One drawing × motion: the capsule figure's row and its worst frames."""
    ch = _character(item["character"], item["data"])
    name, points, depth, _, _ = _motion(item["motion"], item["data"], ch)
    T = min(len(points), item["max_frames"])
    animator = Animator(ch, item["n_vertices"], "ours", item["subkeys_per_limb"])
    kps = animator.retarget(points[:T], None, None, item["motion"])
    drawing = FrameMeasures(ch.texture, ch.mask, ch.keypoints)
    r = radii(ch.mask, ch.keypoints, drawing.rest_widths)
    pad = max(v for v in r.values()) + 8
    allk = np.concatenate([kps.reshape(-1, 2), np.asarray(ch.keypoints, float)])
    allk = allk[np.isfinite(allk).all(axis=1)]
    lo = np.floor(allk.min(axis=0) - pad)
    size = tuple(int(v) for v in (np.ceil(allk.max(axis=0) + pad) - lo)[::-1])
    rest = draw(np.asarray(ch.keypoints, float) - lo, r, size)
    measure = FrameMeasures(rest, rest[..., 3] >= 128, np.asarray(ch.keypoints, float) - lo)
    base = measure.rest()
    row = {"character": ch.name, "motion": name, "set": item["set"], "frames": T}
    counts = dict.fromkeys(COUNTS, 0)
    worst = {"cracks": (0, None), "spikes": (0, None)}
    for t in range(T):
        img = draw(kps[t] - lo, r, size)
        m = measure(img, kps[t] - lo)
        counts["frames_with_cracks"] += int(m["cracks"] > base["cracks"])
        counts["frames_with_joint_cracks"] += int(m["joint_cracks"] > 0)
        counts["frames_notch_over_rest"] += int(m["notch_beyond_rest"] > 4)
        counts["frames_spikes_over_rest"] += int(m["spikes"] > base["spikes"])
        for k in worst:
            extra = m[k] - base[k]
            if extra > worst[k][0]:
                labels = np.zeros(img.shape[:2], np.int32)
                cracks(coverage(img), labels=labels)
                worst[k] = (extra, {"kind": k, "extra": int(extra), "t": t, "character": ch.name, "motion": name,
                                    "set": item["set"], "image": img[..., 3], "cracks": labels > 0})
    row.update({f"ideal_{k}": v for k, v in counts.items()})
    return {"row": row, "examples": [w for _, w in worst.values() if w is not None]}


def figure(examples: list[dict], path: Path, per_row: int = 6, crop: int = 20) -> list[dict]:
    """The capsule frames with the most extra cracks (first row; the second row zooms ``crop`` px about
    the first crack) and spikes (third row), distinct drawings; cracks in red."""
    from matplotlib.figure import Figure

    rows = []
    for kind in ("cracks", "spikes"):
        picked, seen = [], set()
        for e in sorted((e for e in examples if e["kind"] == kind), key=lambda e: (-e["extra"], e["character"])):
            if e["character"] not in seen:
                picked.append(e)
                seen.add(e["character"])
            if len(picked) == per_row:
                break
        rows.append(picked)
    rows.insert(1, rows[0])
    fig = Figure(figsize=(2.6 * per_row, 3.2 * len(rows)), dpi=100)
    for i, picked in enumerate(rows):
        for j, e in enumerate(picked):
            ax = fig.add_subplot(len(rows), per_row, i * per_row + j + 1)
            img = np.repeat(255 - e["image"][..., None], 3, axis=2)
            red = cv2.dilate(e["cracks"].astype(np.uint8), np.ones((3, 3), np.uint8)) > 0 if i == 0 else e["cracks"]
            img[red] = (255, 0, 0)
            title = f"{e['character']} {e['motion']}\nt={e['t']}: {e['extra']} {e['kind']} over rest"
            if i == 1:
                ys, xs = np.nonzero(e["cracks"])
                cy, cx = int(ys[0]), int(xs[0])
                img = img[max(cy - crop, 0):cy + crop + 1, max(cx - crop, 0):cx + crop + 1]
                title = f"±{crop} px about a crack"
            ax.imshow(img, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(title, fontsize=7, loc="left")
    fig.suptitle("The capsule figure (no mesh) posed at the drawing's key points: frames with the most cracks "
                 "over its rest (red; zoomed in the second row) and spikes (bottom)", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return [e for p in rows[1:] for e in p]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, nargs="+", help="data folders (drawings and motions)")
    ap.add_argument("--params", default="params.yaml", help="its reshape_eval section names what is run")
    ap.add_argument("--out", type=Path, default=Path("reports"))
    a = ap.parse_args(argv)
    params = params_mod.load(a.params)

    def get(key, default):
        return checked(params, f"reshape_eval.{key}", default)

    roots = [str(Path(r).resolve()) for r in a.data]
    common = {"data": roots, "n_vertices": get("n_vertices", 800), "max_frames": get("max_frames", 240),
              "subkeys_per_limb": get("subkeys_per_limb", 4)}
    items = [{**common, "character": c, "motion": m, "set": s}
             for s, chars in (("tuning", get("characters", [])), ("heldout", get("heldout", [])))
             for c in chars for m in get("motions", [])]
    t0 = time.perf_counter()
    rows, examples, refused = [], [], []
    for item in items:
        try:
            res = run_item(item)
        except InputError as exc:
            refused.append(f"{item['character']} x {item['motion']}: {exc}")
            continue
        rows.append(res["row"])
        examples += res["examples"]
        r = res["row"]
        print(f"ideal_floor: {r['character']} x {r['motion']}: {r['frames']} frames, "
              + ", ".join(f"{k} {r['ideal_' + k]}" for k in COUNTS), file=sys.stderr, flush=True)
    if not rows:
        print(f"ideal_floor: {a.params}: reshape_eval: no drawing x motion could be run", file=sys.stderr)
        return 2
    table = pd.DataFrame(rows)
    evaluated = a.out / "reshape_eval.csv"
    if evaluated.is_file():
        ours = pd.read_csv(evaluated)
        ours = ours[ours["method"] == "ours"][["character", "motion", *COUNTS]]
        table = table.merge(ours.rename(columns={k: f"ours_{k}" for k in COUNTS}), on=["character", "motion"],
                            how="left")
    write_csv(a.out / "reshape_ideal_floor.csv", table)
    shown = figure(examples, a.out / "figures" / "ideal_floor.png")
    sums = {s: {"items": int(len(d)), "items_with_cracks": int((d["ideal_frames_with_cracks"] > 0).sum()),
                **{k: int(v) for k, v in d.drop(columns=["character", "motion", "set"]).sum().items()}}
            for s, d in table.groupby("set")}
    write_json(a.out / "reshape_ideal_floor.json", {
        "question": __doc__.splitlines()[0], "sets": sums, "refused": refused,
        "figure_examples": [{k: e[k] for k in ("kind", "character", "motion", "set", "t", "extra")} for e in shown],
        "seconds": round(time.perf_counter() - t0, 1),
        "command": "python -m experiments.ideal_floor " + shlex.join(argv if argv is not None else sys.argv[1:])})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
