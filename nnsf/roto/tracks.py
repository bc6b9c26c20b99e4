"""The TRACKS format: a tracker's ``<tracks>/<clip>/curves.npz``, read and checked against the clip's annotation.

``control (T, C, P, 2)`` control points per frame and curve (NaN-padded
rows where a curve has fewer points), ``curve_names`` (side-curve names such
as ``l_forearm.a``), optional ``n_points (C,)`` and ``keyframes``
(docs/formats.md).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.frames.curves import SIDE_INDEX
from nnsf.io import read_npz
from nnsf.schema import Array

#: The arrays of a ``curves.npz`` (nothing else is read from it; sizes named as in the docstring).
TRACKS = {
    "control": Array("f", ("T", "C", "P", 2)),
    "curve_names": Array("U", ("C",)),
    "n_points": Array("iu", ("C",), required=False),
    "keyframes": Array("iu", (None,), required=False),
}

#: Tracked keyframe curves may differ from the annotation by at most this (px).
KEYFRAME_TOL_PX = 0.5


def read_tracks(path, annotation) -> tuple[np.ndarray, list[str], np.ndarray]:
    """Read and check a tracker's ``curves.npz`` against the clip's annotation.

    Returns ``control (T, C, P, 2)``, ``curve_names`` and ``n_points (C,)``.
    InputError (naming ``path``) for a missing file, missing arrays, wrong
    shapes, unknown or repeated curve names, a frame count other than the
    annotation's, or keyframe rows that differ from the annotated curves by
    more than :data:`KEYFRAME_TOL_PX`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "the tracker's curves.npz for this clip (run the tracker)")
    z = read_npz(path, TRACKS, what="file of tracked curves")
    control, names = z["control"], z["curve_names"]
    T = len(annotation.frames)
    if control.ndim != 4 or control.shape[3] != 2 or control.shape[0] != T or control.shape[2] < 2:
        raise InputError(path, "control", f"a float array (T={T} frames, C, P>=2, 2)",
                         f"shape {control.shape}")
    if not np.issubdtype(control.dtype, np.floating):
        raise InputError(path, "control", "a float array", str(control.dtype))
    if names.ndim != 1 or names.dtype.kind != "U" or len(names) != control.shape[1]:
        raise InputError(path, "curve_names", f"{control.shape[1]} curve names (unicode array)",
                         f"{names.dtype} array of shape {names.shape}")
    names = [str(n) for n in names]
    for n in names:
        if n not in SIDE_INDEX:
            raise InputError(path, "curve_names", "side-curve names like l_forearm.a", n)
    if len(set(names)) != len(names):
        raise InputError(path, "curve_names", "each curve once", names)
    P = control.shape[2]
    if "n_points" in z:
        n_points = np.asarray(z["n_points"])
        if (n_points.shape != (len(names),) or n_points.dtype.kind not in "iu"
                or (n_points < 2).any() or (n_points > P).any()):
            raise InputError(path, "n_points", f"{len(names)} integers in [2, {P}]", n_points.tolist())
    else:
        finite = np.isfinite(control).all(-1).any(0)
        n_points = np.where(finite.all(1), P, np.argmin(finite, axis=1))
    n_points = n_points.astype(np.int64)
    for k in annotation.keyframes:
        for c, n in enumerate(names):
            if n in k.curves:
                want = k.curves[n]
                got = control[k.frame, c, : n_points[c]]
                if got.shape != want.shape or not (np.abs(got - want) <= KEYFRAME_TOL_PX).all():
                    raise InputError(path, f"control[{k.frame}, {c}] ({n})",
                                     f"the annotated keyframe curve (within {KEYFRAME_TOL_PX} px)",
                                     np.round(got, 2).tolist())
    return control.astype(np.float64), names, n_points
