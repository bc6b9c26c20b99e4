"""The file of fitted :class:`~nnsf.factor.translate.StyleTranslator` s: one ``.npz``, written and read.

File format (``nnsf.style_model``, version :data:`VERSION`): an uncompressed
``.npz`` read with ``allow_pickle=False``, holding

* ``meta``: a 0-d string array, JSON with ``format``, ``version``, ``styles``,
  ``contents``, ``features_sha256`` (hash of the feature table the model was
  fitted on, or null), ``source`` (free text), optional ``aliases`` and
  ``views``: one entry per camera view the styles were learned in, each with

  - ``view``: the view's name (``front``, ``side``, ``three-quarter``,
    ``azimuth N``) or null for 2D data with no camera;
  - ``params``: that view's translator's ``get_params()``;
  - ``unifier``: the template unification of its training characters
    (:meth:`nnsf.skeleton.Unifier.to_dict`), or null;
  - ``state``: a description of every fitted attribute (``name_``) of the
    translator and of its pooled :class:`~nnsf.factor.nnsf.NNSF`;

* one array per fitted array, named ``a<N>`` and referenced from a ``state``.

Values are encoded generically -- arrays, numbers, strings, lists, dicts with
string or tuple-of-string keys and nested estimators -- but read back only as
the schema declares (:data:`META`, :data:`STATE`): a model file is data.  No
class is imported by a name from the file (:data:`ESTIMATORS` maps fixed
strings to classes), no attribute or parameter outside the schema is set, and
every array is checked (dtype kind, shape with sizes shared across the file,
finite values, index ranges) before the translator sees it.  A field is added
by adding its rule; :func:`save_model` refuses to write an attribute without
one.  Floats go through arrays or through JSON's shortest round-trip repr, so
a loaded model translates bit for bit like the fitted one.
"""
from __future__ import annotations

import hashlib
import json
import math
import numbers
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from nnsf.errors import InputError, summarize
from nnsf.factor.nnsf import NNSF
from nnsf.factor.style_names import check_aliases
from nnsf.io import read_npz, round_floats, write_npz
from nnsf.schema import (Array, Bool, Context, Int, List, Map, Num, Opt, Optional, Record, Rule, Str, Tuple,
                         check)
from nnsf.skeleton import Unifier
from nnsf.skeleton.unify import UNIFIER

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
    """``{name: spec}`` of every fitted attribute (``name_``, not ``_name``) of ``est``.

    Raises ``TypeError`` for a class or attribute :data:`STATE` does not list:
    a file the reader would refuse is never written.
    """
    name = f"{type(est).__module__}.{type(est).__qualname__}"
    if name not in STATE:
        raise TypeError(f"{name} is not an estimator a model file may hold (nnsf.factor.model_file.STATE)")
    attrs = {k: v for k, v in sorted(vars(est).items()) if k.endswith("_") and not k.startswith("_")}
    missing = [k for k in attrs if k not in STATE[name]]
    if missing:
        raise TypeError(f"{name}.{missing[0]} has no entry in nnsf.factor.model_file.STATE: add its rule "
                        "there so that the file can be read back")
    return {k: writer.value(v) for k, v in attrs.items()}


# ----------------------------------------------------------------------------- schema
#: The estimator classes a model file may hold, by the fixed string stored in it.  A string
#: maps to a class here; nothing named in a file is ever imported, and any other name is
#: refused.  The translator itself is the class :func:`load_model` is given (it imports this
#: module), and must be the one named :data:`TRANSLATOR`; a nested rule
#: ``Estimator(TRANSLATOR)`` (e.g. one translator per view) gets that same class.
TRANSLATOR = "nnsf.factor.translate.StyleTranslator"
ESTIMATORS = {"nnsf.factor.nnsf.NNSF": NNSF}

#: Largest total of array bytes a model file may declare (a model of 100 styles x 100
#: contents with their training clips holds a few MB).
MAX_MODEL_BYTES = 256_000_000
#: Named sizes shared by every array of a model: features, atoms, styles, contents.
D, K = "n_features", "n_components"


@dataclass(frozen=True)
class Estimator(Rule):
    """A nested estimator of the class :data:`ESTIMATORS` names ``name`` (its state per :data:`STATE`)."""

    name: str

    @property
    def expected(self) -> str:
        return f"a fitted {self.name.rsplit('.', 1)[-1]}"


