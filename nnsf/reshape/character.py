"""A drawn character: its texture, its silhouette and its 17 key points.

Two formats are read:

* **AnimatedDrawings** folders (``char_cfg.yaml`` beside ``texture.png`` and
  ``mask.png``): a 16-joint skeleton in pixels, mapped to our 17 points as
  documented in :data:`AD_TO_H36M` and :func:`_ad_to_keypoints`;
* **our own** character file, JSON (:func:`write_character` /
  :func:`read_character`)::

      {"format": "nnsf.character", "version": 1, "name": "char1",
       "texture": "char1.texture.png", "mask": "char1.mask.png",
       "keypoints": {"pelvis": [264.0, 397.0], ..., "r_wrist": [46.0, 311.0]}}

  with ``"body": "quadruped"`` for a four-legged character (default ``"biped"``).

  Image paths are relative to the JSON file and must stay inside its folder;
  key points are ``[x, y]`` in pixels of the texture (x right, y down), one
  per name in :data:`nnsf.skeleton.JOINTS`.

Masks with several connected components: the largest component is kept and a
:class:`MaskComponentsWarning` reports what was dropped (drawings often carry
specks of stray ink; refusing them would reject most scanned drawings).  A key
point that then lies outside the kept component is an :class:`InputError`.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
import yaml

from nnsf.errors import InputError
from nnsf.io import atomic_path, read_json, write_json
from nnsf.skeleton import JOINT_INDEX, JOINTS, N_JOINTS, rest_pose
from nnsf.io import parse_yaml, read_text

#: The AnimatedDrawings joint names a supported ``char_cfg.yaml`` holds, each once.
AD_JOINTS: tuple[str, ...] = (
    "root", "hip", "torso", "neck",
    "right_shoulder", "right_elbow", "right_hand", "left_shoulder", "left_elbow", "left_hand",
    "right_hip", "right_knee", "right_foot", "left_hip", "left_knee", "left_foot",
)

#: Our key points that copy one AnimatedDrawings joint.  AnimatedDrawings'
#: left/right is the character's own, as in Human3.6M, so no swap is needed.
#: ``torso`` is the top of AnimatedDrawings' spine (the chest), our thorax;
#: its ``neck`` sits at the base of the head and drives it, our neck/nose.
#: The remaining two are derived in :func:`_ad_to_keypoints`:
#: ``spine`` = midpoint of ``hip`` and ``torso``; ``head_top`` = extrapolated
#: from ``neck`` along the torso→neck direction to just inside the mask.
AD_TO_H36M: dict[str, str] = {
    "pelvis": "root",
    "r_hip": "right_hip", "r_knee": "right_knee", "r_ankle": "right_foot",
    "l_hip": "left_hip", "l_knee": "left_knee", "l_ankle": "left_foot",
    "thorax": "torso", "neck": "neck",
    "l_shoulder": "left_shoulder", "l_elbow": "left_elbow", "l_wrist": "left_hand",
    "r_shoulder": "right_shoulder", "r_elbow": "right_elbow", "r_wrist": "right_hand",
}

#: ``head_top`` stops this fraction of the way from ``neck`` to where the
#: torso→neck ray leaves the mask: inside the silhouette, below stray hair tips.
HEAD_TOP_FRACTION = 0.9

#: What a character's skeleton stands on (:attr:`Character.body`).
BODIES = ("biped", "quadruped")

FORMAT = "nnsf.character"
VERSION = 1


class MaskComponentsWarning(UserWarning):
    """The mask had several connected components; only the largest was kept."""


@dataclass
class Character:
    """A drawn character at rest.

    Attributes
    ----------
    name : str
    texture : ndarray, shape (H, W, 4), uint8
        The drawing, RGBA (channels in RGB order, not OpenCV's BGR).  An
        opaque alpha channel is added when the file has none.
    mask : ndarray, shape (H, W), bool
        The silhouette: one 8-connected component.
    keypoints : ndarray, shape (17, 2), float64
        Rest-pose key points in :data:`nnsf.skeleton.JOINTS` order, pixels
        ``(x, y)`` with the origin at the top-left pixel's centre.
    source : str
        Where the character was read from (for error messages).
    """

    name: str
    texture: np.ndarray
    mask: np.ndarray
    keypoints: np.ndarray
    source: str = "<memory>"
    notes: list[str] = field(default_factory=list)
    #: ``"biped"``, or ``"quadruped"``: four legs, the hind ones our legs and the front ones our
    #: arms, driven about the drawn pose (:mod:`nnsf.reshape.quadruped`).
    body: str = "biped"
    #: Arms beyond the two the skeleton drives (AnimatedDrawings' char5 has three a side):
    #: ``[{"side": "l" | "r", "joints": (3, 2) shoulder, elbow, hand}]``.  A layered mesh moves
    #: each as the driven arm of its side turns (:mod:`nnsf.reshape.pieces`, followers).
    extra_limbs: list = field(default_factory=list)

    def __post_init__(self):
        self.texture = np.asarray(self.texture)
        self.mask = np.asarray(self.mask, dtype=bool)
        self.keypoints = np.asarray(self.keypoints, dtype=np.float64)
        validate(self)

    @property
    def shape(self) -> tuple[int, int]:
        """Image size ``(H, W)`` in pixels."""
        return self.mask.shape


# --------------------------------------------------------------------------- validation

def validate(ch: Character) -> None:
    """Raise :class:`InputError` naming ``ch.source`` and the field if ``ch`` is unusable."""
    src = ch.source
    if ch.body not in BODIES:
        raise InputError(src, "body", " or ".join(BODIES), ch.body)
    if ch.texture.ndim != 3 or ch.texture.shape[2] != 4 or ch.texture.dtype != np.uint8:
        raise InputError(src, "texture", "an (H, W, 4) uint8 RGBA image",
                         f"{ch.texture.dtype} array of shape {ch.texture.shape}")
    if ch.mask.ndim != 2:
        raise InputError(src, "mask", "an (H, W) image", f"shape {ch.mask.shape}")
    if ch.texture.shape[:2] != ch.mask.shape:
        raise InputError(src, "mask", f"the texture's size {ch.texture.shape[1]}x{ch.texture.shape[0]} "
                         "(width x height)", f"{ch.mask.shape[1]}x{ch.mask.shape[0]}")
    if not ch.mask.any():
        raise InputError(src, "mask", "a silhouette with at least one foreground pixel",
                         "an empty mask")
    if ch.keypoints.shape != (N_JOINTS, 2):
        raise InputError(src, "keypoints", f"{N_JOINTS} (x, y) points", f"shape {ch.keypoints.shape}")
    bad = ~np.isfinite(ch.keypoints).all(axis=1)
    if bad.any():
        raise InputError(src, f"keypoints.{JOINTS[np.flatnonzero(bad)[0]]}", "finite pixel coordinates",
                         ch.keypoints[bad][0].tolist())
    inside = points_in_mask(ch.mask, ch.keypoints)
    if not inside.all():
        j = int(np.flatnonzero(~inside)[0])
        raise InputError(src, f"keypoints.{JOINTS[j]}", "a point inside the mask",
                         [round(float(v), 2) for v in ch.keypoints[j]])


def points_in_mask(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each point ``(..., 2)`` (pixels) falls on a foreground pixel (nearest pixel)."""
    pts = np.rint(np.asarray(points, dtype=float)).astype(np.int64)
    h, w = mask.shape
    ok = (pts[..., 0] >= 0) & (pts[..., 0] < w) & (pts[..., 1] >= 0) & (pts[..., 1] < h)
    out = np.zeros(pts.shape[:-1], dtype=bool)
    out[ok] = mask[pts[ok][:, 1], pts[ok][:, 0]]
    return out


def largest_component(mask: np.ndarray, source="<memory>") -> tuple[np.ndarray, str | None]:
    """Keep the largest 8-connected component of ``mask`` ``(H, W)``.

    Returns the cleaned mask and a note (``None`` when there was one
    component); also emits a :class:`MaskComponentsWarning` with that note.
    """
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 2:  # background plus at most one component
        return mask.astype(bool), None
    areas = stats[1:, cv2.CC_STAT_AREA]
    keep = 1 + int(np.argmax(areas))
    note = (f"{source}: mask: kept the largest of {n - 1} components ({areas.max()} px), "
            f"dropped {areas.sum() - areas.max()} px")
    warnings.warn(note, MaskComponentsWarning, stacklevel=3)
    return labels == keep, note


# --------------------------------------------------------------------------- images

def _read_image(path: Path, source, field: str) -> np.ndarray:
    if not path.is_file():
        raise InputError(source, field, "an existing image file", str(path))
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(source, field, "an image OpenCV can read (PNG, JPEG, ...)", str(path))
    return img


def _texture_rgba(img: np.ndarray, source) -> np.ndarray:
    if img.dtype == np.uint16:  # keep 8 bits; textures are only ever displayed
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise InputError(source, "texture", "an 8- or 16-bit image", str(img.dtype))
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGBA)
    if img.shape[2] == 3:
        return cv2.cvtColor(img, cv2.COLOR_BGR2RGBA)
    return cv2.cvtColor(img, cv2.COLOR_BGRA2RGBA)


