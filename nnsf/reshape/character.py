"""A drawn character: its texture, its silhouette, its 17 key points and per-character choices.

Reading a drawing goes through the checks of this module, whatever the format
(:mod:`nnsf.reshape.formats` reads the formats):

* **Image size** (:func:`read_image`): a PNG's header is read before the image is decoded, and a
  drawing over :data:`DECODE_LIMIT` pixels is refused in one line; one over ``max_size``
  megapixels (default :data:`MAX_SIZE`, ``--max-size``) is downscaled to it, with a note, so the
  mesh, the deformation and every frame stay in proportion to what a screen shows.
* **Mask from the border colour** (:func:`mask_from_border`, ``--mask auto``): for a drawing on
  plain paper with no alpha channel.
* **Joints** (:func:`snap_joints`): a key point a few pixels off the drawing (a pose estimator's
  usual error) is moved to the nearest drawn pixel when it is within :data:`SNAP_SHARE` of the
  figure's height, with a note; one farther out is refused, naming the joint and the distance.
* **One silhouette**: the mask's largest 4-connected component is kept, with a note saying what was
  dropped: specks of stray ink, and pieces touching it at a pixel's corner only (no resampled frame
  keeps a zero-width link: they floated beside the body).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from nnsf.errors import InputError
from nnsf.io import MAX_IMAGE_PIXELS, read_image as io_read_image
from nnsf.skeleton import JOINTS, N_JOINTS

#: What a character's skeleton stands on (:attr:`Character.body`).
BODIES = ("biped", "quadruped")
#: A key point off the drawing by at most this share of the figure's height is moved onto it.
SNAP_SHARE = 0.05
#: Drawings over this many megapixels are downscaled to it (``--max-size``).
MAX_SIZE = 4.0
#: Images over this many pixels are refused before they are decoded (400 MB as RGBA).
DECODE_LIMIT = MAX_IMAGE_PIXELS


@dataclass
class Character:
    """A drawn character at rest.

    Attributes
    ----------
    name : str
    texture : ``(H, W, 4)`` uint8 RGBA (RGB order).
    mask : ``(H, W)`` bool, the silhouette: one 4-connected component.
    keypoints : ``(17, 2)`` float64 rest key points in :data:`nnsf.skeleton.JOINTS` order, pixels
        ``(x, y)``, origin at the top-left pixel's centre.
    source : where it was read from (for messages); notes : what the reader changed or chose.
    body : ``"biped"`` or ``"quadruped"`` (hind legs our legs, front legs our arms).
    extra_limbs : arms beyond the two the skeleton drives, ``[{"side": "l" | "r", "joints": (3, 2)}]``
        (shoulder, elbow, hand); each turns as the driven arm of its side.
    arms, head, legs : the character's own choice of :func:`nnsf.reshape.drive.retarget`'s ``arms``
        (``motion`` | ``drawing``), ``head`` and ``legs`` (``motion`` | ``torso``), or None (the caller's;
        legs: ``motion``).
    depth : parts always drawn over others, ``[(over parts, under parts)]`` (ids).
    facing : ``left`` | ``right``: which way a figure drawn from the side faces, or None (found from
        the drawing, :func:`nnsf.reshape.drive.biped_facing`).
    """

    name: str
    texture: np.ndarray
    mask: np.ndarray
    keypoints: np.ndarray
    source: str = "<memory>"
    notes: list[str] = field(default_factory=list)
    body: str = "biped"
    extra_limbs: list = field(default_factory=list)
    arms: str | None = None
    head: str | None = None
    legs: str | None = None
    depth: list = field(default_factory=list)
    facing: str | None = None

    def __post_init__(self):
        self.texture = np.asarray(self.texture)
        self.mask = np.asarray(self.mask, dtype=bool)
        self.keypoints = np.asarray(self.keypoints, dtype=np.float64)
        validate(self)

    @property
    def shape(self) -> tuple[int, int]:
        """Image size ``(H, W)`` in pixels."""
        return self.mask.shape


def validate(ch: Character) -> None:
    """Raise :class:`InputError` naming ``ch.source`` and the field if ``ch`` is unusable."""
    src = ch.source
    if ch.body not in BODIES:
        raise InputError(src, "body", " or ".join(BODIES), ch.body)
    if ch.texture.ndim != 3 or ch.texture.shape[2] != 4 or ch.texture.dtype != np.uint8:
        raise InputError(src, "texture", "an (H, W, 4) uint8 RGBA image",
                         f"{ch.texture.dtype} array of shape {ch.texture.shape}")
    if ch.mask.ndim != 2 or ch.texture.shape[:2] != ch.mask.shape:
        raise InputError(src, "mask", f"an image the texture's size {ch.texture.shape[1]}x{ch.texture.shape[0]}",
                         f"shape {ch.mask.shape}")
    if not ch.mask.any():
        raise InputError(src, "mask", "a silhouette with at least one foreground pixel", "an empty mask")
    if ch.keypoints.shape != (N_JOINTS, 2):
        raise InputError(src, "keypoints", f"{N_JOINTS} (x, y) points", f"shape {ch.keypoints.shape}")
    bad = ~np.isfinite(ch.keypoints).all(axis=1)
    if bad.any():
        raise InputError(src, f"keypoints.{JOINTS[np.flatnonzero(bad)[0]]}", "finite pixel coordinates",
                         ch.keypoints[bad][0].tolist())
    inside = points_in_mask(ch.mask, ch.keypoints)
    if not inside.all():
        j = int(np.flatnonzero(~inside)[0])
        raise InputError(src, f"keypoints.{JOINTS[j]}", "a point inside the mask",
                         [round(float(v), 2) for v in ch.keypoints[j]])


def points_in_mask(mask: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Whether each point ``(..., 2)`` (pixels) falls on a foreground pixel (nearest pixel)."""
    pts = np.rint(np.asarray(points, dtype=float)).astype(np.int64)
    h, w = mask.shape
    ok = (pts[..., 0] >= 0) & (pts[..., 0] < w) & (pts[..., 1] >= 0) & (pts[..., 1] < h)
    out = np.zeros(pts.shape[:-1], dtype=bool)
    out[ok] = mask[pts[ok][:, 1], pts[ok][:, 0]]
    return out


