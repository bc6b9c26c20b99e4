"""A drawn character from any supported file format (:func:`read_character`).

Formats:

* an AnimatedDrawings folder or its ``char_cfg.yaml`` (``texture.png`` and
  ``mask.png`` beside it);
* a single RGBA PNG whose alpha channel is the mask, with a joints YAML
  (``--joints FILE``, or ``<image stem>.yaml`` beside the PNG)::

      image: hero.png          # optional when the YAML sits beside the PNG; relative to the YAML
      name: hero               # optional
      joints:                  # the 17 key points, [x, y] pixels of the image (x right, y down)
        pelvis: [256, 300]
        r_hip: [236, 302]
        ...                    # r_knee r_ankle l_hip l_knee l_ankle spine thorax neck head_top
                               # l_shoulder l_elbow l_wrist r_shoulder r_elbow r_wrist

  (``spine`` may be left out: it is then the midpoint of pelvis and thorax);
* a Kenney toon frame (an RGBA PNG) with the project's hand-made key-point
  file (``tests/data/kenney/<character>.keypoints.json``, format
  ``nnsf.keypoints`` v1) as ``--joints``: the entry of the PNG's file name
  is used; points just off the silhouette are moved onto it;
* our character JSON (``nnsf.character`` v1, :mod:`nnsf.reshape.character`);
* the name of a built-in synthetic character (``bruno``, ``rex``, …),
  drawn by :mod:`nnsf.frames.render`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from nnsf.errors import InputError
from nnsf.io import read_yaml
from nnsf.datasets.synthetic import CHARACTER_NAMES
from nnsf.reshape import character as chmod
from nnsf.reshape.character import Character, load_character
from nnsf.reshape.kenney import read_keypoint_file, snap_inside
from nnsf.reshape.quadruped import QUADRUPED_JOINTS, is_quadruped, quadruped_keypoints
from nnsf.reshape.builtin import synthetic_character
from nnsf.skeleton import JOINTS


def _safe_yaml(path: Path):
    try:
        return read_yaml(path)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark is not None else "file"
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise InputError(path, where, "plain YAML (no tags such as !!python)", problem) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(path, "file", "a readable YAML text file", str(exc)) from None


def _check_ad_config(cfg_path: Path) -> None:
    """Check an AnimatedDrawings ``char_cfg.yaml`` before it is read: images present, joints inside the image."""
    import cv2

    folder = cfg_path.parent
    for name in ("texture.png", "mask.png"):
        if not (folder / name).is_file():
            raise InputError(folder, name, f"the character's {name[:-4]} image beside char_cfg.yaml",
                             "missing")
    cfg = _safe_yaml(cfg_path)
    if not isinstance(cfg, dict) or not isinstance(cfg.get("skeleton"), list):
        raise InputError(cfg_path, "skeleton", "a list of joints with name, loc and parent")
    mask = cv2.imread(str(folder / "mask.png"), cv2.IMREAD_UNCHANGED)
    if mask is None:
        raise InputError(folder / "mask.png", "file", "a PNG OpenCV can read")
    H, W = mask.shape[:2]
    for i, j in enumerate(cfg["skeleton"]):
        if not isinstance(j, dict):
            continue
        loc = j.get("loc")
        try:
            x, y = (float(v) for v in loc)
        except (TypeError, ValueError):
            continue  # the loader names the malformed loc
        if not (0 <= x < W and 0 <= y < H):
            raise InputError(cfg_path, f"skeleton.{j.get('name', i)}.loc",
                             f"a point inside the {W}x{H} image", loc)


def _read_rgba_png(path: Path, source):
    import cv2

    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(source, "image", "a PNG OpenCV can read", str(path))
    if img.ndim != 3 or img.shape[2] != 4:
        raise InputError(path, "alpha", "an RGBA PNG (its alpha channel is the character's mask)",
                         f"{img.shape[2] if img.ndim == 3 else 1} channel(s)")
    if img.dtype == np.uint16:
        img = (img >> 8).astype(np.uint8)
    rgba = cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)
    mask = rgba[..., 3] > 127
    if not mask.any():
        raise InputError(path, "alpha", "a silhouette (some pixels with alpha > 127)", "an empty mask")
    return rgba, mask


def _joints_from_yaml(path: Path, shape) -> tuple[dict, str | None, str | None]:
    obj = _safe_yaml(path)
    if not isinstance(obj, dict) or not isinstance(obj.get("joints"), dict):
        raise InputError(path, "joints", "a mapping of the 17 key point names to [x, y] pixels")
    joints = obj["joints"]
    unknown = [k for k in joints if k not in JOINTS]
    if unknown:
        raise InputError(path, f"joints.{unknown[0]}", "one of the key point names " + ", ".join(JOINTS))
    out = {}
    for name, v in joints.items():
        if (not isinstance(v, (list, tuple)) or len(v) != 2
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in v)):
            raise InputError(path, f"joints.{name}", "[x, y] in pixels", v)
        out[name] = np.asarray(v, dtype=float)
    if "spine" not in out and "pelvis" in out and "thorax" in out:
        out["spine"] = 0.5 * (out["pelvis"] + out["thorax"])
    missing = [j for j in JOINTS if j not in out]
    if missing:
        raise InputError(path, "joints", "all 17 key points (spine may be left out)",
                         "missing " + ", ".join(missing))
    if shape is not None:
        H, W = shape
        for name, (x, y) in out.items():
            if not (0 <= x < W and 0 <= y < H):
                raise InputError(path, f"joints.{name}", f"a point inside the {W}x{H} image", [x, y])
    image = obj.get("image")
    if image is not None and not isinstance(image, str):
        raise InputError(path, "image", "an image path relative to the YAML file", image)
    name = obj.get("name")
    return out, image, (str(name) if name is not None else None)


def _png_character(png: Path, joints_path: Path | None):
    if joints_path is None:
        for cand in (png.with_suffix(".yaml"), png.with_suffix(".yml"), png.with_suffix(".joints.yaml")):
            if cand.is_file():
                joints_path = cand
                break
    if joints_path is None:
        raise InputError(png, "joints", f"a joints YAML ({png.with_suffix('.yaml').name} beside the image, "
                         "or --joints FILE)", "none found")
    if not joints_path.is_file():
        raise InputError(joints_path, "file", "an existing joints file (YAML, or a Kenney nnsf.keypoints JSON)")
    rgba, mask = _read_rgba_png(png, png)
    if joints_path.suffix.lower() == ".json":
        frames = read_keypoint_file(joints_path)
        if png.name not in frames:
            raise InputError(joints_path, "frames", f"key points for {png.name}",
                             ", ".join(sorted(frames)[:6]))
        kp, _ = snap_inside(mask, frames[png.name])
        return Character(name=png.stem, texture=rgba, mask=mask, keypoints=kp, source=str(png))
    joints, _, name = _joints_from_yaml(joints_path, mask.shape)
    kp = np.stack([joints[j] for j in JOINTS])
    return Character(name=name or png.stem, texture=rgba, mask=mask, keypoints=kp, source=str(joints_path))


_ARM = ("shoulder", "elbow", "hand")


def _arm_sets(names) -> dict[str, dict[str, list[str]]]:
    """``{side: {suffix: [shoulder, elbow, hand names]}}`` for numbered arms such as ``right_shoulder2``."""
    import re

    out: dict[str, dict[str, list[str]]] = {}
    for n in names:
        m = re.fullmatch(r"(right|left)_shoulder(\d+)", n)
        if m:
            side, k = m.groups()
            chain = [f"{side}_{j}{k}" for j in _ARM]
            if all(c in names for c in chain):
                out.setdefault(side, {})[k] = chain
    return out


def _load_ad(cfg_path: Path):
    """An AnimatedDrawings character; a skeleton with several numbered arms a side is mapped.

    AnimatedDrawings' char5 has three arms a side (``right_shoulder1..3`` …).
    Our body has one: on each side the arm whose shoulder is nearest the chest
    (AnimatedDrawings' ``torso`` joint) drives the arm, and the other arms
    are part of the body (they move rigidly with the torso; the layered mesh
    gives a limb only the triangles within its capsule).  The choice is
    recorded in the character's notes.  A quadruped (char6: four legs, no
    arms) is read by :func:`_load_quadruped`.  Any other unsupported skeleton
    is refused, naming the joints.
    """
    cfg = _safe_yaml(cfg_path)
    names = [j.get("name") for j in cfg["skeleton"] if isinstance(j, dict)]
    if is_quadruped(names):
        return _load_quadruped(cfg_path)
    sets = _arm_sets(set(names))
    plain = all(f"{side}_{j}" in names for side in ("right", "left") for j in _ARM)
    if plain or set(sets) != {"right", "left"}:
        return chmod.load_character(cfg_path.parent if cfg_path.name == "char_cfg.yaml" else cfg_path)
    loc = {j["name"]: np.asarray(j["loc"], dtype=float) for j in cfg["skeleton"] if isinstance(j, dict)}
    chest = loc.get("torso")
    if chest is None:
        return chmod.load_character(cfg_path)
    joints, notes, extra = {}, [], []
    for side, by_k in sorted(sets.items()):     # sorted: the order of a set of names varies by run
        k = min(by_k, key=lambda q: (float(np.linalg.norm(loc[by_k[q][0]] - chest)), q))
        for j, n in zip(_ARM, by_k[k]):
            joints[f"{side}_{j}"] = loc[n]
        others = [q for q in sorted(by_k) if q != k]
        notes.append(f"{cfg_path}: skeleton: {side} arm {k} drives the {side} arm; arms "
                     f"{', '.join(others)} move with the body and turn as it turns")
        # AnimatedDrawings' left/right is the character's own, as ours (nnsf.reshape.character).
        extra += [{"side": "l" if side == "left" else "r", "name": f"{side} arm {q}",
                   "joints": np.array([loc[n] for n in by_k[q]], dtype=np.float64)} for q in others]
    for n in chmod.AD_JOINTS:
        if n not in joints:
            if n not in loc:
                return chmod.load_character(cfg_path)   # refused, naming what is missing
            joints[n] = loc[n]
    folder = cfg_path.parent
    texture, mask, note = chmod._load_images(folder / "texture.png", folder / "mask.png", cfg_path)
    kp = chmod._ad_to_keypoints(joints, mask, cfg_path)
    return chmod.Character(name=folder.name, texture=texture, mask=mask, keypoints=kp, source=str(cfg_path),
                           notes=([note] if note else []) + notes, extra_limbs=extra)


def _load_quadruped(cfg_path: Path):
    """An AnimatedDrawings quadruped (:mod:`nnsf.reshape.quadruped`): its hind legs read as our legs,
    its front legs as our arms; ``body="quadruped"``, said in a note."""
    cfg, loc = chmod.read_ad_joints(cfg_path)
    texture, mask, note = chmod.read_ad_images(cfg_path, cfg)
    for name, xy in loc.items():
        # Named as the file names it (validation after the mapping would name our key point).
        if name in QUADRUPED_JOINTS[4:] and not chmod.points_in_mask(mask, xy):
            raise InputError(cfg_path, f"skeleton.{name}.loc", "a point inside the mask", xy.tolist())
    kp = quadruped_keypoints(loc, mask, cfg_path)
    said = (f"{cfg_path}: skeleton: a quadruped: its hind legs are driven as legs and its front legs "
            "as arms, each about its drawn pose (a front leg by the other side's leg, so diagonal "
            "pairs step together); body and head move as one piece")
    return chmod.Character(name=cfg_path.parent.name, texture=texture, mask=mask, keypoints=kp,
                           source=str(cfg_path), notes=([note] if note else []) + [said], body="quadruped")


def read_character(spec, joints=None, size: int = 512):
    """A :class:`nnsf.reshape.character.Character` from any supported format (module docstring).

    ``joints``: a joints YAML or Kenney key-point JSON for a PNG character.
    Raises :class:`InputError` naming the file and the field.
    """
    text = str(spec)
    p = Path(text)
    joints = Path(joints) if joints is not None else None
    if not p.exists():
        if "/" in text or "\\" in text or p.suffix:
            raise InputError(p, "file", "an existing character folder, char_cfg.yaml, PNG, YAML or JSON")

        if text not in CHARACTER_NAMES:
            raise InputError("--character", "name", "a character file or folder, or a built-in character: "
                             + ", ".join(CHARACTER_NAMES), text)
        return synthetic_character(text, size)
    if p.is_dir():
        if (p / "char_cfg.yaml").is_file():
            _check_ad_config(p / "char_cfg.yaml")
            return _load_ad(p / "char_cfg.yaml")
        pngs = sorted(p.glob("*.png"))
        yamls = [y for y in sorted(p.glob("*.y*ml"))]
        if len(yamls) == 1 and joints is None:
            return read_character(yamls[0])
        raise InputError(p, "folder", "an AnimatedDrawings folder (char_cfg.yaml, texture.png, mask.png) "
                         "or one joints YAML with its PNG", f"{len(pngs)} PNG(s), {len(yamls)} YAML(s)")
    suffix = p.suffix.lower()
    if suffix == ".png":
        return _png_character(p, joints)
    if suffix in (".yaml", ".yml"):
        obj = _safe_yaml(p)
        if isinstance(obj, dict) and "skeleton" in obj:
            _check_ad_config(p)
            return _load_ad(p)
        if isinstance(obj, dict) and "joints" in obj:
            image = obj.get("image")
            if not isinstance(image, str) or not image:
                raise InputError(p, "image", "the character's RGBA PNG, relative to the YAML file", image)
            png = (p.parent / image)
            if Path(image).is_absolute() or not png.resolve().is_relative_to(p.parent.resolve()):
                raise InputError(p, "image", "a relative path inside the YAML file's folder", image)
            if not png.is_file():
                raise InputError(p, "image", "an existing RGBA PNG", image)
            return _png_character(png, p)
        raise InputError(p, "file", "an AnimatedDrawings char_cfg.yaml (skeleton:) or a joints YAML (joints:)")
    if suffix == ".json":
        return load_character(p)
    raise InputError(p, "file", "a character folder, char_cfg.yaml, RGBA PNG, joints YAML or character JSON")
