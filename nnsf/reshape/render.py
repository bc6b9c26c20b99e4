"""Textured-mesh rasterisation of a deformed character, and animation files.

:class:`MeshRenderer` draws a deformed mesh with the character's texture:
texture coordinates are the rest vertex positions, so every deformed
triangle shows the patch of the drawing it covered at rest.  Parts are drawn
back to front in a given depth order (:mod:`nnsf.reshape.depth`).

Rasterisation, vectorised (no per-triangle Python loop):

1. every triangle's pixel bounding box is expanded into candidate pixels
   (ragged ranges built with ``np.repeat``/``cumsum``);
2. a candidate is inside when its three edge functions are ≥ −ε (a shared
   edge then belongs to both neighbours: no cracks; both give the same
   texture coordinate there since the map is continuous);
3. candidates are written part by part in depth order into a per-pixel
   triangle-id image, so a nearer part overwrites a farther one;
4. each covered pixel's texture coordinate is its triangle's inverse affine
   map applied to the pixel centre, and one ``cv2.remap`` (bilinear)
   samples the premultiplied texture.

Pixel centres are at integer coordinates (pixel (x, y) covers
[x−½, x+½] × [y−½, y+½]), the convention of :mod:`nnsf.reshape.character`.

Writers: :func:`write_png_frames` (a folder of PNGs), :func:`write_gif`
(Pillow) and :func:`write_mp4` (OpenCV's ``VideoWriter``: H.264 when the
build has an encoder, else ``mp4v``, :func:`mp4_codec`; works headless).  All
write atomically.
"""
from __future__ import annotations

import functools

import cv2
import numpy as np

from nnsf.reshape.parts import JOINED_PARTS, PARTS
from nnsf.reshape.regions import body_line
from nnsf.reshape.outline import outline_style, redraw_outline
from nnsf.reshape.tab_texture import TabClip, ink_mask, tab_textures
from nnsf.reshape.seal import DrawnGaps, drawn_hole_limit, over, seal

#: Cracks up to ``2·CRACK_CLOSE + 1`` px wide are sealed on a sprite (a drawing whose scale closing
#: is 1 px): a crack's width comes from how far a joint turns past its piece's overlap, in pixels,
#: not from the drawing's size.  The sprite's own slits, which a closing this wide would fill, are
#: kept (:class:`DrawnGaps`).  A larger drawing keeps its 2-4 px scale closing: on char5 (277 px)
#: 3 px merged two of its extra arms where they turn apart.  Where its scale closing is narrower,
#: the runs of a ``CRACK_CLOSE`` px closing shorter than its disc are sealed too (``corner`` of
#: :func:`~nnsf.reshape.seal.seal_mask`): acute corners between a limb and the body, not gaps.
CRACK_CLOSE = 3


