"""A saved style model applied to new motion: :func:`translate` (``nnsf.translate``) and its helpers.

:class:`StyleModel` is a loaded model file (:mod:`nnsf.factor.model_file`):
per camera view, a fitted :class:`~nnsf.factor.translate.StyleTranslator` and
the unifier of its training characters.  :func:`translate` maps a clip of any body into a
style (unify with the clip's own proportions, Eq. 4; translate, docs/method.md
§8; back to the clip's pixels); :func:`fit_model` fits and saves one, a
translator per view (the ``styles`` stage, ``nnsf styles``);
:func:`translator_params` reads the ``translation`` section of params.yaml.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.factor.style_names import resolve_style
from nnsf.factor.model_file import ModelView, file_sha256, load_model, read_meta, save_model  # noqa: F401  (re-exported)
from nnsf.io import DIGITS
from nnsf.factor.translate import StyleTranslator
from nnsf.datasets.synthetic import FPS as SYNTHETIC_FPS
from nnsf.params import get, require, source_of
from nnsf.skeleton import Unifier, character_scale, to_features, to_points


# ----------------------------------------------------------------------------- applying a model
class StyleModel:
    """A loaded model: one fitted translator and unifier per camera view, ``meta`` and where it came from.

    ``views`` is a list of :class:`~nnsf.factor.model_file.ModelView`; a
    model made in memory from one ``translator`` (and ``unifier``) has one
    view, None (no camera).
    """

    def __init__(self, translator=None, unifier=None, meta=None, path="<memory>", views=None):
        self.views = list(views) if views is not None else [ModelView(None, translator, unifier)]
        self.meta, self.path = meta or {}, str(path)

    @property
    def translator(self):
        """The first view's translator."""
        return self.views[0].translator

    @property
    def unifier(self):
        """The first view's unifier (may be None)."""
        return self.views[0].unifier

    @property
    def view_names(self) -> list:
        """The views the styles were learned in (None: 2D data, no camera)."""
        return [v.view for v in self.views]

    @property
    def styles(self) -> list[str]:
        return [str(s) for s in self.translator.styles_]

    @classmethod
    def load(cls, path) -> "StyleModel":
        views, meta = load_model(path, StyleTranslator)
        return cls(meta=meta, path=path, views=views)

    def check_style(self, style, field: str = "style") -> str:
        """The model's name for ``style`` (any letter case, or one of the model's aliases), else an
        :class:`InputError` listing the known ones (:func:`nnsf.factor.style_names.resolve_style`)."""
        return resolve_style(style, self.styles, self.meta.get("aliases"), self.path, field)

    def pick_view(self, view) -> tuple[ModelView, str | None]:
        """The model's view for a motion seen in ``view``, and a note when none matches (else None).

        ``view`` None (a motion with no camera: 2D key points) takes the
        first view.  A named view the model lacks takes the model's view
        nearest in azimuth (or its first), and the note says so.
        """
        named = [v for v in self.views if v.view is not None]
        if view is None:
            return self.views[0], None
        for v in self.views:
            if v.view == view:
                return v, None
        known = ", ".join(str(v.view) for v in self.views)
        if not named:
            return self.views[0], (f"{self.path}: the styles were learned from 2D key points with no camera "
                                   f"view; this motion is seen in the {view} view")
        target = _azimuth(view)
        best = min(named, key=lambda v: abs(_azimuth(v.view) - target)) if target is not None else named[0]
        return best, (f"{self.path}: no style model for the {view} view (the file has: {known}); "
                      f"using the {best.view} view's (`nnsf styles --data FOLDER` on motion capture "
                      "learns every view)")


def _azimuth(view) -> float | None:
    """Degrees of a view name (``front``, ``side``, ``three-quarter``, ``azimuth N``), else None."""
    named = {"front": 0.0, "side": 90.0, "three-quarter": 45.0}
    if view in named:
        return named[view]
    if isinstance(view, str) and view.startswith("azimuth "):
        try:
            return float(view.split(" ", 1)[1])
        except ValueError:
            return None
    return None


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


