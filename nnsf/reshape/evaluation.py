"""Evaluation of the reshaping (SPEC §6.5-6.6): subkey driving vs key-points-only ARAP.

Every supported AnimatedDrawings character (char5, with several shoulders
per side, and the quadruped char6 are refused by the loader) is driven by several Bandai-Namco motions
(projected front view, 30 fps, :func:`nnsf.datasets.bvh_source.load_clip`)
with four rigs on the same character:

=================  ==========================================================
``connected/keypoints``  one connected mesh, the 17 key points as handles:
                    the plain ARAP baseline (the paper's Fig. 8, left)
``connected/ours``  the same mesh plus subkeys (the paper's method)
``layered/keypoints``  the layered mesh (:func:`nnsf.reshape.mesh.layer_pieces`),
                    key points only
``layered/ours``    the layered mesh plus subkeys: our default
``limbs/keypoints``  whole-limb pieces (``build_mesh(split="limbs")``): each
                    limb one deformable piece (bending at the elbow / knee),
                    cut from the body at the shoulder / hip; key points only
``limbs/ours``      the same plus subkeys: the comparison of the paper's
                    Fig. 8 (on a layered mesh every segment is rigid, so the
                    two methods coincide there)
=================  ==========================================================

Each row of ``reshape_eval.csv`` holds :func:`nnsf.reshape.stage.report`'s
numbers (ARAP energy, σ1/σ2, flips, width drift, limb bending, jitter,
driving-failure ratio, depth agreement and order flips) plus the subkeys'
slide along their limb (``subkey_slide``: mean |u_t − u_0|, u the position
along the bone as a fraction of its length; the "swimming" of the paper's
Eq. 12).  ``reshape_eval.json`` holds the same rows and per-variant means.
Figures: ``reshape_fig8_<character>_<motion>.png`` (the same frames, each
variant a row, like the paper's Fig. 8) and ``reshape_fig9.png`` (a keyframe
strip of ``layered/ours``, one row per motion, like Fig. 9), plus side-by-side
GIFs ``reshape_eval/<character>_<motion>.gif`` (:data:`GIF_PANELS`, left to right).

The Kenney real-frame check (:mod:`nnsf.reshape.kenney`) writes
``reshape_kenney.csv`` / ``.json`` when its annotations and images exist.

Run as a stage (:func:`reshape_eval`) or a script::

    python -m nnsf.reshape.evaluation --data DATA [--out reports]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from nnsf.errors import InputError

#: The supported (biped) AnimatedDrawings examples; char5 (several shoulders per side) and
#: char6 (a quadruped) are refused by the loader.
CHARACTERS = ("char1", "char2", "char3", "char4")
MOTIONS = ("walk_normal_001", "run_active_001", "kick_normal_001", "punch_normal_001")
VARIANTS = (("connected", "keypoints"), ("connected", "ours"), ("limbs", "keypoints"), ("limbs", "ours"),
            ("layered", "keypoints"), ("layered", "ours"))
LABELS = {"connected/keypoints": "ARAP, key points (connected mesh)",
          "connected/ours": "subkeys (connected mesh)",
          "limbs/keypoints": "ARAP, key points (whole-limb pieces)",
          "limbs/ours": "subkeys (whole-limb pieces)",
          "layered/keypoints": "key points (layered mesh)",
          "layered/ours": "ours: subkeys (layered mesh)"}
FIGURE_ITEMS = (("char1", "kick_normal_001"), ("char4", "walk_normal_001"))
#: Side-by-side GIF panels: the key-point baseline and subkeys on whole-limb
#: pieces (the comparison of the paper's Fig. 8), and the stage's default.
GIF_PANELS = ("limbs/keypoints", "limbs/ours", "layered/ours")


def subkey_slide(rig, keypoints: np.ndarray) -> float:
    """Mean |u_t − u_0| of the subkeys (u: position along the bone / its length); NaN without subkeys."""
    from nnsf.reshape.limbs import LIMB_PAIRS

    if rig.tracker is None or len(rig.subkeys) == 0:
        return float("nan")
    rig.tracker.reset()
    q0 = rig.tracker.positions()
    q = rig.tracker.track(keypoints)  # (T, s, 2), starting from rest
    pairs = LIMB_PAIRS[rig.subkeys.limb]
    kp = np.concatenate([rig.character.keypoints[None], keypoints])
    qq = np.concatenate([q0[None], q])
    p0, p1 = kp[:, pairs[:, 0]], kp[:, pairs[:, 1]]
    d = p1 - p0
    u = ((qq - p0) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)
    return float(np.abs(u[1:] - u[:1]).mean())


def evaluate_item(item: dict) -> dict:
    """One (character, motion): rows of metrics per variant, and frames for the figures.

    ``item`` keys: ``character`` (folder), ``motion`` (BVH path), ``n_vertices``,
    ``max_frames``, ``subkeys_per_limb``, ``figure`` (bool), ``gif_dir``
    (or None).  Module-level and picklable for a task-runner map.
    """
    from nnsf.datasets.bvh_source import load_clip
    from nnsf.reshape.character import load_animated_drawings
    from nnsf.reshape.mesh import build_mesh
    from nnsf.reshape.render import MeshRenderer, write_gif
    from nnsf.reshape.stage import animate, build_rig, canvas, report

    ch = load_animated_drawings(item["character"])
    clip = load_clip(item["motion"], fps=30)
    T = min(len(clip.points), item["max_frames"])
    motion, depth = clip.points[:T], clip.depth[:T]
    height = float(np.median(np.ptp(motion[..., 1], axis=1)))
    meshes = {kind: build_mesh(ch.mask, ch.keypoints, item["n_vertices"], split=kind, texture=ch.texture)
              for kind in dict.fromkeys(mesh for mesh, _ in VARIANTS)}
    rows, anims = [], {}
    for mesh, method in VARIANTS:
        rig = build_rig(ch, method, mesh, item["n_vertices"], item["subkeys_per_limb"], base_mesh=meshes[mesh])
        anim = animate(rig, motion, depth, source=str(item["motion"]))
        row = {"character": ch.name, "motion": Path(item["motion"]).stem.replace("dataset-1_", ""),
               "mesh": mesh, "method": method}
        row.update(report(anim, depth_margin=0.02 * height))
        row["subkey_slide"] = subkey_slide(rig, anim.keypoints)
        rows.append(row)
        anims[f"{mesh}/{method}"] = anim
    out = {"rows": rows, "figure": None}
    if item.get("figure") or item.get("gif_dir"):
        allV = np.concatenate([a.frames.reshape(-1, 2) for a in anims.values()])
        offset, size = canvas(ch, allV)
        renderers = {k: MeshRenderer.for_mesh(a.rig.mesh, ch, size=size) for k, a in anims.items()}
        pick = np.linspace(0, T - 1, 6).round().astype(int)
        out["figure"] = {"character": ch.name, "motion": rows[0]["motion"], "frames": pick.tolist(),
                         "images": {k: np.stack([renderers[k].render(a.frames[t] + offset, a.orders[t],
                                                                       background=(255, 255, 255))
                                                 for t in pick]) for k, a in anims.items()}}
        strip = np.linspace(0, T - 1, 8).round().astype(int)
        a = anims["layered/ours"]
        out["strip"] = np.stack([renderers["layered/ours"].render(a.frames[t] + offset, a.orders[t],
                                                                  background=(255, 255, 255)) for t in strip])
        if item.get("gif_dir"):
            panels = [k for k in GIF_PANELS if k in anims]
            frames = [np.hstack([_label(renderers[k].render(anims[k].frames[t] + offset, anims[k].orders[t],
                                                            background=(255, 255, 255))[..., :3], k)
                                 for k in panels])
                      for t in range(0, T, 2)]
            # every other frame at 40 %: a GIF a person can open (15 fps)
            frames = [cv2.resize(f, None, fx=0.4, fy=0.4, interpolation=cv2.INTER_AREA) for f in frames]
            name = f"{ch.name}_{rows[0]['motion']}.gif"
            write_gif(Path(item["gif_dir"]) / name, frames, 15)
            out["gif"] = str(Path(item["gif_dir"]) / name)
    return out


def _label(img: np.ndarray, text: str) -> np.ndarray:
    img = img.copy()
    cv2.putText(img, text, (6, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
    return img


def figure8(fig: dict) -> np.ndarray:
    """Rows = variants, columns = the same frames (RGB image)."""
    rows = []
    for key, imgs in fig["images"].items():
        small = [cv2.resize(i, None, fx=0.4, fy=0.4, interpolation=cv2.INTER_AREA) for i in imgs]
        row = np.hstack(small)
        rows.append(_label(row, LABELS.get(key, key)))
    head = np.full((28, rows[0].shape[1], 3), 255, np.uint8)
    w = rows[0].shape[1] // len(fig["frames"])
    for k, t in enumerate(fig["frames"]):
        cv2.putText(head, f"frame {t}", (k * w + 6, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1, cv2.LINE_AA)
    return np.vstack([head] + rows)


def figure9(strips: list[tuple[str, np.ndarray]]) -> np.ndarray:
    """A keyframe strip per motion (RGB image), frames scaled to a common height."""
    rows = []
    for title, imgs in strips:
        small = [cv2.resize(i, None, fx=0.35, fy=0.35, interpolation=cv2.INTER_AREA) for i in imgs]
        h = max(s.shape[0] for s in small)
        small = [np.pad(s, ((0, h - s.shape[0]), (0, 0), (0, 0)), constant_values=255) for s in small]
        rows.append(_label(np.hstack(small), title))
    W = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, W - r.shape[1]), (0, 0)), constant_values=255) for r in rows]
    return np.vstack(rows)


def summarise(df: pd.DataFrame) -> dict:
    """Per-variant means of the numeric columns, and the failure ratio per (variant, motion)."""
    num = df.select_dtypes("number").columns
    df = df.assign(variant=df["mesh"] + "/" + df["method"])
    means = df.groupby("variant")[list(num)].mean()
    fail = df.pivot_table(index="variant", columns="motion", values="driving_failure_ratio", aggfunc="mean")
    return {"means": {v: {k: (None if not np.isfinite(x) else float(x)) for k, x in r.items()}
                      for v, r in means.iterrows()},
            "failure_ratio": {v: {m: float(x) for m, x in r.items()} for v, r in fail.iterrows()}}


def run(data_root, out_dir=Path("reports"), characters=CHARACTERS, motions=MOTIONS,
        n_vertices: int = 800, max_frames: int = 240, subkeys_per_limb: int = 4, kenney_annotations=None,
        mapper=None) -> dict:
    """Evaluate and write the report files (module docstring); returns the summary dict."""
    from nnsf.io import atomic_path, write_csv, write_json

    data_root, out_dir = Path(data_root), Path(out_dir)
    chars = data_root / "animated-drawings" / "characters"
    mots = data_root / "bandai-namco-1" / "data"
    if not chars.is_dir() or not mots.is_dir():
        raise InputError(data_root, "folder", "animated-drawings/characters and bandai-namco-1/data inside")
    gif_dir = out_dir / "reshape_eval"
    items = [{"character": str(chars / c), "motion": str(mots / f"dataset-1_{m}.bvh"), "n_vertices": n_vertices,
              "max_frames": max_frames, "subkeys_per_limb": subkeys_per_limb,
              "figure": (c, m) in FIGURE_ITEMS or c == characters[0],
              "gif_dir": str(gif_dir) if (c, m) in FIGURE_ITEMS else None}
             for c in characters for m in motions]
    mapper = mapper or (lambda fn, xs: list(map(fn, xs)))
    results = mapper(_safe_item, items)
    failed = [r["item"] for r in results if "error" in r]
    ok = [r for r in results if "error" not in r]
    rows = [row for r in ok for row in r["rows"]]
    if not rows:
        raise InputError(data_root, "items", "at least one (character, motion) that evaluates",
                         "; ".join(r["error"] for r in results)[:300])
    df = pd.DataFrame(rows)
    summary = summarise(df)
    summary["failed_items"] = [r["error"] for r in results if "error" in r]
    write_csv(out_dir / "reshape_eval.csv", df)
    artifacts = [out_dir / "reshape_eval.csv", out_dir / "reshape_eval.json"]
    for r in ok:
        fig = r.get("figure")
        if fig is not None and (fig["character"], fig["motion"]) in FIGURE_ITEMS:
            path = out_dir / f"reshape_fig8_{fig['character']}_{fig['motion']}.png"
            with atomic_path(path) as tmp:
                cv2.imwrite(str(tmp), cv2.cvtColor(figure8(fig), cv2.COLOR_RGB2BGR))
            artifacts.append(path)
    strips = [(f"{r['figure']['character']} {r['figure']['motion']}", r["strip"]) for r in ok
              if r.get("figure") is not None and r["figure"]["character"] == characters[0]]
    if strips:
        path = out_dir / "reshape_fig9.png"
        with atomic_path(path) as tmp:
            cv2.imwrite(str(tmp), cv2.cvtColor(figure9(strips), cv2.COLOR_RGB2BGR))
        artifacts.append(path)
    artifacts += [Path(r["gif"]) for r in ok if r.get("gif")]
    ann = Path(kenney_annotations) if kenney_annotations is not None else None
    if ann is not None and ann.is_dir() and (data_root / "kenney-toon").is_dir():
        from nnsf.reshape.kenney import CHARACTERS as KC, check_character

        krows = []
        for c in KC:
            try:
                krows += check_character(c, data_root / "kenney-toon", ann)
            except InputError as exc:
                summary.setdefault("kenney_failed", []).append(str(exc))
        if krows:
            kdf = pd.DataFrame(krows)
            write_csv(out_dir / "reshape_kenney.csv", kdf)
            table = kdf.groupby(["character", "variant"])["iou"].mean().unstack()
            summary["kenney_iou"] = {c: {v: float(x) for v, x in r.items()} for c, r in table.iterrows()}
            summary["kenney_iou_mean"] = {v: float(x) for v, x in table.mean().items()}
            artifacts.append(out_dir / "reshape_kenney.csv")
    summary["rows"] = df.replace({np.nan: None}).to_dict(orient="records")
    write_json(out_dir / "reshape_eval.json", summary)
    summary["artifacts"] = artifacts
    summary["failed"] = failed
    return summary


def _safe_item(item: dict) -> dict:
    """:func:`evaluate_item`, with bad input turned into an error entry (the other items go on)."""
    try:
        return evaluate_item(item)
    except InputError as exc:
        return {"item": f"{Path(item['character']).name} x {Path(item['motion']).stem}", "error": str(exc)}


def reshape_eval(params: dict, data_root, out_dir=Path("reports"),
                 kenney_annotations=Path("tests/data/kenney"), mapper=None):
    """Stage wrapper of :func:`run`; reads ``reshape_eval.{characters, motions, n_vertices, max_frames,
    subkeys_per_limb}`` (defaults: the module's constants, 800, 240, 4).  Raises one
    :class:`InputError` naming the failed items after writing the others' results."""
    from nnsf.params import require
    from nnsf.stages import StageResult

    def get(key, default):
        try:
            return require(params, f"reshape_eval.{key}")
        except InputError:
            return default

    chars = tuple(get("characters", list(CHARACTERS)))
    motions = tuple(get("motions", list(MOTIONS)))
    n_vertices = get("n_vertices", 800)
    max_frames = get("max_frames", 240)
    per_limb = get("subkeys_per_limb", 4)
    for key, val, ok, what in (
            ("n_vertices", n_vertices, isinstance(n_vertices, int) and 100 <= n_vertices <= 6000, "an integer 100..6000"),
            ("max_frames", max_frames, isinstance(max_frames, int) and 3 <= max_frames <= 5000, "an integer 3..5000"),
            ("subkeys_per_limb", per_limb, isinstance(per_limb, int) and 1 <= per_limb <= 12, "an integer 1..12"),
            ("characters", chars, len(chars) > 0 and all(isinstance(c, str) for c in chars), "a list of names"),
            ("motions", motions, len(motions) > 0 and all(isinstance(c, str) for c in motions), "a list of names")):
        if not ok:
            raise InputError("params.yaml", f"reshape_eval.{key}", what, val)
    s = run(data_root, out_dir, chars, motions, n_vertices, max_frames, per_limb, kenney_annotations, mapper)
    metrics = {}
    for v, m in s["means"].items():
        for k in ("driving_failure_ratio", "arap_energy_mean", "stretch_ratio_max", "flipped_triangles",
                  "depth_agreement", "subkey_slide"):
            if m.get(k) is not None:
                metrics[f"{v.replace('/', '_')}_{k}"] = m[k]
    for v, x in s.get("kenney_iou_mean", {}).items():
        metrics[f"kenney_iou_{v.replace('/', '_')}"] = x
    if s["failed"]:
        raise InputError(data_root, "items", "every (character, motion) to evaluate",
                         "failed: " + ", ".join(s["failed"]))
    return StageResult(params={"reshape_eval.n_vertices": n_vertices, "reshape_eval.max_frames": max_frames,
                               "reshape_eval.subkeys_per_limb": per_limb},
                       metrics=metrics, artifacts=s["artifacts"])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Reshaping evaluation (SPEC §6.5-6.6)")
    ap.add_argument("--data", type=Path, required=True,
                    help="folder holding animated-drawings/, bandai-namco-1/ and kenney-toon/")
    ap.add_argument("--out", type=Path, default=Path("reports"))
    ap.add_argument("--kenney", type=Path, default=Path("tests/data/kenney"))
    ap.add_argument("--vertices", type=int, default=800)
    ap.add_argument("--max-frames", type=int, default=240)
    ap.add_argument("--characters", nargs="+", default=list(CHARACTERS))
    ap.add_argument("--motions", nargs="+", default=list(MOTIONS))
    a = ap.parse_args(argv)
    s = run(a.data, a.out, tuple(a.characters), tuple(a.motions), a.vertices, a.max_frames, 4, a.kenney)
    pd.set_option("display.width", 200)
    print(pd.DataFrame(s["means"]).T[["arap_energy_mean", "stretch_ratio_max", "flipped_triangles",
                                      "driving_failure_ratio", "width_drift_mean", "limb_bending_change",
                                      "temporal_jitter", "depth_agreement", "order_flips_per_100_frames",
                                      "subkey_slide"]].round(4).to_string())
    print(pd.DataFrame(s["failure_ratio"]).T.round(3).to_string())
    if "kenney_iou" in s:
        print(pd.DataFrame(s["kenney_iou"]).T.round(3).to_string())
    for f in s["failed"]:
        print("FAILED:", f)
    return 1 if s["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
