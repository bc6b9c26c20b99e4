"""Your character, your motion, a style: ``nnsf animate`` and the ``animate`` stage.

:func:`animate_files` runs the whole job: read a drawn character
(:func:`read_character`), read a motion (:func:`read_motion_spec`: a BVH file
projected in a chosen view, a feature-matrix CSV, or a built-in synthetic
clip), translate it into a style of a saved style model
(:func:`nnsf.factor.style_model.translate`), retarget it to the character's
proportions (:func:`nnsf.reshape.drive.retarget`), deform the character's
mesh and render every frame (:class:`nnsf.reshape.animator.Animator`) and encode MP4, GIF, PNG frames
and a contact sheet.  It reports the time of each part.  The MP4 is encoded on a thread
(:func:`encoding_meanwhile`) as the frames are drawn, so drawing and encoding share the cores.

Character formats: :func:`nnsf.reshape.formats.read_character`.

Motion formats (:func:`read_motion_spec`): ``*.bvh`` (any skeleton family
:mod:`nnsf.datasets.bvh_skeletons` maps), ``*.csv`` in the feature-matrix
contract (one clip), or ``synthetic:<character>/<motion>[/<frames>]``.
"""
from __future__ import annotations

import itertools
import queue
import sys
import threading
import time
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.reshape.formats import read_character
from nnsf.datasets import synthetic, views
from nnsf.factor.style_model import StyleModel, translate as style_translate
from nnsf.animate.progress import phased
from nnsf.datasets import contract
from nnsf.io import atomic_path, check_writable
from nnsf.reshape.animator import BACKGROUND, Animator, canvas
from nnsf.reshape.character import MAX_SIZE, Character
from nnsf.reshape.drive import seen_from_side
from nnsf.skeleton import JOINT_INDEX as J
from nnsf.skeleton.layout import BONE_NAMES, bone_lengths
from nnsf.params import ARM_CHOICES, HEAD_CHOICES
from nnsf.reshape.drive import read_motion
from nnsf.reshape.render_pool import render_frames
from nnsf.reshape.video import contact_sheet, write_gif, write_mp4, write_png_frames
from nnsf.reshape.stage import extra_arms_notes

#: Frame rate of a built-in synthetic clip (nnsf.datasets.synthetic.FPS).
SYNTHETIC_FPS = 24.0
OUTPUT_KINDS = ("mp4", "gif", "png", "sheet")


def turned_way(ch: Character, share: float = 0.1) -> str | None:
    """``"left"`` or ``"right"`` when both knees of a biped are drawn bent that way, each by ``share`` of
    its shin or more (a figure turned to one side, such as a three-quarter body), else None.  A hint
    only: knees bent one way do not prove it (a dancer's one bent leg, a child's drawing)."""
    if ch.body != "biped":
        return None
    kp = ch.keypoints
    bend = [(kp[J[f"{s}_knee"], 0] - 0.5 * (kp[J[f"{s}_hip"], 0] + kp[J[f"{s}_ankle"], 0]))
            / max(float(np.linalg.norm(kp[J[f"{s}_ankle"]] - kp[J[f"{s}_knee"]])), 1e-9) for s in "lr"]
    if min(abs(b) for b in bend) < share or bend[0] * bend[1] <= 0:
        return None
    return "right" if bend[0] > 0 else "left"


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
                     elevation: float = 0.0, family=None) -> Motion:
    """A motion from a ``.bvh``, a contract ``.csv`` or ``synthetic:<character>/<motion>[/<frames>]``.

    A BVH is projected in ``view`` (:mod:`nnsf.datasets.views`; ``auto``
    picks the one it moves most in) and resampled to ``fps`` (default: the
    file's rate); ``family`` is its skeleton family (a joint map,
    :func:`nnsf.datasets.joint_map.read_joint_map`; None detects it).
    Raises :class:`InputError` naming the file and field.
    """
    text = str(spec)
    if text.startswith("synthetic:"):
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
                                                   elevation=elevation, family=family)
        return Motion(name=p.stem, points=clip_obj.points, fps=clip_obj.fps, depth=clip_obj.depth,
                      view=picked, source=str(p), notes=list(clip_obj.notes))
    if p.suffix.lower() == ".csv":
        name, _, pts = read_motion(p, clip)
        # Two connected key points at one place: the clip's problem, named (unifying it would fail).
        short = np.flatnonzero(~(np.median(bone_lengths(pts), axis=0) > 0))
        if short.size:
            a, b = BONE_NAMES[short[0]].split("-")
            raise InputError(p, f"{name}: {a}, {b}", "key points at distinct places",
                             reason=f"{a} and {b} coincide in most frames")
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


