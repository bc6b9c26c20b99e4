"""Rigid motions of 2-D point sets: the least-squares fit between two placements, and rotations.

Used by the tracker (a limb's rigid motion between frames, :mod:`nnsf.roto.limbs`).
"""
from __future__ import annotations

import numpy as np


def rigid_fit(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation R (2, 2) and translation t with ``dst ≈ src @ R.T + t``.

    Hand-written because OpenCV's ``estimateAffinePartial2D`` also fits a
    scale (a limb does not grow between frames) and samples with RANSAC; in
    2-D the problem has a closed form, the angle of the cross-covariance.
    """
    ms, md = src.mean(0), dst.mean(0)
    H = (src - ms).T @ (dst - md)
    th = np.arctan2(H[0, 1] - H[1, 0], H[0, 0] + H[1, 1])
    R = rotation(th)
    return R, md - ms @ R.T


def rotation(th) -> np.ndarray:
    """Rotation matrices (..., 2, 2) of angles ``th`` (rad)."""
    c, s = np.cos(th), np.sin(th)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)
