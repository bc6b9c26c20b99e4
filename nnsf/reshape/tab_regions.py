"""Where a joint tab and a joint cap lie at rest: pixel regions of a drawing cut into pieces.

A **tab** (:func:`tab_region`) continues a child piece under its parent, as a
paper puppet's limb goes on under the body; a **cap** (:func:`cap_region`)
continues an upper limb segment past its elbow or knee cut under the lower
one.  Both are hidden at rest; when the joint turns, the tab fills the wedge
that opens on the inner side of the bend and the cap rounds its outer side.
Regions are ``(H, W)`` bool images of the drawing's pixels.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.cuts import Cut, SEGMENT_NAMES, _seg_dist


def tab_region(label: np.ndarray, cut: Cut, margin: float = 0.0, band: float | None = None,
               under: np.ndarray | None = None) -> np.ndarray:
    """The child's tab under its parent ``(H, W)`` bool (module docstring).

    ``margin``: away from the cut (farther than ``band``, default a quarter
    of the cut's length, at least 3 px), the tab keeps this far (pixels) inside the
    parent's outline, so a small turn of the joint does not slide a sliver of
    it out along the parent's edge.  ``under`` ``(H, W)`` bool: pixels the
    tab may also cover (the parent's own tab: a parent segment may be drawn
    shorter than the tab).
    """
    if band is None:
        band = max(0.25 * float(np.linalg.norm(cut.p - cut.q)), 3.0)
    H, W = label.shape
    rho = max(0.5 * float(np.linalg.norm(cut.p - cut.q)), 1.0)
    m = cut.mid
    piv = cut.pivot
    reach = max(float(np.linalg.norm(cut.p - piv)), float(np.linalg.norm(cut.q - piv)))
    rho_piv = rho if float(np.linalg.norm(m - piv)) >= rho else max(rho, reach)
    lo = np.floor(np.minimum(m, piv) - max(rho, rho_piv) - 2).astype(int)
    hi = np.ceil(np.maximum(m, piv) + max(rho, rho_piv) + 2).astype(int)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [W - 1, H - 1])
    out = np.zeros((H, W), bool)
    if np.any(hi < lo):
        return out
    yy, xx = np.mgrid[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    pts = np.stack([xx, yy], -1).astype(np.float64)
    inside = (_seg_dist(pts, m, piv) <= rho) | (np.linalg.norm(pts - piv, axis=-1) <= rho_piv)
    depth_ = (pts - m) @ cut.normal
    parent_side = depth_ <= 0.5
    parent = label[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] == cut.parent
    if under is not None:  # a parent drawn too short to hold the tab: what lies under it as well
        parent |= under[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    # Within the drawing: at rest a tab must hide entirely under the pieces drawn over it.
    grow = cv2.dilate(parent.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    inner = cv2.distanceTransform(np.pad((label >= 0).astype(np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    depth_in = inner[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1]
    keep = depth_in >= 2.0
    if margin <= 0 and SEGMENT_NAMES[cut.child].endswith("forearm"):
        # An elbow's tab (no margin): in the band along the cut, where a bend opens its wedge, it
        # reaches the outline's second pixel (distance transform 1 and more: 1.91 straight, 1.37
        # diagonal); kept 2 inside, the outer corner of a bent elbow kept a notch as deep as the
        # rings left out (char4's thin arms).  The outermost (0.96) stays out: a tab there shows
        # at rest along the parent's rendered edge.  Not at the knees: there the Kenney
        # walk's silhouette IoU against the drawn frames fell (0.9016 -> 0.9014).
        keep |= (depth_in >= 1.0) & (depth_ >= -band)
    grow &= keep
    if margin > 0:
        # Inside the parent's outline by ``margin``, except in the band along the cut, where the
        # tab fills the wedge a turning joint opens.
        grow &= (inner[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] > margin) | (depth_ >= -band)
    # The parent's own pixels beyond the cut's line as well (a body's rim that curves below a hip
    # cut, AnimatedDrawings' char3): they stay when the child turns, and the child's turned
    # tab must cover where they would have turned to, or a wedge of page opens at the joint.
    # Only within the drawing's thickness at the pivot (its distance to the outline), where a
    # drawn joint is solid; farther out the turned rim would widen the silhouette.
    own = label[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] == cut.parent
    ij = np.clip(np.rint(piv).astype(int), 0, [W - 1, H - 1])
    own &= np.linalg.norm(pts - piv, axis=-1) <= float(inner[ij[1], ij[0]])
    out[lo[1]:hi[1] + 1, lo[0]:hi[0] + 1] = inside & (parent_side | own) & grow
    return out


def cap_region(label: np.ndarray, cut: Cut) -> np.ndarray:
    """An elbow's or knee's cap ``(H, W)`` bool: the upper segment's end continued past ``cut``
    under the lower segment, a half-disc about the pivot (:func:`tab_region` of the cut seen from
    the other side).  Hidden at rest, it rounds the outer side of a bent joint."""
    flip = Cut(cut.joint, cut.child, cut.parent, cut.p, cut.q, cut.pivot, -cut.normal, cut.half_width)
    return tab_region(label, flip, 0.0)
