"""The snap that can end "ours": each free control point moved across its curve, at most ``radius`` px.

Why a step after the solve.  The space-time energy balances its image terms
against the shape and motion terms, and on small frames (the 96×128 Kenney
walk cycles, limbs 8-10 px wide) the balance leaves outlines a pixel or two
beside the edge they follow: of the tracked Kenney samples 0.64 lie within
1.5 px of the silhouette, 0.75 within 3 px.  A rotoscoping tool's "snap"
does the last pixels without the shape terms.  Two targets
(``roto.snap_to``):

* ``profile`` (:func:`profile_snap`): where the colours across the curve
  (the colour term's ribbon, ±1..K px along the normal) best match the
  keyframes' colours there, blended in time as the colour term's κ.  It
  finds whatever the user annotated: a stroke's centre line, a colour
  boundary.
* ``edge`` (:func:`edge_snap`): the largest colour-gradient magnitude.  On
  flat-colour art without outline strokes that is the part's boundary; on a
  drawn stroke it is one of the stroke's two sides, 1-1.5 px off its centre
  line, so it is for flat-colour art only (README, tracking).

Each free control point searches its curve's normal in steps of
:data:`STEP` px and moves to the best place; ties go to the nearer one, so a
point on a flat area stays.  Keyframes and user edits (``fixed``) never
move.  Control points lie on their Catmull-Rom curve
(:mod:`nnsf.roto.curves`), so the curve passes through the moved points.
The search is a fixed grid over every point of every frame at once (one
vectorised bilinear lookup), not an optimiser: 1-D, bounded, and exact to
the grid step.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.roto.curves import normals
from nnsf.roto.energy import bilinear

#: edge target: strength lost per px of offset (the colour gradient's units: RGB in [0, 1]
#: per px, Sobel-scaled), so that a tie between two edges goes to the nearer one and a flat
#: area keeps its point
PULL = 0.02
#: profile target: cost added per px of offset (squared RGB in [0, 1]), a tie-breaker only:
#: far below any real colour difference, it sends equal matches (a flat area) to the nearer
TIE = 1e-6
#: search step along the normal, px
STEP = 0.25


def offsets(radius: float) -> np.ndarray:
    """The search grid along the normal: multiples of :data:`STEP` in [-radius, radius] px, 0 in the middle."""
    n = int(np.floor(radius / STEP))
    return np.arange(-n, n + 1) * STEP


def gradient_strength(colour: np.ndarray) -> np.ndarray:
    """Colour-gradient magnitude (T, H, W) float32 of frames (T, H, W, 3) float in [0, 1].

    Sobel 3×3 per channel, L2 over channels (a red-to-green edge of equal grey
    counts as an edge).
    """
    out = np.empty(colour.shape[:3], np.float32)
    for t, f in enumerate(colour):
        gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
        out[t] = np.sqrt((gx * gx + gy * gy).sum(-1))
    return out


def edge_snap(strength: np.ndarray, P: np.ndarray, fixed: np.ndarray, frame0: np.ndarray,
              radius: float) -> np.ndarray:
    """Move every free control point along its normal onto the strongest edge within ``radius`` px.

    strength : (T_clip, H, W) from :func:`gradient_strength` (full resolution).
    P        : (G, T, C, 2) control points (px) of G curves over intervals of T frames.
    fixed    : (G, T, C) bool; these points stay.
    frame0   : (G,) clip frame of each row's first interval frame.
    Returns a new (G, T, C, 2) array.  ``radius`` 0 returns ``P`` unchanged.
    """
    P = np.asarray(P, np.float64)
    if radius <= 0 or P.size == 0:
        return P.copy()
    T = P.shape[1]
    offs = offsets(radius)                                                          # (S,)
    nrm = normals(P, P.shape[-2])              # C samples of a C-point spline: at the points
    q = P[..., None, :] + offs[:, None] * nrm[..., None, :]                         # (G, T, C, S, 2)
    frame = np.asarray(frame0)[:, None] + np.arange(T)[None, :]                     # (G, T)
    v = bilinear(strength[..., None], frame[:, :, None, None], q, grad=False)[..., 0]
    return _moved(P, fixed, offs, (v - PULL * np.abs(offs)).argmax(-1), nrm)


def profile_snap(colour: np.ndarray, P: np.ndarray, fixed: np.ndarray, frame0: np.ndarray,
                 radius: float, K: int) -> np.ndarray:
    """Move every free control point along its normal to where the colours across the curve match the keyframes'.

    colour : (T_clip, H, W, 3) float colour frames (the tracker's level 0).
    P, fixed, frame0 : as :func:`edge_snap`.  K : ribbon half-width (px).
    The profile of a control point is the colour at a = ±1..±K px along its
    normal; its target in frame t is the two keyframes' profiles blended
    linearly in t (the colour term's κ, docs/method.md §2.2).  Each free
    point moves to the offset within ``radius`` whose profile is nearest the
    target (sum of squared RGB differences; ties to the nearer offset).
    """
    P = np.asarray(P, np.float64)
    if radius <= 0 or P.size == 0:
        return P.copy()
    T = P.shape[1]
    offs = offsets(radius)                                                          # (S,)
    a = np.concatenate([np.arange(-K, 0), np.arange(1, K + 1)]).astype(np.float64)   # (A,)
    nrm = normals(P, P.shape[-2])                                                  # (G, T, C, 2)
    f0 = np.asarray(frame0)[:, None]
    kf0 = bilinear(colour, f0[:, :, None], P[:, 0, :, None] + a[:, None] * nrm[:, 0, :, None], grad=False)
    kf1 = bilinear(colour, f0[:, :, None] + T - 1, P[:, -1, :, None] + a[:, None] * nrm[:, -1, :, None],
                   grad=False)                                                     # (G, C, A, 3)
    lam = (np.arange(T) / max(T - 1, 1))[None, :, None, None, None]
    target = (1 - lam) * kf0[:, None] + lam * kf1[:, None]                          # (G, T, C, A, 3)
    shift = offs[:, None] + a[None, :]                                              # (S, A)
    q = P[:, :, :, None, None, :] + shift[..., None] * nrm[:, :, :, None, None, :]  # (G, T, C, S, A, 2)
    frame = (f0 + np.arange(T)[None, :])[:, :, None, None, None]
    col = bilinear(colour, frame, q, grad=False)                                    # (G, T, C, S, A, 3)
    cost = ((col - target[:, :, :, None]) ** 2).sum((-1, -2)) + TIE * np.abs(offs)
    return _moved(P, fixed, offs, cost.argmin(-1), nrm)


def _moved(P, fixed, offs, best, nrm) -> np.ndarray:
    """Control points (G, T, C, 2) moved by ``offs[best]`` px along ``nrm``; ``fixed`` ones kept."""
    return np.where(np.asarray(fixed, bool)[..., None], P, P + offs[best][..., None] * nrm)
