"""The ``limb`` initialisation of the space-time solver: each limb tracked as one rigid body.

Why a limb-level start.  The solver refines a guess; on the rendered clips
the guess decides the key points almost alone (the dense-flow start of
:func:`nnsf.roto.solve.flow_init` scored PCK 0.837 before any solving and
0.843 after it), because the image terms barely see a curve sliding along
its own edge, and the joints are read from the curve ends.  Three causes
of the flow start's errors, each measured on the first four rendered clips
(one-step predictions started from the true curves):

* the flow is sampled ON the outline, a motion boundary, where dense flow
  mixes the limb's motion with the background's: 26 % of steps off by more
  than 3 px, against 9 % when a rigid motion is fitted to the flow inside
  the limb (between its two side curves);
* flat-coloured cartoon limbs that move further than their width defeat
  dense flow (DIS, Farneback, DeepFlow, TV-L1, RLOF and PCAFlow all leave
  7-15 % of limb steps more than 3 px off); a search over rigid motions
  scored by the limb's own colours cut the share with more than 1.5 px
  from 20 % to 8 % (measured with a first, slower version of the search:
  finer grid, larger template);
* a limb hidden behind another part at one keyframe is lost when carried
  from there, and the plain blend of the two directions (weights 1-λ, λ)
  spreads that loss over the whole interval.  The direction that misses
  the other keyframe by more is trusted less.

:func:`limb_init` returns the guess and a confidence per curve and frame
(from the two directions' arrival errors at the keyframes) that the energy
uses to weigh its anchor to the guess (:mod:`nnsf.roto.energy`).
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.roto.curves import basis
from nnsf.skeleton.rigid import rigid_fit, rotation

#: across-limb fractions (0 = side a, 1 = side b) of the flow samples (inside the limb)
INSIDE = (0.2, 0.35, 0.5, 0.65, 0.8)
#: ... and of the appearance template (inside, the outline strokes and a little beyond)
TEMPLATE = (-0.15, 0.0, 0.25, 0.5, 0.75, 1.0, 1.15)
COARSE_ANGLES = np.radians(np.arange(-20.0, 20.1, 5.0))
FINE_ANGLES = np.radians(np.arange(-4.0, 4.1, 2.0))
FINEST_ANGLES = np.radians([-1.0, 0.0, 1.0])
COARSE_BLUR = 1.5
#: turns of a limb about one of its ends tried when the grid search fails (a swing too fast for
#: flow and grid: the jump's arms turn up to 80° from one frame to the next)
HINGE_ANGLES = np.radians(np.arange(-90.0, 90.1, 6.0))
NO_TURN = np.zeros(1)



def side_pairs(keys) -> np.ndarray:
    """Row index of each row's partner side curve (``<group>.a`` <-> ``<group>.b``), -1 if none.

    keys : per row, the curve name or a tuple whose last element is the curve
    name and whose other elements tell the row's interval apart (rows of
    different intervals never pair).
    """
    keys = [tuple(k) if isinstance(k, tuple) else (k,) for k in keys]
    where = {k: i for i, k in enumerate(keys)}
    out = np.full(len(keys), -1, np.intp)
    for i, k in enumerate(keys):
        base, _, side = str(k[-1]).rpartition(".")
        if side in ("a", "b") and base:
            j = where.get(k[:-1] + (f"{base}.{'b' if side == 'a' else 'a'}",))
            if j is not None:
                out[i] = j
    return out


#: a limb hangs from its parent's distal end (the forearm from the elbow, the shin from the knee)
PARENT = {"forearm": "upper_arm", "shin": "thigh"}


def limb_parents(keys) -> np.ndarray:
    """Row index of each row's parent limb (its ``.a`` side), -1 if none; ``keys`` as :func:`side_pairs`.

    ``l_forearm.a`` and ``l_forearm.b`` -> the row of ``l_upper_arm.a`` of the
    same interval; ``r_shin.*`` -> ``r_thigh.a``.
    """
    keys = [tuple(k) if isinstance(k, tuple) else (k,) for k in keys]
    where = {k: i for i, k in enumerate(keys)}
    out = np.full(len(keys), -1, np.intp)
    for i, k in enumerate(keys):
        base = str(k[-1]).rpartition(".")[0]
        side, _, part = base.partition("_")
        if part in PARENT:
            out[i] = where.get(k[:-1] + (f"{side}_{PARENT[part]}.a",), -1)
    return out


def limb_weights(C: int, n_along: int, across, extend: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Matrices ``Wa, Wb`` (M, C): the limb points ``Wa @ a + Wb @ b`` of side curves a, b (C, 2).

    ``n_along`` spline samples of each side plus ``extend`` samples linearly
    extrapolated beyond either end (the joint and the limb's end cap fix the
    limb along its axis), blended across the limb at the fractions ``across``
    (0 = on side a, 1 = on side b; outside [0, 1]: beyond the sides).  Side
    a[i] and b[i] are at the same place along the limb (both run from the
    start joint to the end joint).
    """
    B = basis(C, n_along)[0]
    k = np.arange(extend, 0, -1)[:, None]
    rows = np.concatenate([B[0] + k * (B[0] - B[1]), B, B[-1] + k[::-1] * (B[-1] - B[-2])])
    u = np.asarray(across, np.float64)[:, None, None]
    return ((1 - u) * rows[None]).reshape(-1, C), (u * rows[None]).reshape(-1, C)


