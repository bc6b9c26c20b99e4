"""Loading and checking ``params.yaml``.

Each stage reads only the sections it lists in dvc.yaml; :func:`load` checks
every field it knows against :data:`SCHEMA` so that a wrong type or an
unknown choice fails with one line naming the field.
"""
from __future__ import annotations

import difflib
import math
import numbers
import os
from pathlib import Path
from typing import Any, Callable

from nnsf import names
from nnsf.errors import InputError, summarize
from nnsf.errors import read_text
from nnsf.names import is_safe_name
from nnsf.safe_yaml import parse_yaml

DATASETS = ("synthetic", "bvh", "frames")
FACINGS = ("first", "normalise", "none")
INITS = ("random", "nndsvd", "nndsvda", "nndsvdar")
METHODS = ("nnsf", "nnsc", "nmf", "bilinear", "mgpm", "cbgpm")
LABELS = ("motion", "character")
TRACKERS = ("ours", "agarwala", "lk")
TRACK_INITS = ("linear", "lk", "flow", "limb")
LK_ENDS = ("blend", "none")
SNAP_TARGETS = ("profile", "edge", "auto")
#: StyleTranslator settings (nnsf.factor.translate).
BASES = ("aligned", "refit")
SYNTHESES = ("consensus", "source")
AMPLITUDES = ("restore", "style", "none")
TRANSFERS = ("recombine_swing", "offset_swing", "recombine")
RESHAPE_FORMATS = ("png", "gif", "mp4")
#: The pipeline's stages, in dvc.yaml order (nnsf.stages maps each to its function).
STAGE_NAMES = ("frames", "roto", "roto_eval", "data", "features", "factorize", "evaluate", "isomap", "sweep",
               "heldout", "translate", "reshape", "styles", "animate", "results")
#: Camera views of projected motion capture (nnsf.datasets.views).
VIEW_CHOICES = ("front", "side", "three-quarter", "auto")
#: How a drawn character's arms follow a motion (:func:`nnsf.reshape.drive.retarget`).
ARM_CHOICES = ("motion", "drawing")
#: How a drawn character's head follows a motion (:func:`nnsf.reshape.drive.retarget`).
HEAD_CHOICES = ("motion", "torso")
#: How a drawn character's legs follow a motion (:func:`nnsf.reshape.drive.retarget`).
LEG_CHOICES = ("motion", "torso")
TRANSLATION_METHODS = ("nnsf", "nnsf_nosmooth", "nnsf_restore", "nnsf_swapped", "nnsf_refit", "api",
                       "api_source", "bilinear", "mgpm", "cbgpm", "offset", "identity", "real")
#: Methods of the leave-one-content-out protocol (nnsf.evaluate.content_out).
CONTENT_OUT_METHODS = ("api", "api_source", "api_offset_swing", "api_recombine", "offset", "spectral", "identity",
                       "real")


def _g(x) -> str:
    """A bound as people write it: 1000000 -> 1e+06, 0.5 -> 0.5, 12 -> 12."""
    return f"{x:g}" if isinstance(x, float) or abs(x) >= 1e6 else str(x)


def _int(lo: int, hi: int):
    """An integer in ``[lo, hi]`` (booleans are not integers here)."""
    def check(v):
        return isinstance(v, numbers.Integral) and not isinstance(v, bool) and lo <= v <= hi
    return check, f"an integer in [{_g(lo)}, {_g(hi)}]"


def _rank():
    check, _ = _int(1, 34)
    return check, "an integer from 1 to 34 (a rank cannot exceed the 34 features)"


def _num(lo: float, hi: float, strict: bool = False):
    """A finite number in ``[lo, hi]`` (``(lo, hi]`` when ``strict``); no NaN, no infinity."""
    def check(v):
        ok = isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v)
        return ok and (v > lo if strict else v >= lo) and v <= hi
    return check, f"a finite number in {'(' if strict else '['}{_g(lo)}, {_g(hi)}]"


def _human_bytes(n: float) -> str:
    for unit in ("bytes", "KB", "MB", "GB", "TB", "PB"):
        if n < 1000 or unit == "PB":
            return f"{n:.0f} {unit}" if unit == "bytes" else f"{n:.1f} {unit}"
        n /= 1000.0
    return f"{n:.1f} PB"  # pragma: no cover


