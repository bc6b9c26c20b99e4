"""A fitted :class:`~nnsf.factor.translate.StyleTranslator` saved to one ``.npz`` and applied later.

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
from nnsf.io import DIGITS

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
               source: str = "", view: str | None = None, digits: int | None = None) -> Path:
    """Write a fitted translator (and the unifier of its training characters) to ``path``, atomically.

    ``digits=None`` keeps every bit, so a loaded model translates exactly as
    the fitted one.  The ``styles`` stage passes 6 significant digits
    (:data:`nnsf.io.DIGITS`) instead, so that the versioned file, and DVC's
    hash of it, is the same on every machine whatever BLAS noise the fit had.
    """
    from sklearn.utils.validation import check_is_fitted

    from nnsf.io import round_floats, write_npz

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
    return meta, arrays


def load_model(path):
    """Read a model file: ``(translator, unifier or None, meta)``."""
    from nnsf.factor.translate import StyleTranslator
    from nnsf.skeleton import Unifier

    path = Path(path)
    meta, arrays = read_meta(path)
    r = _Reader(arrays, path)
    try:
        tr = StyleTranslator(**r.value(meta["params"]))
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


# ----------------------------------------------------------------------------- applying a model
class StyleModel:
    """A loaded model: ``translator``, ``unifier`` (may be None), ``meta`` and where it came from."""

    def __init__(self, translator, unifier=None, meta=None, path="<memory>"):
        self.translator, self.unifier, self.meta, self.path = translator, unifier, meta or {}, str(path)

    @property
    def styles(self) -> list[str]:
        return [str(s) for s in self.translator.styles_]

    @classmethod
    def load(cls, path) -> "StyleModel":
        tr, unifier, meta = load_model(path)
        return cls(tr, unifier, meta, path)

    def check_style(self, style, field: str = "style") -> str:
        """``style`` if the model knows it, else an :class:`InputError` listing the known ones."""
        if str(style) not in self.styles:
            raise InputError(self.path, field, "a style the model knows: " + ", ".join(self.styles), style)
        return str(style)


def unify_clip(points, unifier, margin: float | None = None) -> tuple[np.ndarray, object]:
    """Features ``(n, 34)`` of a clip of any body ``(n, 17, 2)``, and the unifier mapping back.

    The clip gets its own bone ratios and body scale
    (:func:`nnsf.skeleton.character_scale`) and the training unifier's shared
    offset, so its features sit where the model's training features do.  A
    coordinate that would fall below zero (a pose far outside the training
    range) is clipped to zero.
    """
    from nnsf.skeleton import Unifier, character_scale, to_features

    P = np.asarray(points, dtype=float)
    scale = character_scale(P)
    if unifier is not None:
        u = Unifier(margin=unifier.margin, scales={"__clip__": scale}, offset=np.array(unifier.offset))
        raw = u._linear(P, np.full(len(P), "__clip__"))
    else:
        u = Unifier(margin=0.5 if margin is None else margin).fit(P, np.full(len(P), "__clip__"))
        raw = u._linear(P, np.full(len(P), "__clip__"))
    X = to_features(raw + u.offset)
    return np.maximum(X, 0.0), u


def translate(content_clip, style, model, source_style=None) -> np.ndarray:
    """The motion of ``content_clip`` performed in ``style``, in the clip's own coordinates.

    Parameters
    ----------
    content_clip : array ``(n, 17, 2)`` or ``(n, 34)``
        Key points of one clip in Human3.6M order (:data:`nnsf.skeleton.JOINTS`),
        in any 2D coordinates with y down (pixels, projected world units).
    style : str
        A style of the model (:attr:`StyleModel.styles`); ``"none"`` or None
        returns the clip unchanged.
    model : :class:`StyleModel`, a fitted translator, or a path to a file
        written by :func:`save_model` (``nnsf styles``).
    source_style : a style of the model the clip is performed in, if known;
        by default the clip is read style-neutrally.

    Returns
    -------
    ndarray ``(m, 17, 2)`` in the coordinates and body proportions of
    ``content_clip``: the clip is unified to the template (its own bone
    ratios and scale), translated by
    :meth:`~nnsf.factor.translate.StyleTranslator.translate_clip` (weights
    encoded with the model's temporal smoothness, the target's basis and
    offset, the clip's residual kept, resampled to the target style's tempo
    when the model's ``tempo`` is on, so ``m`` may differ from ``n``), and
    mapped back with the inverse of the same unification.  The held-out
    evaluation scores exactly this function as its ``api`` method.
    """
    return translate_features(content_clip, style, model, source_style)[0]


def translate_features(content_clip, style, model, source_style=None):
    """:func:`translate`, also returning the translated template features and the clip's unifier.

    Returns ``(points (m, 17, 2), X_hat (m, 34) or None, unifier or None)``;
    the last two are None for style ``"none"``.
    """
    from nnsf.skeleton import to_points

    P = np.asarray(content_clip, dtype=float)
    if P.ndim == 2 and P.shape[1] == 34:
        P = to_points(P)
    if P.ndim != 3 or P.shape[1:] != (17, 2):
        raise ValueError(f"translate: content_clip must be (n, 17, 2) or (n, 34), got {P.shape}")
    if style is None or str(style) == "none":
        return P.copy(), None, None
    if isinstance(model, (str, Path)):
        model = StyleModel.load(model)
    elif not isinstance(model, StyleModel):
        model = StyleModel(model, None)
    style = model.check_style(style)
    if source_style is not None:
        model.check_style(source_style, "source_style")
    X, u = unify_clip(P, model.unifier)
    X_hat = model.translator.translate_clip(X, style, source_style)
    return u.inverse_transform(X_hat, "__clip__"), X_hat, u


# ----------------------------------------------------------------------------- fitting one
def fit_model(table, unifier, translator_params: dict, out, *, features_sha256=None, source="",
              view=None):
    """Fit a translator on a unified contract table and save it to ``out``; returns the translator.

    ``table``: the feature-matrix contract in template units (``features.csv``);
    ``unifier``: the :class:`~nnsf.skeleton.Unifier` that made it.
    """
    from threadpoolctl import threadpool_limits

    from nnsf.datasets import contract
    from nnsf.factor.translate import StyleTranslator

    X = contract.features(table)
    clips = table["clip"].astype(str).to_numpy()
    chars = table["character"].astype(str).to_numpy()
    motions = table["motion"].astype(str).to_numpy()
    if len(set(chars)) < 2:
        raise InputError(source or "features", "character", "frames of at least two styles",
                         sorted(set(chars)))
    # One BLAS thread: the products are thin (34 columns), see stages.factorize.
    with threadpool_limits(limits=1, user_api="blas"):
        tr = StyleTranslator(**translator_params).fit(X, motions, chars, clips)
    save_model(tr, out, unifier=unifier, features_sha256=features_sha256, source=source, view=view,
               digits=DIGITS)
    return tr


def unify_table(raw, margin: float, source="keypoints"):
    """Unify a raw contract table (pixels): ``(features table, Unifier)`` (the features stage's step)."""
    from nnsf.datasets import contract
    from nnsf.skeleton import Unifier, to_points

    points = to_points(contract.features(raw))
    try:
        unifier = Unifier(margin=margin).fit(points, raw["character"].to_numpy())
    except ValueError as exc:
        raise InputError(source, "x1..y17", "a skeleton with non-zero bones", str(exc)) from None
    X = unifier.transform(points, raw["character"].to_numpy())
    table = raw.copy()
    table.loc[:, list(contract.COLUMNS[4:])] = X
    return table, unifier


def dataset_view(params: dict) -> str | None:
    """The view a ``dataset.name: bvh`` dataset is projected in (a view name or ``azimuth N``), else None."""
    from nnsf.params import get

    try:
        if get(params, "dataset.name") != "bvh":
            return None
    except KeyError:
        return None
    for key, fmt in (("dataset.bvh.view", "{}"), ("dataset.bvh.azimuth", "azimuth {:g}")):
        try:
            value = get(params, key)
        except KeyError:
            continue
        if value is not None:
            if key.endswith("azimuth"):
                named = {0.0: "front", 90.0: "side", 45.0: "three-quarter"}.get(float(value))
                return named or fmt.format(float(value))
            return str(value)
    return "front"


def styles_by_hand(params: dict, data=None, out=Path("models/styles.npz")):
    """``nnsf styles``: fit and save a model from a features folder or a folder of BVH clips.

    ``data`` None reads ``data/features`` (the pipeline's configured
    dataset); a folder with ``features.csv`` and ``unifier.json`` is read as
    it is; any other folder is read as labelled BVH clips with the
    ``dataset.bvh`` settings, unified with ``unify.margin``.  Returns the
    stage's :class:`~nnsf.stages.StageResult`.
    """
    from nnsf import stages
    from nnsf.params import require

    folder = Path("data/features") if data is None else Path(data)
    if not folder.is_dir():
        raise InputError(folder, "--data", "a folder of labelled .bvh clips or a features folder")
    if (folder / "features.csv").is_file():
        return stages.styles(params, features_csv=folder / "features.csv", out=out)
    from nnsf.evaluate.translation import _check_translator, translator_params

    tp = translator_params(params)
    _check_translator(params, tp)
    bvh_params = dict(params)
    bvh_params["dataset"] = {**params.get("dataset", {}), "name": "bvh", "path": str(folder)}
    import tempfile

    with tempfile.TemporaryDirectory(prefix="nnsf-styles-") as tmp:
        stages.data(bvh_params, out_dir=Path(tmp) / "raw")
        from nnsf.datasets import contract

        raw = contract.read_table(Path(tmp) / "raw" / "keypoints.csv")
    table, unifier = unify_table(raw, float(require(params, "unify.margin")), folder)
    tr = fit_model(table, unifier, tp, out, source=str(folder), view=dataset_view(bvh_params))
    return stages.StageResult(params={f"translation_{k}": v for k, v in tp.items()},
                              metrics={"styles": len(tr.styles_), "contents": len(tr.contents_),
                                       "frames": len(table)}, artifacts=[Path(out)])
