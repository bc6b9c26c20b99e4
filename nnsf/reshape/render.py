"""Rasterise a deformed character mesh and composite its parts, back to front.

Every pixel of a frame comes from a deformed triangle of the drawing: a triangle's texture
coordinates are its rest corners, so it shows the patch of the drawing it covered at rest (the
body underlay's triangles show the body painted in under a limb, the second half of a texture
atlas).  Nothing is repaired after the render.

Per frame, for each part in the frame's back-to-front order:

1. its triangles' ids are filled into an id image over the part's box (``cv2.fillConvexPoly``,
   1/16 px vertices): OpenCV fills a polygon's boundary pixels too, so triangles that share an
   edge leave no pixel between them, flipped or not;
2. each covered pixel's texture coordinate is its triangle's affine map (deformed → rest) of the
   pixel centre, kept within :data:`REACH` of the triangle's rest footprint (:meth:`Renderer.texels`),
   and ``cv2.remap`` samples the premultiplied texture bilinearly;
3. the part is laid over what is drawn so far ("over", premultiplied alpha), so a limb's
   anti-aliased edge blends with the body under it.

Pixel centres are at integer coordinates.  Cost: one fill call per triangle and work per covered
pixel, so time grows with the pixels the character covers.
"""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.mesh import Mesh

#: Transparent columns between the drawing and the underlay in the texture atlas, pixels.
ATLAS_GAP = 8
#: How far outside its triangle's rest footprint a pixel may sample, texels: one pixel, the most by
#: which a pixel the fill gives a triangle lies outside it at rest.
REACH = 1.0


def premultiplied(texture: np.ndarray, mask: np.ndarray | None = None) -> np.ndarray:
    """RGBA ``(H, W, 4)`` uint8 → premultiplied float32 RGBA in [0, 1]; outside ``mask`` transparent."""
    alpha = texture[..., 3].astype(np.float32) / 255.0
    if mask is not None:
        alpha = alpha * np.asarray(mask, dtype=np.float32)
    return np.dstack([texture[..., :3].astype(np.float32) / 255.0 * alpha[..., None], alpha])


