"""Named camera views for projecting 3D motion, and the automatic choice of one.

A view is an azimuth about the vertical axis, applied after facing
normalisation (:func:`nnsf.datasets.projection.project`), so it is relative to the
body: ``front`` looks at the chest (azimuth 0°), ``side`` at the body's left
side (90°), ``three-quarter`` half-way between (45°).

``auto`` picks the view in which the motion moves most: the body-frame
horizontal direction of largest variance of the joints about their mean
positions over time (the first principal direction of the motion in the
ground plane).  A walk swings the legs forwards and backwards, so it reads
from the side; a wave moves the hand across the body, so it reads from the
front.  Of the three named views, the one whose image-right axis captures most
of that variance wins (ties go to the earlier of front, side, three-quarter).
"""
from __future__ import annotations

import numpy as np

from nnsf.errors import InputError
from nnsf.params import VIEW_CHOICES  # the accepted values of dataset.bvh.view and --view
from nnsf.datasets.projection import project
from nnsf.datasets.bvh_source import FACING_PAIRS, load_clip
from nnsf.skeleton.layout import JOINT_INDEX

#: Named views and their azimuths, degrees.
VIEWS: dict[str, float] = {"front": 0.0, "side": 90.0, "three-quarter": 45.0}


def check_view(view, source="--view", field: str = "view") -> str:
    """``view`` if it is one of :data:`VIEW_CHOICES`, else an :class:`InputError`."""
    if view not in VIEW_CHOICES:
        raise InputError(source, field, "one of " + ", ".join(VIEW_CHOICES), view)
    return str(view)


def azimuth_of(view: str) -> float:
    """Azimuth in degrees of a named view (not ``auto``)."""
    return VIEWS[check_view(view)] if view != "auto" else _auto_error()


def _auto_error():
    raise ValueError("azimuth_of('auto'): use pick_view() on the motion first")


def view_variances(front_xy: np.ndarray, front_depth: np.ndarray) -> dict[str, float]:
    """Motion variance seen by each named view, from the front projection.

    Parameters
    ----------
    front_xy : ``(F, K, 2)`` the facing-normalised front view (azimuth 0,
        elevation 0) of a clip, image x right, y down.
    front_depth : ``(F, K)`` its camera depth (``-z`` in the body frame).

    Returns
    -------
    ``{view: variance}``: the variance over time of every joint's image
    position about its mean, summed over joints and both image axes, for each
    view of :data:`VIEWS` (units²).  With elevation 0 the image x of azimuth
    ``a`` is ``x cos a + depth sin a`` and image y does not change.
    """
    xy = np.asarray(front_xy, dtype=float)
    d = np.asarray(front_depth, dtype=float)
    x = xy[..., 0] - xy[..., 0].mean(axis=0)
    z = d - d.mean(axis=0)
    vy = float(np.var(xy[..., 1], axis=0).sum())
    out = {}
    for name, az in VIEWS.items():
        a = np.deg2rad(az)
        out[name] = float(np.mean((x * np.cos(a) + z * np.sin(a)) ** 2, axis=0).sum()) + vy
    return out


def pick_view(front_xy: np.ndarray, front_depth: np.ndarray) -> str:
    """The named view in which the clip moves most (module docstring)."""
    var = view_variances(front_xy, front_depth)
    return max(VIEWS, key=lambda v: (var[v], -list(VIEWS).index(v)))


def resolve_view(view: str, front_xy=None, front_depth=None) -> tuple[str, float]:
    """``(view name, azimuth)``; ``auto`` needs the front projection (see :func:`pick_view`)."""
    view = check_view(view)
    if view == "auto":
        if front_xy is None or front_depth is None:
            raise ValueError("resolve_view('auto') needs the front projection and its depth")
        view = pick_view(front_xy, front_depth)
    return view, VIEWS[view]


def load_clip_in_view(path, view: str = "auto", fps: float | None = 30, elevation: float = 0.0,
                      facing: str = "normalise", center: bool = True, family=None):
    """Read a BVH file and project it in ``view``; returns ``(BVHClip, view name)``.

    ``auto`` first projects the front view to measure the motion
    (:func:`pick_view`), then projects again in the chosen view (one file
    read: the second projection reuses the 3D key points).
    """
    view = check_view(view)
    azimuth = 0.0 if view == "auto" else VIEWS[view]
    clip = load_clip(path, fps=fps, azimuth=azimuth, elevation=elevation if view != "auto" else 0.0,
                     facing=facing, center=center, family=family)
    if view != "auto":
        return clip, view
    view = pick_view(clip.points, clip.depth)
    if VIEWS[view] == 0.0 and elevation == 0.0:
        return clip, view
    win = max(int(round(clip.fps)), 1)
    # clip.points3d is already Y-up: project about +y.
    proj = project(clip.points3d, azimuth=VIEWS[view], elevation=elevation, up="y", facing=facing,
                   across=FACING_PAIRS, root=JOINT_INDEX["pelvis"], center=center, window=win)
    clip.points, clip.depth, clip.yaw = proj.xy, proj.depth, proj.yaw
    return clip, view