def translate(content_clip, style, model, source_style=None, *, view=None, fps=None) -> np.ndarray:
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
        by default the clip is read as the model's neutral style
        (``translation.neutral``; the average style when there is none).
    view : the camera view the clip is seen in (``front``, ``side``,
        ``three-quarter``), to pick the model's view (:meth:`StyleModel.pick_view`);
        None takes the model's first view.
    fps : the clip's frame rate; by default the model's.

    Returns
    -------
    ndarray ``(n, 17, 2)`` in the coordinates and body proportions of
    ``content_clip``: the clip is unified to the template (its own bone
    ratios and scale), translated by
    :meth:`~nnsf.factor.translate.StyleTranslator.translate_clip` (docs/method.md
    §8.4) and mapped back with the inverse of the same unification.  The
    held-out evaluations score exactly this function (``api``).
    """
    return translate_features(content_clip, style, model, source_style, view=view, fps=fps)[0]


def translate_features(content_clip, style, model, source_style=None, *, view=None, fps=None):
    """:func:`translate`, also returning the translated template features and the clip's unifier.

    Returns ``(points (n, 17, 2), X_hat (n, 34) or None, unifier or None)``;
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
    picked, _ = model.pick_view(view)
    X, u = unify_clip(P, picked.unifier)
    X_hat = picked.translator.translate_clip(X, style, source_style, fps=fps)
    return u.inverse_transform(X_hat, "__clip__"), X_hat, u


# ----------------------------------------------------------------------------- fitting one
def fit_translator(table, translator_params: dict, fps=None) -> StyleTranslator:
    """A :class:`StyleTranslator` fitted on a unified contract table (template units) of clips at ``fps``."""
    from threadpoolctl import threadpool_limits

    X = contract.features(table)
    clips = table["clip"].astype(str).to_numpy()
    chars = table["character"].astype(str).to_numpy()
    motions = table["motion"].astype(str).to_numpy()
    # One BLAS thread: the products are thin (34 columns), see stages.factorize.
    with threadpool_limits(limits=1, user_api="blas"):
        return StyleTranslator(**translator_params).fit(X, motions, chars, clips, fps=fps)


def fit_model(views, translator_params: dict, out, *, features_sha256=None, source="", fps=None,
              aliases=None):
    """Fit one translator per view and save them to ``out``; returns the :class:`ModelView` list.

    ``views``: ``[(view name or None, unified contract table, Unifier), ...]``
    -- each table the feature-matrix contract in template units
    (``features.csv``) made by its unifier, all with the same styles.  ``aliases``:
    other names of the styles (:func:`save_model`).
    """
    fitted = []
    for view, table, unifier in views:
        chars = sorted(set(table["character"].astype(str)))
        if len(chars) < 2:
            raise InputError(source or "features", "character", "frames of at least two styles", chars)
        neutral = translator_params.get("neutral")
        if neutral is not None and neutral not in chars:
            raise InputError(source or "features", "translation.neutral",
                             "a style of the data: " + ", ".join(chars), neutral)
        fitted.append(ModelView(view, fit_translator(table, translator_params, fps), unifier))
    save_model(fitted, out, features_sha256=features_sha256, source=source, digits=DIGITS,
               aliases=aliases)
    return fitted


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


def dataset_fps(params: dict) -> float | None:
    """Frame rate of the configured dataset's clips: ``dataset.bvh.fps``, the generator's, else None."""
    try:
        name = get(params, "dataset.name")
    except KeyError:
        return None
    if name == "bvh":
        try:
            return float(get(params, "dataset.bvh.fps"))
        except KeyError:
            return None
    return float(SYNTHETIC_FPS) if name == "synthetic" else None


def translator_params(params: dict) -> dict:
    """StyleTranslator keyword arguments from the ``translation`` section of params.yaml."""
    label = require(params, "translation.label")
    return {
        "n_components": int(require(params, "translation.rank")),
        "alpha": float(require(params, "translation.alpha")),
        "beta": float(require(params, "translation.beta")),
        "label": {"motion": "content", "character": "style"}.get(label, label),
        "basis": require(params, "translation.basis"),
        "amplitude": require(params, "translation.amplitude"),
        "tempo": bool(require(params, "translation.tempo")),
        "transfer": require(params, "translation.transfer"),
        "neutral": require(params, "translation.neutral"),
        "ridge": float(require(params, "translation.ridge")),
        "smooth": float(require(params, "translation.smooth")),
        "max_iter": int(require(params, "translation.max_iter")),
        "align_iter": int(require(params, "translation.align_iter")),
        "random_state": int(require(params, "seed")),
    }


def check_translator(params, tp, synthesis=None):
    """InputError unless ``tp`` (:func:`translator_params`) are valid StyleTranslator settings and
    ``synthesis`` (``translation.synthesis``, if given) fits the basis."""
    if synthesis == "consensus" and tp["basis"] != "aligned":
        raise InputError(source_of(params), "translation.synthesis",
                         "'source' unless translation.basis is 'aligned' (a consensus needs the "
                         "aligned fit's shared weights)", synthesis)
    try:
        StyleTranslator(**tp)._validate_params()
    except ValueError as exc:
        raise InputError(source_of(params), "translation", "valid StyleTranslator settings",
                         reason=str(exc).splitlines()[0]) from None