class MeshRenderer:
    """Draws one character's mesh, deformed, at the texture's resolution.

    Parameters
    ----------
    rest_vertices : ``(n, 2)`` rest positions = texture coordinates, pixels.
    triangles : ``(t, 3)``.
    parts : ``(t,)`` part id per triangle (indices into :data:`PARTS`).
    texture : ``(H, W, 4)`` uint8 RGBA.
    mask : optional ``(H, W)`` bool: texture pixels outside it are transparent.
    size : output ``(H, W)``; default the texture's.
    """

    def __init__(self, rest_vertices, triangles, parts, texture, mask=None, size=None,
                 layer=None, underlay=None, behind=None, rim=None, seal=False, textures=None, reink=None,
                 tuck=None):
        #: Whether :meth:`render` seals holes and joint cracks (:mod:`nnsf.reshape.seal`).
        self.seal = bool(seal)
        #: Outline redrawn along new silhouette edges (:func:`outline_style`, :meth:`_reink`):
        #: ``(rgb, width)`` or None.
        self.reink = reink
        self._seal_kw = {}
        if self.seal and mask is not None:
            self._seal_kw["hole_max"] = drawn_hole_limit(mask)
            # Cracks are closed over a radius that scales with the drawing (4 px
            # on a 600 px character, 1 px on a 128 px sprite whose drawn gaps are a few px).
            ys = np.flatnonzero(np.asarray(mask, dtype=bool).any(axis=1))
            height = float(ys[-1] - ys[0] + 1) if len(ys) else 0.0
            self._seal_kw["close"] = int(np.clip(round(0.007 * height), 1, 4))
            self._seal_kw["tab_close"] = self._seal_kw["close"]
            # Cracks only where a joint joins two parts; a gap between others is drawn.
            self._seal_kw["joined"] = JOINED_PARTS
            self._seal_kw["corner"] = CRACK_CLOSE
            # Not on a sprite (scale closing 1 px): it would fill its 1-2 px drawn slits.
            self._seal_kw["hairline"] = self._seal_kw["close"] > 1
        self.uv = np.asarray(rest_vertices, dtype=np.float64)
        self.triangles = np.asarray(triangles, dtype=np.int64)
        self.parts = np.asarray(parts, dtype=np.int64)
        tex = np.asarray(texture)
        H, W = tex.shape[:2]

        def premultiplied(t):
            alpha = t[..., 3].astype(np.float32) / 255.0
            if mask is not None:
                alpha = alpha * np.asarray(mask, dtype=np.float32)
            # Premultiplied colour, so bilinear sampling at the silhouette's edge
            # does not bleed the drawing's background colour into the result.
            return np.dstack([t[..., :3].astype(np.float32) * alpha[..., None], alpha])

        # Layer-k triangles (a layered mesh's underlay, k = 1, and body rim,
        # k = 2) sample the k-th texture of one atlas, placed side by side: one
        # remap.  A layer without its texture samples the drawing.
        self.layer = (np.zeros(len(self.triangles), np.int64) if layer is None
                      else np.asarray(layer, dtype=np.int64).copy())
        # Rim copies (layer 2) are drawn before every part: they show only
        # where nothing else is drawn (where a limb has moved away), and their
        # transparent texels never hide a limb.
        rim_first = self.layer == 2
        # Each triangle's layer as given (a layer without its texture is drawn as layer 0 below):
        # layers 3 and up are joint tabs, whose slivers the seal closes.
        self._tab_layer = self.layer.copy()
        # Turned tabs to hide beside their parents (:class:`TabClip`; set by :meth:`for_mesh`).
        self._clip = None
        # Layer k ≥ 3: ``textures[k]`` (a pieced mesh's joint tabs, several layers may share one image).
        extra = {1: underlay, 2: rim}
        extra.update(dict(textures or {}))
        for k in np.unique(self.layer):
            if k > 0 and extra.get(int(k)) is None:
                self.layer[self.layer == k] = 0
        # One atlas slot per distinct texture image in use (slot 0: the drawing).
        slots, slot_of = [tex], {0: 0}
        for k in sorted(int(x) for x in np.unique(self.layer) if x > 0):
            img = extra[k]
            for j, other in enumerate(slots):
                if other is img:
                    slot_of[k] = j
                    break
            else:
                slot_of[k] = len(slots)
                slots.append(img)
        self._slots = [premultiplied(np.asarray(t)) for t in slots]
        # Distance (px) of each texel from the drawing's outline, inside it; a tab's texels count as
        # deep inside (every edge of a tab is new): :meth:`_reink` inks new edges only.
        inner = np.zeros((H, W), np.float32) if mask is None else cv2.distanceTransform(
            np.pad(np.asarray(mask, np.uint8), 1), cv2.DIST_L2, 3)[1:-1, 1:-1].astype(np.float32)
        # Slots side by side with a clear 2 px gap, so bilinear sampling at a drawing's right edge
        # never reads the next slot.
        gap = 2
        interiors = [inner if j == 0 or any(slot_of.get(k) == j for k in (1, 2))
                     else np.where(self._slots[j][..., 3] > 0, 1e3, 0).astype(np.float32)
                     for j in range(len(self._slots))]
        self._interior = np.hstack([np.pad(x, ((0, 0), (0, gap))) for x in interiors])
        self._shift = np.array([slot_of[int(k)] for k in self.layer], np.float64) * (W + gap)
        atlas = np.hstack([np.pad(x, ((0, 0), (0, gap), (0, 0))) for x in self._slots])
        self._tex8 = np.clip(np.rint(atlas * np.array([1, 1, 1, 255], np.float32)), 0, 255).astype(np.uint8)
        self.size = tuple(size) if size is not None else (H, W)
        # ``behind[k] = p`` (a layered mesh's collars) draws triangle k just
        # before part p instead of with its own part: under the parent, over
        # whatever lies behind the parent.
        behind = (np.full(len(self.triangles), -1, np.int64) if behind is None
                  else np.asarray(behind, dtype=np.int64))
        P = len(PARTS)
        own = (behind < 0) & ~rim_first
        # Per part: the collars drawn just before it, and its own triangles.
        self._collars = [np.flatnonzero(behind == p) for p in range(P)]
        self._own = [np.flatnonzero((self.parts == p) & own) for p in range(P)]
        self._first = [np.flatnonzero((self.parts == p) & (behind < 0) & rim_first) for p in range(P)]
        # Draw groups: rim copies −1, collars before part p 2p, part p's own 2p + 1 (and, per frame,
        # a tucked band moved before the body −2 − its part: :meth:`_draw_list`).
        self._group = np.where(behind >= 0, 2 * behind, np.where(rim_first, -1, 2 * self.parts + 1))
        # ``tuck[k] = p`` (a thigh's band along its hip cut, :func:`nnsf.reshape.pieces.hip_tucks`):
        # in a frame whose order draws k's part q after part p, triangle k is drawn just before p's
        # own triangles, after p's collars, and q's collars (the tabs hidden under q) with it:
        # under the body, over what lay under the whole thigh before.  Otherwise it is drawn with
        # q.  Per part: its tucked triangles, the part they go under, its own triangles without them.
        tuck = (np.full(len(self.triangles), -1, np.int64) if tuck is None
                else np.where(own, np.asarray(tuck, dtype=np.int64), -1))
        self._tucked = {}
        for q in range(P):
            k = np.flatnonzero((self.parts == q) & (tuck >= 0))
            if k.size:
                under = np.unique(tuck[k])
                if len(under) != 1:
                    raise ValueError(f"part {PARTS[q]} tucks under several parts {under.tolist()}; expected one")
                self._tucked[q] = (k, int(under[0]), self._own[q][~np.isin(self._own[q], k)])
        #: The drawing's own narrow slits (:class:`~nnsf.reshape.seal.DrawnGaps`), kept open by the seal;
        #: None unless sealing a masked sprite (scale closing 1 px, under 214 px tall), whose cracks
        #: are then closed by :data:`CRACK_CLOSE` px (the joint tabs' slivers keep ``tab_close``).
        self._gaps = None
        if self.seal and mask is not None and self._seal_kw["close"] == 1:
            self._seal_kw["close"] = CRACK_CLOSE
            # The rest pose in texture pixels; the atlas's first slot holds the masked drawing's alpha.
            ids = self.maps(self.uv, size=(H, W))[2]
            gaps = DrawnGaps(ids, self._tex8[:, :W, 3], self.uv, self.triangles, self.parts, CRACK_CLOSE,
                             self._seal_kw["tab_close"],
                             self._seal_kw["joined"])
            self._gaps = gaps if len(gaps) else None

    @classmethod
    def for_mesh(cls, mesh, character, size=None, seal=None) -> "MeshRenderer":
        """A renderer for ``mesh`` (:class:`~nnsf.reshape.mesh.Mesh`) of ``character``, with its underlay.

        ``seal``: fill holes and joint cracks (:mod:`nnsf.reshape.seal`);
        default on for a pieced mesh (layered, whole-limb, split), off for a
        connected one (it cannot tear).
        """
        if mesh.overlay is not None and mesh.overlay.any():
            underlay = overlay_texture(character.texture, character.mask, mesh.overlay)
        else:
            underlay = underlay_texture(character.texture, character.mask, mesh) if (mesh.layer == 1).any() else None
        rim = (rim_texture(character.texture, character.mask, character.keypoints)
               if (mesh.layer == 2).any() else None)
        style = outline_style(character.texture, character.mask) if mesh.tabs else None
        textures = tab_textures(mesh, character, style) if mesh.tabs else None
        pieced = mesh.is_split
        out = cls(mesh.vertices, mesh.triangles, mesh.parts, character.texture, character.mask,
                   size=size, layer=mesh.layer, underlay=underlay, behind=mesh.collar, rim=rim, tuck=mesh.tuck,
                   seal=seal if seal is not None else pieced, textures=textures,
                   reink=style if pieced else None)
        out._tab_textures = textures
        out._clip = TabClip(mesh, character.mask) if mesh.tabs else None
        return out

    def _raster(self, V: np.ndarray, order, size=None):
        """Covered pixel runs ``(y, x_first, length, triangle)``, each ``(r,)``, nearest part last.

        Scanline rasterisation vectorised over (triangle, row) pairs: on row
        y each edge's half-plane a x + b y + c ≥ 0 bounds x from one side,
        so a triangle covers the run ⌈max lower bounds⌉ … ⌊min upper bounds⌋;
        only the runs are expanded into pixels.
        """
        H, W = self.size if size is None else size
        sel, grp = self._draw_list(order)
        P = V[self.triangles[sel]]  # (s, 3, 2)
        y0 = np.clip(np.ceil(P[..., 1].min(axis=1) - 1e-9), 0, H).astype(np.int64)
        y1 = np.clip(np.floor(P[..., 1].max(axis=1) + 1e-9), -1, H - 1).astype(np.int64)
        nrows = np.maximum(y1 - y0 + 1, 0)
        area2 = ((P[:, 1, 0] - P[:, 0, 0]) * (P[:, 2, 1] - P[:, 0, 1])
                 - (P[:, 1, 1] - P[:, 0, 1]) * (P[:, 2, 0] - P[:, 0, 0]))
        nrows[np.abs(area2) < 1e-12] = 0
        total = int(nrows.sum())
        if total == 0:
            z = np.zeros(0, np.int64)
            return z, z, z, z, z
        sgn = np.where(area2 >= 0, 1.0, -1.0)
        # Edge k from corner k to k+1: inside when sgn·((q−p) × (x−p)) ≥ 0, i.e.
        # a x + b y + c ≥ 0 with a = −sgn·dy, b = sgn·dx, c = sgn·(dy px − dx py).
        p = P
        q = P[:, [1, 2, 0]]
        dx, dy = q[..., 0] - p[..., 0], q[..., 1] - p[..., 1]
        a = -sgn[:, None] * dy
        b = sgn[:, None] * dx
        c = sgn[:, None] * (dy * p[..., 0] - dx * p[..., 1])
        eps = 1e-7 * np.abs(area2)[:, None] + 1e-9
        row_t = np.repeat(np.arange(len(sel)), nrows)
        start = np.repeat(np.cumsum(nrows) - nrows, nrows)
        y = (y0[row_t] + np.arange(total) - start).astype(np.float64)
        r = b[row_t] * y[:, None] + c[row_t] + eps[row_t]  # (R, 3): a x + r ≥ 0
        ar = a[row_t]
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = -r / ar
        lo = np.where(ar > 0, bound, -np.inf).max(axis=1)
        hi = np.where(ar < 0, bound, np.inf).min(axis=1)
        # An edge parallel to the row excludes the whole row when the row is outside it.
        blocked = ((ar == 0) & (r < 0)).any(axis=1)
        xl = np.clip(np.ceil(lo), 0, W).astype(np.int64)
        xr = np.clip(np.floor(hi), -1, W - 1).astype(np.int64)
        n = np.where(blocked, 0, np.maximum(xr - xl + 1, 0))
        keep = n > 0
        return y[keep].astype(np.int64), xl[keep], n[keep], sel[row_t[keep]], grp[row_t[keep]]

    def _draw_list(self, order) -> tuple[np.ndarray, np.ndarray]:
        """Triangles in drawing order for the part ``order`` of one frame, and each one's draw group."""
        pos = {int(p): i for i, p in enumerate(order)}
        # Tucked bands of parts drawn after the part they tuck under go just before that part.
        moved = {q: t for q, t in self._tucked.items() if q in pos and pos.get(t[1], len(pos)) < pos[q]}
        drawn = [(k, self._group[k]) for k in (self._first[p] for p in order)]
        for p in order:
            if p not in moved:  # a moved part's collars go with its band
                drawn.append((self._collars[p], self._group[self._collars[p]]))
            # A moved band takes the tabs hidden under its own part with it (before it, as under the
            # whole part); nearer parts' bands last, each a group of its own (−2 − its part), so
            # two bands that overlap are written in order.
            for q in sorted((q for q, t in moved.items() if t[1] == p), key=pos.get):
                band = moved[q][0]
                drawn += [(self._collars[q], self._group[self._collars[q]]),
                          (band, np.full(len(band), -2 - q, np.int64))]
            own = moved[p][2] if p in moved else self._own[p]
            drawn.append((own, self._group[own]))
        sel = np.concatenate([np.zeros(0, np.int64)] + [k for k, _ in drawn])
        grp = np.concatenate([np.zeros(0, np.int64)] + [g for _, g in drawn])
        return sel, grp

    def _affine(self, V: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Inverse affine map of every triangle, deformed pixel -> atlas texel: A ``(t, 2, 2)``, b ``(t, 2)``."""
        tri = self.triangles
        D = V[tri]
        U = self.uv[tri]
        Md = np.stack([D[:, 1] - D[:, 0], D[:, 2] - D[:, 0]], axis=-1)  # (t, 2, 2)
        Mu = np.stack([U[:, 1] - U[:, 0], U[:, 2] - U[:, 0]], axis=-1)
        det = Md[:, 0, 0] * Md[:, 1, 1] - Md[:, 0, 1] * Md[:, 1, 0]
        ok = np.abs(det) > 1e-12
        inv = np.zeros_like(Md)
        sd = np.where(ok, det, 1.0)
        inv[:, 0, 0], inv[:, 0, 1] = Md[:, 1, 1] / sd, -Md[:, 0, 1] / sd
        inv[:, 1, 0], inv[:, 1, 1] = -Md[:, 1, 0] / sd, Md[:, 0, 0] / sd
        A = Mu @ inv
        b = U[:, 0] - np.einsum("tij,tj->ti", A, D[:, 0])
        b[:, 0] += self._shift
        return A, b

    def _crop_maps(self, vertices, order, with_ids: bool = False, below: bool = False, size=None):
        """Maps for the bounding box of the drawn pixels: ``(y0, x0, ids, map_x, map_y)``, crop-sized.

        ``ids`` (triangle per pixel, −1 empty) is None unless ``with_ids``.
        With ``below``, three more maps follow: the texel of the draw group
        each pixel showed before the nearest one covered it (−1 where
        nothing lay under it), for compositing a soft edge over what it
        covers (:meth:`render_labelled`), and that texel's triangle (None
        unless ``with_ids``).
        Along a run the texel coordinate is linear in x, so per-run offsets
        are computed once and repeated (no per-pixel gather of triangle maps).
        """
        V = np.asarray(vertices, dtype=np.float64)
        order = list(range(len(PARTS))) if order is None else list(order)
        ry, rx, rn, rt, rg = self._raster(V, order, size)
        if len(ry) == 0:
            e = np.zeros((0, 0), np.float32)
            return (0, 0, (e.astype(np.int32) if with_ids else None), e, e) + ((e, e) if below else ())
        y0, x0 = int(ry.min()), int(rx.min())
        h, w = int(ry.max()) - y0 + 1, int((rx + rn).max()) - x0
        A, b = self._affine(V)
        # Per run: texel = A[:, 0] x + (A[:, 1] y + b).
        a0, a1 = A[rt, 0, 0], A[rt, 1, 0]
        c0 = A[rt, 0, 1] * ry + b[rt, 0]
        c1 = A[rt, 1, 1] * ry + b[rt, 1]
        k = int(rn.sum())
        first = np.cumsum(rn) - rn
        x = (np.arange(k) - np.repeat(first - rx, rn)).astype(np.float32)  # pixel x
        mxv = np.repeat(a0.astype(np.float32), rn) * x + np.repeat(c0.astype(np.float32), rn)
        myv = np.repeat(a1.astype(np.float32), rn) * x + np.repeat(c1.astype(np.float32), rn)
        cpix = np.repeat((ry - y0) * w - x0, rn) + x.astype(np.int64)
        mx = np.full(h * w, -1.0, dtype=np.float32)
        my = np.full(h * w, -1.0, dtype=np.float32)
        ids = np.full(h * w, -1, dtype=np.int32) if with_ids else None
        bx = np.full(h * w, -1.0, dtype=np.float32) if below else None
        by = np.full(h * w, -1.0, dtype=np.float32) if below else None
        bid = np.full(h * w, -1, dtype=np.int32) if (below and with_ids) else None
        # Runs come grouped by part in depth order; numpy leaves the order of
        # duplicate writes within one fancy assignment unspecified, so each
        # part is written separately: a later (nearer) part always wins.
        run_part = rg
        cut = np.flatnonzero(np.diff(run_part)) + 1
        pstart = np.r_[0, first[cut], k] if len(cut) else np.r_[0, k]
        rstart = np.r_[0, cut, len(rt)]
        for g in range(len(pstart) - 1):
            s, e = pstart[g], pstart[g + 1]
            if below:  # what this group covers (read before it is written)
                bx[cpix[s:e]] = mx[cpix[s:e]]
                by[cpix[s:e]] = my[cpix[s:e]]
                if bid is not None:
                    bid[cpix[s:e]] = ids[cpix[s:e]]
            mx[cpix[s:e]] = mxv[s:e]
            my[cpix[s:e]] = myv[s:e]
            if with_ids:
                ids[cpix[s:e]] = np.repeat(rt[rstart[g]:rstart[g + 1]], rn[rstart[g]:rstart[g + 1]])
        out = (y0, x0, None if ids is None else ids.reshape(h, w), mx.reshape(h, w), my.reshape(h, w))
        return out + ((bx.reshape(h, w), by.reshape(h, w), None if bid is None else bid.reshape(h, w))
                      if below else ())

    def maps(self, vertices, order=None, size=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Texture look-up maps for one frame.

        Returns ``map_x, map_y`` ``(H, W)`` float32 (texel coordinates in the
        texture atlas, −1 where nothing is drawn) and the triangle-id image
        ``(H, W)`` int32 (−1 where empty).  ``order``: part ids back to front
        (default: :data:`PARTS` order); parts not listed are not drawn.  ``size``: ``(H, W)`` of
        the image (default the renderer's).
        """
        H, W = self.size if size is None else size
        y0, x0, ids, mx, my = self._crop_maps(vertices, order, with_ids=True, size=(H, W))
        h, w = ids.shape
        full = [np.full((H, W), -1, dtype=d) for d in (np.float32, np.float32, np.int32)]
        for f, c in zip(full, (mx, my, ids)):
            f[y0:y0 + h, x0:x0 + w] = c
        return full[0], full[1], full[2]

    def render(self, vertices, order=None, background=None) -> np.ndarray:
        """One frame: RGBA ``(H, W, 4)`` uint8, or RGB over ``background`` (an RGB triple)."""
        return self.render_labelled(vertices, order, background)[0]

    def render_labelled(self, vertices, order=None, background=None, labels: bool = False):
        """One frame and, with ``labels``, its visible part per pixel ``(H, W)`` int (−1 empty), else None.

        The part image is the rasteriser's (before sealing: a sealed pixel
        shows no part).
        """
        H, W = self.size
        clip = self._clip
        y0, x0, ids, mx, my, bx, by, bid = self._crop_maps(vertices, order, with_ids=self.seal or labels or bool(clip),
                                                           below=True)
        h, w = mx.shape
        if clip and h:
            # Turned tabs that stick out beside their parent show what lies under them (TabClip).
            hide = clip.hidden(vertices, ids, self._tab_layer, y0, x0)
            if hide.any():
                mx[hide], my[hide], ids[hide] = bx[hide], by[hide], bid[hide]
                bx[hide] = by[hide] = -1
        # One bilinear remap of the premultiplied 8-bit atlas, on the drawn box only.
        crop = cv2.remap(self._tex8, mx, my, interpolation=cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0, 0)) if h else None
        if h:
            # A pixel keeps only its nearest triangle's texel; where that texel is part
            # transparent (the soft rim of a limb's outline) it is laid over the texel of
            # the part it covers, premultiplied "over".  Without this a limb crossing the
            # body is edged with the paper's colour: a light hairline along its outline.
            soft = np.flatnonzero(((crop[..., 3] < 255) & (bx >= 0)).ravel())
            if soft.size:
                # only those pixels are looked up again: a (k, 1) map
                under = cv2.remap(self._tex8, bx.ravel()[soft, None], by.ravel()[soft, None],
                                  interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                  borderValue=(0, 0, 0, 0))[:, 0]
                flat = crop.reshape(-1, 4)
                flat[soft] = over(flat[soft], under)
        part_crop = None
        if ids is not None and h:
            part_crop = np.where(ids >= 0, self.parts[np.maximum(ids, 0)], -1)
        if self.seal and h:
            tab = (ids >= 0) & (self._tab_layer[np.maximum(ids, 0)] >= 3)
            slits = None if self._gaps is None else self._gaps.points(vertices)
            keep = None if slits is None else self._gaps.mask(slits, y0, x0, h, w)
            crop = seal(crop, part_crop, tab=tab, keep=keep, **self._seal_kw)
        if self.reink is not None and h:
            # A margin for the half of the stroke that lies outside the silhouette.
            H, W = self.size
            r = int(np.ceil(self.reink[1])) + 2
            py0, px0 = min(r, y0), min(r, x0)
            py1, px1 = min(r, H - (y0 + h)), min(r, W - (x0 + w))
            crop = np.pad(crop, ((py0, py1), (px0, px1), (0, 0)))
            mx = np.pad(mx, ((py0, py1), (px0, px1)), constant_values=-1)
            my = np.pad(my, ((py0, py1), (px0, px1)), constant_values=-1)
            if part_crop is not None:
                part_crop = np.pad(part_crop, ((py0, py1), (px0, px1)), constant_values=-1)
            y0, x0 = y0 - py0, x0 - px0
            h, w = crop.shape[:2]
            inked = self._reink(crop, mx, my)
            if self.seal and inked is not crop:
                # A stroke half outside the silhouette can close a pocket of paper: sealed as well.
                # the slits again, in the crop padded for the stroke
                keep = None if slits is None else self._gaps.mask(slits, y0, x0, h, w)
                inked = seal(inked, part_crop, keep=keep, **self._seal_kw)
            crop = inked
        part_img = None
        if labels:
            part_img = np.full((H, W), -1, np.int64)
            if h:
                part_img[y0:y0 + h, x0:x0 + w] = part_crop
        return self._compose(crop, y0, x0, background), part_img

    def _reink(self, crop: np.ndarray, mx: np.ndarray, my: np.ndarray) -> np.ndarray:
        """Redraw the outline along silhouette edges the drawing had no outline on
        (:func:`nnsf.reshape.outline.redraw_outline`); ``mx``, ``my``: the crop's texture maps."""
        depth = cv2.remap(self._interior, mx, my, interpolation=cv2.INTER_NEAREST,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)
        return redraw_outline(crop, depth, self.reink)

    def _compose(self, crop, y0, x0, background) -> np.ndarray:
        H, W = self.size
        h = 0 if crop is None else crop.shape[0]
        w = 0 if crop is None else crop.shape[1]
        if background is not None:
            out = np.empty((H, W, 3), np.uint8)
            out[:] = np.asarray(background, dtype=np.uint8)
            if h:
                # premultiplied over: rgb + (1 − α) bg, in integers with rounding.  The second term
                # depends on α alone: one 256-entry table per channel (cv2.LUT), then a saturating
                # add; 4× faster than the same sums in uint16 numpy, and the same bytes.
                a = crop[..., 3]
                under = cv2.LUT(cv2.merge([a, a, a]), _under_table(tuple(int(c) for c in background)))
                out[y0:y0 + h, x0:x0 + w] = cv2.add(cv2.cvtColor(crop, cv2.COLOR_RGBA2RGB), under)
            return out
        out = np.zeros((H, W, 4), np.uint8)
        if h:
            a = crop[..., 3:4].astype(np.uint16)
            rgb = (crop[..., :3].astype(np.uint16) * 255 + a // 2) // np.maximum(a, 1)
            out[y0:y0 + h, x0:x0 + w, :3] = np.minimum(rgb, 255).astype(np.uint8)
            out[y0:y0 + h, x0:x0 + w, 3] = crop[..., 3]
        return out

    def render_clip(self, frames, orders=None, background=None) -> np.ndarray:
        """Frames ``(T, n, 2)`` (and orders ``(T, parts)``) -> images ``(T, H, W, 3|4)`` uint8."""
        frames = np.asarray(frames)
        return np.stack([self.render(frames[t], None if orders is None else orders[t], background)
                         for t in range(len(frames))])


@functools.lru_cache(maxsize=8)
def _under_table(background: tuple) -> np.ndarray:
    """``(1, 256, 3)`` uint8: the background ``(r, g, b)`` seen through alpha a, round((255 − a) · bg / 255)."""
    a = np.arange(256, dtype=np.int64)[:, None]
    return (((255 - a) * np.asarray(background, np.int64)[None] + 127) // 255).astype(np.uint8).reshape(1, 256, 3)


def underlay_texture(texture: np.ndarray, mask: np.ndarray, mesh, radius: float = 6.0) -> np.ndarray:
    """The drawing with the limbs lying over the body painted out, ``(H, W, 4)`` uint8 RGBA.

    The region covered at rest by ``mesh``'s layer-1 triangles (grown by
    2 px) is filled with ``cv2.inpaint`` (Telea) from the surrounding
    pixels of the silhouette; pixels outside the silhouette are first set to
    the silhouette's mean colour, so the fill does not pull in the paper.
    """
    H, W = mask.shape
    region = np.zeros((H, W), np.uint8)
    tri = mesh.triangles[mesh.layer == 1]
    if len(tri):
        cv2.fillPoly(region, list(np.rint(mesh.vertices[tri]).astype(np.int32)), 255)
    region = cv2.dilate(region, np.ones((5, 5), np.uint8))
    rgb = np.ascontiguousarray(texture[..., :3]).copy()
    m = np.asarray(mask, dtype=bool)
    if m.any():
        rgb[~m] = rgb[m].mean(axis=0).astype(np.uint8)
    filled = cv2.inpaint(rgb, region, radius, cv2.INPAINT_TELEA)
    return np.dstack([filled, texture[..., 3]])


def overlay_texture(texture: np.ndarray, mask: np.ndarray, overlay: np.ndarray) -> np.ndarray:
    """The drawing with the limbs drawn over the body painted out, ``(H, W, 4)`` uint8 RGBA.

    ``overlay``: those limbs' pixels (:attr:`nnsf.reshape.mesh.Mesh.overlay`),
    grown by 1 % of the drawing's height (at least 2 px) to take the half of
    their outline that lies on the body's side, and the lines around them;
    filled with OpenCV's Telea inpainting from the rest of the silhouette
    (pixels outside it set to the silhouette's median colour first, so the
    paper does not bleed in).
    """
    m = np.asarray(mask, dtype=bool)
    ys = np.flatnonzero(m.any(axis=1))
    r = max(int(round(0.01 * (ys[-1] - ys[0] + 1))), 2) if len(ys) else 2
    region = cv2.dilate(np.asarray(overlay, np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))

    # The lines near the region are painted out too, so the fill comes from the body's colour,
    # not smeared from its outline.
    near = cv2.dilate(region, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (4 * r + 1, 4 * r + 1))) > 0
    unknown = (region > 0) | (near & ink_mask(texture, m))
    rgb = np.ascontiguousarray(texture[..., :3]).copy()
    if m.any():
        rgb[~m] = np.median(rgb[m & ~unknown] if (m & ~unknown).any() else rgb[m], axis=0).astype(np.uint8)
    filled = cv2.inpaint(rgb, unknown.astype(np.uint8), 2 * r + 3, cv2.INPAINT_TELEA)
    return np.dstack([filled, texture[..., 3]])


def rim_texture(texture: np.ndarray, mask: np.ndarray, keypoints: np.ndarray) -> np.ndarray:
    """The body's drawn regions and the drawing's ink, everything else transparent, ``(H, W, 4)`` uint8 RGBA.

    Texture of a layered mesh's rim copies (``Mesh.layer`` 2): the body
    keeps its outline where a limb met it, without bits of the limb's fill.
    """
    keep = body_line(keypoints, texture, mask)
    out = np.array(texture, dtype=np.uint8, copy=True)
    out[..., 3] = np.where(keep, out[..., 3], 0)
    return out


# --------------------------------------------------------------------------- files



