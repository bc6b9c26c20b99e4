"""Your character, your motion, a style: ``nnsf animate`` and the ``animate`` stage.

:func:`animate_files` runs the whole job: read a drawn character
(:func:`read_character`), read a motion (:func:`read_motion_spec`: a BVH file
projected in a chosen view, a feature-matrix CSV, or a built-in synthetic
clip), translate it into a style of a saved style model
(:func:`nnsf.factor.style_model.translate`), retarget it to the character's
proportions (:func:`nnsf.reshape.drive.retarget`), deform the character's
mesh (:mod:`nnsf.reshape.rig`), render every frame
(:class:`nnsf.reshape.render.MeshRenderer`) and encode MP4, GIF, PNG frames
and a contact sheet.  It reports the time of each part.

Character formats (:func:`read_character`):

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

Motion formats (:func:`read_motion_spec`): ``*.bvh`` (any skeleton family
:mod:`nnsf.datasets.bvh_skeletons` maps), ``*.csv`` in the feature-matrix
contract (one clip), or ``synthetic:<character>/<motion>[/<frames>]``.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from nnsf.errors import InputError

#: Frame rate of a built-in synthetic clip (nnsf.datasets.synthetic.FPS).
SYNTHETIC_FPS = 24.0
OUTPUT_KINDS = ("mp4", "gif", "png", "sheet")


# --------------------------------------------------------------------------- characters
def _safe_yaml(path: Path):
    try:
        return yaml.safe_load(path.read_text())
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
    from nnsf.skeleton import JOINTS

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
    from nnsf.reshape.character import Character
    from nnsf.reshape.kenney import read_keypoint_file, snap_inside
    from nnsf.skeleton import JOINTS

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
    recorded in the character's notes.  Any other unsupported skeleton
    (e.g. char6's four legs and no arms) is refused, naming the joints.
    """
    from nnsf.reshape import character as chmod

    cfg = _safe_yaml(cfg_path)
    names = [j.get("name") for j in cfg["skeleton"] if isinstance(j, dict)]
    sets = _arm_sets(set(names))
    plain = all(f"{side}_{j}" in names for side in ("right", "left") for j in _ARM)
    if plain or set(sets) != {"right", "left"}:
        return chmod.load_character(cfg_path.parent if cfg_path.name == "char_cfg.yaml" else cfg_path)
    loc = {j["name"]: np.asarray(j["loc"], dtype=float) for j in cfg["skeleton"] if isinstance(j, dict)}
    chest = loc.get("torso")
    if chest is None:
        return chmod.load_character(cfg_path)
    joints, notes, extra = {}, [], []
    for side, by_k in sets.items():
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


def read_character(spec, joints=None, size: int = 512):
    """A :class:`nnsf.reshape.character.Character` from any supported format (module docstring).

    ``joints``: a joints YAML or Kenney key-point JSON for a PNG character.
    Raises :class:`InputError` naming the file and the field.
    """
    from nnsf.reshape.character import load_character
    from nnsf.reshape.stage import synthetic_character

    text = str(spec)
    p = Path(text)
    joints = Path(joints) if joints is not None else None
    if not p.exists():
        if "/" in text or "\\" in text or p.suffix:
            raise InputError(p, "file", "an existing character folder, char_cfg.yaml, PNG, YAML or JSON")
        from nnsf.datasets.synthetic import CHARACTER_NAMES

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


# --------------------------------------------------------------------------- motion
@dataclass
class Motion:
    """A 17-point clip: ``points (T, 17, 2)`` (y down), optional ``depth (T, 17)``, its ``fps``."""

    name: str
    points: np.ndarray
    fps: float
    depth: np.ndarray | None = None
    view: str | None = None
    source: str = ""
    notes: list[str] = field(default_factory=list)


