"""NNSF translations the held-out evaluation compares but the product does not use (docs/method.md §15.5).

* :func:`swapped_translation` -- the paper's own example read literally
  (``nnsf_swapped``): the basis carries the content and the weights the
  style, X̂ = V_style U_clip.  U_clip is the pooled basis U₀ refitted on the
  content clip alone (its weights fixed, :func:`~nnsf.factor.align.refit_basis`),
  V_style the weights of a fitted clip of the target style -- of the same
  content if the style has one, else of the content whose mean pose is
  nearest the clip's -- so frames and timing are that clip's; the style
  clip's residual X − V_style U₀ is added back.

Everything is read from a fitted :class:`~nnsf.factor.translate.StyleTranslator`
(template units).
"""
from __future__ import annotations

import numpy as np

from nnsf.factor.align import refit_basis


def style_clip(translator, target_style, content, X_clip) -> np.ndarray:
    """A fitted clip ``(m, d)`` of ``target_style``: of ``content`` if the style has one, else of
    the content whose mean pose (over all styles) is nearest ``X_clip``'s mean."""
    have = sorted(c for (s, c) in translator.clips_ if s == str(target_style))
    if not have:
        raise ValueError(f"unknown target style {target_style!r}")
    if str(content) in have:
        return translator.clips_[(str(target_style), str(content))][0]
    means = {c: np.mean([Xq.mean(axis=0) for (s, c2), lst in translator.clips_.items() if c2 == c for Xq in lst],
                        axis=0) for c in have}
    m = np.asarray(X_clip, dtype=float).mean(axis=0)
    best = min(have, key=lambda c: float(np.linalg.norm(means[c] - m)))
    return translator.clips_[(str(target_style), best)][0]


def swapped_translation(translator, X_clip, target_style, content) -> np.ndarray:
    """X̂ = V_style U_clip + (X_style − V_style U₀), ``(m, d)``: the module docstring's reading."""
    X_clip = np.asarray(X_clip, dtype=float)
    U0 = translator.components_
    U_clip = refit_basis(X_clip, translator.encode(X_clip, None), U0, max_iter=translator.max_iter,
                         ridge=translator.ridge)
    X_style = style_clip(translator, target_style, content, X_clip)
    V_style = translator.encode(X_style, None)
    return V_style @ U_clip + X_style - V_style @ U0
