"""The file of fitted :class:`~nnsf.factor.translate.StyleTranslator` s: one ``.npz``, written and read.

File format (``nnsf.style_model``, version :data:`VERSION`): an uncompressed
``.npz`` read with ``allow_pickle=False``, holding

* ``meta``: a 0-d string array, JSON with ``format``, ``version``, ``styles``,
  ``contents``, ``features_sha256`` (hash of the feature table the model was
  fitted on, or null), ``source`` (free text) and ``views``: one entry per
  camera view the styles were learned in, each with

  - ``view``: the view's name (``front``, ``side``, ``three-quarter``,
    ``azimuth N``) or null for 2D data with no camera;
  - ``params``: that view's translator's ``get_params()``;
  - ``unifier``: the template unification of its training characters
    (:meth:`nnsf.skeleton.Unifier.to_dict`), or null;
  - ``state``: a description of every fitted attribute (``name_``) of the
    translator and of its pooled :class:`~nnsf.factor.nnsf.NNSF`;

* one array per fitted array, named ``a<N>`` and referenced from a ``state``.

Fitted attributes are stored generically -- arrays, numbers, strings, lists,
dicts with string or tuple-of-string keys and nested estimators -- so that a
translator that gains an attribute still saves without a change here.
Floats go through arrays or through JSON's shortest round-trip repr, so a
loaded model translates bit for bit like the fitted one.
"""
from __future__ import annotations

import hashlib
import importlib
import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.io import round_floats, write_npz
from nnsf.skeleton import Unifier

FORMAT = "nnsf.style_model"
VERSION = 2


