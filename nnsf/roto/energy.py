"""The space-time energy of docs/method.md §2.2 as least-squares residuals with an analytic sparse Jacobian.

One :class:`SpaceTimeProblem` holds G independent curves (same number of
control points C) over one keyframe interval of T frames (keyframes at
t = 0 and t = T-1, plus any further hard-constrained control points, e.g.
a simulated user's edits).  The unknowns are the free control points; the
residual blocks (each multiplied by sqrt(weight)) are

* velocity   c_t(s_i) - c_{t+1}(s_i)                          (px)
* length     h (|c_t'(s_i)| - |c_{t+1}'(s_i)|), h = n - 1         (px)
* length anchor  h (|c_t'(s_i)| - ℓ_{t,i}) in the in-between frames, ℓ the
             keyframes' |c'(s_i)| blended linearly in t (like κ below),
             weight w_length · ``length_anchor``                (px)
* curvature  c_t''(s_i) - c_{t+1}''(s_i)                        (px)
* edge       D_t(c_t(s_i)), D = lightly smoothed distance to the nearest
             edge line (Canny, closed, thinned), capped (px).  Why this
             edge term: its gradient has unit length everywhere inside the
             cap, so it pulls from as far as the cap (gradient magnitude
             only pulls from within the blur radius), the residual is in px
             like the shape terms and linear in the offset (V-shaped), and
             closing + thinning put its zero on the centre line of a drawn
             outline stroke (Canny marks both sides of a dark line).
* sketch (Eq. 1) I_t(c_t(s_i) + aσ n_t(s_i)) - I_{t+1}(c_{t+1}(s_i) + aσ n_{t+1}(s_i)),
             σ = ±1, a = 1..K (RGB in [0, 1]): the bidirectional ribbon
* colour     I_t(c_t(s_i) + aσ n_t(s_i)) - κ_{t,i,σ}, κ the keyframes'
             mean ribbon colour at sample i on side σ, blended linearly in t
             between the interval's two keyframes (a palette is constant,
             but what lies on the far side of a limb may differ between
             the two keyframes).
* slide      (c_t(s_i) - c̃_t(s_i))·t̃_t(s_i), c̃ the starting guess of
             :func:`nnsf.roto.limbs.limb_init` and t̃ its unit tangent, in
             the in-between frames, weight ``slide`` times the start's
             confidence in that frame (px; optional).

Why the gate and the slide anchor.  Started at the TRUE curves of the first
four rendered clips, the solver (weights of params.yaml, no motion prior)
drifted to a key-point PCK of 0.845 (from 1.0): the energy's minimum was
not at the truth.  Taking terms out one by one located the biases: the
plain velocity term (0.934 without it) and, among the image terms, the
edge term (with velocity off: 0.857 with the edge term as the only image
term, 0.947 with the sketch term as the only one).  The edge map (below) has its zero on the centre
line of a drawn stroke, but where two outlines run within a few px of each
other (a shin beside the other shin) closing merges them and the zero lies
between them, 2-3 px off both; and a side hidden behind another part (the
inner side of the far arm) has no edge of its own, so the term pulls it to
the occluder's.  ``edge_gate`` keeps the edge residual of sample i only if
the keyframes' curves lie within ``edge_gate`` px of an edge at i in BOTH
keyframes (the edge term alone, started at the truth: PCK 0.857 without the
gate, 0.977 with it), or in as far as the start is not trusted; the velocity term's bias is the motion prior's
business (it measures motion against the start's).  The same hidden sides are dragged by the ribbon
terms towards whatever covers them (the near arm passing over the torso's
hidden side), so off-edge samples lose their ribbon residuals too.  Both
only in proportion to the start's confidence: a confident start needs no
image evidence where there is none; an unconfident one (small sprites whose
limb tracks both miss the far keyframe by several px) still needs it.
Along its own outline a sample sees the same colours and the same edge
wherever it slides, so nothing in the image fixes its place along the
curve, which is what the key points are read from (the curve ends): the
slide anchor holds it where the limb start put it, as firmly as the start
is trusted.

Why the length terms look like this.  Derivatives are per sample step, so
|c'| ≈ L/(n-1) for a curve of length L.  The squared form (Agarwala et al.; docs/method.md §2.2),
|c_t'|² - |c_{t+1}'|², is then in px² of a sample step: ≈ 0.7 px² for a
10 px limb side of a small sprite sampled 12 times, so halving that curve cost less
than one unit, while the sketch and colour terms (weight 100 on 2K·3
residuals per sample) gain far more by pulling the samples together onto
the part of the edge whose ribbon matches best (uniform colour away from the
joints): tracked curves shrank to 0.53 of their keyframe length.  Scaled by
h = n - 1 and taken unsquared, the residual is the change of the curve's
length in px, like the velocity and curvature residuals, and independent
of the sample count.  Adjacent-frame differences alone still let a curve
shrink a little per frame and grow back before the next keyframe; the
anchor ties every in-between speed to the keyframes' (the keyframes are the
user's statement of the limb's length), as κ ties the ribbon colours.
Sample positions stay at fixed spline parameters, so the image terms
themselves neither reward nor punish length; the shape terms must hold it.

Images are sampled bilinearly; the Jacobian uses the exact derivative of
the bilinear interpolant, and of the unit normal (R90 (I - t̂t̂ᵀ)/|t|).

Two solvers see the same residuals and Jacobian:

* :func:`nnsf.roto.lm.levenberg_marquardt` (default): every residual touches one frame
  or two adjacent ones, so JᵀJ is block-tridiagonal in t; it is assembled
  directly (the ribbon terms from per-sample 2x2 moments, without forming
  their Jacobian rows) and each damped Gauss-Newton step is one banded
  Cholesky solve.  About 30x faster than the generic path below on a
  48-frame clip with 20 curves.
* ``scipy.optimize.least_squares`` (``solver="scipy"``), with
  :meth:`SpaceTimeProblem.jacobian` as an explicit CSR matrix (pattern
  built once, values refreshed): its ``lsmr`` trust-region steps need
  hundreds of sparse products each on this problem (measured on the same
  loaded machine: 290 s for the 48-frame clip against 12-22 s for the
  first LM version) and are kept as a cross-check.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import scipy.sparse as sp

from nnsf.roto import curves

R90 = np.array([[0.0, -1.0], [1.0, 0.0]])


# ---------------------------------------------------------------- images
@dataclass
class LevelImages:
    """Per-frame features of one pyramid level.

    colour : (T, H, W, 3) float32, RGB in [0, 1], Gaussian-smoothed.
    edge   : (T, H, W, 1) float32, smoothed capped distance to edges (px of this level).
    scale  : this level's size relative to the full frames (1, 1/2, 1/4, ...).
    """

    colour: np.ndarray
    edge: np.ndarray
    scale: float


def build_pyramid(frames: np.ndarray, levels: int = 2, colour_sigma: float = 1.0,
                  edge_sigma: float = 1.0, edge_cap: float = 8.0,
                  canny: tuple[float, float] = (40.0, 120.0), edge_close: int = 2) -> list[LevelImages]:
    """Image pyramid of features for frames ``(T, H, W, 3)`` uint8 RGB.

    Returns ``levels`` entries, finest first (level 0 = full resolution);
    each coarser level is ``cv2.pyrDown`` of the one before.  Canny marks
    both sides of a drawn outline stroke; a morphological closing with a
    disc of radius ``edge_close`` px merges them into one band and thinning
    reduces the band to its centre line, so the distance is the distance to
    the stroke's centre line: a V-shaped residual with unit slope (a
    smoothed flat band would make the residual quadratic near the edge and
    the squared term quartic, i.e. no pull within a pixel or two).
    """
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * edge_close + 1,) * 2) \
        if edge_close > 0 else None
    frames = np.asarray(frames)
    if frames.ndim != 4 or frames.shape[-1] != 3 or frames.dtype != np.uint8:
        raise ValueError(f"frames must be (T, H, W, 3) uint8, got {frames.shape} {frames.dtype}")
    out = []
    cur = list(frames)
    for lev in range(levels):
        if lev > 0:
            cur = [cv2.pyrDown(f) for f in cur]
        col = np.empty((len(cur),) + cur[0].shape, np.float32)
        edg = np.empty(cur[0].shape[:2] + (1,), np.float32)
        edg = np.empty((len(cur),) + edg.shape, np.float32)
        for t, f in enumerate(cur):
            fl = f.astype(np.float32) / 255.0
            col[t] = cv2.GaussianBlur(fl, (0, 0), colour_sigma) if colour_sigma > 0 else fl
            gray = cv2.cvtColor(f, cv2.COLOR_RGB2GRAY)
            e = cv2.Canny(gray, canny[0], canny[1], L2gradient=True)
            if kernel is not None:
                e = cv2.morphologyEx(e, cv2.MORPH_CLOSE, kernel)
            e = cv2.ximgproc.thinning(e)
            d = cv2.distanceTransform(np.where(e > 0, 0, 255).astype(np.uint8), cv2.DIST_L2, 5)
            d = np.minimum(d, edge_cap)
            edg[t, :, :, 0] = cv2.GaussianBlur(d, (0, 0), edge_sigma) if edge_sigma > 0 else d
        out.append(LevelImages(col, edg, 0.5 ** lev))
    return out


def bilinear(stack: np.ndarray, t: np.ndarray, xy: np.ndarray, grad: bool = True):
    """Bilinear samples and their spatial gradient.

    stack : (T, H, W, ch) float image stack.
    t     : integer frame index, broadcastable to ``xy.shape[:-1]``.
    xy    : (..., 2) positions (x, y) in px; clamped to the image.
    Returns ``values (..., ch)`` and ``grad (..., ch, 2)`` (d/dx, d/dy of the
    interpolant; zero across a clamped border); ``grad=False`` returns the
    values only.
    """
    T, H, W, ch = stack.shape
    xy = np.nan_to_num(np.asarray(xy, dtype=stack.dtype), nan=-1.0, posinf=-1.0, neginf=-1.0)
    x = xy[..., 0]
    y = xy[..., 1]
    inx = (x >= 0) & (x <= W - 1)
    iny = (y >= 0) & (y <= H - 1)
    x = np.clip(x, 0, W - 1.001)
    y = np.clip(y, 0, H - 1.001)
    x0 = np.floor(x).astype(np.intp)
    y0 = np.floor(y).astype(np.intp)
    fx = (x - x0)[..., None]
    fy = (y - y0)[..., None]
    flat = stack.reshape(-1, ch)
    base = (np.broadcast_to(t, x0.shape).astype(np.intp) * H + y0) * W + x0
    v00 = flat[base]
    v01 = flat[base + 1]
    v10 = flat[base + W]
    v11 = flat[base + W + 1]
    top = v00 + fx * (v01 - v00)
    bot = v10 + fx * (v11 - v10)
    val = top + fy * (bot - top)
    if not grad:
        return val
    gx = (1 - fy) * (v01 - v00) + fy * (v11 - v10)
    gy = bot - top
    gx = gx * inx[..., None]
    gy = gy * iny[..., None]
    return val, np.stack([gx, gy], axis=-1)


# ---------------------------------------------------------------- problem
@dataclass
class Weights:
    """Energy weights (dimensionless multipliers of the squared residuals)."""

    velocity: float = 3.0
    length: float = 1.0
    curvature: float = 1.0
    edge: float = 1.0
    sketch: float = 100.0
    colour: float = 100.0


@dataclass
class Block:
    """One residual block: ``r (G, Tb, R)`` rows for frames ``t0 .. t0+Tb-1``.

    ``A (G, Tb, R, C*2)`` is d r / d P[g, t0 + tb] (control points flattened
    (c, d)); ``B`` (or None) is d r / d P[g, t0 + tb + 1] for terms that
    couple adjacent frames.
    """

    r: np.ndarray
    A: np.ndarray
    t0: int
    B: np.ndarray | None = None


class SpaceTimeProblem:
    """Residuals and Jacobian of G curves over one interval at one pyramid level.

    Parameters
    ----------
    images : LevelImages of the interval's frames (T frames).
    P0 : (G, T, C, 2) control points in this level's px; the entries under
        ``fixed`` are the hard constraints, the others the initial guess.
    fixed : (G, T, C) bool; t = 0 and t = T-1 are always fixed.
    weights : :class:`Weights`.
    n_samples : samples per curve.
    K : ribbon half-width (samples a = 1..K px on each side).
    use_image_terms : False drops the sketch and colour terms ("agarwala").
    frame0 : (G,) int, optional: index in ``images`` of each curve's frame
        t = 0, so curves of different keyframe intervals (of equal length)
        can share one problem; default 0 (``images`` holds the interval).
    length_anchor : weight of the length anchor relative to ``weights.length``
        (0 drops it: the adjacent-frame length term of Agarwala et al. alone).
    motion_prior : optional (G, T, C, 2) track in this level's px (the flow
        or limb start) whose frame-to-frame motion the velocity term takes
        as its zero.
    prior_confidence : optional (G, T) confidence in [0, 1] of that start
        (:func:`nnsf.roto.limbs.limb_init`); default 1.
    edge_gate : px of this level; > 0 scales the edge and ribbon residuals of
        samples NOT within that distance of an edge in both keyframes by
        1 - the start's mean confidence (0 with no start: dropped).
    slide : weight of the slide anchor to ``motion_prior`` (0: none).
    velocity_trust : with ``motion_prior`` and ``prior_confidence``, scale the
        velocity residuals between frames t and t+1 by sqrt((c_t + c_{t+1}) / 2).

    The unknown vector ``x`` holds the free entries of P (``P[free]`` order).
    """

    def __init__(self, images: LevelImages, P0: np.ndarray, fixed: np.ndarray, weights: Weights,
                 n_samples: int = 12, K: int = 3, use_image_terms: bool = True,
                 frame0: np.ndarray | None = None, length_anchor: float = 4.0,
                 motion_prior: np.ndarray | None = None,
                 prior_confidence: np.ndarray | None = None, edge_gate: float = 0.0,
                 slide: float = 0.0, velocity_trust: bool = False):
        P0 = np.asarray(P0, dtype=np.float64)
        self.G, self.T, self.C, _ = P0.shape
        self.frame0 = np.zeros(self.G, np.intp) if frame0 is None else \
            np.asarray(frame0, np.intp).reshape(self.G)
        if self.T < 3:
            raise ValueError("an interval needs at least one in-between frame")
        self.images = images
        self.P0 = P0.copy()
        self.fixed = np.asarray(fixed, bool).copy()
        self.fixed[:, 0] = self.fixed[:, -1] = True
        self.w = weights
        self.n = int(n_samples)
        self.K = int(K)
        self.image_terms = bool(use_image_terms) and (weights.sketch > 0 or weights.colour > 0) \
            and self.K > 0
        self.B0, self.B1, self.B2 = curves.basis(self.C, self.n)
        # ribbon offsets aσ, shape (2K,): +1..+K (side "a", along +normal), then -1..-K
        a = np.arange(1, self.K + 1, dtype=np.float64)
        self.offsets = np.concatenate([a, -a])
        self.free = np.repeat(~self.fixed[..., None], 2, axis=-1)        # (G, T, C, 2)
        self.n_unknowns = int(self.free.sum())
        conf = None if prior_confidence is None else \
            np.asarray(prior_confidence, np.float64).reshape(self.G, self.T)
        # the edge gate: per sample, whether the keyframes' curves lie on an edge there in both
        # keyframes (on_edge), and the scale of its edge and ribbon residuals (G, n): 1 on an
        # edge, else 1 - the start's mean confidence (a confident start needs no image
        # evidence where there is none; a poor one still does)
        self.on_edge = np.ones((self.G, self.n), bool)
        self.gate = np.ones((self.G, self.n))
        if edge_gate > 0:
            Sk = np.einsum("nc,gtcd->gtnd", self.B0, self.P0[:, [0, -1]])
            ek = bilinear(images.edge, self._t([0, self.T - 1], 1), Sk, grad=False)[..., 0]
            self.on_edge = ek.max(1) <= edge_gate
            c = np.ones(self.G) if conf is None else conf[:, 1:-1].mean(1)
            self.gate = np.where(self.on_edge, 1.0, 1.0 - c[:, None])
        self.rib_w = None
        if self.image_terms:
            self.kappa = self._colour_targets()
            if edge_gate > 0:
                self.rib_w = np.ascontiguousarray(np.broadcast_to(
                    self.gate[:, None, :, None, None], (self.G, 1, self.n, 2 * self.K, 1)))
        self.length_anchor = float(length_anchor)
        D1k = np.einsum("nc,gtcd->gtnd", self.B1, self.P0[:, [0, -1]])
        spk = np.maximum(np.linalg.norm(D1k, axis=-1), 1e-3)               # (G, 2, n)
        lam = (np.arange(1, self.T - 1) / (self.T - 1.0))[None, :, None]
        self.ell = (1 - lam) * spk[:, :1] + lam * spk[:, 1:]               # (G, T-2, n)
        # the velocity term penalises the change of each sample between frames minus
        # that of ``motion_prior`` (e.g. the flow init): motion is then judged against
        # the flow, not against standing still, which punished fast limbs (a jump)
        self.vref = self.vtrust = None
        if motion_prior is not None:
            S0 = np.einsum("nc,gtcd->gtnd", self.B0, np.asarray(motion_prior, np.float64))
            self.vref = S0[:, :-1] - S0[:, 1:]                            # (G, T-1, n, 2)
            if velocity_trust and conf is not None:   # the start trusted as far as it is (§2.2)
                self.vtrust = np.sqrt(np.clip(conf[:, :-1] + conf[:, 1:], 0, 2) / 2)[..., None]
        # the slide anchor: each in-between sample's offset from the prior along the prior's
        # tangent (constant unit vectors, so the residual is linear in P)
        self.slide = None
        if motion_prior is not None and slide > 0:
            D1p = np.einsum("nc,gtcd->gtnd", self.B1, np.asarray(motion_prior, np.float64))[:, 1:-1]
            c = np.ones((self.G, self.T - 2)) if conf is None else conf[:, 1:-1]
            self.slide = (np.sqrt(slide * c)[..., None], S0[:, 1:-1],
                          D1p / np.maximum(np.linalg.norm(D1p, axis=-1, keepdims=True), 1e-9))
        self._pattern = None
        # Kn[n, (j, d), (a, d')] = Bs[a, n, j] δ(d, d'): maps a ribbon row's (u, v) to columns
        Bs = np.stack([self.B0, self.B1])                                 # (2, n, C)
        self._basis_kron = np.einsum("anj,de->njdae", Bs, np.eye(2)).reshape(
            self.n, 2 * self.C, 4)

    def _t(self, idx, extra: int) -> np.ndarray:
        """Image frame indices (G, len(idx), 1 * extra) of interval frames ``idx``."""
        t = self.frame0[:, None] + np.asarray(idx, np.intp)[None, :]
        return t.reshape(t.shape + (1,) * extra)

    # -- parameters
    def x0(self) -> np.ndarray:
        return self.P0[self.free]

    def controls(self, x: np.ndarray) -> np.ndarray:
        P = self.P0.copy()
        P[self.free] = x
        return P

    # -- colour target
    def _ribbon(self, S, D1):
        # a degenerate tangent (coincident control points) gets a finite normal
        tn = np.maximum(np.linalg.norm(D1, axis=-1, keepdims=True), 1e-3)
        that = D1 / tn
        nhat = that @ R90.T
        q = S[..., None, :] + self.offsets[:, None] * nhat[..., None, :]
        return q, that, tn

    def _colour_targets(self):
        Pk = self.P0[:, [0, -1]]
        S = np.einsum("nc,gtcd->gtnd", self.B0, Pk)
        D1 = np.einsum("nc,gtcd->gtnd", self.B1, Pk)
        q, _, _ = self._ribbon(S, D1)
        val, _ = bilinear(self.images.colour, self._t([0, self.T - 1], 2), q)  # (G, 2, n, 2K, 3)
        K = self.K
        side = np.stack([val[..., :K, :].mean(-2), val[..., K:, :].mean(-2)], axis=-2)  # (G,2,n,2,3)
        lam = (np.arange(1, self.T - 1) / (self.T - 1.0))[None, :, None, None, None]
        kap = (1 - lam) * side[:, :1] + lam * side[:, 1:]        # (G, T-2, n, 2, 3)
        return np.repeat(kap, K, axis=3)                          # (G, T-2, n, 2K, 3)

    # -- residual blocks
    def blocks(self, x, jacobian: bool = True, image_terms: bool = True) -> list[Block]:
        """Residual blocks at ``x`` (with their Jacobians unless ``jacobian`` is False).

        ``image_terms=False`` leaves out the sketch and colour blocks (the
        normal equations assemble those from per-sample moments instead).
        """
        P = self.controls(x)
        B0, B1, B2 = self.B0, self.B1, self.B2
        S = np.einsum("nc,gtcd->gtnd", B0, P)
        D1 = np.einsum("nc,gtcd->gtnd", B1, P)
        D2 = np.einsum("nc,gtcd->gtnd", B2, P)
        G, T, C, n = self.G, self.T, self.C, self.n
        C2 = 2 * C
        sV, sL, sC = np.sqrt(self.w.velocity), np.sqrt(self.w.length), np.sqrt(self.w.curvature)
        sE, sS, sP = np.sqrt(self.w.edge), np.sqrt(self.w.sketch), np.sqrt(self.w.colour)
        eye = np.eye(2)
        out = []

        def lin(M, s):  # constant Jacobian of s·(M P_t - M P_{t+1}): rows (n, 2), cols (C, 2)
            J = (s * M[:, None, :, None] * eye[None, :, None, :]).reshape(1, 1, 2 * n, C2)
            return np.broadcast_to(J, (G, T - 1, 2 * n, C2))

        # velocity and curvature (linear)
        for M, s, V in ((B0, sV, S), (B2, sC, D2)):
            dv = V[:, :-1] - V[:, 1:]
            if V is S and self.vref is not None:
                dv = dv - self.vref
            r = (s * dv).reshape(G, T - 1, 2 * n)
            J = lin(M, s) if jacobian else None
            if V is S and self.vtrust is not None:
                r, J = self.vtrust * r, None if J is None else self.vtrust[..., None] * J
            out.append(Block(r, J, 0, None if J is None else -J))
        # length (see the module notes): (n-1)(|c_t'| - |c_{t+1}'|) between adjacent
        # frames, and (n-1)(|c_t'| - ℓ_t) against the keyframes' blended speeds
        h = float(n - 1)
        tn = np.maximum(np.linalg.norm(D1, axis=-1), 1e-3)                 # (G, T, n)
        jl = None
        if jacobian:
            jl = (h * (D1 / tn[..., None])[..., None, :] * B1[None, None, :, :, None]
                  ).reshape(G, T, n, C2)
        r = sL * h * (tn[:, :-1] - tn[:, 1:])
        out.append(Block(r, None if jl is None else sL * jl[:, :-1], 0,
                         None if jl is None else -sL * jl[:, 1:]))
        if self.length_anchor > 0:
            sA = np.sqrt(self.w.length * self.length_anchor)
            # one residual per curve and frame: the whole length (mean speed), weighted
            # by sqrt(n) so that it counts like n per-sample residuals
            k = sA * np.sqrt(n)
            r = k * h * (tn[:, 1:-1] - self.ell).mean(-1, keepdims=True)
            out.append(Block(r, None if jl is None else k * jl[:, 1:-1].mean(2, keepdims=True), 1))
        if self.slide is not None:
            # slide anchor: (S_t - S̃_t)·t̃_t in the in-between frames, times sqrt(w c_t)
            sw, Sp, th = self.slide                      # (G,T-2,1), (G,T-2,n,2), (G,T-2,n,2)
            r = sw * ((S[:, 1:-1] - Sp) * th).sum(-1)                        # (G, T-2, n)
            J = None
            if jacobian:
                J = (sw[..., None, None] * th[..., None, :] * B0[None, None, :, :, None]
                     ).reshape(G, T - 2, n, C2)
            out.append(Block(r, J, 1))
        # edge, in-between frames
        # e (G, T-2, n, 1), ge (G, T-2, n, 1, 2)
        tt = self._t(np.arange(1, T - 1), 1)
        ew = self.gate[:, None, :]                                         # (G, 1, n)
        if jacobian:
            e, ge = bilinear(self.images.edge, tt, S[:, 1:-1])
            J = (sE * ew[..., None, None] * ge[..., 0, None, :] * B0[None, None, :, :, None]
                 ).reshape(G, T - 2, n, C2)
        else:
            e, J = bilinear(self.images.edge, tt, S[:, 1:-1], grad=False), None
        out.append(Block(sE * ew * e[..., 0], J, 1))
        if self.image_terms and image_terms:
            q, that, tn = self._ribbon(S, D1)                              # (G,T,n,2K,2)
            # I (G, T, n, 2K, 3), gI (G, T, n, 2K, 3, 2)
            if jacobian:
                I, gI = bilinear(self.images.colour, self._t(np.arange(T), 2), q)
            else:
                I = bilinear(self.images.colour, self._t(np.arange(T), 2), q, grad=False)
            kappa = self.kappa
            if self.rib_w is not None:
                I = I * self.rib_w
                kappa = kappa * self.rib_w
                if jacobian:
                    gI = gI * self.rib_w[..., None]
            R = n * 2 * self.K * 3
            Jq = None
            if jacobian:
                # d nhat / dP[j] = Nmat B1[n,j], Nmat = R90 (I - t̂t̂ᵀ)/|t|
                Nmat = R90 @ ((eye - that[..., :, None] * that[..., None, :]) / tn[..., None])
                gN = gI @ Nmat[:, :, :, None]                              # (G,T,n,2K,3,2)
                off = self.offsets[None, None, None, :, None, None, None]
                # dI/dP[j,d] = B0[n,j] gI[d] + aσ B1[n,j] gN[d]
                Jq = (B0[None, None, :, None, None, :, None] * gI[..., None, :]
                      + off * B1[None, None, :, None, None, :, None] * gN[..., None, :])
                Jq = Jq.reshape(G, T, R, C2)
            # Eq. 1, the sketch term (docs/method.md §2.2): ribbon colours of adjacent frames.
            r = (sS * (I[:, :-1] - I[:, 1:])).reshape(G, T - 1, R)
            out.append(Block(r, None if Jq is None else sS * Jq[:, :-1], 0,
                             None if Jq is None else -sS * Jq[:, 1:]))
            # The colour penalty (docs/method.md §2.2): ribbon colours against the keyframes' κ.
            r = (sP * (I[:, 1:-1] - kappa)).reshape(G, T - 2, R)
            out.append(Block(r, None if Jq is None else sP * Jq[:, 1:-1], 1))
        return out

    def cost(self, x) -> np.ndarray:
        """0.5 · sum of squared residuals, per curve: (G,)."""
        return 0.5 * sum((b.r ** 2).reshape(self.G, -1).sum(1) for b in self.blocks(x, jacobian=False))

    # -- Gauss-Newton normal equations, block-tridiagonal in t
    def normal_equations(self, x):
        """Cost, gradient Jᵀr and JᵀJ at ``x`` over ALL (G, T, C, 2) entries.

        Returns ``cost (G,)`` per curve, ``g (G, T, C*2)``, ``Hd (G, T, C*2, C*2)`` (diagonal
        blocks) and ``Ho (G, T-1, C*2, C*2)`` (block (t, t+1)); rows and
        columns of fixed entries are included and must be masked by the caller.
        The sketch and colour parts are never formed as Jacobian rows: with
        u = ∇I and v = aσ ∇I·N per ribbon sample, every row is
        B0[n,j] u + B1[n,j] v, so their Gram blocks are sums over samples of
        2x2 moments of (u, v) against the constant basis products.
        """
        G, T, C2 = self.G, self.T, 2 * self.C
        g = np.zeros((G, T, C2))
        Hd = np.zeros((G, T, C2, C2))
        Ho = np.zeros((G, T - 1, C2, C2))
        cost = np.zeros(G)
        for b in self.blocks(x, image_terms=False):
            cost += 0.5 * (b.r ** 2).reshape(G, -1).sum(1)
            Tb = b.r.shape[1]
            At = np.swapaxes(b.A, -1, -2)
            g[:, b.t0:b.t0 + Tb] += np.einsum("gtkr,gtr->gtk", At, b.r)
            Hd[:, b.t0:b.t0 + Tb] += At @ b.A
            if b.B is not None:
                Bt = np.swapaxes(b.B, -1, -2)
                g[:, b.t0 + 1:b.t0 + 1 + Tb] += np.einsum("gtkr,gtr->gtk", Bt, b.r)
                Hd[:, b.t0 + 1:b.t0 + 1 + Tb] += Bt @ b.B
                Ho[:, b.t0:b.t0 + Tb] += At @ b.B
        if self.image_terms:
            cost += self._image_normal(x, g, Hd, Ho)
        return cost, g, Hd, Ho

    def _image_normal(self, x, g, Hd, Ho) -> np.ndarray:
        """Add the sketch and colour terms to g, Hd, Ho in place; return their cost (G,)."""
        P = self.controls(x)
        G, T, C, n = self.G, self.T, self.C, self.n
        S = np.einsum("nc,gtcd->gtnd", self.B0, P)
        D1 = np.einsum("nc,gtcd->gtnd", self.B1, P)
        q, that, tn = self._ribbon(S, D1)
        I, u = bilinear(self.images.colour, self._t(np.arange(T), 2), q)
        kappa = self.kappa
        if self.rib_w is not None:
            I, u, kappa = I * self.rib_w, u * self.rib_w[..., None], kappa * self.rib_w
        eye = np.eye(2)
        Nmat = R90 @ ((eye - that[..., :, None] * that[..., None, :]) / tn[..., None])
        v = (u @ Nmat[:, :, :, None]) * self.offsets[:, None, None]    # (G,T,n,2K,3,2)
        wS, wP = self.w.sketch, self.w.colour
        # Eq. 1 (sketch term) and the colour penalty, docs/method.md §2.2.
        dI = I[:, :-1] - I[:, 1:]                                  # (G,T-1,n,2K,3)
        dP = I[:, 1:-1] - kappa                                    # (G,T-2,n,2K,3)
        cost = 0.5 * (wS * (dI ** 2).reshape(G, -1).sum(1) + wP * (dP ** 2).reshape(G, -1).sum(1))
        # residual times its weight, gathered per frame (each frame's rows share Jq_t)
        e = np.zeros_like(I)
        e[:, :-1] += wS * dI
        e[:, 1:] -= wS * dI
        e[:, 1:-1] += wP * dP
        # rows of Jq at sample n: U[r, (a, d)] with a = 0 (u, times B0) or 1 (v, times B1)
        R = 2 * self.K * 3
        U = np.stack([u, v], axis=-2).reshape(G, T, n, R, 4)       # (G,T,n,R,(a,d))
        Kn = self._basis_kron                                      # (n, 2C, 4)
        gr = (e.reshape(G, T, n, 1, R) @ U)[..., 0, :]             # (G,T,n,4)
        g += np.einsum("nja,gtna->gtj", Kn, gr)
        # per-frame weight of Jq_tᵀJq_t: sketch pairs touching t, plus colour
        wt = np.full(T, 2.0 * wS)
        wt[[0, -1]] = wS
        wt[1:-1] += wP
        Ut = np.swapaxes(U, -1, -2)
        M = Ut @ U                                                 # (G,T,n,4,4)
        Hd += ((Kn @ M @ np.swapaxes(Kn, -1, -2)).sum(2)) * wt[None, :, None, None]
        X = Ut[:, :-1] @ U[:, 1:]
        Ho -= wS * (Kn @ X @ np.swapaxes(Kn, -1, -2)).sum(2)
        return cost

    # -- scipy interface: residual vector and CSR Jacobian over the free entries
    def residuals(self, x) -> np.ndarray:
        return np.concatenate([b.r.ravel() for b in self.blocks(x, jacobian=False)])

    def jacobian(self, x) -> sp.csr_matrix:
        blocks = self.blocks(x)
        if self._pattern is None:
            self._pattern = self._build_pattern(blocks)
        keep, order, indices, indptr, n_res = self._pattern
        vals = []
        for b in blocks:
            vals.append(np.ascontiguousarray(b.A).ravel())
            if b.B is not None:
                vals.append(np.ascontiguousarray(b.B).ravel())
        data = np.concatenate(vals)[keep][order]
        return sp.csr_matrix((data, indices, indptr), shape=(n_res, self.n_unknowns))

    def _build_pattern(self, blocks):
        G, T, C2 = self.G, self.T, 2 * self.C
        colmap = np.full(self.free.shape, -1, np.intp)
        colmap[self.free] = np.arange(self.n_unknowns)
        colmap = colmap.reshape(G, T, C2)
        rows_all, cols_all = [], []
        offset = 0
        for b in blocks:
            Tb, R = b.r.shape[1], b.r.shape[2]
            rid = (np.arange(b.r.size).reshape(b.r.shape) + offset)[..., None]
            offset += b.r.size
            shape = b.r.shape + (C2,)
            for t0 in ((b.t0,) if b.B is None else (b.t0, b.t0 + 1)):
                cols = np.broadcast_to(colmap[:, t0:t0 + Tb, None, :], shape)
                rows_all.append(np.broadcast_to(rid, shape).ravel())
                cols_all.append(cols.ravel())
        rows = np.concatenate(rows_all)
        cols = np.concatenate(cols_all)
        keep = cols >= 0
        rows, cols = rows[keep], cols[keep]
        order = np.lexsort((cols, rows))
        indptr = np.concatenate([[0], np.cumsum(np.bincount(rows, minlength=offset))])
        return keep, order, cols[order].astype(np.int32), indptr, offset


