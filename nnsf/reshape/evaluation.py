"""The reshaping evaluation (docs/method.md §15.7): every drawing × every motion, every frame measured.

Drawings and motions come from ``params.yaml`` (``reshape_eval``), never from this module:

* ``characters`` and ``heldout``: drawings, each a path inside the data folder (``--data``: an
  AnimatedDrawings folder, ...) or a character YAML inside the project whose ``drawing:`` or
  ``image:`` is relative to the data folder (joints written for a drawing that has none, choices).
  The held-out drawings were never looked at while the method was built; they are reported apart.
* ``motions``: BVH files inside the data folder (projected in the view they move most in; a
  quadruped or a figure drawn from the side always from the side, the view it is drawn in) or
  ``synthetic:<character>/<motion>``.

Each (drawing, motion) is driven twice on the same mesh: the paper's method (key points and
subkeys, the default) and key points only (the baseline of the paper's Fig. 8).  Every frame of
both is rendered and measured by :mod:`nnsf.reshape.artefacts` against the drawing.  Written to
``out`` (default ``reports``): ``reshape_eval.csv`` (a row per drawing × motion × method),
``reshape_eval_frames.csv`` (every frame), ``reshape_eval.json`` (totals per set, the Fig. 8 table,
drawings refused) and a contact sheet per drawing × motion; their columns are in docs/formats.md §6.9.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets import synthetic
from nnsf.datasets.views import load_clip_in_view
from nnsf.errors import InputError
from nnsf.io import atomic_path, write_csv, write_json
from nnsf.params import checked
from nnsf.pipeline import StageResult
from nnsf.reshape.animator import Animator, canvas
from nnsf.reshape.artefacts import FrameMeasures, width_stats
from nnsf.reshape.deform import Deformer
from nnsf.reshape.drive import seen_from_side
from nnsf.reshape.formats import read_character
from nnsf.safe_yaml import read_yaml
from nnsf.names import safe_name
from nnsf.reshape.stage import report, write_sheet
from nnsf.reshape.video import over_white

#: Per-frame measures whose worst frame and mean a row keeps.
MEASURES = ("detached", "cracks", "crack_px", "joint_cracks", "specks", "notch_px", "notch_beyond_rest",
            "spikes", "outline_roughness")


def _root(roots, rel) -> Path:
    """The first of the data folders ``roots`` that holds ``rel`` (the first, if none does)."""
    roots = [Path(r) for r in ([roots] if isinstance(roots, (str, Path)) else roots)]
    return next((r for r in roots if (r / rel).exists()), roots[0])


def _motion(spec: str, roots, ch):
    """``(name, points (T, 17, 2), depth (T, 17) or None, fps, view)`` of a motion spec for the character
    ``ch`` (:func:`~nnsf.reshape.drive.seen_from_side`, else the view it moves most in)."""
    if spec.startswith("synthetic:"):
        who, what = spec[len("synthetic:"):].split("/")[:2]
        return f"synthetic-{what}", synthetic.clip_points(who, what, 48), None, 24.0, "front"
    path = _root(roots, spec) / spec
    clip, view = load_clip_in_view(path, view="side" if seen_from_side(ch) else "auto", fps=30.0)
    return path.stem.replace("dataset-1_", ""), clip.points, clip.depth, clip.fps, view


def _character(spec: str, roots):
    p = Path(spec)
    if p.suffix in (".yaml", ".yml") and p.is_file():   # a character YAML of the project
        doc = read_yaml(p)
        rel = (doc.get("drawing") or doc.get("image") or "") if isinstance(doc, dict) else ""
        return read_character(p, root=_root(roots, rel))
    return read_character(_root(roots, spec) / spec)


def drive_item(item: dict):
    """The frames one drawing × motion ``item`` (:func:`run`'s) is measured on: ``(character, motion
    name, view, animator, animation, {method: vertices (T, n, 2)}, offset (2,), canvas size (H, W))``,
    the canvas holding both methods' frames."""
    ch = _character(item["character"], item["data"])
    name, points, depth, _, view = _motion(item["motion"], item["data"], ch)
    T = min(len(points), item["max_frames"])
    points, depth = points[:T], None if depth is None else depth[:T]
    animator = Animator(ch, item["n_vertices"], "ours", item["subkeys_per_limb"])
    anim = animator.animate(points, depth, source=item["motion"])
    base = Deformer(animator.mesh, animator.rig, ch.mask, "keypoints")
    frames = {"ours": anim.frames, "keypoints": base.run(anim.keypoints)}
    offset, size = canvas(np.concatenate(list(frames.values())), shape=ch.shape)
    return ch, name, view, animator, anim, frames, offset, size


