"""``nnsf bvh-info FILE``: what the project makes of a BVH file, before anything is rendered.

:func:`bvh_info` reads the file and reports, as lines of text: its
hierarchy (joints, channels, End Sites), frame count, rate and duration,
the skeleton family detected and its score (with the runners-up), how the
17 key points are made from its joints, the up axis, and the named view the
motion moves most in (:func:`nnsf.datasets.views.view_variances`).  When no
family fits, the lines say so and :class:`~nnsf.errors.InputError` carries
the one-line reason, which the command prints last.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nnsf.datasets import views
from nnsf.datasets.bvh import read_bvh
from nnsf.datasets.bvh_detect import choose_family, rank_families
from nnsf.datasets.bvh_skeletons import SkeletonFamily, mapping_text
from nnsf.datasets.bvh_source import load_clip
from nnsf.datasets.joint_map import check_joint_map
from nnsf.errors import InputError

__all__ = ["BVHInfo", "bvh_info"]

#: Depth of the hierarchy printed (deeper joints, e.g. finger tips, are counted, not listed).
MAX_DEPTH_SHOWN = 12
#: Joints listed at most (a skeleton with fingers and face bones has a few hundred).
MAX_JOINTS_SHOWN = 400


@dataclass
class BVHInfo:
    """The report: ``lines`` to print, and ``error`` (None when the file can be used)."""

    lines: list[str] = field(default_factory=list)
    family: str | None = None
    view: str | None = None
    error: InputError | None = None


def _hierarchy(bvh) -> list[str]:
    depth = np.zeros(len(bvh.names), dtype=int)
    for j, p in enumerate(bvh.parents):
        depth[j] = 0 if p < 0 else depth[p] + 1
    parents = np.asarray(bvh.parents)
    ends_of = np.bincount(parents[bvh.is_end_site & (parents >= 0)], minlength=len(bvh.names))
    out, hidden = [], 0
    for j, name in enumerate(bvh.names):
        if bvh.is_end_site[j]:
            continue
        if depth[j] > MAX_DEPTH_SHOWN or len(out) >= MAX_JOINTS_SHOWN:
            hidden += 1
            continue
        ends = ends_of[j]
        chans = len(bvh.channels[j])
        out.append(f"  {'  ' * depth[j]}{name}  [{chans} channel{'s' if chans != 1 else ''}"
                   + (", End Site" if ends else "") + "]")
    if hidden:
        out.append(f"  ({hidden} joints deeper than {MAX_DEPTH_SHOWN} levels or beyond the first "
                   f"{MAX_JOINTS_SHOWN} not shown)")
    return out


def bvh_info(path, joint_map: SkeletonFamily | None = None, fps: float = 30.0) -> BVHInfo:
    """Describe a BVH file (module docstring).  Raises :class:`InputError` only when the file
    cannot be parsed; a skeleton no family fits is reported in ``error``."""
    path = Path(path)
    bvh = read_bvh(path)
    info = BVHInfo()
    L = info.lines
    n_joints = int((~bvh.is_end_site).sum())
    duration = (bvh.n_frames - 1) / bvh.fps
    L.append(f"file: {path}")
    L.append(f"frames: {bvh.n_frames} at {bvh.fps:g} fps (Frame Time {bvh.frame_time:g} s), "
             f"{duration:.2f} s")
    L += [f"note: {n}" for n in bvh.notes]
    L.append(f"hierarchy: {n_joints} joints, {int(bvh.is_end_site.sum())} End Sites, "
             f"{len(bvh.channel_node)} channels")
    L += _hierarchy(bvh)
    ranked = rank_families(bvh.names, bvh.site_kinds)
    L.append("families by joint names (score 0..1, key points mapped of 17):")
    L += [f"  {m.family.name:18s} {m.score:.2f}  {m.mapped:2d}/17" for m in ranked[:5]]
    try:
        if joint_map is not None:
            check_joint_map(joint_map, bvh.names, path, bvh.site_kinds)
            fam = joint_map
            L.append(f"family: {fam.name} ({fam.description}, from --joint-map)")
        else:
            fam = choose_family(ranked, path)
            L.append(f"family: {fam.name}, score {ranked[0].score:.2f} ({fam.description})")
    except InputError as exc:
        L.append("family: none (below)")
        info.error = exc
        return info
    info.family = fam.name
    L.append("key points:")
    L += [f"  {kp:10s} {rule}" for kp, rule in mapping_text(fam, bvh.names, bvh.site_kinds).items()]
    try:
        clip = load_clip(path, fps=fps, family=fam)
    except InputError as exc:
        info.error = exc
        return info
    L += [f"note: {n}" for n in clip.notes if n not in bvh.notes]
    var = views.view_variances(clip.points, clip.depth)
    info.view = views.pick_view(clip.points, clip.depth)
    L.append(f"up axis: {clip.up}")
    total = sum(var.values())
    L.append("motion seen per view (share of the summed variance): " + ", ".join(
        f"{v} {var[v] / total:.2f}" if total > 0 else f"{v} 0" for v in views.VIEWS))
    L.append(f"view: {info.view} (the motion moves most in it; `nnsf animate --view auto` picks it)")
    return info
