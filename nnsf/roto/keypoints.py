"""Key points from tracked side curves (paper Eq. 2-3, docs/method.md §3).

The calibration points of a curve group are the ends of its two side curves:
p¹ = a[0], p² = b[0] at the start joint and p³ = a[-1], p⁴ = b[-1] at the end
joint.  A joint is a fixed blend of its pair,

    p_start = ω_s p¹ + (1 − ω_s) p²,     p_end = ω_e p³ + (1 − ω_e) p⁴,

with ω fitted on the keyframes that carry annotated key points,
ω = Σ_k (p_j − p²)·(p¹ − p²) / Σ_k ‖p¹ − p²‖² (the least-squares value over
those keyframes; with one keyframe exactly the paper's formula), clipped to
[0, 1].

Which group gives which joint (:data:`JOINT_SOURCES`): the start and end
joints of the eight limbs, ``torso`` gives thorax (start) and pelvis (end),
``head`` gives neck (start) and head top (end).  Elbows and knees are the end
of one limb and the start of the next: **they are the mean of the two
estimates** (either one alone when the other group is missing).  Both
estimates rest on calibration pairs of about the same spacing (the limb's
width at the joint), so neither is better conditioned in general, and the
mean halves the variance of independent tracking errors.  Shoulders and
hips come from the upper arms and thighs only (the torso's side curves end
at thorax and pelvis).

The spine (not at a curve end) is taken on the torso: at arc-length fraction
f of the torso's mid-line (the mean of its two sides, thorax → pelvis),
blended between the two sides at that place with weight ω, p = ω a(f) +
(1 − ω) b(f); f and ω are fitted on the keyframes (grid over f, least
squares for ω).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from nnsf.errors import InputError
from nnsf.frames.annotation import Annotation
from nnsf.frames.curves import GROUP_JOINTS, GROUPS, sample_curve
from nnsf.skeleton.layout import JOINT_INDEX, JOINTS, N_JOINTS

#: joint index -> [(group, "start" | "end"), ...] that estimate it.
JOINT_SOURCES: dict[int, list[tuple[str, str]]] = {j: [] for j in range(N_JOINTS)}
for _g in GROUPS:
    _s, _e = GROUP_JOINTS[_g]
    JOINT_SOURCES[_s].append((_g, "start"))
    JOINT_SOURCES[_e].append((_g, "end"))
SPINE = JOINT_INDEX["spine"]
assert not JOINT_SOURCES[SPINE] and all(JOINT_SOURCES[j] for j in range(N_JOINTS) if j != SPINE)

#: Samples per torso side when locating the spine (uniform in the spline parameter).
SPINE_SAMPLES = 201
_F_GRID = np.linspace(0.0, 1.0, 401)


@dataclass
class KeypointModel:
    """Fitted weights: ``omega[(group, "start"|"end")]`` and the spine's ``(f, ω)``.

    ``fit_residual_px``: RMS distance (px) between the annotated key points and
    the model's estimate on the fitting keyframes, per joint name.
    """

    omega: dict[tuple[str, str], float]
    spine: tuple[float, float] | None
    keyframes: list[int] = field(default_factory=list)
    fit_residual_px: dict[str, float] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {"omega": {f"{g}.{e}": w for (g, e), w in sorted(self.omega.items())},
                "spine": None if self.spine is None else {"f": self.spine[0], "omega": self.spine[1]},
                "keyframes": list(self.keyframes), "fit_residual_px": dict(self.fit_residual_px)}


def _ends(control: np.ndarray, n_points: np.ndarray, ia: int, ib: int):
    """Calibration points (..., 2) p1..p4 of the group with curves ia, ib."""
    T = control.shape[0]
    rows = np.arange(T)
    p1, p2 = control[:, ia, 0], control[:, ib, 0]
    p3, p4 = control[rows, ia, n_points[ia] - 1], control[rows, ib, n_points[ib] - 1]
    return p1, p2, p3, p4


def _sides_at_fraction(a: np.ndarray, b: np.ndarray, f: np.ndarray):
    """Points of sides a, b ``(T, S, 2)`` where the mid-line reaches arc fraction ``f`` ``(F,)``.

    Returns two ``(T, F, 2)`` arrays (NaN rows stay NaN).
    """
    mid = 0.5 * (a + b)
    seg = np.linalg.norm(np.diff(mid, axis=1), axis=-1)
    cum = np.concatenate([np.zeros((mid.shape[0], 1)), np.cumsum(seg, axis=1)], axis=1)
    total = cum[:, -1:]
    s = cum / np.where(total > 0, total, 1.0)
    T, S = s.shape
    idx = np.empty((T, f.size))
    for t in range(T):           # np.interp per frame: T is a clip length, tiny work each
        idx[t] = np.interp(f, s[t], np.arange(S)) if np.isfinite(s[t]).all() else np.nan
    ok = np.isfinite(idx)
    i0 = np.clip(np.floor(np.where(ok, idx, 0)).astype(np.int64), 0, S - 2)
    w = (np.where(ok, idx, 0) - i0)[..., None]
    rows = np.arange(T)[:, None]
    pa = (1 - w) * a[rows, i0] + w * a[rows, i0 + 1]
    pb = (1 - w) * b[rows, i0] + w * b[rows, i0 + 1]
    pa[~ok], pb[~ok] = np.nan, np.nan
    return pa, pb


def _blend_weight(p: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> tuple[float, float]:
    """Least-squares ω of p ≈ ω p1 + (1 − ω) p2 over the first axis, clipped; and RMS residual."""
    d = p1 - p2
    den = (d * d).sum()
    w = float(np.clip((((p - p2) * d).sum()) / den, 0.0, 1.0)) if den > 0 else 0.5
    res = p - (w * p1 + (1 - w) * p2)
    return w, float(np.sqrt((res * res).sum(-1).mean()))


def _curve_arrays(ann: Annotation, frames: list[int]) -> tuple[np.ndarray, list[str], np.ndarray]:
    names = ann.curve_names
    n_points = np.array([len(ann.keyframes[0].curves[n]) for n in names])
    P = int(n_points.max())
    control = np.full((len(frames), len(names), P, 2), np.nan)
    by_frame = {k.frame: k for k in ann.keyframes}
    for i, t in enumerate(frames):
        for c, n in enumerate(names):
            pts = by_frame[t].curves[n]
            control[i, c, : len(pts)] = pts
    return control, names, n_points


def fit_keypoint_model(ann: Annotation) -> KeypointModel:
    """Fit every ω (and the spine's place) on the keyframes of ``ann`` that have key points.

    Raises :class:`InputError` naming the annotation when no keyframe has key
    points or no group has both side curves.
    """
    frames = [k.frame for k in ann.keyframes if k.keypoints is not None]
    if not frames:
        raise InputError(ann.source, "keyframes[*].keypoints",
                         "key points on at least one keyframe (needed to fit ω, Eq. 2-3)")
    if not ann.groups:
        raise InputError(ann.source, "keyframes[0].curves",
                         "both side curves <group>.a and <group>.b of at least one group")
    kp = np.stack([k.keypoints for k in ann.keyframes if k.keypoints is not None])   # (K, 17, 2)
    control, names, n_points = _curve_arrays(ann, frames)
    index = {n: i for i, n in enumerate(names)}
    omega: dict[tuple[str, str], float] = {}
    resid: dict[str, list[float]] = {}
    for g in ann.groups:
        p1, p2, p3, p4 = _ends(control, n_points, index[f"{g}.a"], index[f"{g}.b"])
        s, e = GROUP_JOINTS[g]
        omega[(g, "start")], r0 = _blend_weight(kp[:, s], p1, p2)
        omega[(g, "end")], r1 = _blend_weight(kp[:, e], p3, p4)
        resid.setdefault(JOINTS[s], []).append(r0)
        resid.setdefault(JOINTS[e], []).append(r1)
    spine = None
    if "torso" in ann.groups:
        a = sample_curve(control[:, index["torso.a"], : n_points[index["torso.a"]]], SPINE_SAMPLES)
        b = sample_curve(control[:, index["torso.b"], : n_points[index["torso.b"]]], SPINE_SAMPLES)
        pa, pb = _sides_at_fraction(a, b, _F_GRID)                     # (K, F, 2)
        target = kp[:, SPINE][:, None, :]
        d = pa - pb
        den = (d * d).sum(axis=(0, 2))
        w = np.clip(((target - pb) * d).sum(axis=(0, 2)) / np.where(den > 0, den, 1.0), 0, 1)
        est = w[None, :, None] * pa + (1 - w[None, :, None]) * pb
        err = ((est - target) ** 2).sum(-1).mean(0)                   # (F,)
        best = int(np.argmin(err))
        spine = (float(_F_GRID[best]), float(w[best]))
        resid["spine"] = [float(np.sqrt(err[best]))]
    return KeypointModel(omega=omega, spine=spine, keyframes=frames,
                         fit_residual_px={j: float(np.mean(v)) for j, v in resid.items()})


def keypoints_from_curves(control: np.ndarray, curve_names, model: KeypointModel,
                          n_points: np.ndarray | None = None) -> np.ndarray:
    """Key points of every frame from side-curve control points.

    control ``(T, C, P, 2)`` px (rows of a curve padded with NaN after its
    ``n_points``; a NaN curve row = no estimate that frame); curve_names
    ``(C,)``.  Returns ``(T, 17, 2)`` px with NaN where a joint has no source
    group (group not annotated, not fitted, or not tracked in that frame).
    """
    control = np.asarray(control, dtype=np.float64)
    names = [str(n) for n in curve_names]
    index = {n: i for i, n in enumerate(names)}
    if n_points is None:
        finite = np.isfinite(control).all(-1).any(0)                  # (C, P)
        n_points = np.where(finite.all(1), finite.shape[1], np.argmin(finite, axis=1))
    n_points = np.asarray(n_points, dtype=np.int64)
    T = control.shape[0]
    estimates: dict[int, list[np.ndarray]] = {j: [] for j in range(N_JOINTS)}
    for g in GROUPS:
        if f"{g}.a" not in index or f"{g}.b" not in index or (g, "start") not in model.omega:
            continue
        p1, p2, p3, p4 = _ends(control, n_points, index[f"{g}.a"], index[f"{g}.b"])
        s, e = GROUP_JOINTS[g]
        ws, we = model.omega[(g, "start")], model.omega[(g, "end")]
        estimates[s].append(ws * p1 + (1 - ws) * p2)                  # Eq. 2 (docs/method.md §3)
        estimates[e].append(we * p3 + (1 - we) * p4)                  # Eq. 3
    out = np.full((T, N_JOINTS, 2), np.nan)
    for j, ests in estimates.items():
        if ests:
            stack = np.stack(ests)                                     # (n_src, T, 2)
            ok = np.isfinite(stack).all(-1, keepdims=True)
            cnt = ok.sum(0)
            out[:, j] = np.where(cnt > 0, np.where(ok, stack, 0).sum(0) / np.maximum(cnt, 1), np.nan)
    if model.spine is not None and "torso.a" in index and "torso.b" in index:
        ia, ib = index["torso.a"], index["torso.b"]
        a = sample_curve(control[:, ia, : n_points[ia]], SPINE_SAMPLES)
        b = sample_curve(control[:, ib, : n_points[ib]], SPINE_SAMPLES)
        f, w = model.spine
        pa, pb = _sides_at_fraction(a, b, np.array([f]))
        out[:, SPINE] = w * pa[:, 0] + (1 - w) * pb[:, 0]
    return out
