"""Motion-capture joints seen by a camera: up axis, orthographic projection to 2-D, resampling in time.

:func:`project` turns world positions from :func:`nnsf.datasets.bvh.forward_kinematics`
into image coordinates (x right, y down) for a camera at ``azimuth`` and
``elevation`` around the detected or given up axis (:func:`detect_up_axis`,
:func:`up_rotation`), optionally following the root; :func:`resample` changes
the frame rate by linear interpolation (docs/formats.md, BVH source).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_AXIS_VEC = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _axis_vector(up) -> np.ndarray:
    if isinstance(up, str):
        s = up.strip().lower()
        sign = -1.0 if s.startswith("-") else 1.0
        s = s.lstrip("+-")
        if s not in _AXIS_VEC:
            raise ValueError(f"up must be one of x, y, z with an optional sign, got {up!r}")
        return sign * np.array(_AXIS_VEC[s])
    v = np.asarray(up, dtype=float).reshape(3)
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError("up vector must be non-zero")
    return v / n


def up_rotation(up) -> np.ndarray:
    """Rotation ``(3, 3)`` taking the ``up`` axis onto +y (the smallest such turn).

    ``up`` is ``"y"``, ``"z"``, ``"-y"``, … or a 3-vector.  For ``"z"`` this
    maps (x, y, z) to (x, z, -y), so a Z-up file's +y (usually its forward)
    becomes -z.
    """
    u = _axis_vector(up)
    y = np.array([0.0, 1.0, 0.0])
    v = np.cross(u, y)
    c = float(u @ y)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # 180° about x
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1.0 + c)  # Rodrigues


def detect_up_axis(points: np.ndarray, head: int, feet) -> str:
    """Guess the world up axis from key points ``(F, K, 3)``.

    The signed axis closest to the mean of head minus feet over all frames,
    e.g. ``"y"`` or ``"z"`` (or ``"-y"``).
    """
    pts = np.asarray(points, dtype=float)
    v = (pts[:, head] - pts[:, list(np.atleast_1d(feet))].mean(axis=1)).mean(axis=0)
    k = int(np.argmax(np.abs(v)))
    return ("" if v[k] >= 0 else "-") + "xyz"[k]


def smooth_linear(x: np.ndarray, window: int) -> np.ndarray:
    """Smooth along axis 0, reproducing straight lines exactly.

    The clip's least-squares line (per column) is kept; the residual about
    it is replaced by its centred moving average over ``window`` samples, and
    within half a window of either end by the average of the first / last
    full window.  So constant-velocity travel and constant-rate turning pass
    through unchanged, and a periodic swing (a pelvis turning with each
    stride, a sway about the path) averages out everywhere, ends included (a
    plain moving average with edge padding, or a Savitzky-Golay line fit at
    the ends, would turn half a stride of swing into a bias or a slope there).
    ``window`` is clipped to the largest odd number <= len(x); below 3 the
    input is returned unchanged.  Shapes: ``(n, ...)`` -> ``(n, ...)``.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    w = min(int(window), n)
    if w % 2 == 0:
        w -= 1
    if w < 3:
        return x.copy()
    flat = x.reshape(n, -1)
    t = np.arange(n, dtype=float)
    A = np.stack([np.ones(n), t - t.mean()], axis=1)
    coef, *_ = np.linalg.lstsq(A, flat, rcond=None)
    trend = A @ coef
    r = flat - trend
    c = np.concatenate([np.zeros((1, r.shape[1])), np.cumsum(r, axis=0)])
    full = (c[w:] - c[:-w]) / w                   # mean of r[i:i+w], centred at i + h
    h = w // 2
    sm = np.concatenate([np.repeat(full[:1], h, axis=0), full, np.repeat(full[-1:], h, axis=0)])
    return (trend + sm).reshape(x.shape)


@dataclass
class Projection:
    """Result of :func:`project`.

    xy : ``(F, K, 2)`` image coordinates, x to the right, y down, in the
        BVH's units (orthographic, no scaling).
    depth : ``(F, K)`` camera-space z: distance along the viewing direction,
        larger is farther from the camera (same units).
    yaw : ``(F,)`` degrees each frame was turned about the vertical axis by
        facing normalisation (zeros without it).
    travel : ``(F, 2)`` horizontal root position (world x, z after up
        alignment) that was subtracted (zeros without centring).
    """

    xy: np.ndarray
    depth: np.ndarray
    yaw: np.ndarray
    travel: np.ndarray