def snap_joints(mask: np.ndarray, points: dict, source, field: str = "joints.{}") -> tuple[dict, list[str]]:
    """Joints ``{name: (2,) px}`` on the drawing: each off the mask by at most :data:`SNAP_SHARE` of the
    figure's height moves to the nearest mask pixel (a note says so); farther is an :class:`InputError`
    naming the joint (``field`` with the name filled in) and the distance."""
    rows = np.flatnonzero(mask.any(axis=1))
    reach = SNAP_SHARE * float(rows[-1] - rows[0] + 1)
    _, labels = cv2.distanceTransformWithLabels((~mask).astype(np.uint8), cv2.DIST_L2, cv2.DIST_MASK_PRECISE,
                                                labelType=cv2.DIST_LABEL_PIXEL)
    ys, xs = np.nonzero(mask)
    where = np.zeros((labels.max() + 1, 2))
    where[labels[ys, xs]] = np.column_stack([xs, ys])
    out, notes = {}, []
    H, W = mask.shape
    for name, p in points.items():
        p = np.asarray(p, dtype=np.float64)
        if points_in_mask(mask, p):
            out[name] = p
            continue
        x, y = np.clip(np.rint(p), 0, [W - 1, H - 1]).astype(int)
        target = where[labels[y, x]]
        d = float(np.linalg.norm(target - p))
        if d > reach:
            raise InputError(source, field.format(name), f"a point on the drawing or within {reach:.1f} px of it "
                             f"({100 * SNAP_SHARE:g} % of the figure's height)", f"{d:.1f} px outside it")
        out[name] = target
        notes.append(f"{source}: {field.format(name)} was {d:.1f} px off the drawing: moved onto its nearest pixel")
    return out, notes


def head_top_along(mask: np.ndarray, neck: np.ndarray, up: np.ndarray, share: float = 0.9) -> np.ndarray:
    """The head's top ``(2,)``: ``share`` of the way from ``neck`` along the unit direction ``up`` to where
    that ray leaves the mask (inside the silhouette, below stray hair tips)."""
    steps = np.arange(0.0, float(np.hypot(*mask.shape)), 0.5)
    inside = points_in_mask(mask, neck + steps[:, None] * up)
    exit_at = steps[np.argmin(inside)] if not inside.all() else steps[-1]
    return neck + share * exit_at * up