class Renderer:
    """Draws one character's mesh, deformed, one texture pixel per output pixel.

    Parameters
    ----------
    mesh : :class:`~nnsf.reshape.mesh.Mesh` (rest vertices = texture coordinates; ``layer`` 1 samples
        ``underlay``).
    texture : ``(H, W, 4)`` uint8 RGBA; mask : ``(H, W)`` bool (texels outside are transparent).
    size : output ``(H, W)``.
    underlay : ``(H, W, 4)`` uint8, the texture of the underlay triangles (None: the drawing).
    """

    def __init__(self, mesh: Mesh, texture: np.ndarray, mask: np.ndarray, size, underlay=None):
        self.size = (int(size[0]), int(size[1]))
        self.triangles = np.asarray(mesh.triangles, dtype=np.int64)
        H, W = np.asarray(mask).shape
        tex = premultiplied(texture, mask)
        uv = mesh.vertices[self.triangles].copy()                       # (t, 3, 2)
        if underlay is not None and (mesh.layer == 1).any():
            # A transparent gap between the halves: a triangle reaching past the drawing's edge
            # (the mesh covers the mask grown by a few pixels) samples the page, not the other half.
            gap = np.zeros((H, ATLAS_GAP, 4), tex.dtype)
            tex = np.hstack([tex, gap, premultiplied(underlay, mask)])
            uv[mesh.layer == 1, :, 0] += W + ATLAS_GAP
        # 8 bits a channel, premultiplied: bilinear sampling and compositing run on OpenCV's
        # saturating uint8 arithmetic (a level of rounding per layer, no more).
        self.texture = np.ascontiguousarray(np.clip(tex * 255.0 + 0.5, 0, 255).astype(np.uint8))
        # A pixel samples its triangle's rest footprint grown by REACH texels (:meth:`texels`): the
        # grown corners as weights (t, 3, 3) of the triangle's own (edge k offset by REACH: the
        # barycentric coordinate of the corner opposite it falls to −REACH / height).
        f = uv[:, 1:] - uv[:, :1]
        area = np.abs(f[:, 0, 0] * f[:, 1, 1] - f[:, 0, 1] * f[:, 1, 0])
        opposite = np.linalg.norm(uv[:, [2, 0, 1]] - uv[:, [1, 2, 0]], axis=2)     # (t, 3)
        m = REACH * opposite / np.maximum(area, 1e-12)[:, None]                    # REACH / height
        self._grow = np.eye(3)[None] * (1.0 + m.sum(axis=1))[:, None, None] - m[:, None, :]
        grown = np.einsum("tij,tjx->tix", self._grow, uv)
        # Per triangle (column 0: none, far outside the texture) the texel at barycentric (l1, l2)
        # of its grown footprint: u = u0 + l1 du1 + l2 du2, v likewise (rows u0, du1, du2, v0, ...).
        g = np.concatenate([grown[:, :1], grown[:, 1:] - grown[:, :1]], axis=1).transpose(2, 1, 0)
        self._texels = np.hstack([[[-1e4], [0], [0], [-1e4], [0], [0]], g.reshape(6, -1)]).astype(np.float32)
        self.parts = np.asarray(mesh.parts, dtype=np.int64)
        # Within a part, the last triangle filled wins a pixel.  Where the part folds over itself
        # (a joint bent past its drawn angle), a triangle along the outline (half in the transparent
        # margin around the drawing) must not cover the drawn inside: the part's underlay is filled
        # first, then its triangles from the outline inwards (by their rest depth in the drawing).
        depth = cv2.distanceTransform(np.pad(np.asarray(mask, np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        c = np.rint(mesh.vertices[self.triangles].mean(axis=1)).astype(np.int64)
        inside = depth[np.clip(c[:, 1], 0, H - 1), np.clip(c[:, 0], 0, W - 1)]
        key = np.where(np.asarray(mesh.layer) == 1, -1.0, inside)
        self.part_triangles = [t[np.argsort(key[t], kind="stable")]
                               for t in (np.flatnonzero(self.parts == p) for p in range(int(self.parts.max()) + 1))]
        self._ids = None

    def coefficients(self, vertices: np.ndarray) -> np.ndarray:
        """Per triangle ``(12, t + 1)`` float32 (column 0: "no triangle"): the affine map from a deformed
        pixel to its barycentric coordinates at corners 1 and 2 of the triangle's grown footprint,
        l1 = c0 x + c1 y + c2, l2 = c3 x + c4 y + c5 (a collapsed triangle: one point inside it),
        then the texel at (l1, l2) (rows 6-11, :attr:`_texels`)."""
        D = np.einsum("tij,tjx->tix", self._grow, vertices[self.triangles])
        e = D[:, 1:] - D[:, :1]                                         # (t, 2, 2): deformed edges
        det = e[:, 0, 0] * e[:, 1, 1] - e[:, 0, 1] * e[:, 1, 0]
        ok = np.abs(det) > 1e-9
        inv = np.stack([np.stack([e[:, 1, 1], -e[:, 1, 0]], -1), np.stack([-e[:, 0, 1], e[:, 0, 0]], -1)], -1)
        inv /= np.where(ok, det, 1.0)[:, None, None]                    # columns: inverse of [e0 e1]
        A = inv.transpose(0, 2, 1)                                      # (t, 2 bary, 2 xy)
        A[~ok] = 0
        b = -np.einsum("tij,tj->ti", A, D[:, 0])
        b[~ok] = 1.0 / 3.0
        out = np.zeros((12, len(D) + 1), np.float32)
        out[:2, 1:], out[2, 1:], out[3:5, 1:], out[5, 1:] = A[:, 0].T, b[:, 0], A[:, 1].T, b[:, 1]
        out[6:] = self._texels
        return out

    @staticmethod
    def texels(coef: np.ndarray, ids: np.ndarray, X: np.ndarray, Y: np.ndarray):
        """Texture coordinates ``(u, v)`` (float32, ``ids``' shape) of pixel centres ``X``, ``Y``
        (broadcast to ``ids``) in triangles ``ids`` (1 + the triangle, 0 none), from
        :meth:`coefficients` ``coef``.

        The pixel centre's barycentric coordinates in its triangle's grown footprint, clamped into
        it.  OpenCV fills the pixels a triangle's edges touch, whose centres may lie outside it: at
        rest at most a pixel out, so they sample what they show, but the extrapolated map of a
        triangle squeezed thin reached texels far across the drawing, drawn as specks beside it.
        """
        g = coef.take(ids, axis=1)                                      # (12, ...): one gather
        g[0:4:3] *= X                                                   # rows (0, 3), (1, 4), ...
        g[1:5:3] *= Y
        lam = g[0:4:3]                                                  # (l1, l2), a view
        lam += g[1:5:3]
        lam += g[2:6:3]
        np.maximum(lam, 0, out=lam)
        s = np.maximum(lam[0] + lam[1], 1, out=g[1])
        lam /= s
        g[7:11:3] *= lam[0]
        g[8:12:3] *= lam[1]
        g[6:10:3] += g[7:11:3]
        g[6:10:3] += g[8:12:3]
        return g[6], g[9]

    def render(self, vertices, order=None, background=None) -> np.ndarray:
        """One frame from vertices ``(n, 2)`` (output pixels) and a back-to-front part order:
        RGBA ``(H, W, 4)`` uint8, or RGB over ``background`` (an RGB triple)."""
        V = np.asarray(vertices, dtype=np.float64)
        H, W = self.size
        out = np.zeros((H, W, 4), np.uint8)                             # premultiplied RGBA
        if background is not None:  # an opaque page: the parts are laid straight onto its colour
            out[:] = tuple(int(b) for b in background) + (255,)
        coef = self.coefficients(V)
        P = np.rint(V[self.triangles] * 16).astype(np.int32)            # (t, 3, 2), 4 fractional bits
        order = range(len(self.part_triangles)) if order is None else order
        if self._ids is None or self._ids.shape != (H, W):
            self._ids = np.zeros((H, W), np.int32)
        gx, gy = np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)[:, None]
        for part in order:
            tris = self.part_triangles[part] if part < len(self.part_triangles) else ()
            if not len(tris):
                continue
            pts = P[tris]
            flat = pts.reshape(-1, 2)
            x0, y0 = np.maximum((flat.min(axis=0) >> 4) - 1, 0).tolist()
            x1, y1 = np.minimum((flat.max(axis=0) >> 4) + 2, (W, H)).tolist()
            if x1 <= x0 or y1 <= y0:
                continue
            ids = self._ids[y0:y1, x0:x1]
            ids[:] = 0
            local = list(pts - np.array([x0 * 16, y0 * 16], np.int32))
            for k, tri in zip((tris + 1).tolist(), local):
                cv2.fillConvexPoly(ids, tri, k, cv2.LINE_8, 4)
            X, Y = gx[x0:x1], gy[y0:y1]
            u, v = self.texels(coef, ids, X, Y)
            src = cv2.remap(self.texture, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                            borderValue=(0, 0, 0, 0))
            dst = out[y0:y1, x0:x1]
            keep = cv2.merge([255 - src[..., 3]] * 4)
            cv2.add(cv2.multiply(dst, keep, scale=1.0 / 255.0), src, dst=dst)
        if background is None:
            return to_uint8(out.astype(np.float32) / 255.0)
        return cv2.cvtColor(out, cv2.COLOR_RGBA2RGB)


def to_uint8(premult: np.ndarray) -> np.ndarray:
    """Premultiplied float RGBA ``(H, W, 4)`` in [0, 1] → straight RGBA uint8."""
    a = premult[..., 3:4]
    rgb = np.divide(premult[..., :3], a, out=np.zeros_like(premult[..., :3]), where=a > 1e-6)
    return np.clip(np.dstack([rgb, a]) * 255.0 + 0.5, 0, 255).astype(np.uint8)
