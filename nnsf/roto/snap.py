"""The snap that can end "ours": each free control point moved across its curve, at most ``radius`` px.

Why a step after the solve.  The space-time energy balances its image terms
against the shape and motion terms, and on small frames (sprites about
100 px tall, limbs 8-10 px wide) the balance leaves outlines a pixel or two
beside the edge they follow.  A rotoscoping tool's "snap" does the last
pixels without the shape terms.  Two targets
(``roto.snap_to``):

* ``profile`` (:func:`profile_snap`): where the colours across the curve
  (the colour term's ribbon, ±1..K px along the normal) best match the
  keyframes' colours there, blended in time as the colour term's κ.  It
  finds whatever the user annotated: a stroke's centre line, a colour
  boundary.
* ``edge`` (:func:`edge_snap`): the largest colour-gradient magnitude.  On
  flat-colour art without outline strokes that is the part's boundary; on a
  drawn stroke it is one of the stroke's two sides, 1-1.5 px off its centre
  line, so it is for flat-colour art only (docs/results.md, tracking).
* ``auto`` (:func:`auto_target`): ``edge`` on flat-colour art, no snap on
  stroked art, told apart by the user's own keyframes (:func:`stroke_share`).

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
#: :func:`stroke_share` reads the colours this far (px) either side of a keyframe curve: past
#: the half-width of the 1-3 px strokes of line art at these sizes, inside a limb 8 px wide
SIDE = 2.0
#: ``auto`` takes a clip for stroked art when at least this share of its keyframe control points
#: lie on a stroke.  On the annotated clips the shares fall in separate groups: flat-colour
#: sprites up to 0.04 (a belt or strap 1-2 px wide), stroked line art from 0.17, pixel art with
#: dark outlines from 0.68, pixel art outlined in its own skin colour near 0; a tenth lies
#: between the flat and the stroked groups, set from the shares, not from a tracking score
STROKED = 0.1


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


def stroke_share(frames: np.ndarray, keyframes: dict) -> float:
    """Share of the keyframe control points that lie on a drawn stroke (0 when there are none).

    frames    : (T, H, W, 3) uint8 RGB clip.
    keyframes : ``{frame: {curve: (C, 2) control points (px)}}``, the user's annotation.
    A point is on a stroke when the colour at it differs from the colours
    :data:`SIDE` px either side along the curve's normal more than those two
    differ from each other (RGB in [0, 1], Euclidean): a dark line between
    two fills.  On a boundary between two flat colours the colour at the
    point lies between the two sides, and the test fails.
    """
    hits, total = 0, 0
    for f, curves in keyframes.items():
        img = np.asarray(frames[int(f)], np.float64)[None] / 255.0                 # (1, H, W, 3)
        for P in curves.values():
            P = np.asarray(P, np.float64)
            if len(P) < 2:
                continue
            n = normals(P, len(P))                                                  # (C, 2)
            q = np.stack([P - SIDE * n, P, P + SIDE * n])                            # (3, C, 2)
            c = bilinear(img, np.zeros(q.shape[:-1], np.intp), q, grad=False)         # (3, C, 3)
            across = np.linalg.norm(c[2] - c[0], axis=-1)
            to_side = np.minimum(np.linalg.norm(c[1] - c[0], axis=-1), np.linalg.norm(c[1] - c[2], axis=-1))
            hits += int((to_side > across).sum())
            total += len(P)
    return hits / total if total else 0.0


def resolve_target(snap: float, snap_to: str, frames: np.ndarray, keyframes: dict | None
                   ) -> tuple[str | None, float | None]:
    """What "ours" ends with: (``"profile"``, ``"edge"`` or None for no snap, the stroke share or None).

    ``snap`` (px) 0 is no snap; ``snap_to="auto"`` is :func:`auto_target` on
    ``frames`` (T, H, W, 3) uint8 and ``keyframes`` ``{frame: {curve: (C, 2)}}``,
    which it then needs; the other targets are taken as they are.
    """
    if snap <= 0:
        return None, None
    if snap_to != "auto":
        return snap_to, None
    if keyframes is None:
        raise ValueError("track option snap_to='auto' needs the clip's keyframes")
    return auto_target(frames, keyframes)


def auto_target(frames: np.ndarray, keyframes: dict) -> tuple[str | None, float]:
    """``snap_to: auto`` for one clip: (``"edge"`` or None for no snap, the :func:`stroke_share`).

    Flat-colour art (share below :data:`STROKED`) snaps to the edge, where
    its outlines are; on stroked art the edge lies beside the stroke the user
    drew along, so it does not snap.
    """
    share = stroke_share(frames, keyframes)
    return ("edge" if share < STROKED else None), share


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