def largest_component(mask: np.ndarray, source="<memory>") -> tuple[np.ndarray, str | None]:
    """The largest 4-connected component of ``mask`` ``(H, W)`` and a note of what was dropped (or None)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=4)
    if n <= 2:
        return mask.astype(bool), None
    areas = stats[1:, cv2.CC_STAT_AREA]
    note = (f"{source}: mask: kept the largest of {n - 1} components ({areas.max()} px), "
            f"dropped {areas.sum() - areas.max()} px")
    return labels == 1 + int(np.argmax(areas)), note


# --------------------------------------------------------------------------- images

def read_image(path, source, field: str) -> np.ndarray:
    """An image file as OpenCV reads it (BGR[A], 8 bits; 16 bits are shifted down).

    :func:`nnsf.io.read_image` checks a PNG's whole structure and its size (at most
    :data:`DECODE_LIMIT` pixels) before any pixel is decoded.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(source, field, "an existing image file", str(path))
    img = io_read_image(path, field)
    if img.dtype == np.uint16:  # textures are only displayed: 8 bits
        img = (img >> 8).astype(np.uint8)
    if img.dtype != np.uint8:
        raise InputError(path, field, "an 8- or 16-bit image", str(img.dtype))
    return img


def to_rgba(img: np.ndarray) -> np.ndarray:
    """OpenCV's grey / BGR / BGRA → RGBA uint8."""
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2RGBA)
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGBA if img.shape[2] == 3 else cv2.COLOR_BGRA2RGBA)


def mask_image(img: np.ndarray) -> np.ndarray:
    """A mask image (grey, BGR, or BGRA whose alpha is the silhouette) → bool."""
    if img.ndim == 3:
        img = img[..., 3] if img.shape[2] == 4 else img.max(axis=2)
    return img > (img.max() // 2 if img.max() > 1 else 0)


def mask_from_border(rgba: np.ndarray) -> np.ndarray:
    """The silhouette of a drawing on plain paper ``(H, W, 4)``: what the paper does not reach from the border.

    The paper's colour is the median of the image's border pixels; a pixel is paper when it is within
    a threshold of it (Otsu's on the largest channel difference, at least 24 of 255).  Gaps in the
    outline up to 1 % of the image's size are closed first, so the paper does not flow into the figure
    through a broken line; the figure is then every pixel the border's paper does not reach.
    """
    rgb = rgba[..., :3].astype(np.int16)
    border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
    paper = np.median(border, axis=0)
    diff = np.abs(rgb - paper).max(axis=2).astype(np.uint8)
    thr, _ = cv2.threshold(diff, 0, 255, cv2.THRESH_BINARY | cv2.THRESH_OTSU)
    ink = (diff > max(24.0, thr)).astype(np.uint8)
    r = max(1, int(round(0.005 * max(rgba.shape[:2]))))
    closed = cv2.morphologyEx(ink, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2))
    _, labels = cv2.connectedComponents((closed == 0).astype(np.uint8), connectivity=4)
    edge = np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]]))
    return ~np.isin(labels, edge[edge > 0])


def downscale(texture: np.ndarray, mask: np.ndarray, points: np.ndarray, max_size: float, source):
    """``(texture, mask, points, note)`` scaled to at most ``max_size`` megapixels (note None if unchanged)."""
    H, W = mask.shape
    if max_size <= 0 or H * W <= max_size * 1e6:
        return texture, mask, points, None
    s = float(np.sqrt(max_size * 1e6 / (H * W)))
    size = (max(1, int(W * s)), max(1, int(H * s)))
    sx, sy = size[0] / W, size[1] / H
    tex = cv2.resize(texture, size, interpolation=cv2.INTER_AREA)
    m = cv2.resize(mask.astype(np.uint8) * 255, size, interpolation=cv2.INTER_AREA) >= 128
    pts = (np.asarray(points, dtype=np.float64) + 0.5) * [sx, sy] - 0.5
    note = (f"{source}: {W}x{H} px is over --max-size {max_size:g} megapixels: "
            f"downscaled to {size[0]}x{size[1]} px")
    return tex, m, pts, note