def write_keypoints(path, points, motion: str, style: str) -> Path:
    """Write key points ``(T, 17, 2)`` as one clip of the feature-matrix contract (docs/formats.md §3.1).

    The clip is ``<motion>`` (``<motion>-as-<style>`` when styled); ``character`` holds the style
    (``none`` when unstyled), ``motion`` the motion's name.  Written atomically.
    """
    import pandas as pd

    P = np.asarray(points, dtype=float).reshape(len(points), -1)
    clip = motion if style == "none" else f"{motion}-as-{style}"
    table = pd.concat([pd.DataFrame({"clip": clip, "frame": np.arange(len(P)), "character": style,
                                     "motion": motion}),
                       pd.DataFrame(P, columns=list(contract.COLUMNS[4:]))], axis=1)
    contract.write_table(path, contract.validate(table, path))
    return Path(path)


class _Stopped(Exception):
    """The frames' producer failed or was interrupted: the encoder drops its file."""


@contextmanager
def encoding_meanwhile(write, path, fps):
    """Run ``write(path, frames, fps)`` (:func:`~nnsf.reshape.video.write_mp4`) on a thread
    while the caller draws; yields ``feed(image)``, which hands it the next frame.

    The x264 encoder and the renderer each hold about a core, and both
    release the GIL in their C code, so on a thread the encoder works while
    the next frames are drawn instead of after the last.  Leaving the block
    waits for the file to be finished; an error of the writer is raised
    in the caller (at the next ``feed`` or on leaving); an error or interrupt of
    the caller stops the writer at its next frame, leaving no file.
    """
    frames, stop, failed = queue.SimpleQueue(), threading.Event(), []
    end = object()

    def taken():
        while (img := frames.get()) is not end and not stop.is_set():
            yield img
        if stop.is_set():
            raise _Stopped

    def run():
        try:
            write(path, taken(), fps)
        except _Stopped:
            pass
        except BaseException as exc:  # raised in the caller
            failed.append(exc)

    def feed(img):
        if failed:
            raise failed[0]
        frames.put(img)

    thread = threading.Thread(target=run, name="nnsf-encode", daemon=True)
    thread.start()
    try:
        yield feed
        frames.put(end)
        thread.join()       # the last frames, and the check that decodes the file back
    except BaseException:   # in the caller, or an interrupt while waiting: a writer still taking frames drops its file
        stop.set()
        frames.put(end)
        thread.join()
        raise
    if failed:
        raise failed[0]