def read_motion_spec(spec, view: str = "auto", fps: float | None = None, clip: str | None = None,
                     elevation: float = 0.0) -> Motion:
    """A motion from a ``.bvh``, a contract ``.csv`` or ``synthetic:<character>/<motion>[/<frames>]``.

    A BVH is projected in ``view`` (:mod:`nnsf.datasets.views`; ``auto``
    picks the one it moves most in) and resampled to ``fps`` (default: the
    file's rate).  Raises :class:`InputError` naming the file and field.
    """
    from nnsf.datasets import views

    text = str(spec)
    if text.startswith("synthetic:"):
        from nnsf.datasets import synthetic

        parts = text[len("synthetic:"):].split("/")
        if len(parts) not in (2, 3):
            raise InputError("--motion", "synthetic", "synthetic:<character>/<motion>[/<frames>]", text)
        ch, mo = parts[0], parts[1]
        n = 48
        if len(parts) == 3:
            if not parts[2].isdigit() or not 2 <= int(parts[2]) <= 5000:
                raise InputError("--motion", "synthetic frames", "an integer 2..5000", parts[2])
            n = int(parts[2])
        if ch not in synthetic.CHARACTER_NAMES:
            raise InputError("--motion", "synthetic character", ", ".join(synthetic.CHARACTER_NAMES), ch)
        if mo not in synthetic.MOTIONS:
            raise InputError("--motion", "synthetic motion", ", ".join(synthetic.MOTIONS), mo)
        out_fps = float(fps) if fps else SYNTHETIC_FPS
        # A loop of the clip's own duration, sampled at the requested rate.
        pts = synthetic.clip_points(ch, mo, int(round(n * out_fps / SYNTHETIC_FPS)))
        return Motion(name=f"{ch}-{mo}", points=pts, fps=out_fps, source=text)
    p = Path(text)
    if not p.is_file():
        raise InputError(p, "file", "an existing .bvh or feature-matrix .csv motion, or "
                         "synthetic:<character>/<motion>")
    if p.suffix.lower() == ".bvh":
        views.check_view(view)
        # Motion capture is often 120 fps: 30 is smooth for drawn animation.
        clip_obj, picked = views.load_clip_in_view(p, view=view, fps=float(fps) if fps else 30.0,
                                                   elevation=elevation)
        return Motion(name=p.stem, points=clip_obj.points, fps=clip_obj.fps, depth=clip_obj.depth,
                      view=picked, source=str(p))
    if p.suffix.lower() == ".csv":
        from nnsf.reshape.drive import read_motion

        name, _, pts = read_motion(p, clip)
        return Motion(name=name, points=pts, fps=float(fps) if fps else SYNTHETIC_FPS, source=str(p))
    raise InputError(p, "file", "a .bvh or .csv motion file", p.suffix or "no extension")


# --------------------------------------------------------------------------- the job
@dataclass
class AnimateResult:
    files: dict[str, Path]
    seconds: dict[str, float]       # wall time per part
    cpu_seconds: dict[str, float]   # CPU time of this process per part (all its threads)
    frames: int
    fps: float
    view: str | None
    style: str
    character: str
    motion: str
    notes: list[str] = field(default_factory=list)


def _say(progress, text):
    if progress:
        print(text, file=sys.stderr, flush=True)


