"""A drawn character from any supported file (:func:`read_character`); docs/formats.md §4.

* **An AnimatedDrawings folder** or its ``char_cfg.yaml`` (``texture.png`` and ``mask.png``
  beside it), read as AnimatedDrawings reads it: ``skeleton`` is a list of joints with ``name``,
  ``loc`` ``[x, y]`` (pixels) and ``parent``.  The 16-joint biped maps to our 17 key points
  (:data:`AD_TO_OURS`); numbered arms (``right_shoulder2`` …) give the arm nearest the chest to
  our skeleton and the others become extra arms; the quadruped joints
  (``right_hip_b`` …) are read by :mod:`nnsf.reshape.quadruped`.
* **A PNG** whose alpha channel is the mask (or ``mask="auto"``: from the border colour), with
  a character YAML (``--joints FILE``, or ``<stem>.yaml`` beside it) or an ``nnsf.keypoints`` JSON
  (the entry of the PNG's file name).
* **A character YAML** (below), **our character JSON** (``nnsf.character`` v1,
  :func:`write_character`) or **a built-in character** name.

The character YAML holds the per-character choices, beside the drawing (``character.yaml`` in an
AnimatedDrawings folder, ``<stem>.yaml`` beside a PNG) or given as the character itself; its fields
are in docs/formats.md §4.4 (:func:`_choices` checks them).

Every YAML is read by :func:`nnsf.safe_yaml.read_yaml` (bounded, safe).
"""
from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np

from nnsf.datasets.synthetic import CHARACTER_NAMES
from nnsf.errors import InputError
from nnsf.frames.render import render_character
from nnsf.io import atomic_path, read_json, write_json
from nnsf.safe_yaml import read_yaml
from nnsf.params import ARM_CHOICES, HEAD_CHOICES, LEG_CHOICES
from nnsf.reshape import character as C
from nnsf.reshape.character import Character
from nnsf.reshape.depth import PART_ALIASES
from nnsf.reshape.quadruped import QUADRUPED_JOINTS, is_quadruped, quadruped_keypoints
from nnsf.skeleton import JOINT_INDEX, JOINTS, N_JOINTS

#: Our key points that copy one AnimatedDrawings joint (left/right is the character's own in both).
#: ``torso`` (the top of the spine) is our thorax; ``neck``, at the base of the head, our neck.
#: ``spine`` is the middle of ``hip`` and ``torso``; ``head_top`` is found along the torso → neck line.
AD_TO_OURS: dict[str, str] = {
    "pelvis": "root", "r_hip": "right_hip", "r_knee": "right_knee", "r_ankle": "right_foot",
    "l_hip": "left_hip", "l_knee": "left_knee", "l_ankle": "left_foot", "thorax": "torso", "neck": "neck",
    "l_shoulder": "left_shoulder", "l_elbow": "left_elbow", "l_wrist": "left_hand",
    "r_shoulder": "right_shoulder", "r_elbow": "right_elbow", "r_wrist": "right_hand"}
AD_JOINTS = tuple(AD_TO_OURS.values()) + ("hip", "torso")
#: ``head_top`` stops this share of the way from the neck to where the torso → neck ray leaves the mask.
HEAD_TOP_SHARE = 0.9
#: The most joints a skeleton may list.
MAX_JOINTS = 256
CHOICES = {"arms": ARM_CHOICES, "head": HEAD_CHOICES, "legs": LEG_CHOICES, "extra_arms": ("follow", "body"),
           "facing": ("left", "right")}
FORMAT, VERSION = "nnsf.character", 1


def _point(v, source, field: str) -> np.ndarray:
    """``[x, y]`` → ``(2,)`` float64, checked before any array is built."""
    if (not isinstance(v, (list, tuple)) or len(v) != 2
            or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in v)
            or not all(np.isfinite(c) for c in v)):
        raise InputError(source, field, "[x, y] in pixels", v)
    return np.array(v, dtype=np.float64)


def _inside(base: Path, rel, source, field: str) -> Path:
    """``base / rel`` for a relative path that stays inside ``base``."""
    if not isinstance(rel, str) or not rel:
        raise InputError(source, field, "a path relative to the file", rel)
    p = (base / rel).resolve()
    if Path(rel).is_absolute() or not p.is_relative_to(base.resolve()):
        raise InputError(source, field, "a relative path that stays inside the file's folder", rel)
    return p