@phased("animate")
def animate_files(character, motion, style="none", model=None, view="auto", out="animation.mp4",
                  fps=None, joints=None, source_style=None, n_vertices=800, max_frames=5000,
                  outputs=None, progress=True, size=512, clip=None, arms=None, workers=None,
                  head=None, mask=None, max_size=MAX_SIZE, joint_map=None, keypoints=None,
                  phases=None) -> AnimateResult:
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
    arms : ``motion`` (the arms point as the motion's) or ``drawing`` (they
        swing about the pose they are drawn in), :func:`nnsf.reshape.drive.retarget`; None: the
        character's own choice (its character YAML), else ``motion``.
    head : ``motion`` (the head turns as the performer's) or ``torso`` (it keeps its drawn angle to the
        body: a drawing with no neck); None as for ``arms``.
    mask : ``"auto"``: a PNG without alpha gets its mask from the border colour.
    max_size : megapixels a larger drawing is downscaled to (``--max-size``).
    fps : output frame rate (default: the motion's).
    workers : processes that render the frames (default: the CPUs this process may use, at most 8;
        :func:`nnsf.reshape.render_pool.render_frames`); the frames are the same for any number.
    joint_map : the skeleton family of a BVH motion (:func:`nnsf.datasets.joint_map.read_joint_map`).
    keypoints : a CSV path: the key points that drive the drawing (styled, retargeted; the
        drawing's pixels) are written there in the feature-matrix contract (docs/formats.md §3.1).
    progress : lines on stderr as the phases go; ``phases`` (given by the decorator) times them
        (:class:`nnsf.animate.progress.Phases`).
    """
    views.check_view(view)
    if workers is not None and (isinstance(workers, bool) or not isinstance(workers, (int, np.integer))
                                or workers < 1):
        raise InputError("--workers", "workers", "an integer >= 1", workers)
    if arms is not None and arms not in ARM_CHOICES:
        raise InputError("--arms", "arms", f"one of {', '.join(ARM_CHOICES)}", arms)
    if head is not None and head not in HEAD_CHOICES:
        raise InputError("--head", "head", f"one of {', '.join(HEAD_CHOICES)}", head)
    targets = dict(outputs) if outputs is not None else output_targets(out)
    # Every output folder is checked before any work (a file in the way, a read-only
    # disk): one line naming the folder, and nothing rendered in vain.

    written = [path if kind == "png" else path.parent for kind, path in targets.items()]
    for folder in sorted(set(written + ([Path(keypoints).parent] if keypoints is not None else []))):
        check_writable(folder)
    ph = phases
    t0, c0 = time.perf_counter(), time.process_time()
    ph.start("load", "reading the character and the motion")
    # ---- load: check everything before any work, so bad input leaves nothing behind
    style = "none" if style is None else str(style)
    sm = None
    if style != "none":
        if model is None:
            raise InputError("--model", "model", "a style model file (nnsf styles) for --style " + style)
        sm = model if isinstance(model, StyleModel) else StyleModel.load(model)
        style = sm.check_style(style, "--style")
        if source_style is not None:
            source_style = sm.check_style(source_style, "--source-style")
    ch = (character if isinstance(character, Character)
          else read_character(character, joints, size, mask=mask, max_size=max_size))
    arms, head = arms or ch.arms or "motion", head or ch.head or "motion"
    drawn_side = seen_from_side(ch)
    auto = view == "auto"
    if auto and drawn_side and not isinstance(motion, Motion):
        view = "side"
    mo = motion if isinstance(motion, Motion) else read_motion_spec(motion, view=view, fps=fps, clip=clip,
                                                                    family=joint_map)
    points, depth = mo.points[:max_frames], None if mo.depth is None else mo.depth[:max_frames]
    if sm is not None:
        # The model's view for the motion's: said now, before anything is rendered.
        _, note = sm.pick_view(mo.view)
        if note:
            mo.notes.append(note)
    if ch.body == "quadruped" and arms != "motion":
        mo.notes.append(f"--arms {arms}: {ch.name} is a quadruped; its front legs always swing about "
                        "their drawn pose (docs/method.md §12)")
    mo.notes += extra_arms_notes(ch, arms, "--arms (animate.arms)")
    if drawn_side and mo.view == "front":
        mo.notes.append(f"{ch.name} is drawn from the side: a front view swings its legs "
                        "towards the camera, out of the picture (--view side shows them)")
    turned = turned_way(ch) if auto and not drawn_side else None
    if turned:
        mo.notes.append(f"{ch.name}: both knees are drawn bent to the {turned}: if the figure is turned that "
                        f"way, facing: {turned} in its character YAML has the motion seen from the side, "
                        f"punching and stepping to the {turned} (docs/usage.md)")
    out_fps = float(fps) if fps else mo.fps
    ph.stop()
    for note in list(ch.notes) + mo.notes:
        _say(progress, f"animate: note: {note}")
    if mo.view is not None:
        why = "the view it is drawn in" if drawn_side else "the view the motion moves most in"
        _say(progress, f"animate: view {mo.view}" + (f" (auto: {why})" if auto else ""))
    _say(progress, f"animate: {len(points)} frames of {mo.name} at {out_fps:g} fps onto {ch.name} "
                   f"({ch.shape[1]}x{ch.shape[0]} px), style {style}")
    # ---- translate
    ph.start("translate", f"performing the motion in style {style}")
    moved = points if sm is None else style_translate(points, style, sm, source_style=source_style,
                                                      view=mo.view, fps=mo.fps)
    # ---- mesh: parts, mesh, deformer (once per character)
    ph.start("mesh", f"meshing {ch.name} ({ch.shape[1]}x{ch.shape[0]} px)")
    animator = Animator(ch, n_vertices=n_vertices)
    # ---- retarget
    ph.start("retarget", "fitting the motion to the drawing's proportions")
    kp = animator.retarget(moved, arms, head, source=mo.source or mo.name)
    # ---- deform
    ph.start("deform", f"deforming the mesh over {len(kp)} frames")
    V = animator.deformer.run(kp)
    orders, _ = animator.orders(V, moved, depth)
    ph.stop()
    _say(progress, f"animate: deformed {len(V)} frames ({animator.mesh.n_vertices} vertices) in "
                   f"{ph.seconds['mesh'] + ph.seconds['deform']:.2f} s")
    # ---- render
    ph.start("render", f"rendering {len(V)} frames")
    offset, sz = canvas(V, shape=ch.shape)
    renderer = animator.renderer(sz)
    step = max(1, len(V) // 10)
    said = [0]

    def rendered(done, total):
        ph.step(done, total, "frames")
        if done - said[0] >= step or done == total:
            said[0] = done
            _say(progress, f"animate: rendered frame {done}/{total}")

    files, T = {}, len(V)
    # Only a GIF and PNG frames need every frame at once (a palette, a folder written whole); an
    # MP4 takes them as they come and the sheet a dozen, so a clip's frames are not held for those.
    keep = "gif" in targets or "png" in targets
    pick, picked, count = np.linspace(0, T - 1, min(12, T)).astype(int), {}, itertools.count()
    with (encoding_meanwhile(write_mp4, targets["mp4"], out_fps) if "mp4" in targets
          else nullcontext(None)) as feed:
        def each(image):        # the frames in order, as they are drawn
            t = next(count)
            if t in pick:
                picked[t] = image
            if feed is not None:
                feed(image)

        images = render_frames(renderer, V, orders, offset, BACKGROUND, sz, workers=workers, progress=rendered,
                               each=each, keep=keep)
        # ---- encode (the MP4's last frames; it was encoded as they were drawn)
        ph.start("encode", "writing " + ", ".join(sorted(targets)))
    if "mp4" in targets:
        files["mp4"] = Path(targets["mp4"])
    if "gif" in targets:
        files["gif"] = write_gif(targets["gif"], images, out_fps)
    if "png" in targets:
        write_png_frames(targets["png"], images)
        files["png"] = Path(targets["png"])
    if "sheet" in targets:
        import cv2

        sheet = contact_sheet([picked[t] for t in pick], columns=6, scale=0.5 if sz[0] > 200 else 1.0,
                              labels=[f"t={k}" for k in pick])
        with atomic_path(targets["sheet"]) as tmp:
            if not cv2.imwrite(str(tmp), cv2.cvtColor(sheet, cv2.COLOR_RGB2BGR)):
                raise OSError(f"could not write {targets['sheet']}")
        files["sheet"] = Path(targets["sheet"])
    if keypoints is not None:       # last, beside finished videos: a failed encode leaves no table
        write_keypoints(keypoints, kp[:T], mo.name, style)
    ph.stop()
    seconds, cpu = dict(ph.seconds), dict(ph.cpu_seconds)
    seconds["total"], cpu["total"] = time.perf_counter() - t0, time.process_time() - c0
    return AnimateResult(files=files, seconds=seconds, cpu_seconds=cpu, frames=T, fps=out_fps, view=mo.view,
                         style=style, character=ch.name, motion=mo.name, notes=list(ch.notes) + mo.notes)
