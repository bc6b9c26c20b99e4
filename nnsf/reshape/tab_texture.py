"""What a joint tab shows: the limb's fill continued under its parent, and the drawn outline's band.

A tab (:func:`nnsf.reshape.pieces.tab_region`) is seen only where a joint
turns: in the wedge the bend opens.  It shows the limb's own fill continued
(OpenCV's Telea inpainting from the limb's pixels away from its lines), so a
limb swung away from the body takes no torso fill or torso ink with it,
except in the band of the drawn outline, where it shows the drawing.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.parts import SEGMENT_PART


def ink_mask(texture: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """The drawing's lines ``(H, W)`` bool: mask pixels darker than the midpoint of line and fill.

    Line luminance: the 5th percentile inside the mask; fill: the median.  A
    pixel is ink when darker than their midpoint.
    """
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return m.copy()
    lum = np.asarray(texture)[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
    line, fill = np.percentile(lum[m], 5), np.median(lum[m])
    return m & (lum < 0.5 * (line + fill))


def tab_texture(texture: np.ndarray, label: np.ndarray, child: int, tab: np.ndarray,
                ink: np.ndarray) -> np.ndarray:
    """RGBA ``(H, W, 4)`` uint8: the child's fill continued over ``tab`` (opaque there, clear elsewhere)."""
    H, W = label.shape
    out = np.zeros((H, W, 4), np.uint8)
    if not tab.any():
        return out
    ys, xs = np.nonzero(tab)
    pad = int(max(np.ptp(ys), np.ptp(xs))) + 8
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, H)
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, W)
    # The limb's fill: its pixels away from any line (2 px), so no ink bleeds into the tab.
    lines = cv2.dilate(ink[y0:y1, x0:x1].astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    own = (label[y0:y1, x0:x1] == child) & ~lines
    if own.sum() < 4:
        own = (label[y0:y1, x0:x1] == child) & ~ink[y0:y1, x0:x1]
    if own.sum() < 4:
        own = label[y0:y1, x0:x1] == child
    rgb = np.ascontiguousarray(texture[y0:y1, x0:x1, :3]).copy()
    if own.any():
        rgb[~own] = np.median(rgb[own], axis=0).astype(np.uint8)
        unknown = (~own).astype(np.uint8)
        rgb = cv2.inpaint(rgb, unknown, 5, cv2.INPAINT_TELEA)
    out[y0:y1, x0:x1, :3] = rgb
    out[..., 3] = np.where(tab, 255, 0)
    return out


def tab_textures(mesh, character, style=None) -> dict[int, np.ndarray]:
    """Textures of a pieced mesh's joint tabs: ``{layer: RGBA (H, W, 4) uint8}``.

    Each tab shows its limb's fill continued (:func:`tab_texture`), except in
    the band of the drawn outline (:func:`outline_band`; ``style``: the
    drawing's :func:`nnsf.reshape.outline.outline_style`, None without one), where it
    shows the drawing: a joint turned a little opens a sliver of tab across
    the outline, and fill there cut the line with a tick of paper colour.
    Tabs whose regions do not touch (2 px apart) share one image, so the
    atlas stays a few drawings wide.
    """
    ink = ink_mask(character.texture, character.mask)
    band = outline_band(character.mask, style)
    groups: list[tuple[np.ndarray, np.ndarray]] = []  # (taken pixels, image)
    out = {}
    k3 = np.ones((5, 5), np.uint8)
    for k, tab in enumerate(mesh.tabs):
        if tab.drawn:  # a follower's own region shows the drawing
            continue
        if tab.fill is not None:
            img = tab_texture(character.texture, np.where(tab.fill, 1, 0), 1, tab.region, ink)
        else:
            img = tab_texture(character.texture, mesh.labels, _segment_of(mesh, tab), tab.region, ink)
        if band is not None:
            line = tab.region & band
            img[line] = character.texture[line]
        grown = cv2.dilate(tab.region.astype(np.uint8), k3).astype(bool)
        for taken, gimg in groups:
            if not (taken & grown).any():
                taken |= grown
                gimg[tab.region] = img[tab.region]
                out[3 + k] = gimg
                break
        else:
            groups.append((grown.copy(), img))
            out[3 + k] = img
    return out


def outline_band(mask: np.ndarray, style) -> np.ndarray | None:
    """The drawn outline's band ``(H, W)`` bool: mask pixels no deeper than its paper margin and
    line width (``style``, from :func:`nnsf.reshape.outline.outline_style`), or None without one."""
    if style is None:
        return None
    _, width, paper = style
    m = np.asarray(mask, dtype=bool)
    inner = cv2.distanceTransform(np.pad(m.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    return m & (inner <= paper + width + 0.5)


def _segment_of(mesh, tab) -> int:
    """The label (index into ``nnsf.reshape.pieces.SEGMENT_NAMES``) a tab's child region has."""
    return int(np.flatnonzero(SEGMENT_PART == tab.part)[0])