def _images(texture_path: Path, mask_spec, source, max_size: float):
    """``(texture RGBA, mask, notes, scale (sx, sy))`` for a texture and a mask path, ``"auto"`` or None (alpha)."""
    img = C.read_image(texture_path, source, "texture")
    texture = C.to_rgba(img)
    if mask_spec == "auto":
        mask = C.mask_from_border(texture)
    elif mask_spec is None:
        if img.ndim != 3 or img.shape[2] != 4 or img[..., 3].min() == 255:
            raise InputError(texture_path, "alpha", "an RGBA PNG whose alpha is the character's mask (or "
                             "--mask auto: the mask from the paper's colour at the border)",
                             "no transparent pixel" if img.ndim == 3 and img.shape[2] == 4
                             else f"{img.shape[2] if img.ndim == 3 else 1} channel(s)")
        mask = texture[..., 3] > 127
    else:
        mask = C.mask_image(C.read_image(mask_spec, source, "mask"))
    if texture.shape[:2] != mask.shape:
        raise InputError(source, "mask", f"the texture's size {texture.shape[1]}x{texture.shape[0]}",
                         f"{mask.shape[1]}x{mask.shape[0]}")
    if not mask.any():
        raise InputError(source, "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    H, W = mask.shape
    texture, mask, _, note = C.downscale(texture, mask, np.zeros((0, 2)), max_size, source)
    scale = (mask.shape[1] / W, mask.shape[0] / H)
    mask, kept = C.largest_component(mask, source)
    return texture, mask, [n for n in (note, kept) if n], scale


def _scaled(points: dict, scale) -> dict:
    return {k: (np.asarray(v) + 0.5) * scale - 0.5 for k, v in points.items()}


# --------------------------------------------------------------------------- AnimatedDrawings

def read_ad_joints(cfg_path: Path, cfg) -> dict[str, np.ndarray]:
    """``{name: (2,) px}`` of a char_cfg.yaml's ``skeleton``, each joint checked (shape, finite, once)."""
    skel = cfg.get("skeleton") if isinstance(cfg, dict) else None
    if not isinstance(skel, list) or not 0 < len(skel) <= MAX_JOINTS:
        raise InputError(cfg_path, "skeleton", f"a list of 1..{MAX_JOINTS} joints with name, loc and parent")
    joints = {}
    for i, j in enumerate(skel):
        if not isinstance(j, dict) or not isinstance(j.get("name"), str):
            raise InputError(cfg_path, f"skeleton[{i}].name", "a joint name")
        if j["name"] in joints:
            raise InputError(cfg_path, "skeleton", "each joint once", f"{j['name']} twice")
        joints[j["name"]] = _point(j.get("loc"), cfg_path, f"skeleton.{j['name']}.loc")
    return joints


def head_top(mask: np.ndarray, neck: np.ndarray, below: np.ndarray, source) -> np.ndarray:
    """The head's top along ``below → neck`` beyond the neck (:func:`~nnsf.reshape.character.head_top_along`)."""
    up = neck - below
    if not np.linalg.norm(up) > 0:
        raise InputError(source, "skeleton.neck", "a point distinct from torso", neck.tolist())
    return C.head_top_along(mask, neck, up / np.linalg.norm(up), HEAD_TOP_SHARE)


def _numbered_arms(names) -> dict[str, dict[str, list[str]]]:
    """``{side: {number: [shoulder, elbow, hand]}}`` of numbered arms (``right_shoulder2`` …)."""
    out: dict[str, dict[str, list[str]]] = {}
    for n in names:
        m = re.fullmatch(r"(right|left)_shoulder(\d+)", n)
        if m:
            side, k = m.groups()
            chain = [f"{side}_{j}{k}" for j in ("shoulder", "elbow", "hand")]
            if all(c in names for c in chain):
                out.setdefault(side, {})[k] = chain
    return out


def _read_ad(cfg_path: Path, max_size: float, extra_arms: str = "follow") -> Character:
    cfg = read_yaml(cfg_path)
    joints = read_ad_joints(cfg_path, cfg)
    folder = cfg_path.parent
    for name in ("texture.png", "mask.png"):
        if not (folder / name).is_file():
            raise InputError(folder, name, f"the character's {name[:-4]} image beside char_cfg.yaml", "missing")
    texture, mask, notes, scale = _images(folder / "texture.png", folder / "mask.png", cfg_path, max_size)
    for key, n in (("width", 1), ("height", 0)):
        if key in cfg and cfg[key] != round(mask.shape[n] / scale[1 - n]):
            raise InputError(cfg_path, key, f"the mask's {key} {round(mask.shape[n] / scale[1 - n])} px", cfg[key])
    joints, snapped = C.snap_joints(mask, _scaled(joints, scale), cfg_path, "skeleton.{}.loc")
    notes += snapped
    common = dict(name=folder.name, texture=texture, mask=mask, source=str(cfg_path))
    if is_quadruped(joints):
        notes.append(f"{cfg_path}: skeleton: a quadruped: its hind legs are driven as legs and its front legs as "
                     "arms, each about its drawn pose; body and head move as one piece")
        kp = quadruped_keypoints(joints, mask, cfg_path)
        return Character(keypoints=kp, notes=notes, body="quadruped", **common)
    extra = []
    arms = _numbered_arms(set(joints))
    if set(arms) == {"right", "left"} and "torso" in joints:
        for side, by_k in sorted(arms.items()):
            k = min(by_k, key=lambda q: (float(np.linalg.norm(joints[by_k[q][0]] - joints["torso"])), q))
            for j, n in zip(("shoulder", "elbow", "hand"), by_k[k]):
                joints[f"{side}_{j}"] = joints[n]
            others = [q for q in sorted(by_k) if q != k]
            notes.append(f"{cfg_path}: skeleton: {side} arm {k} drives the {side} arm; arms {', '.join(others)} "
                         + ("turn as it turns" if extra_arms == "follow" else "move with the body"))
            if extra_arms == "follow":
                extra += [{"side": side[0], "joints": np.array([joints[n] for n in by_k[q]])} for q in others]
    missing = [n for n in AD_JOINTS if n not in joints]
    unknown = [n for n in joints if n not in AD_JOINTS and not re.fullmatch(r"(right|left)_(shoulder|elbow|hand)\d+", n)]
    if missing or unknown:
        raise InputError(cfg_path, "skeleton", "the 16 joints of the AnimatedDrawings biped (" + ", ".join(AD_JOINTS)
                         + "), numbered extra arms, or the quadruped's (" + ", ".join(QUADRUPED_JOINTS) + ")",
                         "; ".join(s for s in (f"missing joints: {', '.join(missing)}" if missing else "",
                                               f"unsupported joints: {', '.join(unknown)}" if unknown else "") if s))
    kp = np.empty((N_JOINTS, 2))
    for ours, theirs in AD_TO_OURS.items():
        kp[JOINT_INDEX[ours]] = joints[theirs]
    kp[JOINT_INDEX["spine"]] = 0.5 * (joints["hip"] + joints["torso"])
    kp[JOINT_INDEX["head_top"]] = head_top(mask, joints["neck"], joints["torso"], cfg_path)
    return Character(keypoints=kp, notes=notes, extra_limbs=extra, **common)


# --------------------------------------------------------------------------- character YAML / JSON

def _choices(obj: dict, source) -> dict:
    """The per-character choices of a character YAML, checked."""
    out = {}
    for key, allowed in CHOICES.items():
        if obj.get(key) is not None:
            if obj[key] not in allowed:
                raise InputError(source, key, " or ".join(allowed), obj[key])
            out[key] = obj[key]
    depth = obj.get("depth") or []
    if not isinstance(depth, list):
        raise InputError(source, "depth", "a list such as [left_arm over torso]", depth)
    pairs = []
    for i, item in enumerate(depth):
        words = item.split() if isinstance(item, str) else []
        if len(words) != 3 or words[1] != "over" or words[0] not in PART_ALIASES or words[2] not in PART_ALIASES:
            raise InputError(source, f"depth[{i}]", "'<part> over <part>', parts " + ", ".join(PART_ALIASES), item)
        pairs.append((PART_ALIASES[words[0]], PART_ALIASES[words[2]]))
    out["depth"] = pairs
    return out


def _yaml_joints(obj: dict, source) -> dict[str, np.ndarray]:
    joints = obj.get("joints")
    if not isinstance(joints, dict):
        raise InputError(source, "joints", "a mapping of the 17 key point names to [x, y] pixels")
    unknown = [k for k in joints if k not in JOINT_INDEX]
    if unknown:
        raise InputError(source, f"joints.{unknown[0]}", "one of the key point names " + ", ".join(JOINTS))
    out = {k: _point(v, source, f"joints.{k}") for k, v in joints.items()}
    if "spine" not in out and "pelvis" in out and "thorax" in out:
        out["spine"] = 0.5 * (out["pelvis"] + out["thorax"])
    missing = [j for j in JOINTS if j not in out]
    if missing:
        raise InputError(source, "joints", "all 17 key points (spine may be left out)", "missing " + ", ".join(missing))
    return out


def _from_yaml(path: Path, obj, root: Path | None, max_size: float, mask=None) -> Character:
    """A character YAML (module docstring); its paths are relative to ``root`` (default its folder)."""
    if not isinstance(obj, dict):
        raise InputError(path, "file", "a character YAML (drawing: or image:, joints:, choices)")
    base = Path(root) if root is not None else path.parent
    choices = _choices(obj, path)
    if obj.get("drawing") is None and obj.get("image") is None and path.with_suffix(".png").is_file():
        obj = {**obj, "image": path.with_suffix(".png").name}   # the PNG the YAML sits beside
        base = path.parent
    if obj.get("drawing") is not None:
        drawing = _inside(base, obj["drawing"], path, "drawing")
        cfg = drawing / "char_cfg.yaml" if drawing.is_dir() else drawing
        if not cfg.is_file():
            raise InputError(path, "drawing", "an AnimatedDrawings folder or char_cfg.yaml", obj["drawing"])
        if "joints" in obj:  # joints given here replace the config's
            folder = cfg.parent
            ch = _png(folder / "texture.png", obj, path, max_size, folder / "mask.png")
            ch.name = folder.name
        else:
            ch = _read_ad(cfg, max_size, choices.get("extra_arms", "follow"))
    elif obj.get("image") is not None:
        ch = _png(_inside(base, obj["image"], path, "image"), obj, path, max_size,
                  mask if mask is not None else (obj.get("mask") if obj.get("mask") == "auto" else
                                                 None if obj.get("mask") is None else
                                                 _inside(base, obj["mask"], path, "mask")))
    else:
        raise InputError(path, "drawing", "drawing: (an AnimatedDrawings folder) or image: (a PNG)")
    if obj.get("name") is not None:
        ch.name = str(obj["name"])
    ch.arms, ch.head, ch.legs, ch.facing = (choices.get(k) for k in ("arms", "head", "legs", "facing"))
    ch.depth = choices["depth"]
    said = [f"{k} {v}" for k, v in choices.items() if k != "depth" and v] + (["depth"] if choices["depth"] else [])
    if said:
        ch.notes.append(f"{path}: character choices: " + ", ".join(said))
    return ch


def _png(png: Path, obj: dict, source, max_size: float, mask=None) -> Character:
    texture, mask_img, notes, scale = _images(png, mask, source, max_size)
    joints, snapped = C.snap_joints(mask_img, _scaled(_yaml_joints(obj, source), scale), source)
    kp = np.stack([joints[j] for j in JOINTS])
    return Character(name=png.stem, texture=texture, mask=mask_img, keypoints=kp, source=str(source),
                     notes=notes + snapped)


def read_keypoint_file(path) -> dict[str, np.ndarray]:
    """``{image name: (17, 2)}`` from an ``nnsf.keypoints`` v1 JSON file (hand-made key points)."""
    path = Path(path)
    obj = read_json(path)
    if obj.get("format") != "nnsf.keypoints" or obj.get("version") != 1:
        raise InputError(path, "format", "'nnsf.keypoints' version 1", f"{obj.get('format')!r} {obj.get('version')!r}")
    frames = obj.get("frames")
    if not isinstance(frames, dict) or not frames:
        raise InputError(path, "frames", "an object mapping image names to key points")
    out = {}
    for name, kps in frames.items():
        if not isinstance(kps, dict):
            raise InputError(path, f"frames.{name}", "an object of 17 key points")
        out[name] = np.stack([_point(kps.get(j), path, f"frames.{name}.{j}") for j in JOINTS])
    return out


def read_json_character(path: Path, max_size: float = C.MAX_SIZE) -> Character:
    """Our character JSON (``nnsf.character`` v1, :func:`write_character`)."""
    obj = read_json(path)
    if obj.get("format") != FORMAT or obj.get("version") != VERSION:
        raise InputError(path, "format", f"{FORMAT!r} version {VERSION}", f"{obj.get('format')!r} {obj.get('version')!r}")
    if not isinstance(obj.get("name"), str) or not obj["name"]:
        raise InputError(path, "name", "a non-empty string", obj.get("name"))
    if obj.get("body", "biped") not in C.BODIES:
        raise InputError(path, "body", " or ".join(C.BODIES), obj.get("body"))
    obj["joints"] = obj.get("keypoints")
    ch = _png(_inside(path.parent, obj.get("texture"), path, "texture"), obj, path, max_size,
              _inside(path.parent, obj.get("mask"), path, "mask"))
    ch.name, ch.body = obj["name"], obj.get("body", "biped")
    return ch


def write_character(character: Character, path) -> Path:
    """Write ``character`` as ``path`` (JSON) and two PNGs beside it (``<stem>.texture.png``,
    ``<stem>.mask.png``), each atomically, the JSON last."""
    path = Path(path)
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    names = (f"{stem}.texture.png", f"{stem}.mask.png")
    for name, img in zip(names, (cv2.cvtColor(character.texture, cv2.COLOR_RGBA2BGRA),
                                 character.mask.astype(np.uint8) * 255)):
        with atomic_path(path.parent / name) as tmp:
            if not cv2.imwrite(str(tmp), img):
                raise OSError(f"could not write {path.parent / name}")
    write_json(path, {"format": FORMAT, "version": VERSION, "name": character.name, "texture": names[0],
                      "mask": names[1], "keypoints": {j: [float(x), float(y)] for j, (x, y)
                                                      in zip(JOINTS, character.keypoints)},
                      **({"body": character.body} if character.body != "biped" else {})})
    return path


# --------------------------------------------------------------------------- any format

def synthetic_character(name: str, size: int = 512, source="params.yaml") -> Character:
    """A built-in character of the synthetic set, drawn at rest (:mod:`nnsf.frames.render`)."""
    rgba, mask, kp = render_character(name, size)
    return Character(name=name, texture=rgba, mask=mask, keypoints=kp, source=f"<built-in {name}>")


def read_character(spec, joints=None, size: int = 512, mask=None, max_size: float = C.MAX_SIZE,
                   root=None) -> Character:
    """A :class:`~nnsf.reshape.character.Character` from any supported format (module docstring).

    ``joints``: a character YAML or ``nnsf.keypoints`` JSON for a PNG; ``mask``: ``"auto"`` for the
    mask from the border colour (else the PNG's alpha, or ``mask.png``); ``max_size``: megapixels a
    drawing is downscaled to (``--max-size``); ``root``: the folder a character YAML's paths are
    relative to (default its own).  Raises :class:`InputError` naming the file and the field.
    """
    text = str(spec)
    p = Path(text)
    if not p.exists():
        if "/" in text or "\\" in text or p.suffix or text not in CHARACTER_NAMES:
            raise InputError(p, "file", "an existing character folder, char_cfg.yaml, PNG, YAML or JSON, or a "
                             "built-in character: " + ", ".join(CHARACTER_NAMES))
        return synthetic_character(text, size)
    if mask not in (None, "auto"):
        raise InputError("--mask", "mask", "auto (the mask from the border colour)", mask)
    if p.is_dir():
        if (p / "char_cfg.yaml").is_file():
            return read_character(p / "char_cfg.yaml", joints, size, mask, max_size, root)
        yamls = sorted(p.glob("*.y*ml"))
        if len(yamls) == 1:
            return read_character(yamls[0], joints, size, mask, max_size, root)
        raise InputError(p, "folder", "an AnimatedDrawings folder (char_cfg.yaml, texture.png, mask.png) or one "
                         "character YAML", f"{len(yamls)} YAML file(s)")
    suffix = p.suffix.lower()
    if p.name == "char_cfg.yaml":
        beside = p.parent / "character.yaml"
        if beside.is_file():
            return _from_yaml(beside, read_yaml(beside), None, max_size)
        return _read_ad(p, max_size)
    if suffix in (".yaml", ".yml"):
        obj = read_yaml(p)
        if isinstance(obj, dict) and "skeleton" in obj:
            return _read_ad(p, max_size)
        return _from_yaml(p, obj, root, max_size, mask)
    if suffix == ".png":
        if joints is None:
            for cand in (p.with_suffix(".yaml"), p.with_suffix(".yml"), p.with_suffix(".joints.yaml")):
                if cand.is_file():
                    joints = cand
                    break
        if joints is None:
            raise InputError(p, "joints", f"a character YAML ({p.with_suffix('.yaml').name} beside the image, "
                             "or --joints FILE)", "none found")
        joints = Path(joints)
        if not joints.is_file():
            raise InputError(joints, "file", "an existing joints file (character YAML or nnsf.keypoints JSON)")
        if joints.suffix.lower() == ".json":
            frames = read_keypoint_file(joints)
            if p.name not in frames:
                raise InputError(joints, "frames", f"key points for {p.name}", ", ".join(sorted(frames)[:6]))
            return _png(p, {"joints": dict(zip(JOINTS, frames[p.name].tolist()))}, joints, max_size, mask)
        obj = read_yaml(joints)
        if not isinstance(obj, dict):
            raise InputError(joints, "file", "a character YAML")
        return _from_yaml(joints, {**obj, "image": p.name}, p.parent, max_size, mask)
    if suffix == ".json":
        return read_json_character(p, max_size)
    raise InputError(p, "file", "a character folder, char_cfg.yaml, PNG, character YAML or character JSON")
