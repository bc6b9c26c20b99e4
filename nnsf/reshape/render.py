"""Rasterise a deformed character mesh and composite its parts, back to front.

Every pixel of a frame comes from a deformed triangle of the drawing: a triangle's texture
coordinates are its rest corners, so it shows the patch of the drawing it covered at rest (the
body underlay's triangles, and the body's own beside them, read the body painted in under a limb:
the second half of a texture atlas).  Nothing is repaired after the render.

Per frame, for each part in the frame's back-to-front order:

1. its triangles' ids are filled into an id image over the part's box (``cv2.fillConvexPoly``,
   1/16 px vertices): OpenCV fills a polygon's boundary pixels too, so triangles that share an
   edge leave no pixel between them, flipped or not;
2. each covered pixel's texture coordinate is its triangle's affine map (deformed → rest) of the
   pixel centre, within :data:`REACH` of the rest triangle's edges, and ``cv2.remap`` samples the
   premultiplied texture bilinearly;
3. the part is laid over what is drawn so far ("over", premultiplied alpha), so a limb's
   anti-aliased edge blends with the body under it.

Pixel centres are at integer coordinates.  Cost: one fill call per triangle and work per covered
pixel, so time grows with the pixels the character covers.
"""
from __future__ import annotations

import cv2
import numpy as np

#: Transparent columns between the drawing and the underlay in the texture atlas, pixels.
ATLAS_GAP = 8
#: How far outside its rest triangle a pixel's texel may lie, pixels.
REACH = 1.0
#: How far outside a triangle the centre of a pixel the fill gives it may lie, pixels: ``cv2.fillConvexPoly``
#: gives a triangle the pixels its outline touches (half a diagonal, and its 1/16 px vertices).
FILL_REACH = 0.75


