"""The ``reshape`` stage: a drawn character performing a motion clip, rendered to files.

:func:`reshape` reads the ``reshape:`` section of ``params.yaml`` (every key is commented there;
``arms`` and ``head`` may be set too: unset, the character's own choice applies, else ``motion``)
and writes, atomically as one folder ``out_dir``: ``frames/frame_0000.png`` …, ``<name>.gif``,
``<name>.mp4``, ``<name>_sheet.png`` (a contact sheet) and ``metrics.json`` (docs/method.md §15.7,
with the reader's notes; no wall times, so reruns are byte-identical).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from nnsf.errors import InputError
from nnsf.io import atomic_dir, atomic_path, write_json
from nnsf.params import RESHAPE_FORMATS, checked, source_of
from nnsf.pipeline import RESHAPE_DIR, TRANSLATION_DIR, StageResult
from nnsf.names import safe_name
from nnsf.params import project_path
from nnsf.reshape import depth as depth_mod
from nnsf.reshape.animator import BACKGROUND, Animation, Animator, canvas
from nnsf.reshape.character import Character
from nnsf.reshape.drive import read_motion
from nnsf.reshape.formats import read_character, synthetic_character
from nnsf.reshape.metrics import deformation_report
from nnsf.reshape.video import contact_sheet, write_gif, write_mp4, write_png_frames


def resolve_character(spec, size: int = 512, root=Path("."), source="params.yaml") -> Character:
    """A character from a built-in name, or from a path (relative, inside ``root``) in any format
    :func:`nnsf.reshape.formats.read_character` reads."""
    if isinstance(spec, Character):
        return spec
    if not isinstance(spec, (str, Path)) or not str(spec):
        raise InputError(source, "reshape.character", "a character name or path", spec)
    text = str(spec)
    full = project_path(text, source, "reshape.character", root)
    if full is None:
        try:
            return synthetic_character(text, size)
        except ValueError as exc:
            raise InputError(source, "reshape.character", "a built-in character name or a character "
                             "file/folder", reason=str(exc)) from None
    if not full.exists():
        raise InputError(source, "reshape.character", "an existing character file or folder", text)
    return read_character(full)


def extra_arms_notes(character: Character, arms: str, setting: str) -> list[str]:
    """A note when ``character`` has extra arms and its arms follow the motion: they turn with the
    driven arms, which point as the performer's and may cross the body."""
    if not character.extra_limbs or arms != "motion":
        return []
    return [f"{setting} motion: {character.name}'s extra arms turn with its driven arms, which point as "
            f"the motion's do and may cross its body; {setting} drawing swings them about their drawn pose"]


def report(animator: Animator, anim: Animation) -> dict:
    """docs/method.md §15.7 numbers of an animation (flat dict)."""
    d = animator.deformer
    out = deformation_report(animator.mesh, anim.frames, anim.keypoints, animator.rig.keypoints[:17], d.rest_omega)
    out.update(frames=int(len(anim.frames)), vertices=int(animator.mesh.n_vertices),
               triangles=int(len(animator.mesh.triangles)))
    if anim.part_z is not None:
        pairs = depth_mod.part_overlaps(anim.frames, animator.mesh.triangles, np.minimum(animator.mesh.parts, 9))
        base = np.array([[p for p in o if p < depth_mod.N_PARTS] for o in anim.orders])
        out.update(depth_mod.depth_metric(base, anim.part_z, 0.0, pairs=pairs))
    return out


def write_sheet(path, images, labels, scale: float = 0.5) -> Path:
    """A contact sheet of ``images`` (6 columns) as a PNG, atomically."""
    sheet = contact_sheet(images, columns=6, scale=scale, labels=labels)
    with atomic_path(path) as tmp:
        if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
            raise OSError(f"could not write {path}")
    return Path(path)


def stage_params(params: dict) -> dict:
    """The ``reshape`` section, each field checked by the params schema (defaults when absent).

    The ranges are :data:`nnsf.params.SCHEMA`'s, the ones ``nnsf check`` applies; errors name the
    params file the section came from.
    """
    defaults = {"clip": None, "character": "bruno", "character_size": 512, "n_vertices": 800,
                "subkeys_per_limb": 4, "method": "ours", "propagation": "limb-frame", "fps": 24,
                "max_frames": 240, "formats": list(RESHAPE_FORMATS), "depth_overrides": [], "arms": None, "head": None}
    p = {key: checked(params, f"reshape.{key}", default) for key, default in defaults.items()}
    if p["method"] == "ours" and p["subkeys_per_limb"] == 0:
        raise InputError(source_of(params), "reshape.subkeys_per_limb", "at least 1 for method ours", 0)
    return p


def reshape(params: dict, motion_csv=TRANSLATION_DIR / "translated_features.csv", character_path=None,
            out_dir=RESHAPE_DIR, mapper=None, joints=None) -> StageResult:
    """Render a character performing one clip of ``motion_csv`` into ``out_dir`` (module docstring).

    ``character_path`` (with ``joints`` for a PNG) overrides ``reshape.character``.
    """
    p = stage_params(params)
    source = source_of(params)
    character = (read_character(character_path, joints) if character_path is not None
                 else resolve_character(p["character"], p["character_size"], source=source))
    clip, frame_ids, points = read_motion(motion_csv, p["clip"])
    name = safe_name(character.name, character.source or source, "name") + "_" + safe_name(clip, motion_csv, "clip")
    points, frame_ids = points[: p["max_frames"]], frame_ids[: p["max_frames"]]
    animator = Animator(character, p["n_vertices"], p["method"], p["subkeys_per_limb"], p["propagation"])
    overrides = depth_mod.parse_overrides(p["depth_overrides"], len(points), source=source)
    anim = animator.animate(points, arms=p["arms"], head=p["head"], source=f"{motion_csv} (clip {clip})",
                            frames=frame_ids, overrides=overrides)
    arms = p["arms"] or character.arms or "motion"
    notes = list(character.notes) + extra_arms_notes(character, arms, "reshape.arms")
    offset, size = canvas(anim.frames, shape=character.shape)
    renderer = animator.renderer(size)
    images = np.stack([renderer.render(v + offset, o, BACKGROUND) for v, o in zip(anim.frames, anim.orders)])
    numbers = report(animator, anim)
    out_dir = Path(out_dir)
    artifacts = []
    with atomic_dir(out_dir) as tmp:
        if "png" in p["formats"]:
            write_png_frames(tmp / "frames", images)
        for fmt, write in (("gif", write_gif), ("mp4", write_mp4)):
            if fmt in p["formats"]:
                write(tmp / f"{name}.{fmt}", images, p["fps"])
                artifacts.append(out_dir / f"{name}.{fmt}")
        pick = np.linspace(0, len(images) - 1, min(12, len(images))).astype(int)
        write_sheet(tmp / f"{name}_sheet.png", images[pick], [f"t={t}" for t in pick])
        artifacts.append(out_dir / f"{name}_sheet.png")
        write_json(tmp / "metrics.json", {"character": character.name, "clip": clip, "params": p,
                                          "notes": notes, "metrics": numbers})
    scalar = {f"reshape_{k}": v for k, v in numbers.items() if isinstance(v, (int, float)) and np.isfinite(v)}
    return StageResult(params={f"reshape.{k}": (v if not isinstance(v, list) else ",".join(map(str, v)))
                               for k, v in p.items()},
                       metrics=scalar, artifacts=artifacts + [out_dir / "metrics.json"])

