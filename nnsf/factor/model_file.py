"""The file of a fitted :class:`~nnsf.factor.translate.StyleTranslator`: one ``.npz``, written and read.

File format (``nnsf.style_model``, version :data:`VERSION`): an uncompressed
``.npz`` read with ``allow_pickle=False``, holding

* ``meta``: a 0-d string array, JSON with ``format``, ``version``, ``styles``,
  ``contents``, ``params`` (the translator's ``get_params()``), ``unifier``
  (the template unification of the training characters,
  :meth:`nnsf.skeleton.Unifier.to_dict`), ``features_sha256`` (hash of the
  feature table the model was fitted on, or null), ``source`` (free text)
  and ``state``: a description of every fitted attribute (``name_``) of the
  translator and of its pooled :class:`~nnsf.factor.nnsf.NNSF`;
* one array per fitted array, named ``a<N>`` and referenced from ``state``.

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
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.factor.style_names import check_aliases
from nnsf.io import round_floats, write_npz
from nnsf.skeleton import Unifier

FORMAT = "nnsf.style_model"
VERSION = 1


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
def save_model(translator, path, *, unifier=None, features_sha256: str | None = None,
               source: str = "", view: str | None = None, digits: int | None = None,
               aliases: dict | None = None) -> Path:
    """Write a fitted translator (and the unifier of its training characters) to ``path``, atomically.

    ``digits=None`` keeps every bit, so a loaded model translates exactly as
    the fitted one.  The ``styles`` stage passes 6 significant digits
    (:data:`nnsf.io.DIGITS`) instead, so that the versioned file, and DVC's
    hash of it, is the same on every machine whatever BLAS noise the fit had.
    ``aliases`` (``{alias: style}``, :mod:`nnsf.factor.style_names`) are other names of the
    model's styles; stored only when given, so a model without them is unchanged.
    """
    from sklearn.utils.validation import check_is_fitted

    check_is_fitted(translator, "style_bases_")
    w = _Writer()
    state = fitted_state(translator, w)
    meta = {
        "format": FORMAT, "version": VERSION,
        "class": f"{type(translator).__module__}.{type(translator).__qualname__}",
        "styles": [str(s) for s in translator.styles_],
        "contents": [str(c) for c in translator.contents_],
        "params": w.value(translator.get_params(deep=False)),
        "unifier": unifier.to_dict() if unifier is not None else None,
        "features_sha256": features_sha256,
        "source": str(source),
        # The camera view of a motion-capture dataset (None: drawn/synthetic 2D data).
        "view": view,
        "state": state,
    }
    if aliases:
        # Other names a user may give a style (elderly -> old): a flat {alias: style} of strings.
        meta["aliases"] = check_aliases(aliases, meta["styles"], "--alias", "alias")
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
    for key in ("styles", "contents", "params", "state"):
        if key not in meta:
            raise InputError(path, f"meta.{key}", "present", "missing")
    if "aliases" in meta:
        if not isinstance(meta["styles"], list):
            raise InputError(path, "meta.styles", "a list of style names", meta["styles"])
        meta["aliases"] = check_aliases(meta["aliases"], meta["styles"], path, "meta.aliases")
    return meta, arrays


def load_model(path, translator_class):
    """Read a model file: ``(translator, unifier or None, meta)``; the translator is a ``translator_class``."""
    path = Path(path)
    meta, arrays = read_meta(path)
    r = _Reader(arrays, path)
    try:
        tr = translator_class(**r.value(meta["params"]))
        for k, v in meta["state"].items():
            setattr(tr, k, r.value(v))
        unifier = Unifier.from_dict(meta["unifier"]) if meta.get("unifier") else None
    except InputError:
        raise
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(path, "meta.state", "a style model this nnsf can read",
                         f"{type(exc).__name__}: {exc}") from None
    if not hasattr(tr, "style_bases_"):
        raise InputError(path, "meta.state.style_bases_", "the fitted per-style bases", "missing")
    return tr, unifier, meta
