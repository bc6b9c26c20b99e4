"""Loading and checking ``params.yaml``.

Each stage reads only the sections it lists in dvc.yaml; :func:`load` checks
every field it knows against :data:`SCHEMA` so that a wrong type or an
unknown choice fails with one line naming the field.
"""
from __future__ import annotations

import numbers
from pathlib import Path
from typing import Any, Callable

import yaml

from nnsf.errors import InputError

DATASETS = ("synthetic", "bvh", "frames")
FACINGS = ("normalise", "none")
INITS = ("random", "nndsvd", "nndsvda", "nndsvdar")
METHODS = ("nnsf", "nnsc", "nmf", "bilinear")
LABELS = ("motion", "character")
TRACKERS = ("ours", "agarwala", "lk")
TRANSLATION_METHODS = ("nnsf", "nnsf_swapped", "nnsf_beta0", "nnsf_refit", "bilinear", "identity", "real")


def _optional_str():
    return (lambda v: v is None or (isinstance(v, str) and v != "")), "a non-empty string or null"


def _int(lo=None, hi=None):
    def check(v):
        ok = isinstance(v, numbers.Integral) and not isinstance(v, bool)
        ok = ok and (lo is None or v >= lo) and (hi is None or v <= hi)
        return ok
    rng = f" in [{lo}, {hi}]" if hi is not None else (f" >= {lo}" if lo is not None else "")
    return check, f"an integer{rng}"


def _rank():
    check, _ = _int(1, 34)
    return check, "an integer from 1 to 34 (a rank cannot exceed the 34 features)"


def _num(lo=None, strict=False):
    def check(v):
        ok = isinstance(v, numbers.Real) and not isinstance(v, bool)
        return ok and (lo is None or (v > lo if strict else v >= lo))
    return check, f"a number {'>' if strict else '>='} {lo}" if lo is not None else "a number"


def _choice(options):
    return (lambda v: v in options), "one of " + ", ".join(options)


def _bool():
    return (lambda v: isinstance(v, bool)), "true or false"


def _str():
    return (lambda v: isinstance(v, str) and v != ""), "a non-empty string"


def _list(item):
    check, what = item
    return (lambda v: isinstance(v, list) and len(v) > 0 and all(check(x) for x in v)), \
        f"a non-empty list, each item {what}"