def evaluate_item(item: dict) -> dict:
    """One drawing × motion: rows per method, per-frame rows and a contact sheet (picklable)."""
    ch, name, view, animator, anim, frames, offset, size = drive_item(item)
    T = len(anim.frames)
    renderer = animator.renderer(size)
    measure = FrameMeasures(ch.texture, ch.mask, ch.keypoints)
    rest = measure.rest()
    rows, per_frame, sheet = [], [], None
    for method, V in frames.items():
        t0 = time.perf_counter()
        images = [renderer.render(v + offset, o) for v, o in zip(V, anim.orders)]
        ms = 1000 * (time.perf_counter() - t0) / T
        res = [measure(img, kp + offset) for img, kp in zip(images, anim.keypoints)]
        table = pd.DataFrame([{k: r[k] for k in MEASURES} for r in res])
        row = {"character": ch.name, "motion": name, "view": view, "method": method, "set": item["set"],
               "body": ch.body, "frames": T, "render_ms": ms}
        for k in MEASURES:
            row[f"{k}_max"], row[f"{k}_mean"] = float(table[k].max()), float(table[k].mean())
        for k in ("detached", "cracks", "specks", "notch_px", "spikes", "outline_roughness"):
            row[f"{k}_rest"] = rest[k]
        for k in ("detached", "cracks", "specks"):
            row[f"frames_with_{k}"] = int((table[k] > rest[k]).sum())
        row["frames_with_joint_cracks"] = int((table["joint_cracks"] > 0).sum())
        row["frames_notch_over_rest"] = int((table["notch_beyond_rest"] > 4).sum())
        row["frames_spikes_over_rest"] = int((table["spikes"] > rest["spikes"]).sum())
        row.update(width_stats(np.stack([r["widths"] for r in res]), measure.rest_widths))
        row["outline_roughness_change"] = row["outline_roughness_mean"] - rest["outline_roughness"]
        mover = anim if method == "ours" else type(anim)(anim.keypoints, V, anim.orders, anim.part_z)
        row.update(report(animator, mover))
        rows.append(row)
        if method == "ours":
            per_frame = [{"character": ch.name, "motion": name, "set": item["set"], "t": t, **table.iloc[t].to_dict()}
                         for t in range(T)]
            score = (1000 * (table["detached"] + table["cracks"]) + table["notch_beyond_rest"]
                     + 10 * table["spikes"]).to_numpy()
            pick = list(np.linspace(0, T - 1, 10).round().astype(int))
            worst = [int(t) for t in np.argsort(-score, kind="stable") if t not in pick][:2]
            white = [over_white(images[t]) for t in pick + worst]
            labels = [f"t={t}" for t in pick] + [f"worst t={t}" for t in worst]
            sheet = (safe_name(ch.name, ch.source, "name") + "_" + safe_name(name, item["motion"], "motion"),
                     np.stack(white), labels)
    return {"rows": rows, "frames": per_frame, "sheet": sheet, "notes": ch.notes}


def _safe_item(item: dict) -> dict:
    """:func:`evaluate_item`, with bad input turned into an error entry (the other items go on)."""
    t0 = time.perf_counter()
    try:
        out = evaluate_item(item)
    except InputError as exc:
        return {"item": f"{item['character']} x {item['motion']}", "error": str(exc)}
    print(f"reshape-eval: {item['character']} x {item['motion']}: {time.perf_counter() - t0:.0f} s",
          file=sys.stderr, flush=True)
    return out


def fig8_table(df: pd.DataFrame) -> pd.DataFrame:
    """The paper's Fig. 8 claim: per set, subkeys vs key points on the width and outline measures."""
    cols = ["width_error", "width_change", "width_roughness", "width_jitter", "outline_roughness_change",
            "spikes_mean", "limb_bending_change", "arap_energy_mean"]
    return df[df["body"] != "quadruped"].groupby(["set", "method"])[cols].mean()