def sample_image(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear values (..., ch) of ``img`` (H, W, ch) float32 at points (..., 2) px.

    ``cv2.remap`` (border pixels repeated); its maps must stay below 32767
    rows, so the points are laid out 512 to a row.
    """
    shape = pts.shape[:-1]
    n = int(np.prod(shape))
    width = 512
    p = np.zeros((-(-n // width) * width, 2), np.float32)
    p[:n] = pts.reshape(-1, 2)
    p = p.reshape(-1, width, 2)
    v = cv2.remap(img, p[..., 0], p[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return v.reshape(-1, img.shape[-1])[:n].reshape(shape + (img.shape[-1],))


def sample_flow(flow: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear flow vectors (M, 2) at points (M, 2) of a (H, W, 2) float32 flow field."""
    return sample_image(flow, pts)


def search_rigid(img: np.ndarray, q: np.ndarray, ref: np.ndarray, w: np.ndarray,
                 R0: np.ndarray, t0: np.ndarray, reach: float, step: float, angles,
                 tau: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Best rigid motion of template points ``q`` (M, 2), colours ``ref`` (M, 3), into ``img``.

    Candidates: the motion (R0, t0), then a rotation by each of ``angles``
    about the moved template's centre and a shift on a grid of ``step`` px
    within ±``reach``.  Cost: the ``w``-weighted mean squared colour
    difference, each sample's truncated at ``tau``² (a sample another part
    covers costs at most that).  Returns ``(R, t, cost)`` of the best.
    """
    c = (w[:, None] * q).sum(0) / w.sum()
    c1 = c @ R0.T + t0
    Rs = rotation(np.asarray(angles, np.float64)) @ R0                   # (A, 2, 2)
    g = np.arange(-reach, reach + 1e-9, step) if reach > 0 else np.zeros(1)
    D = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    Rk = np.repeat(Rs, len(D), 0)
    tk = c1 + np.tile(D, (len(Rs), 1)) - Rk @ c
    # candidate k moves sample m to Rk q_m + tk: the remap maps, one row per candidate
    qx, qy = q[:, 0][None].astype(np.float32), q[:, 1][None].astype(np.float32)
    R32, t32 = Rk.astype(np.float32), tk.astype(np.float32)
    mx = R32[:, 0, :1] * qx + R32[:, 0, 1:] * qy + t32[:, :1]
    my = R32[:, 1, :1] * qx + R32[:, 1, 1:] * qy + t32[:, 1:]
    moved = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    diff = moved - np.asarray(ref, np.float32)[None]                      # (K, M, 3)
    d = diff[..., 0] * diff[..., 0]                  # three products: 3x faster than einsum here
    for ch in range(1, diff.shape[-1]):
        d += diff[..., ch] * diff[..., ch]
    np.minimum(d, np.float32(tau * tau), out=d)
    cost = d @ (np.asarray(w, np.float32) / np.float32(w.sum()))
    k = int(np.argmin(cost))
    return Rk[k], tk[k], float(cost[k])


def limb_init(fwd: np.ndarray, bwd: np.ndarray, colour: np.ndarray, P: np.ndarray,
              fixed: np.ndarray, frame0: np.ndarray, pairs: np.ndarray, fallback,
              max_fb: float = 1.0, colour_tol: float = 0.12, tau: float = 0.25,
              search_cost: float = 0.004, search_gain: float = 0.5, parents=None
              ) -> tuple[np.ndarray, np.ndarray]:
    """Initial guess and its confidence: each limb carried as a rigid body from both keyframes.

    fwd, bwd : the clip's dense flows (:func:`nnsf.roto.solve.dense_flows`);
    colour : (T, H, W, 3) float32 RGB in [0, 1] (the solver's smoothed
    frames); P (G, T, C, 2) with the keyframes at t = 0 and T-1; frame0 (G,)
    each row's first clip frame; pairs (G,) each row's partner side
    (:func:`side_pairs`, -1: none); fallback(P, fixed, frame0) -> guess for
    rows without a partner (the point-wise dense-flow start); parents (G,)
    each row's parent limb row (:func:`limb_parents`, -1: none; None: no
    hierarchy).

    Each step t -> t±1 of a limb (both side curves together):

    1. the flow's motion: a rigid fit to the flow sampled inside the limb
       (:data:`INSIDE`), over the samples that pass the forward-backward
       check (``max_fb`` px) and land on the limb's own colour (within
       ``colour_tol`` of the keyframe's colour at that place in the limb: the
       per-limb colour model; where another part covers the limb, the flow
       is that part's);
    2. its check by appearance: the template (:data:`TEMPLATE`, two samples
       beyond either end) moved into the next frame against its colours in
       the keyframe, truncated squared colour difference (``tau``); samples
       whose colour in this frame is not the keyframe's (another part covers
       them) are left out (if that leaves less than a fifth, the limb is
       matched against this frame's colours, all samples, instead).  Matching
       the keyframe's colours rather than the previous frame's keeps small
       errors from piling up over the interval.  A fine search (±1.5 px by
       0.5 and ±4° by 2, then ±0.5 px and ±1° by 1) polishes the flow's
       motion; if that still costs more than ``search_cost``, a grid search
       (±9 px by 3, ±20° by 5: each grid point within the fine search's reach
       of its neighbours) around it, on frames blurred further (σ 1.5 px) so
       that the true motion's basin is wider than the grid step, polished the
       same way, replaces it when
       it costs less than ``search_gain`` times as much (a limb passing over another of its
       colour makes even the true motion cost something; the margin keeps
       the search from following the other part).  If the cost is still
       above ``search_cost``, a hinge search turns the moved limb about
       its proximal end (the joint it hangs from: side curves run from it)
       by ±90° in 6° steps (:data:`HINGE_ANGLES`), each
       turn with shifts of ±6 px by 3 on the blurred frame, polishes the best
       and takes it on the same terms: a limb swinging about its joint faster
       than the grid's ±20°.  It turns about the proximal end only: turning
       about the distal end too fits the outline as well but can swap the
       limb's two joints.
       **Hierarchy**: a limb with a parent (``parents``, :func:`limb_parents`:
       the forearm hangs from the upper arm, the shin from the thigh) is
       tracked after its parent, and its hinge search starts from the
       parent's motion in that step (a rigid fit to the parent's finished
       start, both sides, frame src -> dst) and turns about where that
       motion carries the limb's proximal end (the elbow, the knee): a
       forearm swinging with its upper arm and bending about the elbow at
       once, the elbow itself moving 20-50 px a frame, which neither flow,
       grid nor a turn about the forearm's own displaced end finds.

    The forward track (from t = 0) and the backward one (from T-1) each miss
    the other keyframe, by e_f and e_b px (largest control-point error).  Both
    are bent linearly in t to meet both keyframes (as the LK baseline's
    blend) and mixed with weights ∝ (1-λ)/(1 + e_f²) and λ/(1 + e_b²),
    λ = t/(T-1).  The confidence of frame t is 1/(1 + σ_t²) with
    σ_t = w_f e_f λ + w_b e_b (1-λ), the mixed drift (px); 0 for fallback rows.
    Returns ``(guess (G, T, C, 2), confidence (G, T))``; entries under
    ``fixed`` keep P.
    """
    P = np.asarray(P, np.float64)
    G, T, C, _ = P.shape
    pairs = np.asarray(pairs, np.intp)
    colour = np.asarray(colour, np.float32)
    out = fallback(P, fixed, frame0) if (pairs < 0).any() else P.copy()
    conf = np.zeros((G, T))
    Wa_in, Wb_in = limb_weights(C, 12, INSIDE)
    Wa, Wb = limb_weights(C, 10, TEMPLATE, extend=2)
    lam = (np.arange(T) / (T - 1.0))[:, None, None]
    blurred: dict[int, np.ndarray] = {}

    def blur(t):
        """Frame t blurred further (σ = COARSE_BLUR px): the coarse search's wider basins."""
        if t not in blurred:
            blurred[t] = cv2.GaussianBlur(colour[t], (0, 0), COARSE_BLUR)
        return blurred[t]

    def polish(img, q, ref, w, R, tr):
        R, tr, _ = search_rigid(img, q, ref, w, R, tr, 1.5, 0.5, FINE_ANGLES, tau)
        return search_rigid(img, q, ref, w, R, tr, 0.5, 0.5, FINEST_ANGLES, tau)

    def hinge(img, q, ref, w, R, tr, end):
        """The best motion of :func:`search_rigid` (±6 px by 3, no turn about the centre) after
        turning the moved limb about ``end`` (its proximal end, template coordinates) by each of
        :data:`HINGE_ANGLES`."""
        best = None
        pivot = end @ R.T + tr
        for Rh in rotation(HINGE_ANGLES):
            # x -> Rh (R x + tr - pivot) + pivot
            cand = search_rigid(img, q, ref, w, Rh @ R, pivot + (tr - pivot) @ Rh.T, 6.0, 3.0,
                                NO_TURN, tau)
            if best is None or cand[2] < best[2]:
                best = cand
        return best

    def carry(a0, b0, steps, there, back, key, f0, joint=None):
        ref_in = sample_image(colour[key], Wa_in @ a0 + Wb_in @ b0)
        ref_key = sample_image(colour[key], Wa @ a0 + Wb @ b0)
        ref_key_b = sample_image(blur(key), Wa @ a0 + Wb @ b0)
        A, B = np.empty((T, C, 2)), np.empty((T, C, 2))
        A[0], B[0] = a0, b0
        u = np.full(T, 1e-3)          # u[k+1]: how doubtful step k is (0 clean .. 1 lost)
        a, b = a0.copy(), b0.copy()
        for k, t in enumerate(steps):
            src, dst = (t, t + 1) if there is fwd else (t + 1, t)
            q = Wa_in @ a + Wb_in @ b
            d = sample_flow(there[t], q)
            ok = np.linalg.norm(d + sample_flow(back[t], q + d), axis=1) <= max_fb
            ok &= np.linalg.norm(sample_image(colour[dst], q + d) - ref_in, axis=1) <= colour_tol
            if ok.sum() >= 3:
                R, tr = rigid_fit(q[ok], q[ok] + d[ok])
            else:
                R, tr = np.eye(2), (d[ok].mean(0) if ok.any() else np.zeros(2))
            qt = Wa @ a + Wb @ b
            ref = sample_image(colour[src], qt)
            w = (np.linalg.norm(ref - ref_key, axis=1) <= colour_tol).astype(np.float64)
            seen = w.mean()
            covered = w.sum() < 0.2 * len(w)
            if covered:                          # mostly covered: match what is there
                w[:] = 1.0
            else:                                # match the keyframe's colours: no drift
                ref = ref_key
            R, tr, cost = polish(colour[dst], qt, ref, w, R, tr)
            if cost > search_cost:
                ref_b = sample_image(blur(src), qt) if covered else ref_key_b
                R2, tr2, _ = search_rigid(blur(dst), qt, ref_b, w, R, tr, 9.0, 3.0,
                                          COARSE_ANGLES, tau)
                R2, tr2, c2 = polish(colour[dst], qt, ref, w, R2, tr2)
                if c2 < search_gain * cost:
                    R, tr, cost = R2, tr2, c2
            if cost > search_cost:
                if joint is None:            # turn about its own (moved) proximal end
                    R3, tr3 = R, tr
                else:                        # ... about where the parent carried that end
                    R3, tr3 = rigid_fit(joint[src - f0], joint[dst - f0])
                R3, tr3, c3 = hinge(blur(dst), qt, ref_b, w, R3, tr3, (a[0] + b[0]) / 2)
                R3, tr3, c3 = polish(colour[dst], qt, ref, w, R3, tr3)
                if c3 < search_gain * cost:
                    R, tr, cost = R3, tr3, c3
            a, b = a @ R.T + tr, b @ R.T + tr
            A[k + 1], B[k + 1] = a, b
            u[k + 1] += max(1.0 - seen, min(cost / tau ** 2, 1.0))
        return A, B, np.cumsum(u) / u.sum()

    parents = np.full(G, -1, np.intp) if parents is None else np.asarray(parents, np.intp)
    done = np.zeros(G, bool)
    for g in sorted(range(G), key=lambda g: parents[g] >= 0):      # parents first
        h = pairs[g]
        if h < 0 or done[g]:
            continue
        f0 = int(frame0[g])
        pg = parents[g]
        joint = None
        if pg >= 0 and done[pg] and pairs[pg] >= 0:
            joint = np.concatenate([out[pg], out[pairs[pg]]], axis=1)     # (T, 2C, 2)
        fa, fb, Uf = carry(P[g, 0], P[h, 0], range(f0, f0 + T - 1), fwd, bwd, f0, f0, joint)
        ba, bb, Ub = carry(P[g, -1], P[h, -1], range(f0 + T - 2, f0 - 1, -1), bwd, fwd,
                           f0 + T - 1, f0, joint)
        ba, bb, Ub = ba[::-1], bb[::-1], 1.0 - Ub[::-1]
        ef = max(np.abs(fa[-1] - P[g, -1]).max(), np.abs(fb[-1] - P[h, -1]).max())
        eb = max(np.abs(ba[0] - P[g, 0]).max(), np.abs(bb[0] - P[h, 0]).max())
        # bend each track onto the keyframe it missed, the miss shared out over its steps
        # in proportion to how doubtful each step was
        Uf, Ub = Uf[:, None, None], Ub[:, None, None]
        fa, fb = fa + Uf * (P[g, -1] - fa[-1]), fb + Uf * (P[h, -1] - fb[-1])
        ba, bb = ba + (1 - Ub) * (P[g, 0] - ba[0]), bb + (1 - Ub) * (P[h, 0] - bb[0])
        wf, wb = (1 - lam) / (1 + ef ** 2), lam / (1 + eb ** 2)
        wf, wb = wf / (wf + wb), wb / (wf + wb)
        out[g] = wf * fa + wb * ba
        out[h] = wf * fb + wb * bb
        sig = (wf * ef * Uf + wb * eb * (1 - Ub))[:, 0, 0]
        conf[[g, h]] = 1.0 / (1.0 + sig ** 2)
        conf[[g, h], 0] = conf[[g, h], -1] = 1.0
        done[[g, h]] = True
    fx = np.asarray(fixed, bool)
    return np.where(fx[..., None], P, out), conf