SCHEMA: dict[str, tuple[Callable[[Any], bool], str]] = {
    "seed": _int(0),
    "dataset.name": _choice(DATASETS),
    "dataset.path": _str(),
    "dataset.synthetic.characters": _int(2, 12),
    "dataset.synthetic.clips_per_cell": _int(1),
    "dataset.synthetic.frames": _int(4),
    "dataset.synthetic.noise_px": _num(0),
    "dataset.bvh.fps": _num(0, strict=True),
    "dataset.bvh.azimuth": _num(),
    "dataset.bvh.elevation": _num(),
    "dataset.bvh.facing": _choice(FACINGS),
    "dataset.bvh.center": _bool(),
    "dataset.bvh.complete_grid": _bool(),
    "frames.characters": _int(1, 12),
    "frames.clips_per_cell": _int(1),
    "frames.frames": _int(2),
    "frames.size": _int(64, 4096),
    "frames.keyframe_every": _int(0),
    "frames.control_points": _int(2, 32),
    "track.method": _choice(TRACKERS),
    "track.w_velocity": _num(0),
    "track.w_length": _num(0),
    "track.w_length_anchor": _num(0),
    "track.w_curvature": _num(0),
    "track.w_edge": _num(0),
    "track.w_sketch": _num(0),
    "track.w_colour": _num(0),
    "track.window": _int(1),
    "track.samples": _int(3),
    "track.levels": _int(1),
    "track.max_iter": _int(1),
    "track.init": _choice(("linear", "lk", "flow")),
    "track.lk_end": _choice(("blend", "none")),
    "track.eval_clips": _int(1),
    "track.edit_tol_px": _num(0, strict=True),
    "track.max_edits": _int(0),
    "unify.margin": _num(0, strict=True),
    "nnsf.label": _choice(LABELS),
    "nnsf.rank": _rank(),
    "nnsf.alpha": _num(0),
    "nnsf.beta": _num(0),
    "nnsf.class_in_loop": _bool(),
    "nnsf.max_iter": _int(1),
    "nnsf.tol": _num(0),
    "nnsf.init": _choice(INITS),
    "evaluate.folds": _int(2),
    "evaluate.ranks": _list(_rank()),
    "evaluate.methods": _list(_choice(METHODS)),
    "evaluate.max_iter": _int(1),
    "isomap.samples": _int(20),
    "isomap.neighbors": _int(2),
    "isomap.max_dim": _int(1),
    "sweep.folds": _int(2),
    "sweep.alpha": _list(_num(0)),
    "sweep.beta": _list(_num(0)),
    "sweep.rank": _list(_rank()),
    "sweep.max_iter": _int(1),
    "translation.rank": _rank(),
    "translation.alpha": _num(0),
    "translation.beta": _num(0),
    "translation.label": _choice(LABELS),
    "translation.basis": _choice(("aligned", "refit", "separate")),
    "translation.synthesis": _choice(("consensus", "source")),
    "translation.amplitude": _choice(("restore", "none")),
    "translation.tempo": _bool(),
    "translation.ridge": _num(0),
    "translation.max_iter": _int(1),
    "translation.align_iter": _int(1),
    "translation.bilinear_rank": _int(1),
    "translation.max_sources": _int(0),
    "translation.max_cells": _int(0),
    "translation.examples": _int(0),
    "translation.methods": _list(_choice(TRANSLATION_METHODS)),
    "translation.content_clip": _str(),
    "translation.style": _str(),
    "reshape.clip": _optional_str(),
    "reshape.character": _str(),
    "reshape.character_size": _int(64, 4096),
    "reshape.n_vertices": _int(100, 6000),
    "reshape.subkeys_per_limb": _int(0, 12),
    "reshape.method": _choice(("ours", "keypoints")),
    "reshape.mesh": _choice(("layered", "limbs", "split", "connected")),
    "reshape.propagation": _choice(("limb-frame", "eq12")),
    "reshape.fps": _num(1),
    "reshape.max_frames": _int(1, 5000),
    "reshape.formats": _list(_choice(("png", "gif", "mp4"))),
    "reshape_eval.characters": _list(_str()),
    "reshape_eval.motions": _list(_str()),
    "reshape_eval.n_vertices": _int(100, 6000),
    "reshape_eval.max_frames": _int(3, 5000),
    "reshape_eval.subkeys_per_limb": _int(1, 12),
    "mlflow.experiment": _str(),
}


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


def validate(params: dict, source="params.yaml") -> dict:
    """Check every known field present in ``params``; return ``params``.

    A field the schema knows but the file lacks is reported only when a stage
    asks for it (:func:`require`), so partial files for tests stay usable.
    """
    if not isinstance(params, dict):
        raise InputError(source, "top level", "a mapping of sections")
    for key, (check, what) in SCHEMA.items():
        try:
            value = get(params, key)
        except KeyError:
            continue
        if not check(value):
            raise InputError(source, key, what, value)
    return params


def load(path="params.yaml") -> dict:
    """Read and validate a params file (``yaml.safe_load``)."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing params.yaml")
    try:
        params = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"line {mark.line + 1}" if mark else "file"
        raise InputError(path, where, "valid YAML", getattr(exc, "problem", str(exc))) from None
    out = Params(validate(params or {}, path))
    out.source = str(path)
    return out


def require(params: dict, key: str):
    """Value at ``key``, or an :class:`InputError` saying it is missing."""
    try:
        return get(params, key)
    except KeyError:
        what = SCHEMA.get(key, (None, "a value"))[1]
        raise InputError(source_of(params), key, what + " (the field is missing)") from None
