"""The feature-matrix contract between stages (docs/formats.md §3.1).

One row per frame with columns ``clip, frame, character, motion, x1, y1 …
x17, y17``.  Raw (pixel) tables and unified feature tables share the layout;
a unified table additionally guarantees every coordinate is ≥ 0.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.io import write_csv
from nnsf.skeleton.layout import FEATURE_COLUMNS

LABEL_COLUMNS: tuple[str, ...] = ("clip", "frame", "character", "motion")
COLUMNS: tuple[str, ...] = LABEL_COLUMNS + FEATURE_COLUMNS


def validate(table: pd.DataFrame, source, non_negative: bool = False) -> pd.DataFrame:
    """Check a contract table; return it with canonical dtypes and row order.

    Raises :class:`InputError` naming ``source`` and the offending column for
    missing columns, non-numeric, NaN or infinite coordinates, negative
    coordinates (when ``non_negative``), and duplicate (clip, frame) rows.
    """
    missing = [c for c in COLUMNS if c not in table.columns]
    if missing:
        raise InputError(source, missing[0], "a column of the feature-matrix contract "
                         "(clip, frame, character, motion, x1..y17)")
    if len(table) == 0:
        raise InputError(source, "rows", "at least one frame")
    table = table.loc[:, list(COLUMNS)].copy()
    for col in ("clip", "character", "motion"):
        table[col] = table[col].astype(str)
    frame = pd.to_numeric(table["frame"], errors="coerce")
    if frame.isna().any() or (frame % 1 != 0).any() or (frame < 0).any():
        raise InputError(source, "frame", "whole numbers >= 0")
    table["frame"] = frame.astype(np.int64)
    values = table.loc[:, list(FEATURE_COLUMNS)].apply(pd.to_numeric, errors="coerce")
    arr = values.to_numpy(dtype=float)
    bad = ~np.isfinite(arr)
    if bad.any():
        r, c = np.argwhere(bad)[0]
        raise InputError(source, FEATURE_COLUMNS[c], "finite numbers (no NaN, Inf or text)",
                         f"{table.iloc[r, 4 + c]!r} at row {r + 1}")
    if non_negative and (arr < 0).any():
        r, c = np.argwhere(arr < 0)[0]
        raise InputError(source, FEATURE_COLUMNS[c], "non-negative unified features",
                         f"{arr[r, c]:.6g} at row {r + 1}")
    table[list(FEATURE_COLUMNS)] = arr      # whole columns: float64 even when a CSV held whole numbers
    dup = table.duplicated(["clip", "frame"])
    if dup.any():
        r = int(np.flatnonzero(dup)[0])
        raise InputError(source, "clip/frame", "one row per (clip, frame)",
                         f"{table['clip'].iloc[r]}/{table['frame'].iloc[r]} twice")
    return table.sort_values(["clip", "frame"], kind="stable").reset_index(drop=True)


def read_csv(path) -> pd.DataFrame:
    """A feature-matrix CSV as read, not yet validated (labels as strings); InputError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing feature-matrix CSV")
    try:
        return pd.read_csv(path, dtype={"clip": str, "character": str, "motion": str})
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, OSError) as exc:
        raise InputError(path, "file", "a readable CSV table", reason=str(exc)) from None


def read_table(path, non_negative: bool = False) -> pd.DataFrame:
    """Read and validate a contract CSV."""
    return validate(read_csv(path), Path(path), non_negative=non_negative)


def read_features(path) -> pd.DataFrame:
    """The features stage's table: the contract in template units, every feature >= 0."""
    return read_table(path, non_negative=True)


def write_table(path, table: pd.DataFrame) -> None:
    """Write a contract table atomically (columns in contract order)."""
    write_csv(path, table.loc[:, list(COLUMNS)])


def features(table: pd.DataFrame) -> np.ndarray:
    """The coordinate block ``(n, 34)`` of a contract table, float64."""
    return table.loc[:, list(FEATURE_COLUMNS)].to_numpy(dtype=float)