def _mask_bool(img: np.ndarray) -> np.ndarray:
    # A mask may come as grey, BGR or BGRA (then the alpha channel is the silhouette).
    if img.ndim == 3:
        img = img[..., 3] if img.shape[2] == 4 else img.max(axis=2)
    return img > (img.max() // 2 if img.max() > 1 else 0)


def _load_images(texture_path: Path, mask_path: Path, source) -> tuple[np.ndarray, np.ndarray, str | None]:
    texture = _texture_rgba(_read_image(texture_path, source, "texture"), source)
    mask = _mask_bool(_read_image(mask_path, source, "mask"))
    if texture.shape[:2] != mask.shape:
        raise InputError(source, "mask", f"the texture's size {texture.shape[1]}x{texture.shape[0]} "
                         "(width x height)", f"{mask.shape[1]}x{mask.shape[0]}")
    if not mask.any():
        raise InputError(source, "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    mask, note = largest_component(mask, source)
    return texture, mask, note


# --------------------------------------------------------------------------- AnimatedDrawings

def load_animated_drawings(path, name: str | None = None) -> Character:
    """Read an AnimatedDrawings character folder (or its ``char_cfg.yaml``).

    The folder must hold ``char_cfg.yaml``, ``texture.png`` and ``mask.png``.
    The 16-joint skeleton becomes our 17 key points (:data:`AD_TO_H36M`).
    Skeletons with other joints (e.g. several shoulders per side) or missing
    joints raise :class:`InputError` naming ``char_cfg.yaml`` and ``skeleton``.
    """
    path = Path(path)
    cfg_path = path / "char_cfg.yaml" if path.is_dir() else path
    cfg, joints = read_ad_joints(cfg_path)
    extra = [n for n in joints if n not in AD_JOINTS]
    missing = [n for n in AD_JOINTS if n not in joints]
    if extra or missing:
        # The diagnosis goes into ``expected``: InputError shortens ``got``.
        found = "".join([f"; unsupported joints: {', '.join(extra)}" if extra else "",
                         f"; missing joints: {', '.join(missing)}" if missing else ""])
        raise InputError(cfg_path, "skeleton",
                         "the 16 joints of the biped AnimatedDrawings skeleton, each once ("
                         + ", ".join(AD_JOINTS) + "); several shoulders or legs per side are not "
                         "supported by this reader (nnsf.reshape.formats.read_character, which nnsf reshape, "
                         "nnsf animate and their stages use, reads extra arms and quadrupeds)" + found)
    texture, mask, note = read_ad_images(cfg_path, cfg)
    keypoints = _ad_to_keypoints(joints, mask, cfg_path)
    return Character(name=name or cfg_path.parent.name, texture=texture, mask=mask, keypoints=keypoints,
                     source=str(cfg_path), notes=[note] if note else [])


def read_ad_joints(cfg_path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """An AnimatedDrawings ``char_cfg.yaml``: the parsed file and its joints ``{name: (2,) px}``.

    A missing file, invalid YAML, a malformed joint or a joint named twice
    raises :class:`InputError` naming the file and the field.
    """
    if not cfg_path.is_file():
        raise InputError(cfg_path, "file", "an AnimatedDrawings char_cfg.yaml")
    try:
        cfg = parse_yaml(read_text(cfg_path, 10_000_000, "an AnimatedDrawings char_cfg.yaml"), cfg_path)
    except yaml.YAMLError as exc:
        raise InputError(cfg_path, "file", "valid YAML", reason=str(exc)) from None
    except RecursionError:
        raise InputError(cfg_path, "file", "YAML nested at most a few hundred levels deep") from None
    if not isinstance(cfg, dict) or not isinstance(cfg.get("skeleton"), list):
        raise InputError(cfg_path, "skeleton", "a list of joints with name, loc and parent")
    joints: dict[str, np.ndarray] = {}
    for i, j in enumerate(cfg["skeleton"]):
        if not isinstance(j, dict) or not isinstance(j.get("name"), str):
            raise InputError(cfg_path, f"skeleton[{i}].name", "a joint name")
        loc = j.get("loc")
        try:
            xy = np.asarray(loc, dtype=np.float64)
        except (TypeError, ValueError):
            xy = np.empty(0)
        if xy.shape != (2,) or not np.isfinite(xy).all():
            raise InputError(cfg_path, f"skeleton.{j['name']}.loc", "[x, y] in pixels", loc)
        if j["name"] in joints:
            raise InputError(cfg_path, "skeleton", "each joint once", f"{j['name']} twice")
        joints[j["name"]] = xy
    return cfg, joints


def read_ad_images(cfg_path: Path, cfg: dict):
    """``texture.png`` and ``mask.png`` beside ``cfg_path`` (:func:`_load_images`), the mask's size
    checked against the file's ``width`` / ``height``: ``(texture, mask, note or None)``."""
    folder = cfg_path.parent
    texture, mask, note = _load_images(folder / "texture.png", folder / "mask.png", cfg_path)
    for key, size in (("width", mask.shape[1]), ("height", mask.shape[0])):
        if key in cfg and cfg[key] != size:
            raise InputError(cfg_path, key, f"the mask's {key} {size} px", cfg[key])
    return texture, mask, note


def _ad_to_keypoints(joints: dict[str, np.ndarray], mask: np.ndarray, source) -> np.ndarray:
    """Map the 16 AnimatedDrawings joints to our 17 key points ``(17, 2)``.

    Fifteen are copies (:data:`AD_TO_H36M`); ``spine`` is the midpoint of
    ``hip`` and ``torso``; ``head_top`` continues the torso→neck direction
    from ``neck`` to :data:`HEAD_TOP_FRACTION` of the way to the mask's edge
    (AnimatedDrawings has no head-top joint, and the head's extent is only
    known from the silhouette).
    """
    kp = np.full((N_JOINTS, 2), np.nan)
    for ours, theirs in AD_TO_H36M.items():
        kp[JOINT_INDEX[ours]] = joints[theirs]
    kp[JOINT_INDEX["spine"]] = 0.5 * (joints["hip"] + joints["torso"])
    neck, thorax = joints["neck"], joints["torso"]
    up = neck - thorax
    if not np.linalg.norm(up) > 0:
        raise InputError(source, "skeleton.neck", "a point distinct from torso", neck.tolist())
    if not points_in_mask(mask, neck):
        raise InputError(source, "skeleton.neck", "a point inside the mask", neck.tolist())
    kp[JOINT_INDEX["head_top"]] = head_top_along(mask, neck, up / np.linalg.norm(up))
    return kp


def head_top_along(mask: np.ndarray, neck: np.ndarray, up: np.ndarray) -> np.ndarray:
    """The head's top ``(2,)`` px: :data:`HEAD_TOP_FRACTION` of the way from ``neck`` along the unit
    direction ``up`` to where that ray leaves the mask."""
    # March half a pixel at a time; the first step outside the mask ends the head.
    steps = np.arange(0.0, float(np.hypot(*mask.shape)), 0.5)
    inside = points_in_mask(mask, neck + steps[:, None] * up)
    exit_at = steps[np.argmin(inside)] if not inside.all() else steps[-1]
    return neck + HEAD_TOP_FRACTION * exit_at * up


# --------------------------------------------------------------------------- our JSON format

def _inside(folder: Path, rel, source, field: str) -> Path:
    if not isinstance(rel, str) or not rel:
        raise InputError(source, field, "an image path relative to the character file", rel)
    if Path(rel).is_absolute():
        raise InputError(source, field, "a relative path inside the character file's folder", rel)
    p = (folder / rel).resolve()
    if not p.is_relative_to(folder.resolve()):
        raise InputError(source, field, "a path that stays inside the character file's folder", rel)
    return p


def read_character(path) -> Character:
    """Read our JSON character file (see the module docstring)."""
    path = Path(path)
    obj = read_json(path)
    if obj.get("format") != FORMAT:
        raise InputError(path, "format", repr(FORMAT), obj.get("format"))
    if obj.get("version") != VERSION:
        raise InputError(path, "version", str(VERSION), obj.get("version"))
    name = obj.get("name")
    if not isinstance(name, str) or not name:
        raise InputError(path, "name", "a non-empty string", name)
    kps = obj.get("keypoints")
    if not isinstance(kps, dict):
        raise InputError(path, "keypoints", "an object mapping each of the 17 key point names to [x, y]")
    missing = [j for j in JOINTS if j not in kps]
    if missing:
        raise InputError(path, "keypoints", "all 17 key points " + ", ".join(JOINTS),
                         "missing " + ", ".join(missing))
    unknown = [k for k in kps if k not in JOINT_INDEX]
    if unknown:
        raise InputError(path, "keypoints", "only the names " + ", ".join(JOINTS), ", ".join(unknown))
    keypoints = np.empty((N_JOINTS, 2))
    for j in JOINTS:
        v = kps[j]
        if (not isinstance(v, list) or len(v) != 2
                or not all(isinstance(c, (int, float)) and not isinstance(c, bool) for c in v)):
            raise InputError(path, f"keypoints.{j}", "[x, y] in pixels", v)
        keypoints[JOINT_INDEX[j]] = v
    folder = path.parent
    texture, mask, note = _load_images(_inside(folder, obj.get("texture"), path, "texture"),
                                       _inside(folder, obj.get("mask"), path, "mask"), path)
    body = obj.get("body", "biped")
    if body not in BODIES:
        raise InputError(path, "body", " or ".join(BODIES), body)
    return Character(name=name, texture=texture, mask=mask, keypoints=keypoints, source=str(path),
                     notes=[note] if note else [], body=body)


def write_character(character: Character, path) -> Path:
    """Write ``character`` as ``path`` (JSON) plus two PNGs beside it, atomically.

    The images are ``<stem>.texture.png`` and ``<stem>.mask.png``; each file
    is renamed into place only when complete, and the JSON comes last, so a
    readable JSON always points at finished images.  Returns ``path``.
    """
    path = Path(path)
    stem = path.name[: -len(path.suffix)] if path.suffix else path.name
    tex_name, mask_name = f"{stem}.texture.png", f"{stem}.mask.png"
    for name, img in ((tex_name, cv2.cvtColor(character.texture, cv2.COLOR_RGBA2BGRA)),
                      (mask_name, character.mask.astype(np.uint8) * 255)):
        with atomic_path(path.parent / name) as tmp:
            if not cv2.imwrite(str(tmp), img):
                raise OSError(f"could not write {path.parent / name}")
    write_json(path, {
        "format": FORMAT, "version": VERSION, "name": character.name,
        "texture": tex_name, "mask": mask_name,
        "keypoints": {j: [float(x), float(y)] for j, (x, y) in zip(JOINTS, character.keypoints)},
        **({"body": character.body} if character.body != "biped" else {}),
    })
    return path


def load_character(path, name: str | None = None) -> Character:
    """Read a character from our JSON file or an AnimatedDrawings folder / ``char_cfg.yaml``."""
    path = Path(path)
    if path.suffix.lower() == ".json":
        return read_character(path)
    if path.is_dir() or path.suffix.lower() in (".yaml", ".yml"):
        return load_animated_drawings(path, name=name)
    raise InputError(path, "file", "a character .json file or an AnimatedDrawings folder")


# --------------------------------------------------------------------------- a built-in figure

def stick_figure(height: int = 400, arm_angle: float = 55.0, leg_angle: float = 8.0,
                 limb_width: float = 0.09, name: str = "stick") -> Character:
    """A simple drawn character built from the template body (for tests and benchmarks).

    The template rest pose (:func:`nnsf.skeleton.rest_pose`) is scaled to
    ``height`` pixels, its arms raised ``arm_angle`` degrees from hanging
    and its legs spread ``leg_angle`` degrees, then drawn: thick limbs
    (``limb_width`` × body height), a torso quad and a round head, flat
    colours with dark outlines.  Needs no data files.
    """
    kp = rest_pose()
    J = JOINT_INDEX

    def swing(chain, pivot, deg):
        a = np.radians(deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        kp[chain] = (kp[chain] - kp[pivot]) @ R.T + kp[pivot]

    # (x right, y down): positive angles turn clockwise on screen.
    swing([J["l_elbow"], J["l_wrist"]], J["l_shoulder"], -arm_angle)
    swing([J["r_elbow"], J["r_wrist"]], J["r_shoulder"], arm_angle)
    swing([J["l_knee"], J["l_ankle"]], J["l_hip"], -leg_angle)
    swing([J["r_knee"], J["r_ankle"]], J["r_hip"], leg_angle)
    span = kp.max(0) - kp.min(0)
    scale = 0.8 * height / span[1]
    head_r = 0.22 * scale
    w = int(np.ceil(span[0] * scale + 2 * head_r + 0.2 * height))
    kp = (kp - kp.min(0)) * scale + [(w - span[0] * scale) / 2, 0.1 * height + head_r * 0.3]
    thick = max(3, int(round(limb_width * height)))
    mask = np.zeros((height, w), np.uint8)
    tex = np.zeros((height, w, 3), np.uint8)
    tex[:] = (235, 230, 220)
    colours = {"torso": (70, 120, 200), "arm": (230, 170, 60), "leg": (60, 160, 90), "head": (240, 200, 170)}
    torso = np.array([kp[J["l_hip"]], kp[J["r_hip"]], kp[J["r_shoulder"]], kp[J["l_shoulder"]]])
    head_c = 0.5 * (kp[J["neck"]] + kp[J["head_top"]])

    def draw(img, colour=None, grow=0):
        """Draw the body; ``colour`` None paints each part its own colour."""
        def c(part):
            return colour if colour is not None else colours[part]

        def pt(p):
            return tuple(int(v) for v in np.rint(p))

        for a, b, part in ((11, 12, "arm"), (12, 13, "arm"), (14, 15, "arm"), (15, 16, "arm"),
                           (1, 2, "leg"), (2, 3, "leg"), (4, 5, "leg"), (5, 6, "leg")):
            cv2.line(img, pt(kp[a]), pt(kp[b]), c(part), thick + grow)
        quad = np.rint(torso).astype(np.int32)
        cv2.fillConvexPoly(img, quad, c("torso"))
        cv2.polylines(img, [quad], True, c("torso"), thick // 2 + grow)
        cv2.line(img, pt(kp[J["thorax"]]), pt(head_c), c("head"), thick + grow)
        cv2.circle(img, pt(head_c), int(head_r) + grow, c("head"), -1)

    draw(mask, 255, grow=2)
    draw(tex, (40, 40, 40), grow=2)   # a dark outline, then the fills on top
    draw(tex)
    mask = mask > 0
    rgba = np.dstack([tex, np.where(mask, 255, 0).astype(np.uint8)])
    return Character(name=name, texture=rgba, mask=mask, keypoints=kp, source=f"<stick_figure {name}>")