def _size(lo: int, hi: int, bytes_each, what: str):
    """An integer count in ``[lo, hi]`` whose memory is about ``bytes_each`` per unit.

    ``bytes_each`` may instead be a function of the count giving its bytes.
    The description states the estimate at ``hi``; :func:`validate` adds the
    estimate of the value found (``check.explain``).
    """
    check, _ = _int(lo, hi)
    size = bytes_each if callable(bytes_each) else (lambda n: n * bytes_each)

    def explain(v):
        if isinstance(v, numbers.Real) and not isinstance(v, bool) and math.isfinite(v) and v > 0:
            return f"{_g(v)} {what} would need about {_human_bytes(size(float(v)))} of memory"
        return None
    check.explain = explain
    return check, (f"an integer in [{_g(lo)}, {_g(hi)}] ({_g(hi)} {what} need about "
                   f"{_human_bytes(size(hi))} of memory)")


def _choice(options):
    return (lambda v: isinstance(v, str) and v in options), "one of " + ", ".join(options)


def _bool():
    return (lambda v: isinstance(v, bool)), "true or false"


def _str(max_len: int = 500, optional: bool = False):
    return ((lambda v: (optional and v is None) or (isinstance(v, str) and 0 < len(v) <= max_len)),
            "a non-empty string" + (" or null" if optional else ""))


def _name(optional: bool = False):
    """An id that becomes a file name (:func:`nnsf.names.safe_name`): the writers' rule, applied here too."""
    return ((lambda v: (optional and v is None) or is_safe_name(v)),
            (names.EXPECTED + ", or null") if optional else names.EXPECTED)


#: What a path in params.yaml may be (:func:`project_path`).
PROJECT_PATH = "a name, or a relative path inside the project (no '..'; symbolic links resolved)"


def project_path(value, source, field: str, root=".") -> Path | None:
    """The path ``value`` names in the project ``root``, or None when it is a name (``rex``, ``synthetic:...``).

    ``value`` is a path when it holds a ``/``, ``\\`` or ``.``, or a file or
    link of that name exists in ``root``.  A path must be relative, without
    ``..``, and stay inside ``root`` once symbolic links are resolved
    (checked by resolving it, not by its text); else an :class:`InputError`
    naming ``source`` and ``field``.  The stages and ``nnsf check`` (the
    :data:`SCHEMA` entries of such fields) use this one function.
    """
    text = str(value)
    if text.startswith("synthetic:"):
        return None
    root = Path(root)
    if not any(c in text for c in "/\\.") and not os.path.lexists(root / text):
        return None
    parts = text.replace("\\", "/").split("/")
    p = Path(text)
    try:
        outside = (p.is_absolute() or text.startswith(("/", "\\", "~")) or ".." in parts
                   or not names.real(root / p).is_relative_to(names.real(root)))
    except (OSError, RuntimeError) as exc:   # a loop of symbolic links
        raise InputError(source, field, PROJECT_PATH, text, reason=str(exc)) from None
    if outside:
        raise InputError(source, field, PROJECT_PATH, text)
    return root / p


def _project_path():
    def check(v):
        if not (isinstance(v, str) and 0 < len(v) <= 500):
            return False
        try:
            project_path(v, "", "")
        except InputError:
            return False
        return True
    return check, PROJECT_PATH


def _relative():
    """A path relative to a data folder, without ``..`` (``nnsf reshape-eval --data DIR``)."""
    def check(v):
        if not (isinstance(v, str) and 0 < len(v) <= 500):
            return False
        parts = v.replace("\\", "/").split("/")
        return not (v.startswith(("/", "\\", "~")) or ".." in parts or Path(v).is_absolute())
    return check, "a relative path inside the data folder (no '..')"


def _view():
    return (lambda v: v is None or v in VIEW_CHOICES), \
        "one of " + ", ".join(VIEW_CHOICES) + " or null (null: use dataset.bvh.azimuth)"


def _list(item, max_items: int = 100):
    check, what = item
    return (lambda v: isinstance(v, list) and 0 < len(v) <= max_items and all(check(x) for x in v)), \
        f"a non-empty list of at most {max_items} items, each item {what}"