def figure8(table: pd.DataFrame, path: Path) -> None:
    """Bar chart of :func:`fig8_table` (PNG)."""
    from matplotlib.figure import Figure

    cols = list(table.columns[:5])
    fig = Figure(figsize=(13, 3.2), dpi=110)
    sets = list(dict.fromkeys(s for s, _ in table.index))
    for k, col in enumerate(cols):
        ax = fig.add_subplot(1, len(cols), k + 1)
        x = np.arange(len(sets))
        for j, (method, label) in enumerate((("keypoints", "key points only"), ("ours", "subkeys (ours)"))):
            vals = [table.loc[(s, method), col] if (s, method) in table.index else np.nan for s in sets]
            ax.bar(x + (j - 0.5) * 0.38, vals, 0.38, label=label)
        ax.set_xticks(x, sets, fontsize=8)
        ax.set_title(col, fontsize=9)
        ax.axhline(0, color="k", lw=0.5)
        if k == 0:
            ax.legend(fontsize=7)
    fig.suptitle("Limb width profile and outline smoothness against the drawing (the paper's Fig. 8 claim)",
                 fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def run(data_root, out_dir=Path("reports"), characters=(), heldout=(), motions=(), n_vertices: int = 800,
        max_frames: int = 240, subkeys_per_limb: int = 4, mapper=None) -> dict:
    """Evaluate and write the files of the module docstring; returns the summary.  ``data_root``: a
    data folder, or several (each drawing and motion is looked up in the first that holds it)."""
    roots = [str(Path(r).resolve()) for r in ([data_root] if isinstance(data_root, (str, Path)) else data_root)]
    out_dir = Path(out_dir)
    items = [{"data": roots, "character": c, "motion": m, "set": s, "n_vertices": n_vertices,
              "max_frames": max_frames, "subkeys_per_limb": subkeys_per_limb}
             for s, chars in (("tuning", characters), ("heldout", heldout)) for c in chars for m in motions]
    results = (mapper or (lambda fn, xs: list(map(fn, xs))))(_safe_item, items)
    ok = [r for r in results if "error" not in r]
    failed = sorted({r["error"] for r in results if "error" in r})
    if not ok:
        raise InputError(roots[0], "items", "at least one drawing x motion that evaluates", "; ".join(failed)[:300])
    df = pd.DataFrame([row for r in ok for row in r["rows"]])
    write_csv(out_dir / "reshape_eval.csv", df)
    write_csv(out_dir / "reshape_eval_frames.csv", pd.DataFrame([f for r in ok for f in r["frames"]]))
    sheets = out_dir / "reshape_eval"
    sheets.mkdir(parents=True, exist_ok=True)
    for r in ok:
        name, imgs, labels = r["sheet"]
        write_sheet(sheets / f"{name}.png", imgs, labels, scale=0.5 if imgs.shape[1] > 300 else 1.0)
    ours = df[df["method"] == "ours"]
    summary = {"refused": failed, "sets": {}}
    for s, d in ours.groupby("set"):
        summary["sets"][s] = {
            "items": int(len(d)), "frames": int(d["frames"].sum()),
            "frames_with_detached": int(d["frames_with_detached"].sum()),
            "frames_with_cracks": int(d["frames_with_cracks"].sum()),
            "frames_with_joint_cracks": int(d["frames_with_joint_cracks"].sum()),
            "frames_notch_over_rest": int(d["frames_notch_over_rest"].sum()),
            "frames_spikes_over_rest": int(d["frames_spikes_over_rest"].sum()),
            "render_ms": float(d["render_ms"].mean())}
    table = fig8_table(df)
    summary["fig8"] = {f"{s}/{m}": {c: float(v) for c, v in r.items()} for (s, m), r in table.iterrows()}
    figure8(table, out_dir / "reshape_fig8.png")
    summary["notes"] = sorted({n for r in ok for n in r["notes"]})
    write_json(out_dir / "reshape_eval.json", summary)
    summary["artifacts"] = [out_dir / "reshape_eval.csv", out_dir / "reshape_eval_frames.csv",
                            out_dir / "reshape_eval.json", out_dir / "reshape_fig8.png"]
    return summary


def reshape_eval(params: dict, data_root, out_dir=Path("reports"), mapper=None) -> StageResult:
    """``nnsf reshape-eval``: :func:`run` on the ``reshape_eval`` section of ``params``."""
    def get(key, default):
        return checked(params, f"reshape_eval.{key}", default)

    kw = dict(characters=tuple(get("characters", [])), heldout=tuple(get("heldout", [])),
              motions=tuple(get("motions", [])), n_vertices=get("n_vertices", 800),
              max_frames=get("max_frames", 240), subkeys_per_limb=get("subkeys_per_limb", 4))
    if not kw["motions"] or not (kw["characters"] or kw["heldout"]):
        raise InputError("params.yaml", "reshape_eval", "characters (or heldout) and motions to evaluate")
    s = run(data_root, out_dir, mapper=mapper, **kw)
    metrics = {f"{k}_{m}": v for k, d in s["sets"].items() for m, v in d.items()}
    return StageResult(params={f"reshape_eval.{k}": (",".join(v) if isinstance(v, tuple) else v)
                               for k, v in kw.items()}, metrics=metrics, artifacts=s["artifacts"])
