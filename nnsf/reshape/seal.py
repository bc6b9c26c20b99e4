"""Sealing a rendered frame of a pieced mesh: no holes in the body, no cracks at the joints.

A layered or whole-limb mesh (:func:`nnsf.reshape.mesh.layer_pieces`) draws
every segment as its own piece.  Where the pieces part (a limb swung away
from the chest, a shoulder or a knee bent past what its joint cap covers), the
page shows through: enclosed holes inside the body and thin cracks or notches
where two parts meet.  :func:`seal` closes them on the rendered frame:

* **holes**: background components enclosed by the character (4-connected,
  not touching the crop's border) that are small (at most
  ``hole_share`` × the character's area and at most half the drawing's own
  smallest hole, or no wider than ``2 × thin`` px) are filled; a large
  enclosed gap (an arm forming a loop with the body, the gap between a
  Kenney robot's arm and body) is drawing and stays;
* **cracks and notches**: background pixels inside the morphological
  closing of the coverage (an ellipse of ``2·close + 1`` px) that lie within
  ``close + 1`` px (Chebyshev) of two different parts, in runs that touch the
  drawn pixels (:func:`touching`), are filled.  The closing also rounds the
  inside corner of a bent joint a little, as a drawn joint is.  A small
  drawing's own slits between joined parts, which a closing that wide would
  paint over, are found at rest and kept open in every frame
  (:class:`DrawnGaps`).  A drawing whose closing is narrower than a crack
  can be wide has the short runs of a wider closing sealed as well: the
  acute corners where a limb's outline meets the body's (``corner``).

Filled pixels take the colour of the nearest fully opaque pixel of the frame
(OpenCV's distance transform with per-pixel labels): the body's fill
inside a crack, the ink of the outline across a notch, so an outline cut
by a crack is drawn across it again.  Part-transparent pixels inside the
character (a piece's soft rim beside a filled crack, :func:`inner_soft`)
are laid over that colour, so the page does not show through them.

It works on the renderer's premultiplied RGBA crop and its per-pixel part
image, and costs a few milliseconds per frame (``benchmarks/bench_seal.py``).
"""
from __future__ import annotations

import cv2
import numpy as np
from nnsf.reshape.artefacts import two_parts_near



def joined_near(labels: np.ndarray, reach: int, pairs) -> np.ndarray:
    """Pixels ``(H, W)`` bool within ``reach`` px (Chebyshev) of both parts of one of ``pairs`` ((a, b) part ids)."""
    lab = np.asarray(labels)
    k = np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)
    near = {}
    for p in {x for ab in pairs for x in ab}:
        own = lab == p
        near[p] = cv2.dilate(own.astype(np.uint8), k).astype(bool) if own.any() else None
    out = np.zeros(lab.shape, bool)
    for a, b in pairs:
        if near[a] is not None and near[b] is not None:
            out |= near[a] & near[b]
    return out