#: The fitted attributes of each estimator class a model file holds: attribute -> rule
#: (:mod:`nnsf.schema`).  A file may hold only these; :class:`~nnsf.schema.Optional` ones may
#: be absent (they exist for some settings only).  To store a new fitted attribute, add it
#: here: :func:`save_model` refuses an attribute without an entry.
STATE: dict[str, dict[str, Rule]] = {
    "nnsf.factor.nnsf.NNSF": {
        "components_": Array("f", (K, D), finite=True),
        "n_components_": Int(1, 100_000, dim=K),
        "n_features_in_": Int(1, 100_000, dim=D),
        "n_iter_": Int(0, 10**9),
        "objective_": Array("f", (None,)),
        "reconstruction_err_": Num(0.0),
        "v_update_": Str(max_len=100),
        "classes_": Opt(Array("U", ("n_classes",))),
        "class_map_": Opt(Array("f", (K, "n_classes"), finite=True)),
    },
    TRANSLATOR: {
        "styles_": Array("U", ("n_styles",), labels="styles"),
        "contents_": Array("U", ("n_contents",), labels="contents"),
        "n_features_in_": Int(1, 100_000, dim=D),
        "components_": Array("f", (K, D), finite=True),
        "nnsf_": Estimator("nnsf.factor.nnsf.NNSF"),
        "style_bases_": Map(Array("f", (K, D), finite=True), keys="styles"),
        "style_offsets_": Map(Array("f", (D,), finite=True), keys="styles"),
        "clips_": Map(List(Array("f", (None, D), finite=True), min_len=1),
                      key=Tuple((Str(max_len=1000), Str(max_len=1000))), keys="styles", key_index=0),
        "style_tempo_": Map(Num(0.0, 1e6), keys="styles"),
        # The training clips' frame rate (None: unknown), and per (style, content) cell its
        # mean root-relative pose and per-band swing amplitudes (NaN: a band no clip resolves).
        "fps_": Opt(Num(0.0, 1e6)),
        "cells_": Array("U", ("n_cells", 2)),
        "cell_pose_": Array("f", ("n_cells", "n_relative"), finite=True),
        "cell_bands_": Array("f", ("n_cells", None, "n_relative")),
        "reference_clips_": Optional(Map(Array("U", ()), keys="contents")),
        # "aligned" basis only: the shared weights, then rows of them (ends at most n_rows).
        "shared_weights_": Optional(Array("f", ("n_rows", K), finite=True)),
        "content_rows_": Optional(Map(Tuple((Int(0, below="n_rows"), Int(0, below="n_rows"))), keys="contents")),
        "frame_rows_": Optional(Array("iu", (None,), below="n_rows")),
    },
}


class _Encoded(Rule):
    """The ``params``/``state`` trees of ``meta``: decoded by their own rules (:class:`_Reader`)."""

    expected = "a mapping (the encoded tree)"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, dict):
            self.fail(source, name, value)
        return value


#: The fields of ``meta``.  Add a field here (and write it in :func:`save_model`).
META = Record({
    "format": Str(choices=(FORMAT,)),
    "version": Int(),
    "class": Str(choices=(TRANSLATOR,)),
    "styles": List(Str(max_len=1000), max_len=100_000),
    "contents": List(Str(max_len=1000), max_len=100_000),
    "features_sha256": Opt(Str(max_len=64)),
    "source": Str(max_len=100_000),
    "views": List(Record({
        # The camera view of a motion-capture dataset (None: drawn/synthetic 2D data).
        "view": Opt(Str(max_len=100)),
        "params": _Encoded(),
        "unifier": Opt(UNIFIER),
        "state": _Encoded(),
    }), min_len=1, max_len=100),
    # Other names of styles ({alias: style}, nnsf.factor.style_names), present when given.
    "aliases": Optional(Map(Str(max_len=1000), max_len=10_000)),
})

#: The keys each kind of encoded value may have.
_SPEC_KEYS = {"array": {"kind", "key", "object", "scalar"}, "json": {"kind", "value", "type"},
              "list": {"kind", "tuple", "items"}, "dict": {"kind", "items"},
              "estimator": {"kind", "class", "params", "attrs"}}
#: Deepest nesting of encoded values (a translator holds an estimator holding arrays: 4).
_MAX_DEPTH = 16


