"""A puppet piece's triangles: a mesh that covers the piece's pixels, re-meshed finer when it does not.

Split from :mod:`nnsf.reshape.pieces` (which builds the whole pieced mesh) because it is
the one step of it that only needs :mod:`nnsf.reshape.mesh`'s triangulation.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import QhullError

from nnsf.reshape import mesh as meshmod


#: A piece's triangles must cover this share of its region's pixels at rest, or it is re-meshed
#: finer (:func:`triangulate_region`).  A plain triangulation loses 5-11 % of a small piece's
#: pixels along its outline's staircase (the Kenney sprites' limbs); a piece below 80 % has lost a
#: part of itself (char2's left upper arm: all of it).
COVER = 0.8


def covered_share(region: np.ndarray, vertices: np.ndarray, triangles: np.ndarray) -> float:
    """The share of ``region``'s pixels ``(H, W)`` bool that the triangles, filled at rest, cover."""
    n = int(np.count_nonzero(region))
    if n == 0:
        return 1.0
    img = np.zeros(region.shape, np.uint8)
    if len(triangles):
        cv2.fillPoly(img, list(np.rint(vertices[triangles]).astype(np.int32)), 1)
    return float(np.count_nonzero(region & img.astype(bool))) / n


def triangulate_region(region, spacing, args, cover: float = COVER, retry: bool = True):
    """``(vertices, triangles)`` of a piece's mask, or None when it is too small (under 6 px) or
    nothing can be meshed.

    Tried at ``spacing`` px with ``args`` first.  A thin piece (a stick figure's upper arm, a few
    pixels wide and drawn at a slant) can lose every triangle to the sliver test, or keep only one
    island of them: the polygon simplification turns its pixel staircase into a few long edges
    whose Delaunay triangles are all slivers.  While the triangles cover less than ``cover`` of the
    region's pixels, the spacing shrinks (× 0.75, down to 2 px), then the outline is kept closer to
    the pixels (simplification 0.5 px), then slivers down to 5° are allowed; the best-covering mesh
    is kept.  A piece silently left without triangles is not drawn at all (AnimatedDrawings'
    char2: its left upper arm, so the forearm floated beside the body).  ``retry=False``: the
    first attempt only (None when it fails).
    """
    if region.sum() < 6:
        return None
    variants = [dict(args), dict(args, simplify=min(args.get("simplify", 0.75), 0.5)),
                dict(args, simplify=min(args.get("simplify", 0.75), 0.5), min_angle=min(args.get("min_angle", 15.0), 5.0))]
    best, best_share = None, -1.0
    for kw in variants:
        h = spacing  # as given (the first attempt must be the plain triangulation's, to the bit)
        while True:
            try:
                v, t, _ = meshmod._triangulate_at(region, h, **kw)
            except (ValueError, IndexError, QhullError):  # every triangle dropped, or too few points
                v, t = None, np.zeros((0, 3), np.int64)
            if v is not None and len(t):
                share = covered_share(region, v, t)
                if share > best_share:
                    best, best_share = (v, t), share
                if share >= cover:
                    return best
            if h <= 2.0 or not retry:
                break
            h = max(0.75 * h, 2.0)
        if not retry:
            break
    return best