def premultiplied(texture: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """RGBA ``(H, W, 4)`` uint8 → premultiplied float32 RGBA in [0, 1]; outside ``mask`` ``(H, W)`` transparent."""
    alpha = texture[..., 3].astype(np.float32) / 255.0 * np.asarray(mask, dtype=np.float32)
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
    ring : ``(t,)`` bool, drawn triangles that sample ``underlay`` too (:func:`~nnsf.reshape.mesh.underlay_ring`).
    """

    def __init__(self, mesh, texture: np.ndarray, mask: np.ndarray, size, underlay=None, ring=None):
        self.size = (int(size[0]), int(size[1]))
        self.triangles = np.asarray(mesh.triangles, dtype=np.int64)
        H, W = np.asarray(mask).shape
        tex = premultiplied(texture, mask)
        uv = mesh.vertices[self.triangles].copy()                       # (t, 3, 2)
        if underlay is not None and (mesh.layer == 1).any():
            # A transparent gap between the halves: a triangle reaching past the drawing's edge
            # (the mesh covers the mask grown by a few pixels) samples the page, not the other half.
            tex = np.hstack([tex, np.zeros((H, ATLAS_GAP, 4), tex.dtype), premultiplied(underlay, mask)])
            uv[(mesh.layer == 1) | (False if ring is None else ring), :, 0] += W + ATLAS_GAP
        # 8 bits a channel, premultiplied: sampling and compositing run on OpenCV's saturating uint8 arithmetic.
        self.texture = np.ascontiguousarray(np.clip(tex * 255.0 + 0.5, 0, 255).astype(np.uint8))
        self.set_texture_coordinates(uv)
        self.parts = np.asarray(mesh.parts, dtype=np.int64)
        # Within a part, the last triangle filled wins a pixel.  Where the part folds over itself (a joint bent
        # past its drawn angle), a triangle along the outline (half in the transparent margin around the drawing)
        # must not cover the drawn inside: the underlay is filled first, then the triangles from the outline inwards.
        depth = cv2.distanceTransform(np.pad(np.asarray(mask, np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
        c = np.rint(mesh.vertices[self.triangles].mean(axis=1)).astype(np.int64)
        inside = depth[np.clip(c[:, 1], 0, H - 1), np.clip(c[:, 0], 0, W - 1)]
        key = np.where(np.asarray(mesh.layer) == 1, -1.0, inside)
        self.part_triangles = [t[np.argsort(key[t], kind="stable")]
                               for t in (np.flatnonzero(self.parts == p) for p in range(int(self.parts.max()) + 1))]

    def set_texture_coordinates(self, uv: np.ndarray) -> None:
        """Each triangle's corners in the texture ``(t, 3, 2)`` texels, and what :meth:`_maps` and :meth:`_clamp` take from them."""
        self.uv = uv
        f = uv[:, 1:] - uv[:, :1]                                       # (t, 2, 2): rest edges
        self.edges = (f[:, 0, 0], f[:, 0, 1], f[:, 1, 0], f[:, 1, 1])    # u0, v0 of e0; u1, v1 of e1
        # Texel → λ1 + iλ2 = L0 u + L1 v + L2, barycentric of corners 1, 2 (one gather for both; row 0: none),
        L0, L1 = (np.linalg.pinv(f.transpose(0, 2, 1)) * [[1], [1j]]).sum(axis=1).T    # [e0 e1]^-1, rows as λ1 + iλ2
        self.bary = np.vstack([np.zeros(3), np.column_stack([L0, L1, -(L0 * uv[:, 0, 0] + L1 * uv[:, 0, 1])])]).T.copy()
        # and per corner, the least λ of a texel REACH beyond the edge facing it.
        twice = np.abs(f[:, 0, 0] * f[:, 1, 1] - f[:, 0, 1] * f[:, 1, 0])
        facing = np.linalg.norm(np.roll(uv, -1, axis=1) - np.roll(uv, 1, axis=1), axis=2)
        self.least = np.vstack([np.zeros(3), -REACH * facing / np.maximum(twice, 1e-12)[:, None]]).T.copy()

    def _maps(self, vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per triangle the affine map from a deformed pixel to its texel, u + iv = k0 x + k1 y + k2, ``(3, t + 1)``
        complex64 (a gather fetches a pair; u + iv as float32 pairs is OpenCV's two-channel map; row 0, "no triangle",
        maps far off the texture), and whether it is squashed ``(t + 1,)``: stretched by more than REACH / FILL_REACH."""
        D = vertices[self.triangles]
        # Component arithmetic on (t,) arrays: einsum over 2 × 2 blocks costs more than the maps.
        ex0, ey0 = D[:, 1, 0] - D[:, 0, 0], D[:, 1, 1] - D[:, 0, 1]      # deformed edges e0, e1
        ex1, ey1 = D[:, 2, 0] - D[:, 0, 0], D[:, 2, 1] - D[:, 0, 1]
        fu0, fv0, fu1, fv1 = self.edges
        det = ex0 * ey1 - ex1 * ey0
        ok = np.abs(det) > 1e-9
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)            # a collapsed triangle: one texel
        # [f0 f1] · [e0 e1]^-1, the inverse being [[ey1, -ex1], [-ey0, ex0]] / det.
        a, bb = (fu0 * ey1 - fu1 * ey0) * inv, (fu1 * ex0 - fu0 * ex1) * inv
        c, d = (fv0 * ey1 - fv1 * ey0) * inv, (fv1 * ex0 - fv0 * ex1) * inv
        u0, v0 = self.uv[:, 0, 0], self.uv[:, 0, 1]
        out = np.empty((3, len(D) + 1), np.complex64)
        out[:, 0] = (0, 0, -1e4 - 1e4j)
        out[0, 1:], out[1, 1:] = a + 1j * c, bb + 1j * d
        out[2, 1:] = np.where(ok, u0 - a * D[:, 0, 0] - bb * D[:, 0, 1], self.uv[:, :, 0].mean(axis=1)) + 1j * \
            np.where(ok, v0 - c * D[:, 0, 0] - d * D[:, 0, 1], self.uv[:, :, 1].mean(axis=1))
        sigma = 0.5 * (np.hypot(a + d, c - bb) + np.hypot(a - d, bb + c))  # the map's larger singular value
        return out, np.r_[False, sigma * FILL_REACH > REACH]

    def render(self, vertices, order=None, background=None) -> np.ndarray:
        """One frame from vertices ``(n, 2)`` (output pixels) and a back-to-front part order:
        RGBA ``(H, W, 4)`` uint8, or RGB over ``background`` (an RGB triple)."""
        V = np.asarray(vertices, dtype=np.float64)
        H, W = self.size
        out = np.zeros((H, W, 4), np.uint8)                             # premultiplied RGBA
        if background is not None:  # an opaque page: the parts are laid straight onto its colour
            # One 32-bit word a pixel: numpy broadcasts a 4-tuple over an image far more slowly.
            out.view(np.uint32)[:] = np.array(tuple(int(b) for b in background) + (255,), np.uint8).view(np.uint32)[0]
        maps, squashed = self._maps(V)
        P = np.rint(V[self.triangles] * 16).astype(np.int32)            # (t, 3, 2), 4 fractional bits
        order = range(len(self.part_triangles)) if order is None else order
        gx, gy = np.arange(W, dtype=np.float32), np.arange(H, dtype=np.float32)[:, None]
        boxes = []                                                      # per part: its box's corner, ids and texels
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
            ids = np.zeros((y1 - y0, x1 - x0), np.int32)
            local = list(pts - np.array([x0 * 16, y0 * 16], np.int32))
            for k, tri in zip((tris + 1).tolist(), local):
                cv2.fillConvexPoly(ids, tri, k, cv2.LINE_8, 4)
            # ids are in range by construction: mode="clip" skips numpy's bounds check.
            w = maps[0].take(ids, mode="clip") * gx[x0:x1] + maps[1].take(ids, mode="clip") * gy[y0:y1]
            w += maps[2].take(ids, mode="clip")
            boxes.append((x0, y0, ids, w))
        self._clamp(boxes, maps, squashed, V)
        for x0, y0, ids, w in boxes:
            src = cv2.remap(self.texture, w.view(np.float32).reshape(ids.shape + (2,)), None, cv2.INTER_LINEAR,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0))
            dst = out[y0:y0 + ids.shape[0], x0:x0 + ids.shape[1]]
            keep = cv2.merge([255 - src[..., 3]] * 4)
            cv2.add(cv2.multiply(dst, keep, scale=1.0 / 255.0), src, dst=dst)
        if background is None:
            return to_uint8(out.astype(np.float32) / 255.0)
        return cv2.cvtColor(out, cv2.COLOR_RGBA2RGB)

    def _clamp(self, boxes, maps, squashed, V) -> None:
        """The texels ``u + iv`` of each part's ``boxes`` (``(x0, y0, ids, texels)``) at the pixels of squashed
        triangles whose texel lies beyond REACH of an edge of the rest triangle: the texel of the nearest
        point of the deformed triangle, moved at most REACH towards the pixel's own, so a pixel beside a
        sliver shows its edge, not a texel its map carries far off (all parts at once: numpy's cost is per call)."""
        hits = [np.flatnonzero(squashed.take(ids, mode="clip")) for _, _, ids, _ in boxes]   # flat, per box
        k = np.concatenate([b[2].take(h) for b, h in zip(boxes, hits)] + [np.zeros(0, np.int32)])
        c = np.concatenate([b[3].take(h) for b, h in zip(boxes, hits)] + [np.zeros(0, np.complex64)])
        lam = self.bary[0].take(k) * c.real + self.bary[1].take(k) * c.imag + self.bary[2].take(k)   # float64
        bad = np.flatnonzero((lam.real < self.least[1].take(k)) | (lam.imag < self.least[2].take(k))
                             | (1 - lam.real - lam.imag < self.least[0].take(k)))
        box = np.repeat(np.arange(len(boxes)), [len(h) for h in hits])[bad]
        flat = np.concatenate(hits + [np.zeros(0, np.int64)])[bad]
        x0, y0, width = np.array([(b[0], b[1], b[2].shape[1]) for b in boxes] + [(0, 0, 1)])[box].T
        y, x = np.divmod(flat, width)
        p = np.column_stack([x + x0, y + y0]).astype(np.float64)
        D = V[self.triangles[k[bad] - 1]]                               # (k, 3, 2)
        e = D[:, [1, 2, 0]] - D                                         # each edge's direction from its start
        t = np.clip(np.einsum("kex,kex->ke", p[:, None] - D, e) / np.maximum((e * e).sum(2), 1e-12), 0, 1)
        near = D + t[..., None] * e
        q = near[np.arange(len(bad)), np.argmin(((p[:, None] - near) ** 2).sum(2), axis=1)]
        z = maps[0, k[bad]] * q[:, 0] + maps[1, k[bad]] * q[:, 1] + maps[2, k[bad]]
        off = c[bad] - z
        z += off * np.minimum(1.0, REACH / np.maximum(np.abs(off), 1e-12))
        for j in np.unique(box):
            np.put(boxes[j][3], flat[box == j], z[box == j])


def to_uint8(premult: np.ndarray) -> np.ndarray:
    """Premultiplied float RGBA ``(H, W, 4)`` in [0, 1] → straight RGBA uint8."""
    a = premult[..., 3:4]
    rgb = np.divide(premult[..., :3], a, out=np.zeros_like(premult[..., :3]), where=a > 1e-6)
    return np.clip(np.dstack([rgb, a]) * 255.0 + 0.5, 0, 255).astype(np.uint8)