def output_targets(out) -> dict[str, Path]:
    """What ``--out`` asks for: ``{kind: path}`` with kind in mp4, gif, png (a folder) and sheet."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix in (".mp4", ".gif"):
        return {suffix[1:]: out, "sheet": out.with_name(out.stem + "_sheet.png")}
    if suffix:
        raise InputError(out, "--out", "FILE.mp4, FILE.gif or a folder (PNG frames)", suffix)
    return {"png": out, "sheet": out.with_name(out.name + "_sheet.png")}


def animate_files(character, motion, style="none", model=None, view="auto", out="animation.mp4",
                  fps=None, joints=None, source_style=None, n_vertices=800, max_frames=5000,
                  outputs=None, progress=True, size=512, clip=None) -> AnimateResult:
    """Run the whole job (module docstring) and write the outputs; returns what was written and the times.

    Parameters
    ----------
    character : a character spec for :func:`read_character`, or a ``Character``.
    motion : a motion spec for :func:`read_motion_spec`, or a :class:`Motion`.
    style : a style of ``model``, or ``"none"`` (the motion as it is).
    model : path of a style model (``nnsf styles``), or a loaded
        :class:`~nnsf.factor.style_model.StyleModel`; needed unless style is none.
    view : front | side | three-quarter | auto, for a BVH motion.
    out : ``FILE.mp4``, ``FILE.gif`` or a folder for PNG frames; a contact
        sheet ``<stem>_sheet.png`` is written beside.  Ignored when
        ``outputs`` (``{kind: path}``, kinds of :data:`OUTPUT_KINDS`) is given.
    fps : output frame rate (default: the motion's).
    """
    from nnsf.datasets import views
    from nnsf.factor.style_model import StyleModel
    from nnsf.factor.style_model import translate as style_translate
    from nnsf.reshape import depth as depth_mod
    from nnsf.reshape.character import Character
    from nnsf.reshape.drive import retarget
    from nnsf.reshape.render import MeshRenderer, contact_sheet, write_gif, write_mp4, write_png_frames
    from nnsf.reshape.stage import BACKGROUND, build_rig, canvas

    views.check_view(view)
    targets = dict(outputs) if outputs is not None else output_targets(out)
    # Every output folder is checked before any work (a file in the way, a read-only
    # disk): one line naming the folder, and nothing rendered in vain.
    from nnsf.io import check_writable

    for folder in sorted({path if kind == "png" else path.parent for kind, path in targets.items()}):
        check_writable(folder)
    seconds: dict[str, float] = {}
    cpu: dict[str, float] = {}
    t0, c0 = time.perf_counter(), time.process_time()
    # ---- load: check everything before any work, so bad input leaves nothing behind
    style = "none" if style is None else str(style)
    sm = None
    if style != "none":
        if model is None:
            raise InputError("--model", "model", "a style model file (nnsf styles) for --style " + style)
        sm = model if isinstance(model, StyleModel) else StyleModel.load(model)
        sm.check_style(style, "--style")
        if source_style is not None:
            sm.check_style(source_style, "--source-style")
    ch = character if isinstance(character, Character) else read_character(character, joints, size)
    mo = motion if isinstance(motion, Motion) else read_motion_spec(motion, view=view, fps=fps, clip=clip)
    points, depth = mo.points[:max_frames], None if mo.depth is None else mo.depth[:max_frames]
    learned = sm.meta.get("view") if sm is not None else None
    if learned not in (None, "auto") and mo.view is not None and learned != mo.view:
        mo.notes.append(f"{sm.path}: the styles were learned in the {learned} view; this motion is seen "
                        f"in the {mo.view} view (--view {learned} matches the model)")
    out_fps = float(fps) if fps else mo.fps
    seconds["load"], cpu["load"] = time.perf_counter() - t0, time.process_time() - c0
    if mo.view is not None:
        _say(progress, f"animate: view {mo.view}" + (" (auto: the view the motion moves most in)"
                                                     if view == "auto" else ""))
    _say(progress, f"animate: {len(points)} frames of {mo.name} at {out_fps:g} fps onto {ch.name} "
                   f"({ch.shape[1]}x{ch.shape[0]} px), style {style}")
    # ---- translate
    t, c = time.perf_counter(), time.process_time()
    moved = points if sm is None else style_translate(points, style, sm, source_style=source_style)
    if depth is not None and len(moved) != len(depth):
        # The style's tempo resampled the motion (nnsf.translate); the depths follow.
        from nnsf.factor.translate import resample_clip

        depth = resample_clip(depth, len(moved))
    moved = moved[:max_frames]              # a slower style's tempo may lengthen the motion
    depth = None if depth is None else depth[:max_frames]
    if len(moved) != len(points):
        _say(progress, f"animate: {len(points)} -> {len(moved)} frames at the tempo of style {style}")
    seconds["translate"], cpu["translate"] = time.perf_counter() - t, time.process_time() - c
    # ---- retarget
    t, c = time.perf_counter(), time.process_time()
    kp = retarget(moved, ch.keypoints, source=mo.source or mo.name)
    seconds["retarget"], cpu["retarget"] = time.perf_counter() - t, time.process_time() - c
    # ---- deform
    t, c = time.perf_counter(), time.process_time()
    rig = build_rig(ch, n_vertices=n_vertices)
    V = rig.animate(kp)
    if depth is None:
        orders = np.tile(depth_mod.default_order(), (len(V), 1))
    else:
        z = depth_mod.part_depths(depth)
        height = float(np.median(np.ptp(moved[..., 1], axis=1)))
        pairs = depth_mod.part_overlaps(V, rig.mesh.triangles, rig.mesh.parts)
        orders = depth_mod.depth_orders(z, 0.015 * height, pairs=pairs)
    seconds["deform"], cpu["deform"] = time.perf_counter() - t, time.process_time() - c
    _say(progress, f"animate: deformed {len(V)} frames ({rig.mesh.n_vertices} vertices) in "
                   f"{seconds['deform']:.2f} s")
    # ---- render
    t, c = time.perf_counter(), time.process_time()
    offset, sz = canvas(ch, V)
    renderer = MeshRenderer.for_mesh(rig.mesh, ch, size=sz)
    images = np.empty((len(V), sz[0], sz[1], 3), np.uint8)
    step = max(1, len(V) // 10)
    for i in range(len(V)):
        images[i] = renderer.render(V[i] + offset, orders[i], background=BACKGROUND)
        if (i + 1) % step == 0 or i + 1 == len(V):
            _say(progress, f"animate: rendered frame {i + 1}/{len(V)}")
    seconds["render"], cpu["render"] = time.perf_counter() - t, time.process_time() - c
    # ---- encode
    t, c = time.perf_counter(), time.process_time()
    files = {}
    if "mp4" in targets:
        files["mp4"] = write_mp4(targets["mp4"], images, out_fps)
    if "gif" in targets:
        files["gif"] = write_gif(targets["gif"], images, out_fps)
    if "png" in targets:
        write_png_frames(targets["png"], images)
        files["png"] = Path(targets["png"])
    if "sheet" in targets:
        import cv2

        from nnsf.io import atomic_path

        pick = np.linspace(0, len(images) - 1, min(12, len(images))).astype(int)
        sheet = contact_sheet(images[pick], columns=6, scale=0.5 if sz[0] > 200 else 1.0,
                              labels=[f"t={k}" for k in pick])
        with atomic_path(targets["sheet"]) as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
                raise OSError(f"could not write {targets['sheet']}")
        files["sheet"] = Path(targets["sheet"])
    seconds["encode"], cpu["encode"] = time.perf_counter() - t, time.process_time() - c
    seconds["total"], cpu["total"] = time.perf_counter() - t0, time.process_time() - c0
    return AnimateResult(files=files, seconds=seconds, cpu_seconds=cpu, frames=len(images), fps=out_fps, view=mo.view,
                         style=style, character=ch.name, motion=mo.name, notes=list(ch.notes) + mo.notes)
