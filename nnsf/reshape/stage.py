"""The ``reshape`` stage: a drawn character performing a motion clip, rendered to files.

:func:`reshape` reads the ``reshape:`` section of ``params.yaml``::

    reshape:
      clip: null            # clip name in the motion CSV; null = the first clip
      character: bruno      # a built-in synthetic character name (rendered by
                            # nnsf.frames.render), or a path inside the project to any
                            # character nnsf animate reads (docs/formats.md §4): a
                            # character .json, an AnimatedDrawings folder (extra arms
                            # and quadrupeds too), a joints YAML beside its RGBA PNG
      character_size: 512   # px, for a synthetic character
      n_vertices: 800       # mesh size (100..6000)
      subkeys_per_limb: 4   # 0..12
      method: ours          # ours (key points + subkeys) | keypoints (the ARAP baseline)
      mesh: layered         # layered | limbs | split | connected
      propagation: limb-frame   # limb-frame | eq12
      fps: 24               # frames per second of the motion rows (1..120)
      max_frames: 240       # at most this many frames are rendered (1..5000)
      formats: [png, gif, mp4]
      depth_overrides: []   # e.g. ["left_arm over torso from 12 to 30"] (frames 0-based, inclusive)

and writes, atomically as one folder ``out_dir``: ``frames/frame_0000.png``…,
``<name>.gif``, ``<name>.mp4``, ``<name>_sheet.png`` (a contact sheet) and
``metrics.json`` (docs/method.md §15.7, with the reader's notes on the character, e.g. how
extra arms were mapped; no wall times, so reruns are byte-identical).

:func:`animate` is the shared pipeline (also used by the evaluation):
character + motion -> key points -> rig -> deformed vertices -> depth orders.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.io import atomic_dir, write_json
from nnsf.params import RESHAPE_FORMATS
from nnsf.reshape import depth as depth_mod
from nnsf.reshape import metrics
from nnsf.reshape.builtin import synthetic_character, write_rendered_character  # noqa: F401  (re-exported)
from nnsf.reshape.character import Character
from nnsf.reshape.formats import read_character
from nnsf.reshape.drive import read_motion, retarget
from nnsf.reshape.quadruped import quadruped_orders
from nnsf.reshape.render import MeshRenderer
from nnsf.reshape.video import contact_sheet, write_gif, write_mp4, write_png_frames
from nnsf.reshape.rig import Rig
from nnsf.pipeline import RESHAPE_DIR, TRANSLATION_DIR, StageResult
from nnsf.names import safe_name
from nnsf.params import checked, project_path, source_of

METHODS = {"ours": "subkeys", "keypoints": "keypoints"}
MESHES = {"layered": "layered", "limbs": "limbs", "split": True, "connected": False}
FORMATS = RESHAPE_FORMATS
BACKGROUND = (255, 255, 255)


# --------------------------------------------------------------------------- characters

def resolve_character(spec, size: int = 512, root=Path("."), source="params.yaml") -> Character:
    """A character from a built-in name, or from a path in any format ``nnsf animate`` reads
    (:func:`nnsf.reshape.formats.read_character`: our ``.json``, an AnimatedDrawings folder or
    ``char_cfg.yaml``, biped, extra arms or quadruped, a joints YAML beside its RGBA PNG).

    A path given in a config file must be relative and stay inside ``root``.
    """
    if isinstance(spec, Character):
        return spec
    if not isinstance(spec, (str, Path)) or not str(spec):
        raise InputError(source, "reshape.character", "a character name or path", spec)
    text = str(spec)
    looks_like_path = ("/" in text or "\\" in text or text.endswith((".json", ".yaml", ".yml", ".png")))
    if not looks_like_path:
        return synthetic_character(text, size, source=source)
    full = project_path(text, source, "reshape.character", root) or Path(root) / text
    if not full.exists():
        raise InputError(source, "reshape.character", "an existing character file or folder", text)
    return read_character(full)


def extra_arms_notes(character: Character, arms: str, setting: str) -> list[str]:
    """A note when ``character`` has extra arms and ``arms`` is ``motion`` (else none): they turn
    with the driven arms, which point as the performer's and may cross the body.  ``setting``
    names the option the user sets (``reshape.arms``, ``--arms``)."""
    if not character.extra_limbs or arms != "motion":
        return []
    return [f"{setting} motion: {character.name}'s extra arms turn with its driven arms, which point as "
            f"the motion's do and may cross its body; {setting} drawing swings them about their drawn pose"]


# --------------------------------------------------------------------------- the pipeline

@dataclass
class Animation:
    """A driven character: key points ``(T, 17, 2)``, vertices ``(T, n, 2)``, orders ``(T, 10)``."""

    rig: Rig
    keypoints: np.ndarray
    frames: np.ndarray
    orders: np.ndarray
    part_z: np.ndarray | None


def build_rig(character: Character, method: str = "ours", mesh: str = "layered", n_vertices: int = 800,
              subkeys_per_limb: int = 4, propagation: str = "limb-frame", base_mesh=None,
              source="params.yaml") -> Rig:
    """The rig of one method (``ours`` | ``keypoints``) and mesh kind (``layered`` | ``limbs`` | ``split`` | ``connected``).

    ``source``: the params file named in errors.
    """
    if method not in METHODS:
        raise InputError(source, "reshape.method", "ours or keypoints", method)
    if mesh not in MESHES:
        raise InputError(source, "reshape.mesh", "layered, limbs, split or connected", mesh)
    return Rig.build(character, n_vertices=n_vertices, handle_set=METHODS[method], split=MESHES[mesh],
                     subkeys_per_limb=subkeys_per_limb, propagation=propagation, mesh=base_mesh)


def animate(rig: Rig, motion: np.ndarray, joint_depth: np.ndarray | None = None, source="motion",
            frames=None, hysteresis: float = 0.015, overrides=None, arms: str = "motion",
            head: str = "motion") -> Animation:
    """Drive ``rig`` with a motion ``(T, 17, 2)`` (any units); depth ``(T, 17)`` optional.

    ``hysteresis``: depth tie band as a fraction of the motion's body height
    (median vertical extent of its key points).  ``overrides``: checked user
    depth overrides (:func:`nnsf.reshape.depth.parse_overrides`), applied
    last, on their frames only.  ``arms``: ``motion`` or ``drawing``; ``head``: ``motion`` or
    ``torso`` (:func:`nnsf.reshape.drive.retarget`).
    """
    kp = retarget(motion, rig.character.keypoints, source=source, frames=frames, arms=arms, body=rig.character.body,
                  head=head)
    V = rig.animate(kp)
    orders, z = part_orders(rig, V, motion, joint_depth, hysteresis)
    if overrides:
        orders = depth_mod.apply_overrides(orders, overrides)
    return Animation(rig, kp, V, orders, z)


def part_orders(rig: Rig, V: np.ndarray, motion: np.ndarray, joint_depth: np.ndarray | None = None,
                hysteresis: float = 0.015):
    """Back-to-front part orders ``(T, 10)`` of ``rig``'s frames ``V`` ``(T, n, 2)``, and the part
    depths ``(T, 10)`` (None without ``joint_depth``), docs/method.md §14.

    From the motion's joint depths ``(T, 17)`` (tie band ``hysteresis`` × the
    motion's body height, ``motion`` ``(T, 17, 2)``), or one static order
    without them; a quadruped's near legs go in front and its far legs behind
    (:func:`nnsf.reshape.quadruped.quadruped_orders`).
    """
    if joint_depth is None:
        orders = np.tile(depth_mod.default_order(), (len(V), 1))
        z = None
    else:
        z = depth_mod.part_depths(joint_depth)
        height = float(np.median(np.ptp(np.asarray(motion)[..., 1], axis=1)))
        pairs = depth_mod.part_overlaps(V, rig.mesh.triangles, rig.mesh.parts)
        orders = depth_mod.depth_orders(z, hysteresis * height, pairs=pairs)
    if rig.character.body == "quadruped":
        orders = quadruped_orders(orders, rig.character.keypoints)
    return orders, z


def report(anim: Animation, depth_margin: float | None = None) -> dict:
    """docs/method.md §15.7 numbers for an animation (flat dict; see :func:`metrics.deformation_report`)."""
    rig, V = anim.rig, anim.frames
    m = rig.mesh
    om = np.broadcast_to(rig.rest_omega, (len(V),) + rig.rest_omega.shape)
    out = metrics.deformation_report(m.vertices, V, m.triangles, parts=m.parts, keypoints=rig.drive(anim.keypoints),
                                     omega=om, rest_keypoints=rig.rest_keypoints,
                                     rest_omega=rig.rest_omega, pieces=m.pieces if m.is_split else None)
    bend = metrics.deformed_bending(rig, V, anim.keypoints)
    out["limb_bending_mean"] = float(np.nanmean(bend))
    out["limb_bending_change"] = float(np.nanmean(np.abs(bend - metrics.limb_bending(rig.rest_omega))))
    out["frames"] = int(len(V))
    out["vertices"] = int(m.n_vertices)
    out["triangles"] = int(len(m.triangles))
    if anim.part_z is not None:
        margin = depth_margin if depth_margin is not None else 0.0
        pairs = depth_mod.part_overlaps(V, m.triangles, m.parts)
        out.update(depth_mod.depth_metric(anim.orders, anim.part_z, margin, pairs=pairs))
    return out


def canvas(character: Character, frames: np.ndarray, margin: int = 16) -> tuple[np.ndarray, tuple[int, int]]:
    """Offset ``(2,)`` and size ``(H, W)`` of a canvas holding every frame ``(T, n, 2)``.

    The scale stays the drawing's (one pixel per texture pixel); the canvas
    is cropped to the box of all deformed vertices over the clip plus
    ``margin`` pixels (so the character fills it instead of sitting in the
    drawing's mostly empty page), with even sides (video codecs want them).
    Without frames it is the drawing's box.
    """
    H, W = character.shape
    V = np.asarray(frames, dtype=np.float64).reshape(-1, 2)
    V = V[np.isfinite(V).all(axis=1)]
    if not len(V):
        return np.zeros(2), (H + H % 2, W + W % 2)
    lo = np.floor(V.min(axis=0)) - margin
    hi = np.ceil(V.max(axis=0)) + margin
    w, h = int(hi[0] - lo[0] + 1), int(hi[1] - lo[1] + 1)
    return -lo, (h + h % 2, w + w % 2)


# --------------------------------------------------------------------------- the stage

def stage_params(params: dict) -> dict:
    """The ``reshape`` section, each field checked by the params schema (defaults when absent).

    The ranges are :data:`nnsf.params.SCHEMA`'s, the ones ``nnsf check``
    applies; errors name the params file the section came from.
    """
    defaults = {"clip": None, "character": "bruno", "character_size": 512, "n_vertices": 800,
                "subkeys_per_limb": 4, "method": "ours", "mesh": "layered", "propagation": "limb-frame",
                "fps": 24, "max_frames": 240, "formats": list(FORMATS),
                "depth_overrides": [], "arms": "motion", "head": "motion"}
    p = {key: checked(params, f"reshape.{key}", default) for key, default in defaults.items()}
    if p["method"] == "ours" and p["subkeys_per_limb"] == 0:
        raise InputError(source_of(params), "reshape.subkeys_per_limb", "at least 1 for method ours", 0)
    return p


def reshape(params: dict, motion_csv=TRANSLATION_DIR / "translated_features.csv", character_path=None,
            out_dir=RESHAPE_DIR, mapper=None, joints=None) -> StageResult:
    """Render a character performing one clip of ``motion_csv`` into ``out_dir`` (module docstring).

    By default the translate stage's output, on ``reshape.character``;
    ``character_path`` (any file or folder :func:`nnsf.reshape.formats.read_character`
    reads; ``joints``: the joints file of a PNG) overrides ``reshape.character``.  Writes PNG frames, GIF, MP4, a contact
    sheet and ``metrics.json`` (docs/method.md §10-§14).
    """
    p = stage_params(params)
    source = source_of(params)
    character = (read_character(character_path, joints) if character_path is not None
                 else resolve_character(p["character"], p["character_size"], source=source))
    clip, frame_ids, points = read_motion(motion_csv, p["clip"])
    name = safe_name(character.name, character.source or source, "name") + "_" + safe_name(clip, motion_csv, "clip")
    points, frame_ids = points[: p["max_frames"]], frame_ids[: p["max_frames"]]
    rig = build_rig(character, p["method"], p["mesh"], p["n_vertices"], p["subkeys_per_limb"], p["propagation"],
                    source=source)
    overrides = depth_mod.parse_overrides(p["depth_overrides"], len(points), source=source)
    anim = animate(rig, points, source=f"{motion_csv} (clip {clip})", frames=frame_ids, overrides=overrides,
                   arms=p["arms"], head=p["head"])
    notes = list(character.notes) + extra_arms_notes(character, p["arms"], "reshape.arms")
    offset, size = canvas(character, anim.frames)
    renderer = MeshRenderer.for_mesh(rig.mesh, character, size=size)
    images = renderer.render_clip(anim.frames + offset, anim.orders, background=BACKGROUND)
    numbers = report(anim)
    out_dir = Path(out_dir)
    artifacts = []
    with atomic_dir(out_dir) as tmp:
        if "png" in p["formats"]:
            write_png_frames(tmp / "frames", images)
        if "gif" in p["formats"]:
            write_gif(tmp / f"{name}.gif", images, p["fps"])
            artifacts.append(out_dir / f"{name}.gif")
        if "mp4" in p["formats"]:
            write_mp4(tmp / f"{name}.mp4", images, p["fps"])
            artifacts.append(out_dir / f"{name}.mp4")
        import cv2

        pick = np.linspace(0, len(images) - 1, min(12, len(images))).astype(int)
        sheet = contact_sheet(images[pick], columns=6, scale=0.5, labels=[f"t={t}" for t in pick])
        cv2.imwrite(str(tmp / f"{name}_sheet.png"), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR))
        artifacts.append(out_dir / f"{name}_sheet.png")
        write_json(tmp / "metrics.json", {"character": character.name, "clip": clip, "params": p,
                                          "notes": notes, "metrics": numbers})
    scalar = {f"reshape_{k}": v for k, v in numbers.items() if isinstance(v, (int, float)) and np.isfinite(v)}
    return StageResult(params={f"reshape.{k}": (v if not isinstance(v, list) else ",".join(map(str, v)))
                               for k, v in p.items()},
                       metrics=scalar, artifacts=artifacts + [out_dir / "metrics.json"])
