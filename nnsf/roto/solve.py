"""Keyframe-based contour tracking of a clip: the space-time solver and the LK baseline.

:func:`track_clip` tracks every annotated side curve of a clip between each
pair of consecutive keyframes.  Three methods:

* ``"ours"``      — the space-time energy with sketch term and colour penalty
                    (docs/method.md §2.2), coarse to fine;
* ``"agarwala"``  — the same solver without sketch term and colour penalty;
* ``"lk"``        — per-frame pyramidal Lucas-Kanade (``cv2.calcOpticalFlowPyrLK``)
                    on the control points, started from the first keyframe of
                    each interval.  With ``lk_end="blend"`` (default) the drift
                    found on arrival at the next keyframe is spread linearly
                    back over the interval, so the track meets that keyframe
                    as any rotoscoper would force it to; ``lk_end="none"`` is
                    the naive forward-only tracker.  A point LK loses (mid-edge
                    points: the aperture problem) moves with its curve's median
                    displacement.

All (interval, curve) problems of equal interval length and control-point
count are solved together as one block-diagonal problem (they are
independent; batching only removes Python overhead), coarse to fine on a
``cv2.pyrDown`` pyramid, from a start chosen by ``init`` (see
:class:`TrackOptions`).  The start decides where the joints go, so
``limb`` (params.yaml's default) starts from each limb's own rigid motion;
the solve then mostly brings the curves onto the outlines.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, fields

import cv2
import numpy as np
from scipy.optimize import least_squares

from nnsf.params import LK_ENDS, SNAP_TARGETS, TRACK_INITS, TRACKERS
from nnsf.roto.energy import LevelImages, SpaceTimeProblem, Weights, build_pyramid
from nnsf.roto.lm import levenberg_marquardt
from nnsf.roto.limbs import limb_init, limb_parents, side_pairs
from nnsf.roto.snap import edge_snap, gradient_strength, profile_snap, resolve_target

METHODS = TRACKERS
INITS = TRACK_INITS
SOLVERS = ("lm", "scipy")


@dataclass
class TrackOptions:
    """Every tunable of the trackers (the lead maps them to params.yaml ``track:``).

    Weights multiply squared residuals (see :mod:`nnsf.roto.energy`);
    ``length_anchor`` weighs the anchor of the curve's length to the keyframes
    relative to ``length`` (not in params.yaml; with 4 the in-between curves of
    real sprite walk cycles keep their keyframes' length, where the
    adjacent-frame term alone, 0, lets them shrink); ``K``
    is the ribbon half-width in samples of 1 px (of each pyramid level);
    ``levels`` the pyramid depth (1 = full resolution only); ``edge_close``
    the edge map's closing radius (px; none on frames under 128 px, :func:`edge_close`).

    ``init`` starts the solver from ``linear`` interpolation, the blended
    ``lk`` track, dense ``flow`` (:func:`flow_init`) or ``limb``
    (:func:`nnsf.roto.limbs.limb_init`: each limb as a rigid body, checked by
    its colours; for "ours" only, as it uses the per-limb colour model
    Agarwala's tracker lacks: "agarwala" runs ``flow`` then).  Two terms of
    "ours" build on it: ``edge_gate`` (px; 0 = off) scales the edge and
    ribbon residuals of samples that do not lie within that distance of an
    image edge in both keyframes by 1 - the start's confidence, and
    ``slide`` weighs the anchor of each sample's position ALONG its curve to
    the limb start, times the start's confidence (see
    :class:`nnsf.roto.energy.SpaceTimeProblem`).  ``velocity_trust`` (off by
    default) weighs the velocity term against the start's motion by the
    start's confidence too.  ``snap`` (px; 0 = off) ends "ours" by moving
    each free control point across its curve, at most that far: to where the
    colours across the curve match the keyframes' (``snap_to="profile"``),
    onto the strongest colour edge (``"edge"``), or ``"auto"``: onto the
    edge on flat-colour art, not at all on stroked art, as the clip's
    keyframes show (:mod:`nnsf.roto.snap`).
    """

    # The energy weights and their defaults are :class:`Weights`' (one source).
    velocity: float = Weights.velocity
    length: float = Weights.length
    curvature: float = Weights.curvature
    edge: float = Weights.edge
    sketch: float = Weights.sketch
    colour: float = Weights.colour
    K: int = 3
    n_samples: int = 12
    levels: int = 2
    init: str = "linear"
    max_nfev: int = 20
    ftol: float = 1e-4
    max_step: float = 4.0
    solver: str = "lm"
    colour_sigma: float = 1.0
    edge_sigma: float = 0.7
    edge_close: int = 2
    edge_cap: float = 8.0
    lk_window: int = 21
    lk_levels: int = 3
    lk_end: str = "blend"
    length_anchor: float = 4.0
    edge_gate: float = 0.0
    slide: float = 0.0
    velocity_trust: bool = False
    snap: float = 0.0
    snap_to: str = "profile"

    def __post_init__(self):
        for name in ("velocity", "length", "curvature", "edge", "sketch", "colour", "length_anchor",
                     "colour_sigma", "edge_sigma", "edge_cap", "max_step", "edge_gate", "slide", "snap"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0:
                raise ValueError(f"track option {name} must be a finite number >= 0, got {v!r}")
        for name, lo in (("K", 0), ("edge_close", 0), ("n_samples", 3), ("levels", 1), ("max_nfev", 1),
                         ("lk_window", 5), ("lk_levels", 0)):
            v = getattr(self, name)
            if int(v) != v or v < lo:
                raise ValueError(f"track option {name} must be an integer >= {lo}, got {v!r}")
        if self.init not in INITS:
            raise ValueError(f"track option init must be one of {INITS}, got {self.init!r}")
        if self.solver not in SOLVERS:
            raise ValueError(f"track option solver must be one of {SOLVERS}, got {self.solver!r}")
        if not 0 < self.ftol < 1:
            raise ValueError(f"track option ftol must be in (0, 1), got {self.ftol!r}")
        if not isinstance(self.velocity_trust, (bool, np.bool_)):
            raise ValueError(f"track option velocity_trust must be true or false, got {self.velocity_trust!r}")
        if self.snap_to not in SNAP_TARGETS:
            raise ValueError(f"track option snap_to must be one of {SNAP_TARGETS}, got {self.snap_to!r}")
        if self.lk_end not in LK_ENDS:
            raise ValueError(f"track option lk_end must be one of {LK_ENDS}, got {self.lk_end!r}")

    @property
    def weights(self) -> Weights:
        return Weights(**{f.name: getattr(self, f.name) for f in fields(Weights)})

    @classmethod
    def from_kwargs(cls, **kw) -> "TrackOptions":
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(kw) - known)
        if unknown:
            raise TypeError(f"unknown track option(s) {unknown}; known: {sorted(known)}")
        return cls(**kw)


# ---------------------------------------------------------------- LK
def lk_track(gray: np.ndarray, P: np.ndarray, fixed: np.ndarray, window: int = 21,
             levels: int = 3, end: str = "blend") -> np.ndarray:
    """Per-frame pyramidal LK of control points between anchors.

    gray  : (T, H, W) uint8 frames.
    P     : (G, T, C, 2) control points (px); entries under ``fixed`` are anchors.
    fixed : (G, T, C) bool; every point must be fixed at t = 0.
    Each point is tracked forward frame to frame and reset to its anchor
    wherever it has one.  ``end="blend"`` adds, between consecutive anchors
    a < b, the arrival error (anchor_b - tracked_b)·(t-a)/(b-a).
    Returns (G, T, C, 2).  A point LK loses (status 0) moves with the median
    displacement of the tracked points of its curve.
    """
    P = np.asarray(P, np.float64)
    G, T, C, _ = P.shape
    fx = np.asarray(fixed, bool).reshape(G, T, C).transpose(1, 0, 2).reshape(T, -1)   # (T, M)
    anchors = P.transpose(1, 0, 2, 3).reshape(T, -1, 2)                               # (T, M, 2)
    if not fx[0].all():
        raise ValueError("every point needs an anchor in the first frame")
    fwd = np.empty_like(anchors)
    fwd[0] = anchors[0]
    cur = anchors[0].astype(np.float32)
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 30, 0.01)
    for t in range(1, T):
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(
            gray[t - 1], gray[t], cur.reshape(-1, 1, 2), None, winSize=(window, window),
            maxLevel=levels, criteria=crit)
        nxt = nxt.reshape(-1, 2).astype(np.float64)
        ok = status.reshape(-1).astype(bool) & np.isfinite(nxt).all(1)
        # A lost point (e.g. mid-edge, the aperture problem) follows the median
        # displacement of its curve's tracked points; if all are lost it stays.
        disp = np.where(ok[:, None], nxt - cur, np.nan).reshape(G, C, 2)
        with np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(disp, axis=1, keepdims=True)
        med = np.nan_to_num(np.broadcast_to(med, disp.shape).reshape(-1, 2))
        nxt = np.where(ok[:, None], nxt, cur + med)
        fwd[t] = nxt
        cur = np.where(fx[t][:, None], anchors[t], nxt).astype(np.float32)
    out = np.where(fx[..., None], anchors, fwd)
    if end == "blend":
        t = np.arange(T)[:, None]
        prev_a = np.maximum.accumulate(np.where(fx, t, -1), axis=0)                  # (T, M)
        nxt_a = np.flip(np.minimum.accumulate(np.flip(np.where(fx, t, T), 0), axis=0), 0)
        has_next = nxt_a < T
        b = np.where(has_next, nxt_a, 0)
        m = np.arange(fx.shape[1])[None, :]
        drift = anchors[b, m] - fwd[b, m]                                               # (T, M, 2)
        lam = np.where(has_next & ~fx, (t - prev_a) / np.maximum(b - prev_a, 1), 0.0)
        out = out + lam[..., None] * drift
    elif end != "none":
        raise ValueError(f"end must be one of {LK_ENDS}, got {end!r}")
    return out.reshape(T, G, C, 2).transpose(1, 0, 2, 3)


# ---------------------------------------------------------------- dense-flow init
def dense_flows(gray: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward and backward dense optical flow between consecutive frames.

    gray : (T, H, W) uint8.  Returns ``fwd, bwd`` (T-1, H, W, 2) float32 px:
    ``fwd[t]`` maps frame t to t+1, ``bwd[t]`` frame t+1 to t.  OpenCV's DIS
    flow (``PRESET_MEDIUM``): dense, so a point on a straight outline gets
    the motion its neighbourhood implies instead of being lost (LK's
    aperture problem), and a few ms per 256-px frame.
    """
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_MEDIUM)
    T, H, W = gray.shape
    fwd = np.empty((max(T - 1, 0), H, W, 2), np.float32)
    bwd = np.empty_like(fwd)
    for t in range(T - 1):
        fwd[t] = dis.calc(gray[t], gray[t + 1], None)
        bwd[t] = dis.calc(gray[t + 1], gray[t], None)
    return fwd, bwd


