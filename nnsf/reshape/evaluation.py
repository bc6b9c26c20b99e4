"""Evaluation of the reshaping (docs/method.md §15.7): subkey driving vs key-points-only ARAP.

Every AnimatedDrawings character (char5's extra arms follow its driven ones;
char6, a quadruped, is driven about its drawn pose, :mod:`nnsf.reshape.quadruped`,
and sees every motion from the side) is driven by several Bandai-Namco motions
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

``layered/ours_unsealed`` is ``layered/ours`` rendered without the seal of
:mod:`nnsf.reshape.seal` (pieced meshes are sealed by default): what the
seal fixes.  Walks are projected from the side (:data:`AZIMUTH`,
``reshape_eval.azimuth``).  The six Kenney sprites (:mod:`nnsf.reshape.kenney`,
their ``idle`` drawing and hand key points) are driven by the same motions
when their images and annotations exist; their rows are in the CSV, the
per-variant means of the JSON's ``means`` are the AnimatedDrawings bipeds'
(``means_by_source`` has ``animated_drawings``, ``quadruped`` and ``kenney``).

Besides the deformation numbers, every row has the rendered-frame artefacts
of :func:`nnsf.reshape.artefacts.clip_artefacts` (holes, tears, outline
ink, spikes, limb width profile and jitter), measured on every
:data:`ARTEFACT_EVERY`-th frame; ``reshape_fig8_widths.png`` and the JSON's
``fig8_widths`` compare key points and subkeys on the limb widths (the
paper's Fig. 8 claim); ``reshape_eval/sheets/`` holds a contact sheet of
the default variant per AnimatedDrawings character and motion, and of
:data:`KENNEY_SHEET`.

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
from nnsf.datasets.bvh_source import load_clip
from nnsf.io import atomic_path, write_csv, write_json
from nnsf.params import checked, source_of
from nnsf.pipeline import StageResult
from nnsf.reshape.artefacts import clip_artefacts
from nnsf.reshape.formats import read_character
from nnsf.reshape.kenney import CHARACTERS as KC, kenney_character
from nnsf.reshape.kenney_check import check_character
from nnsf.reshape.limbs import LIMB_PAIRS
from nnsf.reshape.layers import build_mesh
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.video import contact_sheet, write_gif
from nnsf.reshape.stage import animate, build_rig, canvas, report

#: The AnimatedDrawings examples evaluated: the bipeds, and char5, whose three arms a side are
#: mapped by :func:`nnsf.reshape.formats.read_character` (the arm nearest the chest drives each side).
CHARACTERS = ("char1", "char2", "char3", "char4", "char5", "char6")
#: Examples the loader refuses, reported with its reason (none since char6, the quadruped, is read).
REFUSED: tuple[str, ...] = ()
#: The projection (degrees) every motion gets on a quadruped: drawn from the side, it walks in the
#: plane a side view shows (from the front a leg's swing is towards the camera, out of the picture).
QUADRUPED_AZIMUTH = 90.0
MOTIONS = ("walk_normal_001", "run_active_001", "kick_normal_001", "punch_normal_001")
VARIANTS = (("connected", "keypoints"), ("connected", "ours"), ("limbs", "keypoints"), ("limbs", "ours"),
            ("layered", "keypoints"), ("layered", "ours"), ("layered", "ours_unsealed"))
#: Projection azimuth (degrees) per motion: a walk seen from the side, where its legs swing
#: (from the front, mocap walking toward the camera hides the swing).  Overridden by
#: ``reshape_eval.azimuth`` in params.yaml.
AZIMUTH = {"walk_normal_001": 90.0}
#: ``arms`` of :func:`nnsf.reshape.drive.retarget` per character (others: ``motion``): char5's six
#: arms are drawn spread, and driven by direction they hang behind its body.  Overridden by
#: ``reshape_eval.arms`` in params.yaml.
ARMS = {"char5": "drawing"}
#: ``head`` of :func:`nnsf.reshape.drive.retarget` per character (others: ``motion``): char3, a
#: candy corn, has no neck; its head is the cone's tip, which turned on its own shows its drawn
#: outline as a line across the body.  Overridden by ``reshape_eval.head`` in params.yaml.
HEAD = {"char3": "torso"}
#: Every how many frames the rendered-frame artefacts (:mod:`nnsf.reshape.artefacts`) are measured:
#: every frame, so the width jitter is frame to frame.
ARTEFACT_EVERY = 1
LABELS = {"connected/keypoints": "ARAP, key points (connected mesh)",
          "connected/ours": "subkeys (connected mesh)",
          "limbs/keypoints": "ARAP, key points (whole-limb pieces)",
          "limbs/ours": "subkeys (whole-limb pieces)",
          "layered/keypoints": "key points (layered mesh)",
          "layered/ours": "ours: subkeys (layered mesh)",
          "layered/ours_unsealed": "subkeys (layered mesh), not sealed"}
FIGURE_ITEMS = (("char1", "kick_normal_001"), ("char4", "walk_normal_001"))
#: Columns of :func:`nnsf.reshape.artefacts.clip_artefacts` (copied for a variant with the same frames).
ARTEFACT_COLUMNS = ("hole_px", "holes_gt4", "holes_gt4_rest", "extra_holes", "seam_holes", "pose_holes",
                    "frames_with_seam_holes", "frames_with_holes", "tear_px",
                    "tear_px_max", "tear_px_rest", "outline_ink", "outline_ink_rest", "spikes", "spikes_rest",
                    "joint_gap_px", "joint_gap_max", "joint_gap_rest", "frames_with_joint_gaps",
                    "tear_beyond_rest", "tear_beyond_rest_max", "joint_gap_beyond_rest",
                    "joint_gap_beyond_rest_max", "frames_with_joint_gaps_beyond_rest",
                    "frames_with_tears", "detached", "frames_with_detached", "artefact_frames", "width_change", "width_error", "width_roughness",
                    "width_jitter")
#: Side-by-side GIF panels: the key-point baseline and subkeys on whole-limb
#: pieces (the comparison of the paper's Fig. 8), and the stage's default.
GIF_PANELS = ("limbs/keypoints", "limbs/ours", "layered/ours")


def subkey_slide(rig, keypoints: np.ndarray) -> float:
    """Mean |u_t − u_0| of the subkeys (u: position along the bone / its length); NaN without subkeys."""
    if rig.tracker is None or len(rig.subkeys) == 0:
        return float("nan")
    rig.tracker.reset()
    keypoints = rig.drive(keypoints)
    q0 = rig.tracker.positions()
    q = rig.tracker.track(keypoints)  # (T, s, 2), starting from rest
    pairs = LIMB_PAIRS[rig.subkeys.limb]
    kp = np.concatenate([rig.rest_keypoints[None], keypoints])
    qq = np.concatenate([q0[None], q])
    p0, p1 = kp[:, pairs[:, 0]], kp[:, pairs[:, 1]]
    d = p1 - p0
    u = ((qq - p0) * d).sum(-1) / np.maximum((d * d).sum(-1), 1e-12)
    return float(np.abs(u[1:] - u[:1]).mean())


def _character(item: dict):
    """The item's character: an AnimatedDrawings folder, or a Kenney sprite (``item["kenney"]``)."""
    if item.get("kenney"):
        return kenney_character(item["kenney"], item["kenney_root"], item["kenney_annotations"])[0]

    return read_character(item["character"])