def _motions():
    """``frames.motions``: a count, or a list of distinct motion names.

    The names (and a count above the built-in motions) are checked against
    the generator's list by the frames stage (:func:`nnsf.frames.stage.frames_params`):
    importing the generator here would make every stage depend on it.
    """
    def check(v):
        if isinstance(v, numbers.Integral) and not isinstance(v, bool):
            return 1 <= v <= 100
        return (isinstance(v, list) and 0 < len(v) <= 100 and all(isinstance(m, str) and m for m in v)
                and len(set(v)) == len(v))
    return check, "a count in [1, 100] or a non-empty list of distinct motion names"


#: Bytes of memory per key-point row of the feature table while the stages
#: run (34 float64 coordinates, 4 label strings, copies made by validation,
#: unification and the fits), measured coarsely; used in size messages.
ROW_BYTES = 1000
#: Bytes per pixel of a clip held by the tracker: RGB uint8 frames plus
#: float64 grey levels, gradients and their pyramid (about 4 planes).
TRACK_PIXEL_BYTES = 3 + 8 * 4
#: Memory budget of one stage for the size checks.
MEMORY_BUDGET = 4e9

# One entry per dotted key: (check, description).  Add new parameters here:
# every key of params.yaml must be listed, and the stages read values with
# :func:`require`, which applies the same check (one definition of each range).
SCHEMA: dict[str, tuple[Callable[[Any], bool], str]] = {
    "seed": _int(0, 2**32 - 1),
    "dataset.name": _choice(DATASETS),
    "dataset.path": _str(),
    "dataset.synthetic.characters": _int(2, 12),
    "dataset.synthetic.clips_per_cell": _size(1, 1000, 15 * 12 * 24 * ROW_BYTES,
                                              "clips per cell (12 characters x 15 motions x 24 frames)"),
    "dataset.synthetic.frames": _size(4, 10000, 12 * 15 * ROW_BYTES,
                                      "frames per clip (12 characters x 15 motions, one clip each)"),
    "dataset.synthetic.noise_px": _num(0, 100),
    "dataset.bvh.fps": _num(0, 1000, strict=True),
    "dataset.bvh.azimuth": _num(-360, 360),
    "dataset.bvh.view": _view(),
    "dataset.bvh.elevation": _num(-90, 90),
    "dataset.bvh.facing": _choice(FACINGS),
    "dataset.bvh.center": _bool(),
    "dataset.bvh.complete_grid": _bool(),
    "dataset.bvh.joint_map": _str(optional=True),
    "frames.characters": _int(1, 12),
    "frames.motions": _motions(),
    "frames.clips_per_cell": _int(1, 100),
    "frames.frames": _size(2, 1000, 256 * 256 * TRACK_PIXEL_BYTES, "frames of 256x256 px in one clip"),
    "frames.size": _int(64, 4096),
    "frames.keyframe_every": _int(0, 10000),
    "frames.control_points": _int(2, 32),
    "roto.method": _choice(TRACKERS),
    "roto.w_velocity": _num(0, 1e6),
    "roto.w_length": _num(0, 1e6),
    "roto.w_length_anchor": _num(0, 1e6),
    "roto.w_curvature": _num(0, 1e6),
    "roto.w_edge": _num(0, 1e6),
    "roto.w_sketch": _num(0, 1e6),
    "roto.w_colour": _num(0, 1e6),
    "roto.window": _int(1, 32),
    "roto.samples": _int(3, 200),
    "roto.levels": _int(1, 8),
    "roto.max_iter": _int(1, 10000),
    "roto.w_slide": _num(0, 1e6),
    "roto.edge_gate": _num(0, 1000),
    "roto.velocity_trust": _bool(),
    "roto.snap": _num(0, 100),
    "roto.snap_to": _choice(SNAP_TARGETS),
    "roto.init": _choice(TRACK_INITS),
    "roto.lk_end": _choice(LK_ENDS),
    "roto.eval_clips": _int(1, 1000),
    "roto.edit_tol_px": _num(0, 1000, strict=True),
    "roto.max_edits": _int(0, 10000),
    "unify.margin": _num(0, 1000, strict=True),
    "nnsf.label": _choice(LABELS),
    "nnsf.rank": _rank(),
    "nnsf.alpha": _num(0, 1e6),
    "nnsf.beta": _num(0, 1e9),
    "nnsf.class_in_loop": _bool(),
    "nnsf.max_iter": _int(1, 100000),
    "nnsf.tol": _num(0, 1),
    "nnsf.init": _choice(INITS),
    "evaluate.folds": _int(2, 100),
    "evaluate.ranks": _list(_rank(), 34),
    "evaluate.methods": _list(_choice(METHODS), 20),
    "evaluate.max_iter": _int(1, 100000),
    "evaluate.gp.phase_bins": _int(1, 100),
    "evaluate.gp.max_iter": _int(1, 100000),
    # The GP baselines in the held-out translation (nnsf.evaluate.gp_translation);
    # the rank is also checked against the data (at most max(styles, contents)).
    "translation.gp_rank": _rank(),
    "translation.gp_phase_bins": _int(1, 100),
    "translation.gp_max_iter": _int(1, 100000),
    "isomap.samples": _size(20, 10000, lambda n: 3 * 8 * n * n,
                            "frames embedded (ISOMAP holds about three n x n float64 matrices)"),
    "isomap.neighbors": _int(2, 1000),
    "isomap.max_dim": _int(1, 200),
    "sweep.folds": _int(2, 100),
    "sweep.alpha": _list(_num(0, 1e6), 50),
    "sweep.beta": _list(_num(0, 1e9), 50),
    "sweep.rank": _list(_rank(), 34),
    "sweep.max_iter": _int(1, 100000),
    "translation.rank": _rank(),
    "translation.alpha": _num(0, 1e6),
    "translation.beta": _num(0, 1e9),
    "translation.label": _choice(LABELS),
    "translation.basis": _choice(BASES),
    "translation.synthesis": _choice(SYNTHESES),
    "translation.amplitude": _choice(AMPLITUDES),
    "translation.transfer": _choice(TRANSFERS),
    "translation.neutral": _str(optional=True),
    "translation.tempo": _bool(),
    "translation.ridge": _num(0, 1e6),
    "translation.smooth": _num(0, 1e6),
    "translation.max_iter": _int(1, 100000),
    "translation.align_iter": _int(1, 100000),
    "translation.bilinear_rank": _int(1, 34),
    "translation.max_sources": _int(0, 100000),
    "translation.max_cells": _int(0, 100000),
    "translation.examples": _int(0, 100),
    "translation.methods": _list(_choice(TRANSLATION_METHODS), 20),
    "translation.content_methods": _list(_choice(CONTENT_OUT_METHODS), 20),
    "translation.max_contents": _int(0, 100000),
    "translation.content_clip": _str(),
    "translation.style": _str(),
    "reshape.clip": _name(optional=True),
    "reshape.character": _project_path(),
    "reshape.character_size": _int(64, 4096),
    "reshape.n_vertices": _int(100, 6000),
    "reshape.subkeys_per_limb": _int(0, 12),
    "reshape.method": _choice(("ours", "keypoints")),
    "reshape.propagation": _choice(("limb-frame", "eq12")),
    "reshape.arms": _choice(ARM_CHOICES),
    "reshape.head": _choice(HEAD_CHOICES),
    "reshape.fps": _num(1, 120),
    "reshape.max_frames": _size(1, 5000, 512 * 512 * 3, "rendered frames of 512x512 px"),
    "reshape.formats": _list(_choice(RESHAPE_FORMATS), 3),
    # Parts and frame ranges are checked against the clip by nnsf.reshape.depth.parse_overrides.
    "reshape.depth_overrides": ((lambda v: isinstance(v, list) and len(v) <= 1000
                                 and all(isinstance(x, (str, dict)) for x in v)),
                                "a list of overrides such as 'left_arm over torso from 12 to 30'"),
    "reshape_eval.characters": _list(_relative(), 100),
    "reshape_eval.heldout": _list(_relative(), 100),
    "reshape_eval.motions": _list(_relative(), 100),
    "reshape_eval.n_vertices": _int(100, 6000),
    "reshape_eval.max_frames": _int(3, 5000),
    "reshape_eval.subkeys_per_limb": _int(1, 12),
    "animate.character": _project_path(),
    "animate.motion": _project_path(),
    "animate.style": _str(),
    "animate.view": _choice(VIEW_CHOICES),
    "animate.arms": _choice(ARM_CHOICES),
    "animate.head": _choice(HEAD_CHOICES),
    "animate.fps": _num(1, 120),
    "animate.n_vertices": _int(100, 6000),
    "animate.max_frames": _int(1, 5000),
    "animate.output": _list(_choice(("mp4", "gif", "sheet")), 3),
    "mlflow.experiment": _str(),
}