def touching(fill: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """The 8-connected components of ``fill`` ``(h, w)`` bool that touch ``cov`` ``(h, w)`` bool.

    A gap between two parts about twice the crack reach wide has only its
    middle line within reach of both: filled alone, that line floats in the
    gap, a speck of colour apart from the character.  Such a gap is open, not
    a crack, and stays so.
    """
    if not fill.any():
        return fill
    n, comp = cv2.connectedComponents(fill.astype(np.uint8), connectivity=8)
    near = cv2.dilate(cov.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool) & fill
    keep = np.zeros(n, bool)
    keep[np.unique(comp[near])] = True
    keep[0] = False
    return keep[comp]


def crack_candidates(labels: np.ndarray, cov: np.ndarray, close: int, joined=None) -> np.ndarray:
    """Background pixels ``(h, w)`` bool inside the closing of coverage ``cov`` ``(h, w)`` bool by an
    ellipse of ``2·close + 1`` px and within ``close + 1`` px of two parts of ``labels`` ``(h, w)``
    (of a pair in ``joined``, when given): a crack's or a notch's pixels, before :func:`touching`."""
    k = 2 * close + 1
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    # Page all round the crop: OpenCV's default border would let the closing fill the crop's edge.
    fill = cv2.morphologyEx(np.pad(cov.astype(np.uint8), k), cv2.MORPH_CLOSE, ker)[k:-k, k:-k].astype(bool) & ~cov
    if fill.any():
        # Only the box of the candidates, and its reach: the part tests dilate once per part.
        ys, xs = np.nonzero(fill)
        r = close + 1
        y0, y1 = max(ys.min() - r, 0), ys.max() + r + 1
        x0, x1 = max(xs.min() - r, 0), xs.max() + r + 1
        lab = np.where(cov[y0:y1, x0:x1], labels[y0:y1, x0:x1], -1)
        fill[y0:y1, x0:x1] &= two_parts_near(lab, r) if joined is None else joined_near(lab, r, joined)
    return fill


def hairlines(fill: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Page pixels ``(h, w)`` bool in runs of 1 or 2 px along a row or a column between a pixel of
    ``fill`` ``(h, w)`` bool and one of ``cov`` ``(h, w)`` bool.

    Where a crack is wider than the reach of the two-part test but within the
    closing (a crack between thighs parting at the crotch), only its middle
    lies within reach of both parts: filled alone, it leaves a line of page on
    each side, two white hairlines where there was one crack (char4's walk).
    The patterns are read at the page pixels within 2 px of the fill only.
    """
    out = np.zeros(fill.shape, bool)
    if not fill.any():
        return out
    f8 = np.ascontiguousarray(fill).view(np.uint8)
    c8 = np.ascontiguousarray(cov).view(np.uint8)
    # OpenCV passes and findNonZero: numpy's where / nonzero over the frame cost 1-3 ms each
    near = cv2.bitwise_and(cv2.dilate(f8, np.ones((5, 5), np.uint8)), cv2.bitwise_not(cv2.bitwise_or(f8, c8)))
    pts = cv2.findNonZero(near)
    if pts is None:
        return out
    xs, ys = pts.reshape(-1, 2).T.astype(np.int64)
    H, W = fill.shape

    def at(dy, dx):  # 0 page, 1 fill, 2 drawn at (ys + dy, xs + dx); page outside the image
        yy, xx = ys + dy, xs + dx
        ok = (yy >= 0) & (yy < H) & (xx >= 0) & (xx < W)
        yy, xx = np.clip(yy, 0, H - 1), np.clip(xx, 0, W - 1)
        return np.where(ok, f8[yy, xx] + 2 * c8[yy, xx], 0)

    hit = np.zeros(len(ys), bool)
    for dy, dx in ((0, 1), (1, 0)):  # along the row, then the column
        m2, m1, p1, p2 = (at(k * dy, k * dx) for k in (-2, -1, 1, 2))
        # a 1 px run: fill | page | drawn, either way; a 2 px run with this pixel first or second
        hit |= (m1 == 1) & (p1 == 2) | (m1 == 2) & (p1 == 1)
        hit |= (p1 == 0) & ((m1 == 1) & (p2 == 2) | (m1 == 2) & (p2 == 1))
        hit |= (m1 == 0) & ((m2 == 1) & (p1 == 2) | (m2 == 2) & (p1 == 1))
    out[ys[hit], xs[hit]] = True
    return out


def short_runs(mask: np.ndarray, extent: int) -> np.ndarray:
    """The 8-connected components of ``mask`` ``(h, w)`` bool whose bounding box is shorter than
    ``extent`` px both ways, ``(h, w)`` bool."""
    ys, xs = np.nonzero(mask)
    if not len(ys):
        return mask
    y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
    n, comp, st, _ = cv2.connectedComponentsWithStats(mask[y0:y1, x0:x1].astype(np.uint8), connectivity=8)
    short = np.maximum(st[:, cv2.CC_STAT_WIDTH], st[:, cv2.CC_STAT_HEIGHT]) < extent
    short[0] = False
    out = np.zeros(mask.shape, bool)
    out[y0:y1, x0:x1] = short[comp]
    return out


def seal_mask(labels: np.ndarray, alpha: np.ndarray, close: int = 4, hole_share: float = 0.02,
              thin: float = 3.0, hole_max: float | None = None, joined=None, keep=None,
              corner: int | None = None, hairline: bool = False) -> np.ndarray:
    """Pixels ``(h, w)`` bool to fill, from visible parts ``(h, w)`` int (−1 empty) and alpha ``(h, w)`` uint8.

    ``hole_max``: fill no wider-than-thin hole larger than this (px²); the
    renderer sets it to half the drawing's own smallest hole
    (:func:`drawn_hole_limit`), so a gap the artist drew is never filled.
    ``joined``: part pairs ``[(a, b), ...]`` joined at a joint; when given, a
    crack is filled only between the two parts of such a pair.  A crack
    between parts no joint joins (two legs, an arm and the body's side) is
    the drawing's own gap: the Kenney robot's 2 px crotch, which the
    closing otherwise paints over.
    ``keep``: pixels ``(h, w)`` bool the crack step leaves open (the drawing's
    own slits in this frame, :meth:`DrawnGaps.mask`); a slit a sealed crack
    encloses is filled as a thin hole, as any enclosed crack is.
    ``corner``: a closing wider than ``close`` whose extra fill is sealed too
    where it comes in runs shorter than its disc (``2·corner + 2`` px): the
    acute corner where a limb's outline meets the body's, a pixel or two of
    page a closing of 2 px leaves.  A longer run is a gap, between two of
    char5's arms that turn apart, and stays open.
    ``hairline``: also fill the :func:`hairlines` beside the crack fill.  Not
    on a sprite: its drawn slits are 1-2 px wide, and beside a crack filled at
    one end (a Kenney sprite's crotch, below the body) the rule painted the
    whole slit over.
    """
    cov = np.asarray(alpha) >= 128
    if not cov.any():
        return np.zeros(cov.shape, bool)
    # Cracks and notches first: closing a notch's mouth can enclose a hole behind it.
    fill = crack_candidates(labels, cov, close, joined)
    if corner is not None and corner > close:
        fill |= short_runs(crack_candidates(labels, cov, corner, joined) & ~fill, 2 * corner + 2)
    if keep is not None:
        fill &= ~np.asarray(keep, dtype=bool)
    if fill.any():
        fill = touching(fill, cov)
        if hairline:
            fill |= hairlines(fill, cov)
    drawn = cov | fill
    bg = (~drawn).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bg, connectivity=4)
    if n > 1:
        border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
        inner = np.setdiff1d(np.arange(1, n), border)
        if len(inner):
            area = stats[inner, cv2.CC_STAT_AREA]
            limit = max(hole_share * drawn.sum(), 16)
            if hole_max is not None:
                limit = min(limit, hole_max)
            small = inner[area <= limit]
            big = np.setdiff1d(inner, small)
            if len(big):  # thin enclosed cracks, whatever their length
                dist = cv2.distanceTransform(bg, cv2.DIST_L2, 3)
                # Each big hole's widest point.  Not ndimage.maximum(dist, lab, big): it sorts the
                # whole image (10-30 ms a frame); this visits only the big holes' pixels.
                is_big = np.zeros(n, bool)
                is_big[big] = True
                sel = is_big[lab]
                widest = np.zeros(n, np.float32)
                np.maximum.at(widest, lab[sel], dist[sel])
                small = np.concatenate([small, big[widest[big] <= thin]])
            fill |= np.isin(lab, small)
    return fill


def drawn_hole_limit(mask: np.ndarray) -> float | None:
    """Half the area (px²) of the drawing's smallest enclosed hole larger than 4 px², or None without one."""
    bg = (~np.asarray(mask, dtype=bool)).astype(np.uint8)
    n, lab, stats, _ = cv2.connectedComponentsWithStats(bg, connectivity=4)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    areas = [stats[i, cv2.CC_STAT_AREA] for i in range(1, n) if i not in border]
    areas = [a for a in areas if a > 4]
    return 0.5 * float(min(areas)) if areas else None


def tab_slivers(alpha: np.ndarray, tab: np.ndarray, close: int = 4) -> np.ndarray:
    """Pixels ``(h, w)`` bool of joint tabs ``tab`` seen through a crack no wider than the closing
    of :func:`seal_mask` (``2·close + 1`` px) between the pieces drawn over them.

    A tab shows the limb's fill continued: right for the wedge a bent joint
    opens, wrong in a sliver a joint turned a degree or two opens across the
    drawing's lines (char1's neck: a line of paper colour through the torso's
    top line).  A sliver is sealed as a crack is.
    """
    over = (np.asarray(alpha) >= 128) & ~np.asarray(tab, dtype=bool)
    k = 2 * close + 1
    ker = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k))
    return np.asarray(tab, dtype=bool) & cv2.morphologyEx(over.astype(np.uint8), cv2.MORPH_CLOSE, ker).astype(bool)


def over(top: np.ndarray, under: np.ndarray) -> np.ndarray:
    """Premultiplied RGBA ``top`` laid over ``under`` (both ``(k, 4)`` uint8): ``top + (1 − α_top) · under``,
    in integers with rounding, ``(k, 4)`` uint8."""
    t = np.asarray(top).astype(np.uint16)
    return np.minimum(t + ((255 - t[:, 3:4]) * np.asarray(under).astype(np.uint16) + 127) // 255, 255).astype(np.uint8)


def _window(img: np.ndarray, ys: np.ndarray, xs: np.ndarray, r: int, outside) -> np.ndarray:
    """The ``(2r + 1)²`` neighbours ``(k, (2r + 1)²)`` of pixels ``(ys, xs)`` of ``img`` (``outside`` beyond it)."""
    d = np.arange(-r, r + 1)
    yy = (ys[:, None, None] + d[None, :, None]).repeat(len(d), axis=2)
    xx = (xs[:, None, None] + d[None, None, :]).repeat(len(d), axis=1)
    inside = (yy >= 0) & (yy < img.shape[0]) & (xx >= 0) & (xx < img.shape[1])
    vals = img[np.clip(yy, 0, img.shape[0] - 1), np.clip(xx, 0, img.shape[1] - 1)]
    return np.where(inside, vals, outside).reshape(len(ys), -1)


def inner_soft(alpha: np.ndarray, fill: np.ndarray, labels: np.ndarray | None = None, margin: int = 2,
               reach: int = 3) -> np.ndarray:
    """Part-transparent pixels ``(h, w)`` bool (0 < α < 255) farther than ``margin`` px (Chebyshev) from
    any background (α < 128, not in ``fill``) of alpha ``(h, w)`` uint8: soft edges inside the character;
    with part ``labels`` ``(h, w)`` (−1 empty), only those within ``reach`` px of two parts (a seam).

    A piece's anti-aliased rim is part transparent.  Where the piece lies
    on another, :meth:`~nnsf.reshape.render.MeshRenderer.render_labelled`
    lays the rim over it; where the rim bordered a drawn gap or a crack the
    seal fills, nothing lies under it, and the page shows through it: a
    dotted light line inside the body (a Kenney sprite's arm against its
    vest, at rest; char1's ink where its leg meets its body).  An edge
    against the page, even a wide soft one, lies within ``margin`` of the
    page and keeps its transparency; so does a drawing's own translucent
    paint away from a seam.  The seam test looks at windows around the few
    remaining pixels, not at a morphology pass over the frame.
    """
    a = np.ascontiguousarray(alpha, dtype=np.uint8)
    cand = cv2.inRange(a, 1, 254)  # 255 where part transparent; OpenCV passes, not numpy temporaries
    if not cv2.countNonZero(cand):
        return np.zeros(a.shape, bool)
    bg = cv2.bitwise_and(cv2.inRange(a, 0, 127), cv2.bitwise_not(np.asarray(fill, dtype=bool).view(np.uint8) * 255))
    k = np.ones((2 * margin + 1, 2 * margin + 1), np.uint8)
    near_bg = cv2.dilate(bg, k, borderType=cv2.BORDER_CONSTANT, borderValue=255)
    out = cv2.bitwise_and(cand, cv2.bitwise_not(near_bg)).astype(bool)
    ys, xs = np.nonzero(out)
    if labels is not None and len(ys):
        win = np.where(_window(a, ys, xs, reach, 0) > 0, _window(np.asarray(labels), ys, xs, reach, -1), -1)
        big = np.iinfo(win.dtype).max
        hi = win.max(axis=1)
        lo = np.where(win >= 0, win, big).min(axis=1)
        drop = ~((hi >= 0) & (lo != hi))
        out[ys[drop], xs[drop]] = False
    return out


def seal(crop: np.ndarray, labels: np.ndarray, tab: np.ndarray | None = None, tab_close: int | None = None,
         **kw) -> np.ndarray:
    """A premultiplied RGBA crop ``(h, w, 4)`` uint8 with :func:`seal_mask` filled (nearest opaque colour).

    ``tab`` ``(h, w)`` bool: the pixels showing a joint tab; its slivers
    (:func:`tab_slivers`) are filled as well, from the pixels around them.
    The soft edges inside the character (:func:`inner_soft`) within 3 px of
    two parts are laid over the nearest opaque colour, premultiplied "over",
    and become opaque.
    """
    fill = seal_mask(labels, crop[..., 3], **kw)
    if tab is not None and tab.any():
        fill |= tab_slivers(crop[..., 3], tab, tab_close if tab_close is not None else kw.get("close", 4))
    soft = inner_soft(crop[..., 3], fill, labels) & ~fill
    if not fill.any() and not soft.any():
        return crop
    ys, xs = np.nonzero(fill | soft)
    pad = 8
    y0, y1 = max(ys.min() - pad, 0), min(ys.max() + pad + 1, crop.shape[0])
    x0, x1 = max(xs.min() - pad, 0), min(xs.max() + pad + 1, crop.shape[1])
    solid = (crop[y0:y1, x0:x1, 3] == 255) & ~fill[y0:y1, x0:x1]
    if not solid.any():
        return crop
    # Nearest opaque pixel of every pixel: OpenCV labels each zero pixel of its input in raster
    # order (DIST_LABEL_PIXEL), so label k is the k-th opaque pixel of np.argwhere.
    _, lab = cv2.distanceTransformWithLabels((~solid).astype(np.uint8), cv2.DIST_L2, 5,
                                             labelType=cv2.DIST_LABEL_PIXEL)
    src = np.argwhere(solid)
    out = crop.copy()
    box = out[y0:y1, x0:x1]
    f = fill[y0:y1, x0:x1]
    if f.any():
        near = src[lab[f] - 1]
        box[f] = crop[y0:y1, x0:x1][near[:, 0], near[:, 1]]
    s = soft[y0:y1, x0:x1]
    if s.any():
        near = src[lab[s] - 1]
        box[s] = over(crop[y0:y1, x0:x1][s], crop[y0:y1, x0:x1][near[:, 0], near[:, 1]])
    return out


class DrawnGaps:
    """The drawing's own narrow slits between joined parts, carried through the deformation.

    A sprite's artist draws slits a few pixels wide where two joined parts
    meet (a Kenney robot's arm beside its body, the slit between a sleeve and
    a vest).  A crack the deformation opens is no wider, so a closing wide
    enough to seal the cracks would paint the drawn slits over too.  The
    drawn ones are known at rest: the pixels a closing of ``close`` px fills
    there beyond what one of ``narrow`` px fills, in runs longer than the
    closing's disc (``2·close + 2`` px).  A shorter run is a concave corner
    where two parts meet on the outline (hair on a shoulder): it is sealed
    like a crack.  Each slit pixel lies between two parts; it is tied to the
    rest triangle of the nearest pixel of each (barycentric coordinates,
    extrapolated past the triangle's edge) and carried by both into every
    frame.  :meth:`mask` keeps the pixels between the two carried copies open:
    as the parts swing apart the slit widens with them, as they close in it
    narrows.

    ``ids``: the rest pose's triangle per pixel ``(H, W)`` int (−1 empty),
    ``alpha``: its alpha ``(H, W)`` uint8, both in texture pixels;
    ``vertices`` ``(n, 2)`` rest positions, ``triangles`` ``(t, 3)``, ``parts`` ``(t,)``;
    ``joined``: the part pairs whose cracks are sealed (:func:`seal_mask`).
    """

    #: Points sampled along each slit pixel's segment between its two carried copies.
    SAMPLES = 9

    def __init__(self, ids, alpha, vertices, triangles, parts, close: int, narrow: int, joined=None):
        ids = np.asarray(ids)
        cov = (np.asarray(alpha) >= 128) & (ids >= 0)
        labels = np.where(cov, np.asarray(parts)[np.maximum(ids, 0)], -1)
        wide = crack_candidates(labels, cov, close, joined)
        gap = wide & ~short_runs(wide, 2 * close + 2) & ~touching(crack_candidates(labels, cov, narrow, joined), cov)
        yx = np.argwhere(gap)
        self.triangles = np.zeros((2, 0, 3), np.int64)
        self.bary = np.zeros((2, 0, 3))
        present = [int(q) for q in np.unique(labels) if q >= 0]
        if not len(yx) or len(present) < 2:
            return
        # The two nearest parts of each gap pixel, and the nearest pixel of each: one distance
        # transform per part, with the index of its nearest zero pixel.
        dist = np.empty((len(present), len(yx)), np.float32)
        near = np.empty((len(present), len(yx), 2), np.int64)
        for j, q in enumerate(present):
            own = labels == q
            d, lab = cv2.distanceTransformWithLabels((~own).astype(np.uint8), cv2.DIST_L2, 5,
                                                     labelType=cv2.DIST_LABEL_PIXEL)
            dist[j] = d[yx[:, 0], yx[:, 1]]
            near[j] = np.argwhere(own)[lab[yx[:, 0], yx[:, 1]] - 1]
        two = np.argsort(dist, axis=0, kind="stable")[:2]  # (2, k)
        at = near[two, np.arange(len(yx))[None, :]]        # (2, k, 2) row, col
        tri = np.asarray(triangles)[ids[at[..., 0], at[..., 1]]]  # (2, k, 3)
        P = np.asarray(vertices, dtype=np.float64)[tri]  # (2, k, 3, 2)
        # Barycentric coordinates of each pixel centre in each triangle: solve [B − A, C − A] w = p − A.
        M = np.stack([P[..., 1, :] - P[..., 0, :], P[..., 2, :] - P[..., 0, :]], axis=-1)
        w = np.linalg.solve(M, (yx[None, :, ::-1] - P[..., 0, :])[..., None])[..., 0]
        self.triangles = tri
        self.bary = np.concatenate([1.0 - w.sum(axis=-1, keepdims=True), w], axis=-1)

    def __len__(self) -> int:
        return self.bary.shape[1]

    def points(self, vertices) -> np.ndarray:
        """Pixel positions ``(SAMPLES · k, 2)`` (x, y) along each slit pixel's segment between its two
        carried copies in the frame of ``vertices`` ``(n, 2)``."""
        q = np.einsum("akj,akjd->akd", self.bary, np.asarray(vertices, dtype=np.float64)[self.triangles])
        s = np.linspace(0.0, 1.0, self.SAMPLES)[:, None, None]
        return (q[0][None] * (1.0 - s) + q[1][None] * s).reshape(-1, 2)

    def mask(self, pts: np.ndarray, y0: int, x0: int, h: int, w: int) -> np.ndarray:
        """Pixels ``(h, w)`` bool of the crop at ``(y0, x0)`` that the slits cover, from their
        :meth:`points` ``pts``: widened by a pixel and closed (3 × 3)."""
        x = np.rint(pts[:, 0]).astype(np.int64) - x0
        y = np.rint(pts[:, 1]).astype(np.int64) - y0
        ok = (x >= 0) & (x < w) & (y >= 0) & (y < h)
        out = np.zeros((h, w), np.uint8)
        out[y[ok], x[ok]] = 1
        # Closed as well: neighbouring slit pixels carried by different parts (a slit beside the
        # arm, then beside the leg) part by a pixel, and a crack fill in that line is a sliver in the gap.
        ker = np.ones((3, 3), np.uint8)
        return cv2.morphologyEx(cv2.dilate(out, ker), cv2.MORPH_CLOSE, ker).astype(bool)