def _sample_flow(flow: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear flow (M, 2) at points xy (M, 2) px (clamped to the frame)."""
    H, W = flow.shape[:2]
    x = np.clip(xy[:, 0], 0, W - 1.001)
    y = np.clip(xy[:, 1], 0, H - 1.001)
    x0, y0 = np.floor(x).astype(int), np.floor(y).astype(int)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    f = flow.astype(np.float64)
    return ((1 - fx) * (1 - fy) * f[y0, x0] + fx * (1 - fy) * f[y0, x0 + 1]
            + (1 - fx) * fy * f[y0 + 1, x0] + fx * fy * f[y0 + 1, x0 + 1])


def flow_init(fwd: np.ndarray, bwd: np.ndarray, P: np.ndarray, fixed: np.ndarray,
              frame0: np.ndarray, max_fb: float = 1.0) -> np.ndarray:
    """Initial guess of the free points by dense flow from both keyframes of an interval.

    fwd, bwd : the clip's flows (:func:`dense_flows`); P (G, T, C, 2) with
    the keyframes at t = 0 and T-1; frame0 (G,) each row's first clip frame.
    Points are carried forward from t = 0 and backward from t = T-1, and the
    two tracks are blended with weights (1-λ, λ), λ = t/(T-1), so the guess
    meets both keyframes.  A step whose forward-backward check fails (the
    round trip misses by more than ``max_fb`` px: occlusion, a flat region)
    moves the point with its curve's median reliable step instead (or not at
    all).  Hard constraints under ``fixed`` other than the ends are kept.
    """
    P = np.asarray(P, np.float64)
    G, T, C, _ = P.shape

    def carry(start, steps, there, back):
        out = np.empty((T, C, 2))
        out[0] = start
        cur = start.copy()
        for k, t in enumerate(steps):
            d = _sample_flow(there[t], cur)
            rt = d + _sample_flow(back[t], cur + d)
            ok = np.linalg.norm(rt, axis=1) <= max_fb
            if ok.any():
                d = np.where(ok[:, None], d, np.median(d[ok], axis=0))
            else:
                d = np.zeros_like(d)
            cur = cur + d
            out[k + 1] = cur
        return out

    guess = P.copy()
    lam = (np.arange(T) / (T - 1.0))[:, None, None]
    for g in range(G):
        a = int(frame0[g])
        f = carry(P[g, 0], range(a, a + T - 1), fwd, bwd)
        b = carry(P[g, -1], range(a + T - 2, a - 1, -1), bwd, fwd)[::-1]
        guess[g] = (1 - lam) * f + lam * b
    fx = np.asarray(fixed, bool)
    return np.where(fx[..., None], P, guess)


# ---------------------------------------------------------------- space-time solve
def _to_level(P, s):
    return (P + 0.5) * s - 0.5


def _from_level(P, s):
    return (P + 0.5) / s - 0.5


def linear_init(P: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """Free points interpolated linearly in t between their neighbouring fixed values.

    P (G, T, C, 2), fixed (G, T, C) with t = 0 and t = T-1 fixed.
    """
    P = np.asarray(P, np.float64).copy()
    G, T, C, _ = P.shape
    t = np.arange(T)[None, :, None]
    fx = np.asarray(fixed, bool)
    a = np.maximum.accumulate(np.where(fx, t, -1), axis=1)
    b = np.flip(np.minimum.accumulate(np.flip(np.where(fx, t, T), 1), axis=1), 1)
    a = np.clip(a, 0, T - 1)
    b = np.clip(b, 0, T - 1)
    g = np.arange(G)[:, None, None]
    c = np.arange(C)[None, None, :]
    Pa, Pb = P[g, a, c], P[g, b, c]
    lam = np.where(b > a, (t - a) / np.maximum(b - a, 1), 0.0)[..., None]
    return np.where(fx[..., None], P, (1 - lam) * Pa + lam * Pb)


def solve_interval(pyramid: list[LevelImages], P: np.ndarray, fixed: np.ndarray,
                   opts: TrackOptions, use_image_terms: bool = True,
                   levels: int | None = None, frame0: np.ndarray | None = None,
                   motion_prior: np.ndarray | None = None,
                   prior_confidence: np.ndarray | None = None, edge_gate: float = 0.0,
                   slide: float = 0.0, velocity_trust: bool = False) -> np.ndarray:
    """Solve the space-time problem of G curves over one interval, coarse to fine.

    pyramid : the interval's frames as from :func:`build_pyramid`, finest first
              (T frames per level).
    P       : (G, T, C, 2) full-resolution control points: the hard constraints
              under ``fixed`` and the initial guess elsewhere.
    fixed   : (G, T, C) bool; t = 0 and t = T-1 are always treated as fixed.
    levels  : how many pyramid levels to use (default all of ``pyramid``).
    frame0  : (G,) index in ``pyramid`` of each curve's first frame (default 0),
              so curves of several intervals of equal length solve together.
    motion_prior : optional (G, T, C, 2) full-resolution track (the flow init)
              whose frame-to-frame motion the velocity term takes as its zero.
    prior_confidence, edge_gate, slide, velocity_trust : see
              :class:`nnsf.roto.energy.SpaceTimeProblem`
              (``edge_gate`` in full-resolution px).
    Returns (G, T, C, 2) full-resolution control points.
    """
    P = np.asarray(P, np.float64).copy()
    fixed = np.asarray(fixed, bool).copy()
    fixed[:, 0] = fixed[:, -1] = True
    if P.shape[1] < 3 or fixed.all():
        return P
    nlev = len(pyramid) if levels is None else min(levels, len(pyramid))
    w = opts.weights
    for lev in range(nlev - 1, -1, -1):
        L = pyramid[lev]
        Pl = _to_level(P, L.scale)
        prob = SpaceTimeProblem(L, Pl, fixed, w, n_samples=opts.n_samples, K=opts.K,
                                use_image_terms=use_image_terms, frame0=frame0,
                                length_anchor=opts.length_anchor,
                                motion_prior=None if motion_prior is None
                                else _to_level(motion_prior, L.scale),
                                prior_confidence=prior_confidence,
                                edge_gate=edge_gate * L.scale, slide=slide,
                                velocity_trust=velocity_trust)
        if opts.solver == "lm":
            x, _ = levenberg_marquardt(prob, prob.x0(), max_iter=opts.max_nfev, ftol=opts.ftol,
                                      max_step=opts.max_step)
        else:
            x = least_squares(prob.residuals, prob.x0(), jac=prob.jacobian, method="trf",
                              tr_solver="lsmr", max_nfev=opts.max_nfev, ftol=opts.ftol,
                              xtol=1e-6, gtol=1e-8).x
        P = _from_level(prob.controls(x), L.scale)
    return P


# ---------------------------------------------------------------- clips
def keyframe_curves(annotation) -> tuple[list[str], dict[int, dict[str, np.ndarray]]]:
    """Curve names (first-seen order) and ``{frame: {curve: (C, 2) array}}`` of an annotation.

    Accepts the format-v1 dict (docs/formats.md §2.2) or any object with a
    ``keyframes`` attribute holding such entries (``frame`` and ``curves``,
    as mappings or attributes).
    """
    kfs = annotation["keyframes"] if isinstance(annotation, dict) else annotation.keyframes
    out: dict[int, dict[str, np.ndarray]] = {}
    names: list[str] = []
    for kf in kfs:
        frame = kf["frame"] if isinstance(kf, dict) else kf.frame
        cv = kf["curves"] if isinstance(kf, dict) else kf.curves
        out[int(frame)] = {k: np.asarray(v, np.float64) for k, v in cv.items()}
        for k in cv:
            if k not in names:
                names.append(k)
    return names, dict(sorted(out.items()))


@dataclass
class Batch:
    """Curves of equal interval length and control count, solved together.

    jobs   : (k0, k1, curve name) per row g.
    P      : (G, T, C, 2) control points (keyframes at t = 0 and T-1).
    fixed  : (G, T, C) hard constraints.
    frame0 : (G,) first frame of each row's interval in the clip.
    """

    jobs: list[tuple[int, int, str]]
    P: np.ndarray
    fixed: np.ndarray
    frame0: np.ndarray


def plan(annotation) -> tuple[list[str], dict[int, dict[str, np.ndarray]], list[Batch]]:
    """Curve names, keyframe curves and the batches of (interval, curve) problems of a clip."""
    names, kfs = keyframe_curves(annotation)
    keys = list(kfs)
    groups: dict[tuple[int, int], list[tuple[int, int, str]]] = {}
    for k0, k1 in zip(keys[:-1], keys[1:]):
        if k1 - k0 < 2:
            continue
        for name in names:
            a, b = kfs[k0].get(name), kfs[k1].get(name)
            if a is None or b is None:
                continue
            if a.shape != b.shape:
                raise ValueError(f"curve {name!r} has {a.shape[0]} control points in keyframe "
                                 f"{k0} but {b.shape[0]} in keyframe {k1}")
            groups.setdefault((k1 - k0 + 1, a.shape[0]), []).append((k0, k1, name))
    batches = []
    for (Tn, C), jobs in sorted(groups.items()):
        P = np.zeros((len(jobs), Tn, C, 2))
        P[:, 0] = np.stack([kfs[k0][n] for k0, _, n in jobs])
        P[:, -1] = np.stack([kfs[k1][n] for _, k1, n in jobs])
        fixed = np.zeros((len(jobs), Tn, C), bool)
        fixed[:, [0, -1]] = True
        batches.append(Batch(jobs, P, fixed, np.array([k0 for k0, _, _ in jobs], np.intp)))
    return names, kfs, batches


def edge_close(radius: int, size: tuple[int, int]) -> int:
    """The edge map's closing radius for frames of ``size`` (H, W): ``radius``, or 0 below 128 px.

    The closing merges the two Canny lines on either side of a drawn stroke
    (2-3 px wide on the rendered and toy clips).  On small drawings the
    strokes are one pixel and the parts a few px apart, and a 2-px closing
    merged the outlines of neighbouring parts (the legs of the 64-px LPC
    sprites): the edge term then pulled curves into the gaps between them,
    and Agarwala's tracker, which has no colour terms to resist it, kept 0.50
    of the LPC outline samples within 1.5 px of the silhouette against 0.92
    for interpolating the keyframes without tracking (0.975 without the
    closing).  Frames smaller than 128 px (small sprites, 64×64 LPC tiles)
    get no closing; larger ones keep ``radius``.
    """
    return int(radius) if min(size) >= 128 else 0


class ClipTracker:
    """Pre-processed clip (pyramid and/or gray frames) that solves batches by one method.

    frames : (T, H, W, 3) uint8 RGB; method : "ours" | "agarwala" | "lk".
    keyframes : ``{frame: {curve: (C, 2)}}``, needed by ``snap_to="auto"``,
    which decides once per clip from them: ``snap_target`` is then "edge"
    or None (no snap) and ``stroke_share`` the share it was decided by.
    """

    def __init__(self, frames: np.ndarray, method: str, opts: TrackOptions, keyframes: dict | None = None):
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
            raise ValueError(f"frames must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
        self.method, self.opts = method, opts
        self.gray = None
        self.pyramid = None
        self.strength = None     # the edge snap's gradient magnitude, built on first use
        # only "ours" snaps (Agarwala's tracker and LK are compared as published)
        self.snap_target, self.stroke_share = (resolve_target(opts.snap, opts.snap_to, frames, keyframes)
                                               if method == "ours" else (None, None))
        if method == "lk" or opts.init in ("lk", "flow", "limb"):
            self.gray = np.stack([cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames])
        self.flows = dense_flows(self.gray) if method != "lk" and opts.init in ("flow", "limb") \
            else None
        if method != "lk":
            self.pyramid = build_pyramid(frames, opts.levels, opts.colour_sigma, opts.edge_sigma,
                                         opts.edge_cap, edge_close=edge_close(opts.edge_close,
                                                                              frames.shape[1:3]))

    def snap(self, P: np.ndarray, fixed: np.ndarray, frame0: np.ndarray) -> np.ndarray:
        """The last step of "ours": every free control point snapped across its curve (:mod:`nnsf.roto.snap`)."""
        colour = self.pyramid[0].colour
        if self.snap_target == "profile":
            return profile_snap(colour, P, fixed, frame0, self.opts.snap, self.opts.K)
        if self.strength is None:
            self.strength = gradient_strength(colour)
        return edge_snap(self.strength, P, fixed, frame0, self.opts.snap)

    def lk(self, P, fixed, frame0, end):
        Tn = P.shape[1]
        out = P.copy()
        for k0 in np.unique(frame0):
            sel = frame0 == k0
            out[sel] = lk_track(self.gray[k0:k0 + Tn], P[sel], fixed[sel], self.opts.lk_window,
                                self.opts.lk_levels, end)
        return out

    def solve(self, P: np.ndarray, fixed: np.ndarray, frame0: np.ndarray,
              warm: bool = False, names=None) -> np.ndarray:
        """Track one batch: (G, T, C, 2) with hard constraints under ``fixed``.

        ``warm=False`` initialises the free points (``opts.init``) and solves
        coarse to fine; ``warm=True`` (re-solve after an edit) starts from
        ``P`` as given and solves at full resolution only (LK re-tracks from
        every anchor, which is its re-solve).  ``names`` (G,) are the rows'
        curve names: the ``limb`` start pairs ``<group>.a`` with ``<group>.b``
        of the same interval (without names every row starts by ``flow``).
        """
        opts = self.opts
        if self.method == "lk":
            return self.lk(P, fixed, frame0, opts.lk_end)
        ours = self.method == "ours"
        prior = conf = None
        if not warm:
            if opts.init == "lk":
                P = self.lk(P, fixed, frame0, "blend")
            elif opts.init == "limb" and ours and names is not None:
                keys = [(int(f), n) for f, n in zip(frame0, names)]
                P, conf = limb_init(*self.flows, self.pyramid[0].colour, P, fixed, frame0,
                                    side_pairs(keys),
                                    lambda P_, f_, k_: flow_init(*self.flows, P_, f_, k_),
                                    parents=limb_parents(keys))
                prior = P
            elif opts.init in ("flow", "limb"):
                P = prior = flow_init(*self.flows, P, fixed, frame0)
            else:
                P = linear_init(P, fixed)
        P = solve_interval(self.pyramid, P, fixed, opts, use_image_terms=ours,
                           levels=1 if warm else None, frame0=frame0, motion_prior=prior,
                           prior_confidence=conf, edge_gate=opts.edge_gate if ours else 0.0,
                           slide=opts.slide if conf is not None else 0.0,
                           velocity_trust=opts.velocity_trust)
        if ours and self.snap_target is not None:
            P = self.snap(P, fixed, frame0)
        return P


def assemble(T: int, names: list[str], kfs: dict, batches: list[Batch],
             solved: list[np.ndarray]) -> np.ndarray:
    """Clip array (T, N, P, 2) from keyframes and solved batches (NaN elsewhere)."""
    Pmax = max(c.shape[0] for kf in kfs.values() for c in kf.values())
    out = np.full((T, len(names), Pmax, 2), np.nan)
    for f, kf in kfs.items():
        for k, c in kf.items():
            out[f, names.index(k), :c.shape[0]] = c
    for b, P in zip(batches, solved):
        C = P.shape[2]
        for g, (k0, k1, name) in enumerate(b.jobs):
            out[k0:k1 + 1, names.index(name), :C] = P[g]
    return out


def track_clip(frames: np.ndarray, annotation, method: str = "ours", **options) -> np.ndarray:
    """Track every annotated curve of a clip between consecutive keyframes.

    frames     : (T, H, W, 3) uint8 RGB.
    annotation : format-v1 annotation (dict or reader object), see :func:`keyframe_curves`.
    method     : "ours" | "agarwala" | "lk".
    options    : :class:`TrackOptions` fields.
    Returns control points ``(T, N, P, 2)`` float64 (px) for the N curves in
    ``keyframe_curves(annotation)[0]`` order, P = the largest control-point
    count; NaN where a curve has fewer points, before its first or after its
    last keyframe, or in an interval where it lacks one of the keyframes.
    Keyframe rows equal the annotation.
    """
    opts = TrackOptions.from_kwargs(**options)
    names, kfs, batches = plan(annotation)
    tracker = ClipTracker(frames, method, opts, keyframes=kfs)
    solved = [tracker.solve(b.P, b.fixed, b.frame0, names=[n for _, _, n in b.jobs])
              for b in batches]
    return assemble(len(frames), names, kfs, batches, solved)


def interpolate_clip(annotation, n_frames: int) -> np.ndarray:
    """No tracking: every curve interpolated linearly in t between consecutive keyframes.

    The do-nothing floor the trackers are compared with; same layout as
    :func:`track_clip` (``(T, N, P, 2)``, NaN where :func:`track_clip` has NaN).
    """
    names, kfs, batches = plan(annotation)
    return assemble(int(n_frames), names, kfs, batches,
                    [linear_init(b.P, b.fixed) for b in batches])