def file_sha256(path) -> str:
    """Hex SHA-256 of a file's bytes."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


# ----------------------------------------------------------------------------- encode
class _Writer:
    def __init__(self):
        self.arrays: dict[str, np.ndarray] = {}

    def array(self, a: np.ndarray) -> dict:
        key = f"a{len(self.arrays)}"
        spec = {"kind": "array", "key": key}
        if a.dtype == object:
            # Labels held as object arrays: stored as unicode, restored as object.
            spec["object"] = True
            a = a.astype(str)
        self.arrays[key] = a
        return spec

    def value(self, v):
        from sklearn.base import BaseEstimator

        if isinstance(v, np.ndarray):
            return self.array(v)
        if isinstance(v, np.generic):
            return self.array(np.asarray(v)) | {"scalar": True}
        if v is None or isinstance(v, (bool, str)):
            return {"kind": "json", "value": v}
        if isinstance(v, (int, float)):
            return {"kind": "json", "value": v, "type": type(v).__name__}
        if isinstance(v, (list, tuple)):
            return {"kind": "list", "tuple": isinstance(v, tuple), "items": [self.value(x) for x in v]}
        if isinstance(v, dict):
            items = []
            for k, x in v.items():
                if isinstance(k, (str, np.str_)):
                    key = str(k)
                elif isinstance(k, tuple) and all(isinstance(e, (str, np.str_)) for e in k):
                    key = [str(e) for e in k]
                else:
                    raise TypeError(f"cannot store a dict key of type {type(k).__name__}")
                items.append([key, self.value(x)])
            return {"kind": "dict", "items": items}
        if isinstance(v, BaseEstimator):
            return self.estimator(v)
        raise TypeError(f"cannot store a value of type {type(v).__name__}")

    def estimator(self, est) -> dict:
        cls = type(est)
        return {"kind": "estimator", "class": f"{cls.__module__}.{cls.__qualname__}",
                "params": self.value(est.get_params(deep=False)), "attrs": fitted_state(est, self)}


def fitted_state(est, writer: _Writer) -> dict:
    """``{name: spec}`` of every fitted attribute (``name_``, not ``_name``) of ``est``."""
    return {k: writer.value(v) for k, v in sorted(vars(est).items())
            if k.endswith("_") and not k.startswith("_")}


# ----------------------------------------------------------------------------- decode
class _Reader:
    def __init__(self, arrays, path):
        self.arrays, self.path = arrays, path

    def value(self, spec):
        kind = spec.get("kind") if isinstance(spec, dict) else None
        if kind == "array":
            key = spec["key"]
            if key not in self.arrays:
                raise InputError(self.path, f"array {key}", "an array the model's metadata refers to",
                                 "missing")
            a = self.arrays[key]
            if spec.get("object"):
                a = a.astype(object)
            return a[()] if spec.get("scalar") else a
        if kind == "json":
            v = spec["value"]
            if spec.get("type") == "float":
                return float(v)
            if spec.get("type") == "int":
                return int(v)
            return v
        if kind == "list":
            items = [self.value(x) for x in spec["items"]]
            return tuple(items) if spec.get("tuple") else items
        if kind == "dict":
            return {(tuple(k) if isinstance(k, list) else k): self.value(x) for k, x in spec["items"]}
        if kind == "estimator":
            return self.estimator(spec)
        raise InputError(self.path, "meta.state", "a known value kind", kind)

    def estimator(self, spec):
        module, _, name = spec["class"].rpartition(".")
        if not module.startswith("nnsf."):
            raise InputError(self.path, "meta.state", "an nnsf estimator class", spec["class"])
        try:
            cls = getattr(importlib.import_module(module), name)
        except (ImportError, AttributeError):
            raise InputError(self.path, "meta.state", "an estimator class of this nnsf version",
                             spec["class"]) from None
        est = cls(**self.value(spec["params"]))
        for k, v in spec["attrs"].items():
            setattr(est, k, self.value(v))
        return est


# ----------------------------------------------------------------------------- files
@dataclass(frozen=True)
class ModelView:
    """One view of a model file: its name (None: no camera), fitted translator and unifier (or None)."""

    view: str | None
    translator: object
    unifier: Unifier | None = None


def save_model(views, path, *, features_sha256: str | None = None, source: str = "",
               digits: int | None = None) -> Path:
    """Write fitted translators, one per view (a list of :class:`ModelView`), to ``path``, atomically.

    Every view must know the same styles.  ``digits=None`` keeps every bit,
    so a loaded model translates exactly as the fitted one.  The ``styles``
    stage passes 6 significant digits (:data:`nnsf.io.DIGITS`) instead, so
    that the versioned file, and DVC's hash of it, is the same on every
    machine whatever BLAS noise the fit had.
    """
    from sklearn.utils.validation import check_is_fitted

    views = list(views)
    if not views:
        raise ValueError("save_model: no view to save")
    names = [v.view for v in views]
    if len(set(names)) != len(names):
        raise ValueError(f"save_model: each view once, got {names}")
    first = views[0].translator
    w = _Writer()
    entries = []
    for v in views:
        check_is_fitted(v.translator, "style_bases_")
        if list(v.translator.styles_) != list(first.styles_):
            raise ValueError(f"save_model: view {v.view!r} has styles {list(v.translator.styles_)}, "
                             f"view {views[0].view!r} {list(first.styles_)}")
        entries.append({"view": v.view, "params": w.value(v.translator.get_params(deep=False)),
                        "unifier": v.unifier.to_dict() if v.unifier is not None else None,
                        "state": fitted_state(v.translator, w)})
    meta = {
        "format": FORMAT, "version": VERSION,
        "class": f"{type(first).__module__}.{type(first).__qualname__}",
        "styles": [str(s) for s in first.styles_],
        "contents": [str(c) for c in first.contents_],
        "features_sha256": features_sha256,
        "source": str(source),
        "views": entries,
    }
    if digits is not None:
        meta = round_floats(meta, digits)
    write_npz(path, digits=digits, meta=np.array(json.dumps(meta, sort_keys=True)), **w.arrays)
    return Path(path)


def read_meta(path) -> tuple[dict, dict]:
    """``(meta, arrays)`` of a model file, or an :class:`InputError` naming the file and what is wrong."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing style model (.npz written by `nnsf styles`)")
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except (ValueError, OSError, zipfile.BadZipFile, EOFError, KeyError) as exc:
        raise InputError(path, "file", "a readable .npz style model", str(exc).splitlines()[0]
                         if str(exc) else type(exc).__name__) from None
    if "meta" not in arrays:
        raise InputError(path, "array meta", "the model's JSON metadata", "missing")
    try:
        meta = json.loads(str(arrays.pop("meta")[()]))
    except (json.JSONDecodeError, TypeError, ValueError) as exc:
        raise InputError(path, "meta", "JSON metadata", str(exc)) from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(path, "meta.format", repr(FORMAT),
                         meta.get("format") if isinstance(meta, dict) else type(meta).__name__)
    if meta.get("version") != VERSION:
        raise InputError(path, "meta.version", f"format version {VERSION} (this nnsf)", meta.get("version"))
    for key in ("styles", "contents", "views"):
        if key not in meta:
            raise InputError(path, f"meta.{key}", "present", "missing")
    views = meta["views"]
    if not isinstance(views, list) or not views:
        raise InputError(path, "meta.views", "a non-empty list of fitted views", type(views).__name__)
    for i, v in enumerate(views):
        for key in ("view", "params", "unifier", "state"):
            if not isinstance(v, dict) or key not in v:
                raise InputError(path, f"meta.views[{i}].{key}", "present", "missing")
    return meta, arrays


def load_model(path, translator_class) -> tuple[list[ModelView], dict]:
    """Read a model file: ``(views, meta)``, each view's translator a ``translator_class``."""
    path = Path(path)
    meta, arrays = read_meta(path)
    r = _Reader(arrays, path)
    out = []
    for i, entry in enumerate(meta["views"]):
        try:
            tr = translator_class(**r.value(entry["params"]))
            for k, v in entry["state"].items():
                setattr(tr, k, r.value(v))
            unifier = Unifier.from_dict(entry["unifier"]) if entry.get("unifier") else None
        except InputError:
            raise
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(path, f"meta.views[{i}].state", "a style model this nnsf can read",
                             f"{type(exc).__name__}: {exc}") from None
        if not hasattr(tr, "style_bases_"):
            raise InputError(path, f"meta.views[{i}].state.style_bases_", "the fitted per-style bases", "missing")
        view = entry["view"]
        if view is not None and not isinstance(view, str):
            raise InputError(path, f"meta.views[{i}].view", "a view name or null", view)
        out.append(ModelView(view, tr, unifier))
    return out, meta
