"""The per-source baselines of the held-out translation: the style offset and the identity (docs/method.md §15.5).

Each is a factory ``BASELINES[name](cell) -> translate(X_source, source_style)``
built from one cell's remaining data (:class:`CellData`): ``offset`` adds the
difference of the two styles' mean poses, ``identity`` returns the source
clip unchanged.  They are the floors NNSF must beat.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

@dataclass(frozen=True)
class CellData:
    """The training side of one held-out cell, for a baseline factory.

    ``X`` (n, 34) unified training features (template units), ``clip_rows``
    the rows of every training clip, ``clip_style``/``clip_content`` their
    labels, ``style``/``content`` the hidden cell.  Nothing of the hidden
    cell is in it.
    """

    X: np.ndarray
    clip_rows: list
    clip_style: np.ndarray
    clip_content: np.ndarray
    style: str
    content: str


def style_offset(cell: CellData, source_style: str, target_style: str) -> np.ndarray:
    """Mean pose offset from ``source_style`` to ``target_style``, ``(34,)`` template units.

    The mean over the contents c' that both styles perform in the training
    data, other than the cell's content, of mean_pose(target, c') −
    mean_pose(source, c'), each mean pose the mean frame over that
    (style, content)'s clips (each clip weighing the same).  Zeros when they
    share no such content.
    """
    def mean_pose(s, c):
        idx = np.flatnonzero((cell.clip_style == s) & (cell.clip_content == c))
        return np.mean([cell.X[cell.clip_rows[i]].mean(axis=0) for i in idx], axis=0)

    have = lambda s: set(cell.clip_content[cell.clip_style == s]) - {cell.content}  # noqa: E731
    shared = sorted(have(source_style) & have(target_style))
    if not shared or source_style == target_style:
        return np.zeros(cell.X.shape[1])
    return np.mean([mean_pose(target_style, c) - mean_pose(source_style, c) for c in shared], axis=0)


def _offset_baseline(cell: CellData):
    """``offset``: the source clip plus the mean pose offset from its style to the target's
    (:func:`style_offset`); from the ``normal`` style this is "normal clip + the style's mean
    pose offset"."""
    cache = {}

    def run(Xs, source_style):
        if source_style not in cache:
            cache[source_style] = style_offset(cell, source_style, cell.style)
        return np.asarray(Xs, dtype=float) + cache[source_style]
    return run


def _identity_baseline(cell: CellData):
    """``identity``: the source clip unchanged."""
    return lambda Xs, source_style: np.asarray(Xs, dtype=float)


#: Per-source baselines of :func:`evaluate_cell`: name -> factory.  A factory
#: gets the cell's :class:`CellData` once and returns ``f(X_source (n, 34),
#: source_style) -> X_hat (m, 34)``; register a new baseline by adding it here
#: (and to :data:`METHODS` / :data:`STAGE_METHODS` for the table order).
BASELINES: dict = {"offset": _offset_baseline, "identity": _identity_baseline}
