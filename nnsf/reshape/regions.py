"""The drawn regions of a character: what the ink outlines, and which of it is the body's.

A drawing's ink lines bound regions (:func:`drawn_regions`); a region that
contains the body's spine and no limb bone is the body's
(:func:`body_region_triangles`), and :func:`body_line` / :func:`ink_rim_triangles`
give the body's own drawn outline, so a limb drawn over the chest is not
meshed as chest.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.mesh import _lookup
from nnsf.skeleton import JOINT_INDEX, LIMBS

def drawn_regions(texture: np.ndarray, mask: np.ndarray, ink: float = 0.55, min_area: float = 0.002) -> np.ndarray:
    """Ink-bounded regions of a drawing: a label ``(H, W)`` int, −1 outside ``mask``.

    Ink is a pixel darker than ``ink`` × the median luminance of the mask;
    the regions are the connected components (4-neighbour) of the rest of
    the mask with at least ``min_area`` × the mask's area; every other mask
    pixel (ink, specks) takes the label of the nearest region pixel, so a
    line between two regions is split down its middle.
    """
    from scipy.ndimage import distance_transform_edt

    m = np.asarray(mask, dtype=bool)
    out = np.full(m.shape, -1, np.int64)
    if not m.any():
        return out
    fill = m & ~ink_pixels(texture, m, ink)
    n, lab = cv2.connectedComponents(fill.astype(np.uint8), connectivity=4)
    area = np.bincount(lab.ravel(), minlength=n)
    big = np.flatnonzero(area >= max(min_area * m.sum(), 1))
    big = big[big > 0]
    if len(big) == 0:
        out[m] = 0
        return out
    keep = np.isin(lab, big)
    _, (iy, ix) = distance_transform_edt(~keep, return_indices=True)
    out[m] = lab[iy[m], ix[m]]
    return out


def body_region_triangles(vertices, triangles, keypoints, texture, mask, pixels: bool = False) -> np.ndarray:
    """Triangles ``(t,)`` that lie in a region of the drawing (:func:`drawn_regions`) that is the body's only.

    A region is the body's when it holds a point of the spine or neck
    (pelvis–spine–thorax–neck, sampled), and a limb's when it holds a point of
    the limb's outer bone (upper segment λ ∈ [0.6, 0.95], lower segment
    λ ∈ [0.1, 0.9]).  A region that is both (a limb not separated from the
    body by a line, as in many sketches) says nothing and is not returned.
    ``pixels``: return the pixels ``(H, W)`` of those regions instead.
    """
    kp = np.asarray(keypoints, dtype=np.float64)
    lab = drawn_regions(texture, mask)
    J = JOINT_INDEX

    def regions_along(a, b, lo, hi):
        lam = np.linspace(lo, hi, 9)[:, None]
        pts = kp[a] + lam * (kp[b] - kp[a])
        r = _lookup(lab, pts)
        return set(r[_lookup(np.asarray(mask, np.uint8), pts) > 0].tolist()) - {-1}

    body = set()
    for a, b in (("pelvis", "spine"), ("spine", "thorax"), ("thorax", "neck")):
        body |= regions_along(J[a], J[b], 0.0, 1.0)
    limb = set()
    for name, (a, b) in LIMBS.items():
        upper = "upper" in name or "thigh" in name
        limb |= regions_along(a, b, *((0.6, 0.95) if upper else (0.1, 0.9)))
    only_body = np.array(sorted(body - limb), dtype=np.int64)
    if pixels:
        return np.isin(lab, only_body)
    c = np.asarray(vertices)[np.asarray(triangles)].mean(axis=1)
    return np.isin(_lookup(lab, c), only_body)


def ink_pixels(texture, mask, ink: float = 0.55) -> np.ndarray:
    """Ink of a drawing ``(H, W)`` bool: mask pixels darker than ``ink`` × the mask's median luminance."""
    m = np.asarray(mask, dtype=bool)
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    return m & (lum < ink * np.median(lum[m])) if m.any() else m.copy()


def body_line(keypoints, texture, mask, ink: float = 0.55) -> np.ndarray:
    """The body's drawing with its own outline, ``(H, W)`` bool.

    The body's drawn regions (:func:`body_region_triangles`) plus the ink
    within one line width of them; the width is twice the ink's typical
    (90th percentile) medial distance, plus a pixel.  :func:`drawn_regions`
    splits a line between the body and a limb down its middle, so without
    this the limb would take the outer half of the body's outline.
    """
    m = np.asarray(mask, dtype=bool)
    body = body_region_triangles(None, None, keypoints, texture, m, pixels=True)
    dark = ink_pixels(texture, m, ink)
    if not dark.any() or not body.any():
        return body
    dist = cv2.distanceTransform(np.pad(dark.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    width = 2.0 * float(np.percentile(dist[dark], 90)) + 1.0
    near = cv2.distanceTransform((~body).astype(np.uint8), cv2.DIST_L2, 3) <= width
    return body | (dark & near)


def ink_rim_triangles(vertices, triangles, body_triangles, keypoints, texture, mask) -> np.ndarray:
    """Triangles ``(t,)`` not in ``body_triangles`` that cover a pixel of the body's outline (:func:`body_line`).

    :func:`layer_pieces` gives the body a copy of those a limb owns, textured
    with :func:`body_line` only (``Mesh.layer`` 2), so a limb swung away
    leaves the body outlined instead of notched.
    """
    tri = np.asarray(triangles)
    bt = np.asarray(body_triangles, dtype=bool)
    line = body_line(keypoints, texture, mask)
    owner = np.full(line.shape, -1, np.int32)
    V = np.rint(np.asarray(vertices)).astype(np.int32)
    for k in np.flatnonzero(~bt):
        cv2.fillPoly(owner, [V[tri[k]]], int(k))
    out = np.zeros(len(tri), dtype=bool)
    out[owner[line & (owner >= 0)]] = True  # owners are non-body triangles only
    return out