# ----------------------------------------------------------------------------- decode
class _Reader:
    """Decodes ``meta``'s trees, each value by the rule its place in the schema gives it."""

    def __init__(self, arrays, path, classes: dict):
        self.arrays, self.path, self.used, self.ctx = arrays, path, set(), Context()
        self.classes = classes         # fixed name -> class: ESTIMATORS and the translator

    def spec(self, spec, name: str, kinds: tuple[str, ...]) -> dict:
        kind = spec.get("kind") if isinstance(spec, dict) else None
        if kind not in kinds:
            raise InputError(self.path, name, "an encoded " + " or ".join(kinds), kind or spec)
        extra = set(spec) - _SPEC_KEYS[kind]
        if extra:
            raise InputError(self.path, f"{name}.{sorted(extra)[0]}", f"only the keys of an encoded {kind}",
                             "an unknown key")
        return spec

    def value(self, rule: Rule, spec, name: str, depth: int = 0):
        if depth > _MAX_DEPTH:
            raise InputError(self.path, name, f"values nested at most {_MAX_DEPTH} deep")
        if isinstance(rule, Optional):
            return self.value(rule.rule, spec, name, depth)
        if isinstance(rule, Opt):
            if isinstance(spec, dict) and spec.get("kind") == "json" and spec.get("value") is None:
                return None
            return self.value(rule.rule, spec, name, depth)
        if isinstance(rule, Array):
            return self.array(rule, self.spec(spec, name, ("array",)), name)
        if isinstance(rule, (Int, Num, Str, Bool, _Scalar)):
            spec = self.spec(spec, name, ("json", "array"))
            if spec["kind"] == "array":      # a numpy scalar, stored as a 0-d array
                a = self.array(Array("fiubU", ()), spec, name)
                return rule.check(self.path, name, a[()] if isinstance(a, np.ndarray) else a, self.ctx)
            v = rule.check(self.path, name, spec.get("value"), self.ctx)
            kind = spec.get("type")
            if kind is None:
                return v
            want = {"int": numbers.Integral, "float": numbers.Real}.get(kind)
            if want is None or not isinstance(v, want) or isinstance(v, bool):
                raise InputError(self.path, f"{name}.type", "int or float, as the value is", kind)
            return float(v) if kind == "float" else int(v)
        if isinstance(rule, (List, Tuple)):
            spec = self.spec(spec, name, ("list",))
            items = spec.get("items")
            n = len(rule.items) if isinstance(rule, Tuple) else None
            if not isinstance(items, list) or (n is not None and len(items) != n) \
                    or (n is None and not rule.min_len <= len(items) <= rule.max_len):
                raise InputError(self.path, name, rule.expected, summarize(items))
            subs = rule.items if isinstance(rule, Tuple) else [rule.item] * len(items)
            out = [self.value(r, x, f"{name}[{i}]", depth + 1) for i, (r, x) in enumerate(zip(subs, items))]
            return tuple(out) if spec.get("tuple") or isinstance(rule, Tuple) else out
        if isinstance(rule, Map):
            spec = self.spec(spec, name, ("dict",))
            items = spec.get("items")
            if not isinstance(items, list) or len(items) > rule.max_len:
                raise InputError(self.path, name, rule.expected, summarize(items))
            out = {}
            for i, item in enumerate(items):
                if not (isinstance(item, list) and len(item) == 2):
                    raise InputError(self.path, f"{name}[{i}]", "a [key, value] pair", item)
                k = tuple(item[0]) if isinstance(item[0], list) else item[0]
                k = rule.key.check(self.path, f"{name}[{i}].key", k, self.ctx)
                if k in out:
                    raise InputError(self.path, f"{name}[{i}].key", "each key once", k)
                shown = "|".join(k) if isinstance(k, tuple) else k
                out[k] = self.value(rule.value, item[1], f"{name}.{shown}", depth + 1)
            # The key sets (styles, contents) are checked by the rule on the decoded mapping.
            return Map(_ANY, key=_ANY, keys=rule.keys, key_index=rule.key_index, max_len=rule.max_len).check(
                self.path, name, out, self.ctx)
        if isinstance(rule, Estimator):
            return self.estimator(rule, self.spec(spec, name, ("estimator",)), name, depth)
        raise TypeError(f"no decoder for the rule {rule!r}")  # a schema bug, not a bad file

    def array(self, rule: Array, spec: dict, name: str):
        key = spec.get("key")
        if not isinstance(key, str):
            raise InputError(self.path, f"{name}.key", "the name of an array of the file", key)
        if key not in self.arrays:
            raise InputError(self.path, name, f"the array {key} it refers to, in the file", "missing")
        if key in self.used:
            raise InputError(self.path, name, "an array referred to once", key)
        self.used.add(key)
        a = rule.check(self.path, f"{name} (array {key})", self.arrays[key], self.ctx)
        if spec.get("object"):
            a = a.astype(object)
        return a[()] if spec.get("scalar") else a

    def params(self, cls, spec, name: str) -> dict:
        """Constructor arguments: the class's own parameter names, JSON scalars, validated by the class."""
        names = set(cls._get_param_names())
        params = self.value(Map(_Scalar()), spec, name)
        unknown = sorted(set(params) - names)
        if unknown:
            raise InputError(self.path, f"{name}.{unknown[0]}", f"a parameter of {cls.__name__}", "unknown")
        return params

    def build(self, cls, params: dict, name: str):
        est = cls(**params)
        check = "_validate_params" if getattr(cls, "_parameter_constraints", None) else "_check_params"
        try:
            getattr(est, check, lambda: None)()
        except (TypeError, ValueError) as exc:
            raise InputError(self.path, name, f"parameters {cls.__name__} accepts", reason=str(exc)) from None
        return est

    def state(self, est, class_name: str, attrs, name: str, depth: int):
        """Set every fitted attribute :data:`STATE` lists for ``class_name`` from ``attrs``."""
        schema = STATE[class_name]
        if not isinstance(attrs, dict):
            raise InputError(self.path, name, "a mapping of fitted attributes", attrs)
        unknown = [k for k in attrs if k not in schema]
        if unknown:
            raise InputError(self.path, f"{name}.{unknown[0]}",
                             f"a fitted attribute of {class_name.rsplit('.', 1)[-1]} this nnsf knows", "unknown")
        for attr, rule in schema.items():
            if attr in attrs:
                setattr(est, attr, self.value(rule, attrs[attr], f"{name}.{attr}", depth + 1))
            elif not isinstance(rule, Optional):
                raise InputError(self.path, f"{name}.{attr}", rule.expected, "missing")
        return est

    def estimator(self, rule: Estimator, spec: dict, name: str, depth: int):
        if spec.get("class") != rule.name or rule.name not in self.classes:
            raise InputError(self.path, f"{name}.class", f"{rule.name!r} (an estimator class a model "
                             "file may hold)", spec.get("class"))
        cls = self.classes[rule.name]
        est = self.build(cls, self.params(cls, spec.get("params"), f"{name}.params"), f"{name}.params")
        return self.state(est, rule.name, spec.get("attrs"), f"{name}.attrs", depth)


