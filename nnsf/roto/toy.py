"""Tiny analytic test clips: filled polygons with dark outlines on a plain background.

Used by the tests and as a fallback benchmark input; the renderer of
:mod:`nnsf.frames` is the real source of tracking clips.  Polygon edges are
drawn anti-aliased with sub-pixel vertices, so each edge is known exactly.
"""
from __future__ import annotations

import cv2
import numpy as np

_SHIFT = 4  # cv2 sub-pixel bits


def draw_polygons(size: tuple[int, int], polygons: list[np.ndarray], fills: list[tuple],
                  background=(235, 235, 228), outline=(25, 25, 30), thickness: int = 2) -> np.ndarray:
    """One RGB frame (H, W, 3) uint8 with filled, outlined polygons drawn in order.

    size : (width, height); polygons : list of (V, 2) vertex arrays (px).
    """
    W, H = size
    img = np.empty((H, W, 3), np.uint8)
    img[:] = background
    for poly, fill in zip(polygons, fills):
        pts = np.round(np.asarray(poly, np.float64) * (1 << _SHIFT)).astype(np.int32)
        cv2.fillPoly(img, [pts], fill, lineType=cv2.LINE_AA, shift=_SHIFT)
        if thickness > 0:
            cv2.polylines(img, [pts], True, outline, thickness, lineType=cv2.LINE_AA, shift=_SHIFT)
    return img


def rect(cx: float, cy: float, w: float, h: float, angle: float = 0.0) -> np.ndarray:
    """Corners (4, 2) of a rectangle centred at (cx, cy), rotated by ``angle`` rad,
    in the order top-left, top-right, bottom-right, bottom-left (before rotation)."""
    c = np.array([[-w / 2, -h / 2], [w / 2, -h / 2], [w / 2, h / 2], [-w / 2, h / 2]])
    R = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    return c @ R.T + [cx, cy]


def segment_controls(p: np.ndarray, q: np.ndarray, n_control: int) -> np.ndarray:
    """``n_control`` equally spaced control points from p to q: (n_control, 2)."""
    lam = np.linspace(0, 1, n_control)[:, None]
    return (1 - lam) * np.asarray(p, float) + lam * np.asarray(q, float)
