"""A saved style model applied to new motion: :func:`translate` (``nnsf.translate``) and its helpers.

:class:`StyleModel` is a loaded model file (:mod:`nnsf.factor.model_file`):
the fitted :class:`~nnsf.factor.translate.StyleTranslator` and the unifier of
its training characters.  :func:`translate` maps a clip of any body into a
style (unify with the clip's own proportions, Eq. 4; translate, docs/method.md
§8; back to the clip's pixels); :func:`fit_model` fits and saves one
(the ``styles`` stage); :func:`translator_params` reads the ``translation``
section of params.yaml.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.factor.style_names import resolve_style
from nnsf.factor.model_file import file_sha256, load_model, read_meta, save_model  # noqa: F401  (re-exported)
from nnsf.io import DIGITS
from nnsf.factor.translate import StyleTranslator
from nnsf.params import get, require, source_of
from nnsf.skeleton import Unifier, character_scale, to_features, to_points


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
        tr, unifier, meta = load_model(path, StyleTranslator)
        return cls(tr, unifier, meta, path)

    def check_style(self, style, field: str = "style") -> str:
        """The model's name for ``style`` (any letter case, or one of the model's aliases), else an
        :class:`InputError` listing the known ones (:func:`nnsf.factor.style_names.resolve_style`)."""
        return resolve_style(style, self.styles, self.meta.get("aliases"), self.path, field)


def unify_clip(points, unifier, margin: float | None = None) -> tuple[np.ndarray, object]:
    """Features ``(n, 34)`` of a clip of any body ``(n, 17, 2)``, and the unifier mapping back.

    The clip gets its own bone ratios and body scale
    (:func:`nnsf.skeleton.character_scale`) and the training unifier's shared
    offset, so its features sit where the model's training features do.  A
    coordinate that would fall below zero (a pose far outside the training
    range) is clipped to zero.
    """
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
        source_style = model.check_style(source_style, "source_style")
    X, u = unify_clip(P, model.unifier)
    X_hat = model.translator.translate_clip(X, style, source_style)
    return u.inverse_transform(X_hat, "__clip__"), X_hat, u


# ----------------------------------------------------------------------------- fitting one
def fit_model(table, unifier, translator_params: dict, out, *, features_sha256=None, source="",
              view=None, aliases=None):
    """Fit a translator on a unified contract table and save it to ``out``; returns the translator.

    ``table``: the feature-matrix contract in template units (``features.csv``);
    ``unifier``: the :class:`~nnsf.skeleton.Unifier` that made it.
    """
    from threadpoolctl import threadpool_limits

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
               digits=DIGITS, aliases=aliases)
    return tr


def unify_table(raw, margin: float, source="keypoints"):
    """Unify a raw contract table (pixels): ``(features table, Unifier)`` (the features stage's step)."""
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


def translator_params(params: dict) -> dict:
    """StyleTranslator keyword arguments from the ``translation`` section of params.yaml."""
    label = require(params, "translation.label")
    return {
        "n_components": int(require(params, "translation.rank")),
        "alpha": float(require(params, "translation.alpha")),
        "beta": float(require(params, "translation.beta")),
        "label": {"motion": "content", "character": "style"}.get(label, label),
        "basis": require(params, "translation.basis"),
        "synthesis": require(params, "translation.synthesis"),
        "amplitude": require(params, "translation.amplitude"),
        "tempo": bool(require(params, "translation.tempo")),
        "ridge": float(require(params, "translation.ridge")),
        "smooth": float(require(params, "translation.smooth")),
        "smooth_order": int(require(params, "translation.smooth_order")),
        "max_iter": int(require(params, "translation.max_iter")),
        "align_iter": int(require(params, "translation.align_iter")),
        "random_state": int(require(params, "seed")),
    }


def check_translator(params, tp):
    """InputError unless ``tp`` (:func:`translator_params`) are valid StyleTranslator settings."""
    if tp["synthesis"] == "consensus" and tp["basis"] != "aligned":
        raise InputError(source_of(params), "translation.synthesis",
                         "'source' unless translation.basis is 'aligned' (a consensus needs the "
                         "aligned fit's shared weights)", tp["synthesis"])
    try:
        StyleTranslator(**tp)._check_params()
    except ValueError as exc:
        raise InputError(source_of(params), "translation", "valid StyleTranslator settings", reason=str(exc)) from None
