"""The two Gaussian-process baselines as held-out style translators (docs/method.md §15.5).

The held-out evaluation (:func:`nnsf.evaluate.translation.evaluate_cell`) hides
one (style, content) cell, fits every method on the rest and translates each
remaining clip of the content into the hidden style.  These functions do that
for the MGPM and the CBGPM with the same inputs as the bilinear method there:

* :func:`fit_gp_translator` -- fit on the training rows of the protocol
  (unified features ``X``, their contents, styles and clips);
* :func:`gp_translate` -- a source clip ``Xs`` of the content in style
  ``source_style`` rendered in ``target_style``: the model's synthesis of the
  (target, content) cell at the source frames' phases, plus -- like the
  bilinear method's ``bilinear_residual`` -- the source frames' residual from
  the model's own synthesis of the (source, content) cell, so frame-to-frame
  detail of the source survives;
* :func:`translation_gp_params` -- the ``translation.gp_*`` fields of
  params.yaml, checked against the data (one-line :class:`InputError`).
"""
from __future__ import annotations

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.params import require, source_of
from nnsf.factor.cbgpm import CBGPM
from nnsf.factor.mgpm import MGPM
from nnsf.skeleton import N_FEATURES

__all__ = ["GP_TRANSLATION_METHODS", "fit_gp_translator", "gp_translate", "translation_gp_params"]

#: Method names of the held-out evaluation these functions provide.
GP_TRANSLATION_METHODS: tuple[str, ...] = ("mgpm", "cbgpm")


def fit_gp_translator(method: str, X, content, style, clip, *, rank: int, phase_bins: int = 3,
                      max_iter: int = 50, seed: int = 0, phase=None):
    """Fit ``method`` ("mgpm" or "cbgpm") on the training rows of a held-out protocol.

    Parameters
    ----------
    X : array (n, d)
        Unified features of the training rows (the hidden cell removed).
    content, style, clip : arrays (n,)
        Motion, character and clip of each row; rows of a clip in frame order.
    rank : int
        Latent dimension (MGPM, at most max(styles, contents)) or principal
        components (CBGPM, at most d).
    phase_bins, max_iter, seed
        As in :class:`~nnsf.factor.mgpm.MGPM` / :class:`~nnsf.factor.cbgpm.CBGPM`.
    phase : array (n,), optional
        Phase of each row in its clip; default its position in the clip.

    Returns
    -------
    The fitted estimator.
    """
    if method == "mgpm":
        model = MGPM(n_components=rank, phase_bins=phase_bins, max_iter=max_iter, random_state=seed)
    elif method == "cbgpm":
        model = CBGPM(n_components=rank, phase_bins=phase_bins, max_iter=max_iter)
    else:
        raise ValueError(f"unknown GP translation method {method!r}; choose from {GP_TRANSLATION_METHODS}")
    return model.fit(np.asarray(X, dtype=float), np.asarray(content), np.asarray(style),
                     phase=phase, groups=None if phase is not None else np.asarray(clip))


def gp_translate(model, Xs, source_style, target_style, content, residual: bool = True) -> np.ndarray:
    """Source clip ``Xs`` (T, d) of ``content`` in ``source_style``, performed in ``target_style``.

    Frame ``t`` has phase ``t / (T − 1)``.  Returns ``(T, d)`` unified features:
    ``synth(target, content, φ_t)`` plus, with ``residual``,
    ``Xs[t] − synth(source, content, φ_t)``.
    """
    Xs = np.asarray(Xs, dtype=float)
    if Xs.ndim != 2 or Xs.shape[0] < 1:
        raise ValueError(f"Xs must be a (frames, features) array, got shape {Xs.shape}")
    phase = np.linspace(0.0, 1.0, len(Xs)) if len(Xs) > 1 else np.zeros(1)
    out = model.synthesize(target_style, content, phase)
    if residual:
        out = out + (Xs - model.synthesize(source_style, content, phase))
    return out


def translation_gp_params(params: dict, table: pd.DataFrame, methods=GP_TRANSLATION_METHODS) -> dict:
    """``rank``, ``phase_bins``, ``max_iter`` from ``translation.gp_*``, checked against ``table``.

    ``table`` is the contract table the held-out evaluation runs on.  The
    MGPM's latent dimension may not exceed ``max(styles, contents)``, the
    CBGPM's components not the number of features, and the phase bins not
    the frames of the shortest clip (the subsample cannot be larger than
    the data).  Each failure is an :class:`InputError` naming the field.
    """
    rank = int(require(params, "translation.gp_rank"))
    bins = int(require(params, "translation.gp_phase_bins"))
    max_iter = int(require(params, "translation.gp_max_iter"))
    src = source_of(params)
    n_styles, n_contents = table["character"].nunique(), table["motion"].nunique()
    d = N_FEATURES
    if "mgpm" in methods and rank > max(n_styles, n_contents):
        raise InputError(src, "translation.gp_rank",
                         f"a rank of at most max(styles, contents) = max({n_styles}, {n_contents}) "
                         "for the MGPM", rank)
    if "cbgpm" in methods and rank > d:
        raise InputError(src, "translation.gp_rank", f"a rank of at most the {d} features for the CBGPM", rank)
    shortest = int(table.groupby("clip").size().min())
    if bins > shortest:
        raise InputError(src, "translation.gp_phase_bins",
                         f"at most the frames of the shortest clip ({shortest}); the GP models' "
                         "subsample cannot be larger than the data", bins)
    return {"rank": rank, "phase_bins": bins, "max_iter": max_iter}