class _Any(Rule):
    expected = "any value"

    def check(self, source, name, value, ctx=None):
        return value


_ANY = _Any()


class _Scalar(Rule):
    """A JSON scalar: a number, string, true/false or null (an estimator's parameter value)."""

    expected = "a number, string, true/false or null"

    def check(self, source, name, value, ctx=None):
        if value is not None and not isinstance(value, (bool, str, numbers.Real)) \
                or isinstance(value, str) and len(value) > 1000 \
                or isinstance(value, float) and not math.isfinite(value):
            self.fail(source, name, value)
        return value


# ----------------------------------------------------------------------------- files
@dataclass(frozen=True)
class ModelView:
    """One view of a model file: its name (None: no camera), fitted translator and unifier (or None)."""

    view: str | None
    translator: object
    unifier: Unifier | None = None


def save_model(views, path, *, features_sha256: str | None = None, source: str = "",
               digits: int | None = None, aliases: dict | None = None) -> Path:
    """Write fitted translators, one per view (a list of :class:`ModelView`), to ``path``, atomically.

    Every view must know the same styles and contents.  ``digits=None`` keeps
    every bit, so a loaded model translates exactly as the fitted one.  The
    ``styles`` stage passes 6 significant digits (:data:`nnsf.io.DIGITS`)
    instead, so that the versioned file, and DVC's hash of it, is the same on
    every machine whatever BLAS noise the fit had.  ``aliases`` (``{alias:
    style}``, :mod:`nnsf.factor.style_names`) are other names of the model's
    styles; stored only when given.
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
        for field in ("styles_", "contents_"):
            if list(getattr(v.translator, field)) != list(getattr(first, field)):
                raise ValueError(f"save_model: view {v.view!r} has {field} {list(getattr(v.translator, field))}, "
                                 f"view {views[0].view!r} {list(getattr(first, field))}")
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
    if aliases:
        # Other names a user may give a style (elderly -> old): a flat {alias: style} of strings.
        meta["aliases"] = check_aliases(aliases, meta["styles"], "--alias", "alias")
    if digits is not None:
        meta = round_floats(meta, digits)
    write_npz(path, digits=digits, meta=np.array(json.dumps(meta, sort_keys=True)), **w.arrays)
    return Path(path)


def read_meta(path) -> tuple[dict, dict]:
    """``(meta, arrays)`` of a model file, or an :class:`InputError` naming the file and what is wrong.

    ``meta`` follows :data:`META` (format, version, known fields only); each
    view's ``params`` and ``state`` are still encoded (:func:`load_model` decodes them).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing style model (.npz written by `nnsf styles`)")
    arrays = read_npz(path, max_bytes=MAX_MODEL_BYTES, what="style model (written by `nnsf styles`)")
    if "meta" not in arrays:
        raise InputError(path, "array meta", "the model's JSON metadata", "missing")
    meta_array = arrays.pop("meta")
    if meta_array.dtype.kind != "U" or meta_array.shape != ():
        raise InputError(path, "array meta", "a 0-d unicode array (JSON text)",
                         f"{meta_array.dtype} of shape {meta_array.shape}")
    try:
        meta = json.loads(str(meta_array[()]))
    except (json.JSONDecodeError, TypeError, ValueError) as exc:
        raise InputError(path, "meta", "JSON metadata", str(exc)) from None
    except RecursionError:
        raise InputError(path, "meta", "JSON metadata nested at most a few hundred levels deep") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise InputError(path, "meta.format", repr(FORMAT),
                         meta.get("format") if isinstance(meta, dict) else type(meta).__name__)
    if meta.get("version") != VERSION:
        raise InputError(path, "meta.version", f"format version {VERSION} (this nnsf)", meta.get("version"))
    meta = check(path, META, meta, "meta")
    for name in arrays:
        if not re.fullmatch(r"a\d{1,6}", name):
            raise InputError(path, f"array {name}", "arrays named a0, a1, ... (and meta)", "an unknown array")
    if "aliases" in meta:
        # The schema checks the shape; the targets must be this model's styles.
        meta["aliases"] = check_aliases(meta["aliases"], meta["styles"], path, "meta.aliases")
    return meta, arrays


