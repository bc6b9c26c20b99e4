"""Tracking metrics against ground truth (docs/method.md §15.6).

* point-to-curve error: distance (px) of every tracked spline sample to the
  true side curve (a dense polyline), over the in-between frames;
* its reverse, curve-to-point: distance of every dense true sample to the
  tracked curve.  The forward direction alone rewards a tracker that shrinks
  a curve onto the part of the true edge it matches best (every tracked
  sample is then close to the truth); the reverse direction measures how
  much of the true curve is left uncovered.  ``*_sym`` figures average the
  two directions;
* length ratio: mean control-polygon length of the in-between frames over
  that of the keyframes (about 1 for limbs that keep their size; well
  below 1 flags shrinking tracks);
* key-point PCK at 0.05 × torso length (key points derived from the tracked
  curves by :mod:`nnsf.frames.keypoints`);
* the simulated user's edit ratio (the paper's Fig. 4a): the correction
  loop of :mod:`nnsf.roto.correct` — the user corrects the worst frame of
  each interval (the control points off by more than ``tol`` px), it
  becomes a keyframe, the touched intervals are re-tracked — until every
  control point of the in-between frames is within ``tol`` px of the truth.
  ratio = edited control points / (control points × in-between frames).
"""
from __future__ import annotations

import numpy as np

from nnsf.roto import curves
from nnsf.roto.curves import polyline_projection, nearest_vertex, project_to_polyline  # noqa: F401  (re-exported for callers)
from nnsf.roto.solve import ClipTracker, TrackOptions, plan
from nnsf.roto.correct import simulate_user


def curve_errors(control: np.ndarray, truth: np.ndarray, n_samples: int = 32,
                 visible: np.ndarray | None = None):
    """Point-to-curve error of tracked curves.

    control : (T, N, P, 2) tracked control points (NaN-padded rows allowed:
              a curve with fewer points uses its non-NaN prefix).
    truth   : (T, N, S, 2) dense true side curves, same curve order.
    visible : optional (T, N, S) bool visibility of the truth samples.
    Returns (T, N, n_samples) distances in px (NaN where the curve has no
    estimate); with ``visible`` also a (T, N, n_samples) bool: whether the
    nearest true point is visible (not covered by another part).
    """
    control = np.asarray(control, np.float64)
    T, N, P, _ = control.shape
    valid = np.isfinite(control).all(-1)                            # (T, N, P)
    counts = valid.sum(-1)
    out = np.full((T, N, n_samples), np.nan)
    vis = np.zeros((T, N, n_samples), bool)
    for cnt in np.unique(counts[counts >= 2]):
        sel = counts == cnt
        S = curves.sample(control[sel][:, :cnt], n_samples)
        d, _, k = polyline_projection(S, truth[sel])
        out[sel] = d
        if visible is not None:
            vis[sel] = np.take_along_axis(np.asarray(visible)[sel], k, -1)
    return out if visible is None else (out, vis)


def reverse_errors(control: np.ndarray, truth: np.ndarray, n_samples: int = 64) -> np.ndarray:
    """Curve-to-point error: distance (px) of every true sample to the tracked curve.

    control : (T, N, P, 2) tracked control points (NaN-padded as for :func:`curve_errors`).
    truth   : (T, N, S, 2) dense true side curves, same curve order.
    The tracked curve is sampled at ``n_samples`` points as a polyline.
    Returns (T, N, S) distances (NaN where the curve has no estimate).
    """
    control = np.asarray(control, np.float64)
    truth = np.asarray(truth, np.float64)
    T, N, P, _ = control.shape
    valid = np.isfinite(control).all(-1)
    counts = valid.sum(-1)
    out = np.full((T, N, truth.shape[2]), np.nan)
    for cnt in np.unique(counts[counts >= 2]):
        sel = counts == cnt
        S = curves.sample(control[sel][:, :cnt], n_samples)
        out[sel] = polyline_projection(truth[sel], S)[0]
    return out


def symmetric_summary(forward: np.ndarray, reverse: np.ndarray) -> dict[str, float]:
    """Both directions of the point-to-curve error and their symmetric combination.

    ``mean_px``/``p95_px``: tracked -> truth (:func:`curve_errors`);
    ``mean_px_rev``/``p95_px_rev``: truth -> tracked (:func:`reverse_errors`);
    ``mean_px_sym`` = the mean of the two means, ``p95_px_sym`` = the larger
    of the two 95th percentiles (a robust Hausdorff distance).
    """
    f, r = error_summary(forward), error_summary(reverse)
    return {**f, "mean_px_rev": r["mean_px"], "p95_px_rev": r["p95_px"],
            "mean_px_sym": 0.5 * (f["mean_px"] + r["mean_px"]),
            "p95_px_sym": max(f["p95_px"], r["p95_px"])}