def evaluate_item(item: dict) -> dict:
    """One (character, motion): rows of metrics per variant, and frames for the figures.

    ``item`` keys: ``character`` (folder) or ``kenney`` (a Kenney character
    name, with ``kenney_root`` and ``kenney_annotations``), ``motion`` (BVH
    path), ``azimuth`` (projection, degrees), ``arms`` (``motion`` or
    ``drawing``, default ``motion``), ``head`` (``motion`` or ``torso``,
    default ``motion``), ``n_vertices``,
    ``max_frames``, ``subkeys_per_limb``, ``figure`` (bool), ``gif_dir``
    (or None).  Module-level and picklable for a task-runner map.
    """
    ch = _character(item)
    azimuth = QUADRUPED_AZIMUTH if ch.body == "quadruped" else float(item.get("azimuth", 0.0))
    clip = load_clip(item["motion"], fps=30, azimuth=azimuth)
    T = min(len(clip.points), item["max_frames"])
    motion, depth = clip.points[:T], clip.depth[:T]
    height = float(np.median(np.ptp(motion[..., 1], axis=1)))
    meshes = {kind: build_mesh(ch.mask, ch.keypoints, item["n_vertices"], split=kind, texture=ch.texture,
                               extra_limbs=ch.extra_limbs)
              for kind in dict.fromkeys(mesh for mesh, _ in VARIANTS)}
    rows, anims, renderers = [], {}, {}
    results = {}
    for mesh, method in VARIANTS:
        base = method.replace("_unsealed", "")
        key = f"{mesh}/{method}"
        if base != method and f"{mesh}/{base}" in results:
            anim = results[f"{mesh}/{base}"]  # the same animation, rendered without the seal
        else:
            rig = build_rig(ch, base, mesh, item["n_vertices"], item["subkeys_per_limb"], base_mesh=meshes[mesh])
            anim = animate(rig, motion, depth, source=str(item["motion"]), arms=item.get("arms", "motion"),
                           head=item.get("head", "motion"))
        results[key] = anim
    allV = np.concatenate([a.frames.reshape(-1, 2) for a in results.values()])
    offset, size = canvas(ch, allV)
    measured = {}
    for (mesh, method), (key, anim) in zip(VARIANTS, results.items()):
        renderers[key] = MeshRenderer.for_mesh(anim.rig.mesh, ch, size=size,
                                               seal=False if method.endswith("_unsealed") else None)
        row = {"character": ch.name, "motion": Path(item["motion"]).stem.replace("dataset-1_", ""),
               "mesh": mesh, "method": method, "azimuth": azimuth, "body": ch.body,
               "arms": item.get("arms", "motion"), "head": item.get("head", "motion"),
               "sealed": bool(renderers[key].seal)}
        row.update(report(anim, depth_margin=0.02 * height))
        row["subkey_slide"] = subkey_slide(anim.rig, anim.keypoints)
        # A variant whose frames equal an already measured one's (on the layered mesh subkeys pin
        # rigid segments exactly where their key points do) has the same pictures: measured once.
        twin = next((k for k, (a2, r2) in measured.items()
                     if a2.frames.shape == anim.frames.shape and r2.seal == renderers[key].seal
                     and a2.rig.mesh is anim.rig.mesh and np.abs(a2.frames - anim.frames).max() < 1e-6
                     and np.array_equal(a2.orders, anim.orders)), None)
        row["frames_as"] = twin or ""
        if twin is not None:
            row.update({k: v for k, v in next(r for r in rows if f"{r['mesh']}/{r['method']}" == twin).items()
                        if k in ARTEFACT_COLUMNS})
        else:
            row.update(clip_artefacts(renderers[key], anim.frames, anim.orders, anim.rig.drive(anim.keypoints),
                                      anim.rig.mesh.vertices, anim.rig.rest_keypoints, ch.texture, ch.mask,
                                      every=ARTEFACT_EVERY, offset=offset))
        measured[key] = (anim, renderers[key])
        rows.append(row)
        anims[key] = anim
    out = {"rows": rows, "figure": None}
    if item.get("figure") or item.get("gif_dir"):
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
    if item.get("sheet"):
        a = anims["layered/ours"]
        pick = np.linspace(0, T - 1, 12).round().astype(int)
        out["sheet"] = (f"{ch.name}_{rows[0]['motion']}",
                        np.stack([renderers["layered/ours"].render(a.frames[t] + offset, a.orders[t],
                                                                   background=(255, 255, 255)) for t in pick]),
                        pick.tolist())
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
    kenney = ~df["character"].str.startswith("char")
    quad = (df["body"] == "quadruped") if "body" in df else pd.Series(False, index=df.index)
    by_source = {src: {v: {k: (None if not np.isfinite(x) else float(x)) for k, x in r.items()}
                       for v, r in d.groupby("variant")[list(num)].mean().iterrows()}
                 for src, d in (("animated_drawings", df[~kenney & ~quad]), ("quadruped", df[quad]),
                                ("kenney", df[kenney])) if len(d)}
    # The means (and the stage's metrics) stay the AnimatedDrawings bipeds'.
    df = df[~kenney & ~quad] if (~kenney & ~quad).any() else df
    means = df.groupby("variant")[list(num)].mean()
    fail = df.pivot_table(index="variant", columns="motion", values="driving_failure_ratio", aggfunc="mean")
    return {"means": {v: {k: (None if not np.isfinite(x) else float(x)) for k, x in r.items()}
                      for v, r in means.iterrows()},
            "failure_ratio": {v: {m: float(x) for m, x in r.items()} for v, r in fail.iterrows()},
            "means_by_source": by_source}


