"""What a joint tab shows: the limb's fill continued under its parent, and the drawn outline's band.

A tab (:func:`nnsf.reshape.tab_regions.tab_region`) is seen only where a joint
turns: in the wedge the bend opens.  It shows the limb's own fill continued
(OpenCV's Telea inpainting from the limb's pixels away from its lines), so a
limb swung away from the body takes no torso fill or torso ink with it,
except in the band of the drawn outline, where it shows the drawing.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.parts import SEGMENT_PART
from nnsf.skeleton.rigid import rigid_fit


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


class TabClip:
    """The pixels of turned joint tabs that stick out beside their parent, to hide.

    At rest a tab lies under its parent (the thigh above a knee, the body
    above a hip or a leg whose thigh the body hides), its rim
    along the parent's outline.  It turns with the child, so where the joint
    bends the rim swings out beside the parent, and its edge, stroked as a
    new edge, runs beside the parent's drawn outline: a double line.  Only
    the wedge the bend opens beyond the cut needs the tab.  Hidden, per
    frame: a tab pixel that, taken back into the parent's rest frame (the
    parent piece's rigid motion, a least-squares fit to its vertices), lies
    on the parent's side of the cut (``side`` px past its line) and outside
    the drawing by more than ``off`` px.  What the tab filled inside the
    parent's outline, or past the cut, stays.

    ``mesh``: a pieced mesh with ``tabs``; ``mask`` ``(H, W)`` bool: the
    drawing's silhouette, rest pixels.  Pieces move rigidly, so the fit is
    exact; a follower's tab (no cut) is left as it is.
    """

    def __init__(self, mesh, mask: np.ndarray, off: float = 1.5, side: float = 0.5):
        m = np.asarray(mask, dtype=bool)
        # Distance (px) of each rest pixel from the drawing, outside it (0 inside).
        self.outside = cv2.distanceTransform(np.pad((~m).astype(np.uint8), 1, constant_values=1),
                                             cv2.DIST_L2, 3)[1:-1, 1:-1]
        self.off, self.side = float(off), float(side)
        self.clips = []
        inner = cv2.distanceTransform(np.pad(m.astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        H, W = m.shape
        tri, pieces, layer = mesh.triangles, mesh.pieces, np.asarray(mesh.layer)
        V0 = np.asarray(mesh.vertices, dtype=np.float64)
        for k, tab in enumerate(mesh.tabs):
            cut = tab.cut
            if cut is None or tab.parent_piece is None or tab.parent_piece == tab.piece:
                continue
            idx = np.unique(tri[(pieces == tab.parent_piece) & (layer < 3)].ravel())
            if len(idx) < 2 or len(tab.vertices) < 2:
                continue
            piv = np.asarray(cut.pivot, np.float64)
            i, j = np.clip(np.rint(piv).astype(int), 0, [W - 1, H - 1])
            tv = np.asarray(tab.vertices)
            self.clips.append((3 + k, idx, V0[idx], tv, V0[tv], piv, float(inner[j, i]),
                               np.asarray(cut.mid, np.float64), np.asarray(cut.normal, np.float64)))

    def __bool__(self) -> bool:
        return bool(self.clips)

    def hidden(self, vertices: np.ndarray, ids: np.ndarray, layer: np.ndarray, y0: int, x0: int) -> np.ndarray:
        """Pixels ``(h, w)`` bool to hide, of a crop at ``(y0, x0)`` whose nearest triangle is ``ids``
        ``(h, w)`` int (−1 empty); ``layer`` ``(t,)``: each triangle's layer (tab k: 3 + k);
        ``vertices`` ``(n, 2)``: the frame's, px."""
        out = np.zeros(ids.shape, bool)
        h, w = ids.shape
        H, W = self.outside.shape
        V = np.asarray(vertices, dtype=np.float64)
        for lay, pidx, prest, tidx, trest, piv, radius, mid, normal in self.clips:
            # Only the box around the tab's vertices is looked at: the crop is the whole character.
            P = V[tidx]
            bx0, by0 = np.maximum(np.floor(P.min(axis=0)).astype(int) - [x0, y0], 0)
            bx1, by1 = np.minimum(np.ceil(P.max(axis=0)).astype(int) - [x0, y0] + 1, [w, h])
            if bx1 <= bx0 or by1 <= by0:
                continue
            box = ids[by0:by1, bx0:bx1]
            ys, xs = np.nonzero((box >= 0) & (layer[np.maximum(box, 0)] == lay))
            if not len(ys):
                continue
            ys, xs = ys + by0, xs + bx0
            pts = np.stack([xs + x0, ys + y0], -1).astype(np.float64)
            R, t = rigid_fit(prest, V[pidx])  # the parent piece's motion: u = its rest place
            u = (pts - t) @ R
            # The joint is solid about its pivot (where the child turns now) out to the drawing's
            # thickness there: kept, so a pivot carried off the parent keeps its joint closed.
            Rt, tt = rigid_fit(trest, P)
            near = np.hypot(*(pts - (piv @ Rt.T + tt)).T) <= radius
            before = (u - mid) @ normal < -self.side
            ij = np.rint(u).astype(np.int64)
            inside = (ij[:, 0] >= 0) & (ij[:, 0] < W) & (ij[:, 1] >= 0) & (ij[:, 1] < H)
            far = np.ones(len(ys), bool)
            far[inside] = self.outside[ij[inside, 1], ij[inside, 0]] > self.off
            hide = before & far & ~near
            out[ys[hide], xs[hide]] = True
        return out