def load_model(path, translator_class) -> tuple[list[ModelView], dict]:
    """Read a model file: ``(views, meta)``, each view's translator a ``translator_class``.

    Nothing in the file chooses code: the translator is ``translator_class``
    (which must be :data:`TRANSLATOR`), nested estimators come from
    :data:`ESTIMATORS`, and every parameter, fitted attribute and array is
    checked against :data:`STATE` before it is set.  Anything else is one
    :class:`InputError` naming the file and the field.
    """
    path = Path(path)
    if f"{translator_class.__module__}.{translator_class.__qualname__}" != TRANSLATOR:
        raise TypeError(f"load_model reads {TRANSLATOR} models, not {translator_class!r}")
    meta, arrays = read_meta(path)
    r = _Reader(arrays, path, {**ESTIMATORS, TRANSLATOR: translator_class})
    out, seen = [], set()
    for i, entry in enumerate(meta["views"]):
        name = f"meta.views[{i}]"
        if entry["view"] in seen:
            raise InputError(path, f"{name}.view", "each view once", entry["view"])
        seen.add(entry["view"])
        r.ctx = Context()        # sizes such as the shared weights' rows belong to one view
        tr = r.build(translator_class, r.params(translator_class, entry["params"], f"{name}.params"),
                     f"{name}.params")
        r.state(tr, TRANSLATOR, entry["state"], f"{name}.state", 0)
        for field in ("styles", "contents"):
            held = [str(s) for s in getattr(tr, f"{field}_")]
            if meta[field] != held:
                raise InputError(path, f"meta.{field}", f"the {field} of {name}.state.{field}_ ({summarize(held)})",
                                 meta[field])
        unifier = Unifier.from_dict(entry["unifier"], path) if entry.get("unifier") else None
        out.append(ModelView(entry["view"], tr, unifier))
    unused = sorted(set(arrays) - r.used)
    if unused:
        raise InputError(path, f"array {unused[0]}", "an array the model's metadata refers to", "unreferenced")
    return out, meta