def polygon_lengths(control: np.ndarray) -> np.ndarray:
    """Control-polygon length (px) per row: (..., P, 2) -> (...); NaN-padded points skipped.

    A row with fewer than two finite points has NaN length.
    """
    c = np.asarray(control, np.float64)
    seg = np.linalg.norm(np.diff(c, axis=-2), axis=-1)
    n_ok = np.isfinite(c).all(-1).sum(-1)
    return np.where(n_ok >= 2, np.nansum(seg, -1), np.nan)


def length_ratio(control: np.ndarray, keyframes) -> float:
    """Mean control-polygon length of the in-between frames over the keyframes' mean.

    control : (T, N, P, 2) (NaN rows ignored); keyframes : frame indices.
    Frames outside the first and last keyframe are not in-between frames.
    """
    L = polygon_lengths(control)                                    # (T, N)
    keys = sorted(int(k) for k in keyframes)
    T = L.shape[0]
    kf = np.zeros(T, bool)
    kf[keys] = True
    inb = ~kf
    inb[: keys[0]] = False
    inb[keys[-1] + 1:] = False
    a, b = L[inb], L[kf]
    a, b = a[np.isfinite(a)], b[np.isfinite(b)]
    if a.size == 0 or b.size == 0 or b.mean() <= 0:
        return float("nan")
    return float(a.mean() / b.mean())


def error_summary(err: np.ndarray) -> dict[str, float]:
    """Mean and 95th percentile (px) of the finite entries of an error array."""
    e = np.asarray(err)[np.isfinite(err)]
    if e.size == 0:
        return {"mean_px": float("nan"), "p95_px": float("nan")}
    return {"mean_px": float(e.mean()), "p95_px": float(np.percentile(e, 95))}


def pck(pred: np.ndarray, truth: np.ndarray, torso: np.ndarray, alpha: float = 0.05) -> float:
    """Share of key points within ``alpha`` × torso length of the truth.

    pred, truth : (T, J, 2) px (NaN predictions count as wrong);
    torso : (T,) torso length per frame (px).
    """
    d = np.linalg.norm(np.asarray(pred, float) - np.asarray(truth, float), axis=-1)
    ok = np.where(np.isfinite(d), d <= alpha * np.asarray(torso, float)[:, None], False)
    return float(ok.mean()) if ok.size else float("nan")


def edit_ratio(frames: np.ndarray, annotation, truth: np.ndarray, names_truth: list[str],
               method: str, tol: float = 2.0, max_edits: int = 20, **options) -> dict:
    """The simulated user's edit ratio for one clip and tracker (the paper's Fig. 4a).

    frames : (T, H, W, 3) uint8; truth : (T, N_truth, S, 2) dense true side
    curves named ``names_truth``; method : "ours" | "agarwala" | "lk".
    The user runs the correction loop of :func:`nnsf.roto.correct.simulate_user`:
    each round corrects the worst frame of every keyframe interval that
    still has a control point more than ``tol`` px off (moving only those
    points onto the true curve), the corrected frames become keyframes and
    the touched intervals are re-tracked, until every in-between control
    point is within ``tol``.  ``max_edits`` caps the rounds (points still
    off then count one edit each, so the figure stays comparable).
    ratio = edits / (control points × in-between frames).
    Returns ``{"edit_ratio", "edits", "control_points", "capped_curves",
    "corrected_frames", "rounds", "names", "tracked", "control"}``:
    ``tracked`` is the tracker's result before any correction and
    ``control`` the corrected one, both (T, N, P, 2) in ``names`` order (as
    :func:`nnsf.roto.solve.track_clip` returns); ``capped_curves`` counts
    the curves with control points still off when the cap stopped the loop.
    """
    opts = TrackOptions.from_kwargs(**options)
    names, kfs, batches = plan(annotation)
    tracker = ClipTracker(frames, method, opts, keyframes=kfs)
    slots = sum(b.P.shape[0] * b.P.shape[2] * (b.P.shape[1] - 2) for b in batches)
    n_points = [max(len(kf[n]) for kf in kfs.values() if n in kf) for n in names]
    tru = np.asarray(truth)[:, [names_truth.index(n) for n in names]]
    res = simulate_user(tracker, names, kfs, tru, n_points, tol=tol, max_rounds=max_edits)
    return {"edit_ratio": res["edits"] / slots if slots else float("nan"), "edits": res["edits"],
            "control_points": slots, "capped_curves": res["left_curves"],
            "corrected_frames": res["corrected_frames"], "rounds": res["rounds"], "names": names,
            "tracked": res["tracked"], "control": res["control"]}