def project(points: np.ndarray, azimuth: float = 0.0, elevation: float = 0.0, up="y",
            facing: str = "none", across: tuple[int, ...] | None = None, root: int | None = None,
            center: bool = False, window: int = 31) -> Projection:
    """Orthographic projection of 3D points to image coordinates.

    Parameters
    ----------
    points : ``(F, K, 3)`` world positions (file units).
    azimuth, elevation : degrees.  The camera looks at the origin from
        direction ``(sin az cos el, sin el, cos az cos el)`` in the Y-up
        frame.  ``0, 0`` is the front view: looking along -z, so a
        character facing +z (the BVH convention, and what facing
        normalisation produces) faces the camera and its left side appears
        on the image's right.  ``azimuth=90`` views its left side.
    up : the world up axis, ``"y"`` (BVH default), ``"z"``, ``"-y"``, … or a
        3-vector; points are first turned so that it becomes +y.
    facing : ``"none"``, ``"first"`` or ``"normalise"``.  ``"first"`` turns
        the whole clip once, about the vertical axis through the root's first
        position, so that the body faces +z at the start (its heading over
        the first ``window`` frames): turning within the clip is kept, only
        the clip's initial orientation is removed.  ``"normalise"`` turns every frame
        about the vertical axis through the root so that the body faces +z.
        The facing direction is ``(left - right) x up`` of the ``across``
        pairs (e.g. hips and shoulders), smoothed over ``window`` frames
        (unwrapped angle, :func:`smooth_linear`) so that turning and walking
        in circles are removed but the pelvis' swing within a stride is kept.
        ``window=1`` normalises every frame exactly.
    across : indices ``(left_1, right_1, left_2, right_2, ...)`` into K of
        left/right pairs; required for facing normalisation.
    root : index of the root point (pelvis); required for ``center`` and used
        as the pivot of facing normalisation (else the origin).
    center : subtract the root's horizontal travel, smoothed over ``window``
        frames, from every point (vertical motion such as a jump is kept, and
        so is the sway about the path).  ``window=1`` pins the root exactly.

    Returns
    -------
    :class:`Projection`
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 3 or P.shape[-1] != 3:
        raise ValueError(f"points must be (frames, points, 3), got {P.shape}")
    F = P.shape[0]
    P = P @ up_rotation(up).T
    travel = np.zeros((F, 2))
    if root is not None:
        pivot = smooth_linear(P[:, root][:, [0, 2]], window)
    else:
        pivot = np.zeros((F, 2))
    yaw = np.zeros(F)
    if facing not in ("none", "first", "normalise", "normalize"):
        raise ValueError(f"facing must be 'none', 'first' or 'normalise', got {facing!r}")
    if facing != "none":
        if not across or len(across) % 2:
            raise ValueError("facing normalisation needs left/right index pairs in `across`")
        lr = np.asarray(across).reshape(-1, 2)
        d = (P[:, lr[:, 0]] - P[:, lr[:, 1]]).sum(axis=1)   # (F, 3) summed left-minus-right
        # forward = d x (0,1,0) = (-d_z, 0, d_x); heading angle from +z toward +x
        theta = np.unwrap(np.arctan2(-d[:, 2], d[:, 0]))
        if facing == "first":
            # One turn for the whole clip (the heading of its first frames, the
            # pelvis' swing averaged out) about the root's first position:
            # a turn within the clip stays a turn.
            theta = np.full(F, theta[:max(min(int(window), F), 1)].mean())
            pivot = np.broadcast_to(pivot[0], pivot.shape)
        else:
            theta = smooth_linear(theta, window)
        yaw = -np.rad2deg(theta)  # per frame; constant with "first"
        c, s = np.cos(-theta), np.sin(-theta)
        hx = P[..., 0] - pivot[:, None, 0]
        hz = P[..., 2] - pivot[:, None, 1]
        P = P.copy()
        # rotation about y by phi = -theta: x' = x c + z s, z' = -x s + z c
        P[..., 0] = hx * c[:, None] + hz * s[:, None] + pivot[:, None, 0]
        P[..., 2] = -hx * s[:, None] + hz * c[:, None] + pivot[:, None, 1]
        if facing == "first" and root is not None:
            # The root's path turned with the clip: centre on the turned path.
            pivot = smooth_linear(P[:, root][:, [0, 2]], window)
    if center:
        if root is None:
            raise ValueError("center=True needs the root index")
        travel = pivot
        P = P.copy()
        P[..., 0] -= travel[:, None, 0]
        P[..., 2] -= travel[:, None, 1]
    az, el = np.deg2rad(azimuth), np.deg2rad(elevation)
    d = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])  # towards camera
    r = np.array([np.cos(az), 0.0, -np.sin(az)])                                  # image right
    u = np.cross(d, r)                                                           # image up
    xy = np.stack([P @ r, -(P @ u)], axis=-1)
    depth = -(P @ d)
    return Projection(xy=xy, depth=depth, yaw=yaw, travel=travel)


def resample_times(n_frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """Sample times (in source frames) for resampling ``n_frames`` to ``dst_fps``.

    The clip's duration ``(n-1)/src_fps`` is covered by ``m = round(duration
    * dst_fps) + 1`` evenly spaced samples that include both end frames, so
    the output rate is ``dst_fps`` to within half a frame over the clip
    (30 -> 15 fps on 129 frames gives exactly every other frame, 65 frames).
    """
    if not (src_fps > 0 and dst_fps > 0):
        raise ValueError("frame rates must be positive")
    if n_frames < 2:
        return np.zeros(max(n_frames, 0))
    duration = (n_frames - 1) / src_fps
    m = max(int(np.floor(duration * dst_fps + 0.5)) + 1, 2)
    return np.linspace(0.0, n_frames - 1, m)


def resample(x: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Resample per-frame data ``(F, ...)`` from ``src_fps`` to ``dst_fps``.

    Linear interpolation of positions between neighbouring frames (of
    positions, not joint angles: it needs no care with Euler angle wrap, and
    at 30 fps source rates the chord shortening of a rotating bone between
    two samples is negligible).  Both end frames are kept; see
    :func:`resample_times` for the frame count.  Returns ``(M, ...)``.
    """
    x = np.asarray(x, dtype=np.float64)
    if abs(src_fps - dst_fps) < 1e-9 * src_fps:
        return x.copy()
    t = resample_times(x.shape[0], src_fps, dst_fps)
    i0 = np.clip(np.floor(t).astype(np.int64), 0, max(x.shape[0] - 2, 0))
    w = (t - i0).reshape((-1,) + (1,) * (x.ndim - 1))
    i1 = np.minimum(i0 + 1, x.shape[0] - 1)
    return (1.0 - w) * x[i0] + w * x[i1]