def _products(params: dict) -> list[tuple[str, str, float, float, str]]:
    """Sizes that depend on several fields: (fields, what, estimate, budget, formula).

    Each is checked only when all its fields are present and individually valid.
    """
    out = []

    def have(*keys):
        try:
            vals = [get(params, k) for k in keys]
        except KeyError:
            return None
        return vals if all(SCHEMA[k][0](v) for k, v in zip(keys, vals)) else None

    v = have("dataset.synthetic.characters", "dataset.synthetic.clips_per_cell", "dataset.synthetic.frames")
    if v:
        rows = v[0] * 15 * v[1] * v[2]
        out.append(("dataset.synthetic", "rows", rows * ROW_BYTES, MEMORY_BUDGET,
                    f"characters x 15 motions x clips_per_cell x frames = {v[0]} x 15 x {v[1]} x {v[2]} "
                    f"= {rows} key-point rows"))
    v = have("frames.frames", "frames.size")
    if v:
        px = v[0] * v[1] * v[1]
        out.append(("frames.frames, frames.size", "clip", px * TRACK_PIXEL_BYTES, MEMORY_BUDGET,
                    f"frames x size^2 = {v[0]} x {v[1]}^2 = {px} pixels per clip"))
    v = have("reshape.max_frames", "reshape.character_size")
    if v:
        px = v[0] * v[1] * v[1]
        out.append(("reshape.max_frames, reshape.character_size", "frames", px * 3.0, MEMORY_BUDGET,
                    f"max_frames x character_size^2 = {v[0]} x {v[1]}^2 = {px} RGB pixels held"))
    return out