#: Width measures of the paper's Fig. 8 claim ("thinner and smoother limbs"), with what they mean.
WIDTH_MEASURES = (("width_error", "|w / w_rest - 1|, mean"), ("width_change", "w / w_rest - 1, mean (< 0: thinner)"),
                  ("width_roughness", "bumpiness along the limb minus the drawing's"),
                  ("width_jitter", "|w_t - w_t-1| / w_rest, mean"))
#: The Kenney character whose contact sheets are written (besides every AnimatedDrawings one).
KENNEY_SHEET = "robot"


def width_table(df: pd.DataFrame) -> pd.DataFrame:
    """Fig. 8 claim: per (source, mesh), key points vs subkeys on the width measures (means over items)."""
    d = df[df["method"].isin(["keypoints", "ours"]) & df["mesh"].isin(["connected", "limbs"])]
    if "body" in d:  # a quadruped's legs swing about their drawn pose: not the paper's comparison
        d = d[d["body"] != "quadruped"]
    d = d.assign(source=np.where(d["character"].str.startswith("char"), "AnimatedDrawings", "Kenney"))
    cols = [k for k, _ in WIDTH_MEASURES] + ["arap_energy_mean"]
    return d.groupby(["source", "mesh", "method"])[cols].mean()


def figure_widths(table: pd.DataFrame, path: Path) -> None:
    """Bar chart of :func:`width_table` (PNG): key points vs subkeys per mesh and source, one panel per measure."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12, 3.4), dpi=110)
    groups = [(src, mesh) for src, mesh in dict.fromkeys((a, b) for a, b, _ in table.index)]
    for k, (col, what) in enumerate(WIDTH_MEASURES):
        ax = fig.add_subplot(1, len(WIDTH_MEASURES), k + 1)
        x = np.arange(len(groups))
        for j, (method, label) in enumerate((("keypoints", "ARAP, key points"), ("ours", "subkeys"))):
            vals = [table.loc[(src, mesh, method), col] if (src, mesh, method) in table.index else np.nan
                    for src, mesh in groups]
            ax.bar(x + (j - 0.5) * 0.38, vals, 0.38, label=label)
        ax.set_xticks(x, [f"{'AD' if s.startswith('A') else s}\n{m}" for s, m in groups], fontsize=8)
        ax.set_title(col, fontsize=9)
        ax.set_xlabel(what, fontsize=7)
        ax.axhline(0, color="k", lw=0.5)
        if k == 0:
            ax.legend(fontsize=7)
    fig.suptitle("Limb width against the drawing, per rendered frame (the paper's Fig. 8 claim)", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")


def run(data_root, out_dir=Path("reports"), characters=CHARACTERS, motions=MOTIONS,
        n_vertices: int = 800, max_frames: int = 240, subkeys_per_limb: int = 4, kenney_annotations=None,
        mapper=None, azimuth=None, kenney_characters=None, kenney_vertices: int = 300, arms=None,
        head=None) -> dict:
    """Evaluate and write the report files (module docstring); returns the summary dict.

    ``azimuth``: projection per motion (degrees; default :data:`AZIMUTH`).
    ``arms``: ``{character: "motion" | "drawing"}`` (default :data:`ARMS`).
    ``head``: ``{character: "motion" | "torso"}`` (default :data:`HEAD`).
    ``kenney_characters``: Kenney sprites driven by the same motions (default
    all six of :mod:`nnsf.reshape.kenney` when their images and
    ``kenney_annotations`` exist), meshed with ``kenney_vertices``.
    """
    data_root, out_dir = Path(data_root), Path(out_dir)
    chars = data_root / "animated-drawings" / "characters"
    mots = data_root / "bandai-namco-1" / "data"
    if not chars.is_dir() or not mots.is_dir():
        raise InputError(data_root, "folder", "animated-drawings/characters and bandai-namco-1/data inside")
    az = dict(AZIMUTH if azimuth is None else azimuth)
    arm_mode = dict(ARMS if arms is None else arms)
    head_mode = dict(HEAD if head is None else head)
    gif_dir = out_dir / "reshape_eval"
    items = [{"character": str(chars / c), "motion": str(mots / f"dataset-1_{m}.bvh"), "n_vertices": n_vertices,
              "max_frames": max_frames, "subkeys_per_limb": subkeys_per_limb, "azimuth": float(az.get(m, 0.0)),
              "arms": arm_mode.get(c, "motion"), "head": head_mode.get(c, "motion"),
              "figure": (c, m) in FIGURE_ITEMS or c == characters[0], "sheet": True,
              "gif_dir": str(gif_dir) if (c, m) in FIGURE_ITEMS else None}
             for c in characters for m in motions]
    ann = Path(kenney_annotations) if kenney_annotations is not None else None
    kroot = data_root / "kenney-toon"
    if ann is not None and ann.is_dir() and kroot.is_dir():
        for c in (KC if kenney_characters is None else kenney_characters):
            items += [{"kenney": c, "kenney_root": str(kroot), "kenney_annotations": str(ann),
                       "motion": str(mots / f"dataset-1_{m}.bvh"), "n_vertices": kenney_vertices,
                       "max_frames": max_frames, "subkeys_per_limb": subkeys_per_limb,
                       "azimuth": float(az.get(m, 0.0)), "head": head_mode.get(c, "motion"),
                       "figure": False, "gif_dir": None,
                       "sheet": c == KENNEY_SHEET} for m in motions]
    refused = {}
    for c in REFUSED:  # reported with the loader's reason
        if (chars / c).is_dir():
            try:
                _character({"character": str(chars / c)})
            except InputError as exc:
                refused[c] = str(exc)
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
    summary["refused_characters"] = refused
    # On the layered mesh, are subkeys a no-op?  (Each rigid segment is pinned by its two key
    # points, and the subkeys are tracked in the limb's frame: their targets are where the
    # rigid motion puts them.)  Rows measured as another variant's say so in ``frames_as``.
    if "frames_as" in df:
        summary["same_frames"] = {f"{r.character} {r.motion} {r.mesh}/{r.method}": r.frames_as
                                  for r in df.itertuples() if r.frames_as}
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
    for r in ok:  # contact sheets of the default (layered, subkeys, sealed), 12 frames each
        if r.get("sheet"):
            name, imgs, pick = r["sheet"]
            scale = 0.5 if imgs.shape[1] > 300 else 2.0
            sheet = contact_sheet(imgs, columns=6, scale=scale, labels=[f"t={t}" for t in pick])
            path = gif_dir / "sheets" / f"{name}.png"
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp:
                cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
            artifacts.append(path)
    wt = width_table(df)
    if len(wt):
        summary["fig8_widths"] = {"/".join(k): {c: float(v) for c, v in r.items()} for k, r in wt.iterrows()}
        figure_widths(wt, out_dir / "reshape_fig8_widths.png")
        artifacts.append(out_dir / "reshape_fig8_widths.png")
    if ann is not None and ann.is_dir() and (data_root / "kenney-toon").is_dir():
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
    import sys
    import time

    t0 = time.perf_counter()
    try:
        out = evaluate_item(item)
        print(f"reshape-eval: {item.get('kenney') or Path(item['character']).name} x {Path(item['motion']).stem} "
              f"{time.perf_counter() - t0:.0f} s", file=sys.stderr, flush=True)
        return out
    except InputError as exc:
        return {"item": f"{Path(item['character']).name} x {Path(item['motion']).stem}", "error": str(exc)}


def reshape_eval(params: dict, data_root, out_dir=Path("reports"),
                 kenney_annotations=Path("tests/data/kenney"), mapper=None):
    """Stage wrapper of :func:`run`; reads ``reshape_eval.{characters, motions, n_vertices, max_frames,
    subkeys_per_limb}`` (defaults: the module's constants, 800, 240, 4).  Raises one
    :class:`InputError` naming the failed items after writing the others' results."""
    def get(key, default):  # the schema's check when present (nnsf.params.SCHEMA)
        return checked(params, f"reshape_eval.{key}", default)

    chars = tuple(get("characters", list(CHARACTERS)))
    motions = tuple(get("motions", list(MOTIONS)))
    n_vertices = get("n_vertices", 800)
    max_frames = get("max_frames", 240)
    per_limb = get("subkeys_per_limb", 4)
    azimuth = get("azimuth", dict(AZIMUTH))
    arms = get("arms", dict(ARMS))
    head = get("head", dict(HEAD))
    if not (isinstance(azimuth, dict) and all(isinstance(k, str) and isinstance(v, (int, float))
                                              and not isinstance(v, bool) for k, v in azimuth.items())):
        raise InputError("params.yaml", "reshape_eval.azimuth", "a mapping motion -> degrees", azimuth)
    for key, val, ok, what in (
            ("n_vertices", n_vertices, isinstance(n_vertices, int) and 100 <= n_vertices <= 6000, "an integer 100..6000"),
            ("max_frames", max_frames, isinstance(max_frames, int) and 3 <= max_frames <= 5000, "an integer 3..5000"),
            ("subkeys_per_limb", per_limb, isinstance(per_limb, int) and 1 <= per_limb <= 12, "an integer 1..12"),
            ("characters", chars, len(chars) > 0 and all(isinstance(c, str) for c in chars), "a list of names"),
            ("motions", motions, len(motions) > 0 and all(isinstance(c, str) for c in motions), "a list of names")):
        if not ok:
            raise InputError(source_of(params), f"reshape_eval.{key}", what, val)
    s = run(data_root, out_dir, chars, motions, n_vertices, max_frames, per_limb, kenney_annotations, mapper,
            azimuth=azimuth, arms=arms, head=head)
    metrics = {}
    for v, m in s["means"].items():
        for k in ("driving_failure_ratio", "arap_energy_mean", "stretch_ratio_max", "flipped_triangles",
                  "depth_agreement", "subkey_slide", "extra_holes", "seam_holes", "tear_px", "outline_ink", "spikes",
                  "width_error", "width_jitter"):
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
    ap = argparse.ArgumentParser(description="Reshaping evaluation (docs/method.md §15.7)")
    ap.add_argument("--data", type=Path, required=True,
                    help="folder holding animated-drawings/, bandai-namco-1/ and kenney-toon/")
    ap.add_argument("--out", type=Path, default=Path("reports"))
    ap.add_argument("--kenney", type=Path, default=Path("tests/data/kenney"))
    ap.add_argument("--vertices", type=int, default=800)
    ap.add_argument("--max-frames", type=int, default=240)
    ap.add_argument("--characters", nargs="+", default=list(CHARACTERS))
    ap.add_argument("--motions", nargs="+", default=list(MOTIONS))
    ap.add_argument("--workers", type=int, default=1, help="processes for the items (default 1)")
    a = ap.parse_args(argv)
    mapper = None
    if a.workers > 1:
        from concurrent.futures import ProcessPoolExecutor

        def mapper(fn, xs):
            with ProcessPoolExecutor(a.workers) as ex:
                return list(ex.map(fn, xs))
    s = run(a.data, a.out, tuple(a.characters), tuple(a.motions), a.vertices, a.max_frames, 4, a.kenney,
            mapper=mapper)
    pd.set_option("display.width", 200)
    print(pd.DataFrame(s["means"]).T[["arap_energy_mean", "stretch_ratio_max", "flipped_triangles",
                                      "driving_failure_ratio", "width_drift_mean", "limb_bending_change",
                                      "temporal_jitter", "depth_agreement", "order_flips_per_100_frames",
                                      "subkey_slide"]].round(4).to_string())
    print(pd.DataFrame(s["failure_ratio"]).T.round(3).to_string())
    print(pd.DataFrame(s["means"]).T[["hole_px", "holes_gt4", "extra_holes", "seam_holes", "pose_holes", "tear_px",
                                      "tear_px_max",
                                      "joint_gap_px", "joint_gap_max", "outline_ink", "outline_ink_rest", "spikes",
                                      "spikes_rest", "width_error", "width_change", "width_roughness",
                                      "width_jitter"]].round(4).to_string())
    if "kenney_iou" in s:
        print(pd.DataFrame(s["kenney_iou"]).T.round(3).to_string())
    for c, why in s.get("refused_characters", {}).items():
        print(f"REFUSED: {c}: {why}")
    for f in s["failed"]:
        print("FAILED:", f)
    return 1 if s["failed"] else 0


if __name__ == "__main__":
    raise SystemExit(main())