def _sections() -> set[str]:
    """Every proper prefix of a schema key: the keys whose value is a mapping of further keys."""
    out = set()
    for key in SCHEMA:
        parts = key.split(".")
        out.update(".".join(parts[:i]) for i in range(1, len(parts)))
    return out


#: Unknown keys named in one message, at most.
UNKNOWN_SHOWN = 10


def unknown_keys(params: dict) -> list[str]:
    """Dotted keys of ``params`` that the schema does not know (in file order).

    Only the schema's sections are entered, so the walk is bounded by the
    schema, not by the file (an alias bomb under an unknown key is never
    visited).  Non-string keys are shown as their summary.
    """
    sections = _sections()
    found: list[str] = []

    def walk(node: dict, prefix: str):
        for k in node:
            name = k if isinstance(k, str) else summarize(k, 30)
            dotted = f"{prefix}{name}"
            if isinstance(k, str) and dotted in SCHEMA:
                continue
            if isinstance(k, str) and dotted in sections:
                child = node[k]
                if isinstance(child, dict):
                    walk(child, dotted + ".")
                continue
            found.append(dotted)
    walk(params, "")
    return found


def _suggest(key: str) -> str | None:
    """The nearest known key to ``key`` (difflib), or None."""
    known = list(SCHEMA) + sorted(_sections())
    best = difflib.get_close_matches(key, known, n=1, cutoff=0.6)
    if not best:  # a misspelt last part under a right section: compare the last parts
        head, _, tail = key.rpartition(".")
        peers = [k.rpartition(".")[2] for k in known if k.rpartition(".")[0] == head]
        near = difflib.get_close_matches(tail, peers, n=1, cutoff=0.6)
        best = [f"{head}.{near[0]}" if head else near[0]] if near else []
    return best[0] if best else None


class Params(dict):
    """A params mapping that remembers the file it came from (for error messages)."""

    source: str = "params.yaml"


def source_of(params: dict) -> str:
    """The file ``params`` was read from, or ``"params.yaml"``."""
    return getattr(params, "source", "params.yaml")


def get(params: dict, key: str):
    """Value at a dotted key, or ``KeyError``."""
    node = params
    for part in key.split("."):
        if not isinstance(node, dict) or part not in node:
            raise KeyError(key)
        node = node[part]
    return node


def _check_field(source, key: str, value) -> None:
    check, what = SCHEMA[key]
    if not check(value):
        explain = getattr(check, "explain", None)
        raise InputError(source, key, what, value, reason=explain(value) if explain else None)


def _check_sections(params: dict, source) -> None:
    """Every schema section present must be a mapping (or empty)."""
    for section in sorted(_sections(), key=lambda k: k.count(".")):
        try:
            node = get(params, section)
        except KeyError:
            continue
        if node is not None and not isinstance(node, dict):
            raise InputError(source, section, f"a mapping of {section}.* keys", node)


def validate(params: dict, source="params.yaml") -> dict:
    """Check ``params`` against :data:`SCHEMA`; return ``params``.

    Raises :class:`InputError` for keys the schema does not know (all of
    them in one line, each with the nearest known key), for a section that is
    not a mapping, for a field outside its type or range, and for sizes
    whose memory estimate exceeds :data:`MEMORY_BUDGET`.  A field the schema
    knows but the file lacks is reported only when a stage asks for it
    (:func:`require`), so partial files for tests stay usable.
    """
    if not isinstance(params, dict):
        raise InputError(source, "top level", "a mapping of sections", params)
    unknown = unknown_keys(params)
    if unknown:
        shown = []
        for key in unknown[:UNKNOWN_SHOWN]:
            near = _suggest(key)
            shown.append(f"{key} (did you mean {near}?)" if near else key)
        more = f" and {len(unknown) - UNKNOWN_SHOWN} more" if len(unknown) > UNKNOWN_SHOWN else ""
        noun = "unknown key" if len(unknown) == 1 else f"{len(unknown)} unknown keys"
        raise InputError(source, f"{noun} " + ", ".join(shown) + more,
                         "only the parameters listed in nnsf/params.py SCHEMA")
    _check_sections(params, source)
    for key in SCHEMA:
        try:
            value = get(params, key)
        except KeyError:
            continue
        _check_field(source, key, value)
    for fields, _, estimate, budget, formula in _products(params):
        if estimate > budget:
            raise InputError(source, fields, f"sizes that fit in {_human_bytes(budget)} of memory",
                             reason=f"{formula}, about {_human_bytes(estimate)}")
    return params


#: Largest params file read (bytes); a parameters file is a few KB.
MAX_PARAMS_BYTES = 1_000_000


def load(path="params.yaml") -> dict:
    """Read and validate a params file (the bounded safe loader, :func:`nnsf.safe_yaml.parse_yaml`).

    Every failure is an :class:`InputError` naming the file: missing,
    unreadable (permissions), larger than :data:`MAX_PARAMS_BYTES`, not
    UTF-8, not YAML, nested too deep, or not matching :data:`SCHEMA`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing params.yaml")
    params = parse_yaml(read_text(path, max_bytes=MAX_PARAMS_BYTES, what="a params file"), path)
    out = Params(validate(params if params is not None else {}, path))
    out.source = str(path)
    return out


#: The package's own parameters for commands run outside a project (``nnsf styles`` with no
#: params.yaml): the sections those commands read, equal to the project's params.yaml
#: (tests/test_cli_styles.py checks that they agree).
DEFAULTS_FILE = Path(__file__).with_name("defaults.yaml")


def load_defaults() -> dict:
    """:data:`DEFAULTS_FILE`, read and validated as :func:`load` does; its ``source`` names it."""
    return load(DEFAULTS_FILE)


def require(params: dict, key: str):
    """Value at ``key``, checked against :data:`SCHEMA`; else an :class:`InputError`.

    The error names the params file, the key and the expectation: the key is
    missing, or its value is outside the schema's type or range (the same
    definition ``nnsf check`` applies, so a stage never accepts what the check
    refuses or the other way round).
    """
    try:
        value = get(params, key)
    except KeyError:
        what = SCHEMA.get(key, (None, "a value"))[1]
        raise InputError(source_of(params), key, what + " (the field is missing)") from None
    if key in SCHEMA:
        _check_field(source_of(params), key, value)
    return value


def checked(params: dict, key: str, default):
    """Like :func:`require`, but ``default`` when ``key`` is absent."""
    try:
        get(params, key)
    except KeyError:
        return default
    return require(params, key)
