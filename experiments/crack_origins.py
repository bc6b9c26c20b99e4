"""Question answered: where do the cracks the reshaping evaluation counts come from?

A crack (:func:`nnsf.reshape.artefacts.cracks`) is enclosed background no wider than 3 px.  In
a frame drawn from deformed triangles of the drawing, such a pixel can be background for three
reasons, told apart here by which triangle lies on top of it and what texel that triangle shows:

* ``opening``: no triangle covers the pixel: the mesh tore (a cut or seam opened);
* ``page``: the topmost triangle shows a texel outside the drawing's mask: the drawing's own page,
  carried along because the mesh covers the mask grown by a few pixels and narrow concavities,
  enclosed where two outlines meet or a thin gap of page pinches shut.  Sub-split by where that
  texel lies at rest: ``gap`` inside the mask's closing with a 7 px disc (a narrow gap or
  concavity of the drawing), else ``margin`` within 3 px of the mask, else ``far``;
* ``thinned``: the texel is inside the mask but its alpha after bilinear resampling is below 128 (an
  anti-aliased stroke or edge thinned by the resampling, or a faint stroke of the drawing);
  ``thinned_edge_px`` counts its pixels whose texel is drawn (alpha ≥ 128) but lies at the mask's
  edge, where the renderer's mask cuts the bilinear sample.

A crack component is an ``opening`` if any of its pixels is uncovered (``opening_tear``: the
covered pixels about the uncovered ones mostly show the drawing, so a cut through it parted; the
rest lie between outlines further apart than the mesh's margin, which the mesh around them shows),
else ``page`` or ``thinned`` by the majority of its pixels (``mixed`` counts the
components that had both).  ``underlay_px``: crack pixels whose topmost triangle is of the body
underlay.

Method: every frame of every drawing × motion of ``params.yaml`` ``reshape_eval`` is driven and
rendered as ``nnsf reshape-eval`` does (the default method, ``ours``; the same helpers, the same
canvas), and measured with the measure itself, which hands back the pixels it counted.  On a frame
with cracks the frame's renderer draws it once more with every triangle showing one texel that
names it (:class:`Footprint`), which gives each pixel's topmost triangle; that triangle's affine
map gives the pixel's texel, read off the drawing.  ``beyond_px`` (``page_far_beyond_px``: of
the far page) counts crack pixels whose texel lies more than 1 px outside its own triangle at
rest (the renderer keeps it within a pixel of the triangle's rest edges): a thin or folded
triangle's map stretched over the pixels the rasteriser gives it along its edges.

    python -m experiments.crack_origins --data /work/shared/data /work/extra-drawings /work/extra-drawings-tuning --out reports

Answer (``reports/reshape_crack_origins.{csv,json}``, every frame): the crack counts are the
measure's own (per drawing × motion, equal to ``reshape_eval_frames.csv``).  Of the 8,330 cracks
on the tuning set (27 drawings), 97.1 % are the drawing's page (53.0 % a gap or concavity of the
drawing, 43.4 % the mesh's margin, 0.6 % far page, mostly texels a thin or folded triangle
stretched beyond itself), 1.2 % thinned strokes and 144 openings (1.7 %): 143 in
gopher_sketch_ballet, at its shoulders and bow (142 tears), and 1 uncovered pixel (not a tear) in
the cartwheel; of the 3,027 held-out ones (8 drawings) 76.7 % page (27.6 % gap, 48.5 % margin,
0.6 % far), 21.2 % openings (642 in noto_person_walking: the slit round its hand's place at the
hips, which its mesh cut open once the hand no longer took the hips from the body, docs/method.md
§13; 1 uncovered pixel in cowboy_pixel) and 2.0 % thinned.

Writes ``OUT/reshape_crack_origins.csv`` (one row per drawing × motion), ``OUT/reshape_crack_origins.json``
(totals per set, the frames with openings, how it ran) and ``OUT/figures/crack_origins.png`` (for each
origin a few of the largest examples, each 41 × 41 px about the crack, × 6: the frame, the crack in
red, and the footprint).  A diagnostic, not a measure: it changes nothing that is measured.
"""
from __future__ import annotations

import argparse
import copy
import shlex
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pandas as pd

from nnsf import params as params_mod
from nnsf.errors import InputError
from nnsf.io import atomic_path, write_csv, write_json
from nnsf.params import checked
from nnsf.reshape.artefacts import FrameMeasures, coverage, cracks
from nnsf.reshape.evaluation import drive_item
from nnsf.reshape.render import Renderer
from nnsf.reshape.video import over_white

#: Origins of a crack component, in the order they are decided.
ORIGINS = ("opening", "page", "thinned")
#: Where a page texel lies at rest.
PAGE_KINDS = ("gap", "margin", "far")
#: Diameter of the disc that closes the mask (px): page inside the closing is a gap of the drawing.
GAP_DISC = 7
#: Page texels at most this far from the mask (px) are its margin.
MARGIN = 3.0
#: A texel further than this (px) outside its own triangle at rest is an extrapolated one.
BEYOND = 1.0
#: Half the side of a figure crop (px) and its magnification.
CROP, ZOOM = 20, 6
#: Examples per origin in the figure.
EXAMPLES = 4


class Footprint:
    """What the topmost triangle shows at each pixel of a frame (module docstring).

    ``renderer`` draws the frame; ``mesh``, ``texture`` ``(H, W, 4)``, ``mask`` ``(H, W)`` and
    ``underlay`` (or None) are what it was built from.  A shallow copy of the renderer keeps its
    triangles, their fill order and its compositing, but each triangle's texture coordinates all
    point at one texel of an opaque texture that names it: drawn, a frame holds each pixel's
    topmost triangle.  The renderer's own texel for that triangle at the pixel (its affine map, kept
    within a pixel of the rest triangle: ``Renderer._maps``, ``Renderer._clamp``) is read off the drawing.
    :meth:`__call__` returns ``(H, W)`` bool maps, filled at the pixels of ``where``: ``covered``
    (some triangle), ``in_mask`` (the texel lies in the mask: bilinear mask ≥ ½), ``drawn`` (the
    drawing's alpha there, the underlay's for underlay triangles, ≥ 128), ``gap``, ``margin`` (page
    kinds; a gap is never margin), ``underlay`` (an underlay triangle) and ``beyond`` (the texel lies more than :data:`BEYOND` px outside its own
    triangle at rest: a thin or folded triangle's map stretched over pixels it barely touches).
    """

    def __init__(self, renderer: Renderer, mesh, texture: np.ndarray, mask: np.ndarray, underlay):
        self.mesh, self.renderer = mesh, renderer
        t = len(mesh.triangles)
        side = int(np.ceil(np.sqrt(t + 1)))
        ids = np.arange(side * side)
        name = np.dstack([ids & 255, (ids >> 8) & 255, (ids >> 16) & 255, np.full_like(ids, 255)])
        self.ids = copy.copy(renderer)
        self.ids.texture = np.ascontiguousarray(name.reshape(side, side, 4).astype(np.uint8))
        at = np.stack([ids[:t] % side, ids[:t] // side], axis=-1).astype(np.float64)
        self.ids.set_texture_coordinates(np.repeat(at[:, None], 3, axis=1))   # one texel per triangle
        m = np.asarray(mask, bool)
        disc = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (GAP_DISC, GAP_DISC))
        pad = GAP_DISC                                       # the closing sees no image border
        closed = cv2.morphologyEx(np.pad(m, pad).astype(np.uint8), cv2.MORPH_CLOSE, disc)[pad:-pad, pad:-pad]
        gap = (closed > 0) & ~m
        dist = cv2.distanceTransform(np.pad(~m, 1, constant_values=True).astype(np.uint8), cv2.DIST_L2,
                                     cv2.DIST_MASK_PRECISE)[1:-1, 1:-1]
        margin = ~m & ~gap & (dist <= MARGIN)
        und = texture if underlay is None else underlay
        # Channels read bilinearly: mask, the drawing's alpha; and at the nearest texel gap, margin.
        self.layers = [np.dstack([m, tex[..., 3] / 255.0]).astype(np.float32) for tex in (texture, und)]
        self.kinds = np.dstack([gap, margin]).astype(np.float32)

    def top(self, vertices: np.ndarray, order) -> np.ndarray:
        """The topmost triangle of each pixel ``(H, W)`` int64, −1 where none."""
        img = self.ids.render(vertices, order)
        tid = img[..., 0].astype(np.int64) | (img[..., 1].astype(np.int64) << 8) | (img[..., 2].astype(np.int64) << 16)
        return np.where(img[..., 3] >= 128, tid, -1)

    def __call__(self, vertices: np.ndarray, order, where: np.ndarray) -> dict[str, np.ndarray]:
        top = self.top(vertices, order)
        shape = top.shape
        out = {k: np.zeros(shape, bool) for k in ("covered", "in_mask", "drawn", "gap", "margin", "underlay",
                                                 "beyond")}
        ys, xs = np.nonzero(where & (top >= 0))
        out["covered"][ys, xs] = True
        if not len(ys):
            return out
        k = top[ys, xs]
        ids = np.zeros(shape, np.int32)
        ids[ys, xs] = k + 1
        V, R = np.asarray(vertices, np.float64), self.mesh.vertices[self.mesh.triangles[k]]       # (N, 3, 2) rest
        maps, squashed = self.renderer._maps(V)
        gx, gy = np.arange(shape[1], dtype=np.float32), np.arange(shape[0], dtype=np.float32)[:, None]
        w = maps[0].take(ids) * gx + maps[1].take(ids) * gy + maps[2].take(ids)   # as Renderer.render
        self.renderer._clamp([(0, 0, ids, w)], maps, squashed, V)
        # The renderer's texels of an underlay triangle lie in the atlas's second half: back to the drawing's.
        uv = np.column_stack([w.real[ys, xs], w.imag[ys, xs]]) - (self.renderer.uv[k, 0] - R[:, 0])
        out["beyond"][ys, xs] = _outside(uv, R) > BEYOND
        layer = np.asarray(self.mesh.layer)[k]
        u, v = uv[:, 0].astype(np.float32), uv[:, 1].astype(np.float32)
        read = np.zeros((len(k), 2), np.float32)
        for i, img in enumerate(self.layers):
            sel = layer == i
            read[sel] = _sample(img, u[sel], v[sel])
        kinds = _sample(self.kinds, np.rint(u), np.rint(v))
        inside = read[:, 0] >= 0.5
        out["in_mask"][ys, xs] = inside
        out["drawn"][ys, xs] = inside & (read[:, 1] >= 0.5)
        out["gap"][ys, xs] = ~inside & (kinds[:, 0] > 0.5)
        out["margin"][ys, xs] = ~inside & (kinds[:, 1] > 0.5)
        out["underlay"][ys, xs] = layer == 1
        return out


def _sample(img: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Bilinear samples ``(N, C)`` of a float32 image at ``u``, ``v`` ``(N,)`` (0 off the image)."""
    n, rows = len(u), -(-len(u) // 512)     # cv2.remap wants maps under 32767 a side: rows of 512
    if not n:
        return np.zeros((0, img.shape[2]), np.float32)
    u, v = (np.pad(np.asarray(a, np.float32), (0, 512 * rows - n)).reshape(rows, 512) for a in (u, v))
    got = cv2.remap(img, u, v, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return got.reshape(-1, img.shape[2])[:n]


def _outside(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Distance ``(N,)`` of points ``(N, 2)`` from triangles ``(N, 3, 2)`` (0 inside)."""
    a, b = tri, np.roll(tri, -1, axis=1)                     # the edges a -> b
    ab, ap = b - a, p[:, None] - a
    s = np.clip((ab * ap).sum(-1) / np.maximum((ab * ab).sum(-1), 1e-12), 0, 1)
    edge = np.linalg.norm(ap - s[..., None] * ab, axis=-1).min(axis=1)
    cross = ab[..., 0] * ap[..., 1] - ab[..., 1] * ap[..., 0]
    inside = (cross >= 0).all(axis=1) | (cross <= 0).all(axis=1)
    return np.where(inside, 0.0, edge)


def classify(labels: np.ndarray, n: int, fp: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Per crack ``k = 1..n`` of ``labels`` ``(H, W)`` (0: no crack): its pixels by origin and page
    kind, its ``origin`` (index into :data:`ORIGINS`) and ``page_kind`` (into :data:`PAGE_KINDS`,
    -1 when no page pixel), ``mixed`` (page and thinned pixels both) and ``tear`` (an opening whose
    covered pixels about its uncovered ones show the drawing more often than page)."""
    lab = labels.ravel()

    def count(sel):
        return np.bincount(lab[sel.ravel()], minlength=n + 1)[1:]

    opening = count(~fp["covered"])
    page = count(fp["covered"] & ~fp["in_mask"])
    thinned = count(fp["in_mask"])
    edge = count(fp["in_mask"] & fp["drawn"])
    gap = count(fp["gap"] & ~fp["in_mask"])
    margin = count(fp["margin"] & ~fp["in_mask"])
    far = fp["covered"] & ~fp["in_mask"] & ~fp["gap"] & ~fp["margin"]
    kinds = np.stack([gap, margin, page - gap - margin])
    origin = np.where(opening > 0, 0, np.where(page >= thinned, 1, 2))
    # What lies about an opening: the drawing (a cut through it parted) or page (two outlines apart
    # by more than the mesh's margin).  Cracks lie two drawn pixels apart, so the rings are disjoint.
    ring = cv2.dilate(np.where(fp["covered"], 0, labels).astype(np.float32), np.ones((3, 3), np.uint8))
    ring = np.rint(ring).astype(np.int64).ravel()
    around = np.bincount(ring[fp["covered"].ravel()], minlength=n + 1)[1:]
    drawing = np.bincount(ring[fp["in_mask"].ravel()], minlength=n + 1)[1:]
    return {"opening": opening, "page": page, "thinned": thinned, "gap": gap, "margin": margin,
            "far": kinds[2], "edge": edge, "underlay": count(fp["underlay"]), "beyond": count(fp["beyond"]),
            "far_beyond": count(far & fp["beyond"]), "origin": origin,
            "page_kind": np.where(page > 0, np.argmax(kinds, axis=0), -1),
            "mixed": (opening == 0) & (page > 0) & (thinned > 0),
            "tear": (opening > 0) & (2 * drawing >= around)}


def crack_labels(rgba: np.ndarray) -> tuple[int, np.ndarray]:
    """The measure's crack count of a frame and its pixels, numbered by crack ``(H, W)`` int32."""
    labels = np.zeros(rgba.shape[:2], np.int32)
    n, _ = cracks(coverage(rgba), labels=labels)
    return n, labels


def _row_name(origin: int, kind: int) -> str:
    return f"page-{PAGE_KINDS[kind]}" if ORIGINS[origin] == "page" else ORIGINS[origin]


def _crop(img: np.ndarray, cy: int, cx: int, fill) -> np.ndarray:
    pad = np.pad(img, [(CROP, CROP), (CROP, CROP)] + [(0, 0)] * (img.ndim - 2), constant_values=fill)
    return pad[cy:cy + 2 * CROP + 1, cx:cx + 2 * CROP + 1].copy()


def footprint_colours(fp: dict[str, np.ndarray]) -> np.ndarray:
    """An RGB picture of a footprint: uncovered black, drawn texel grey, thin texel in the mask
    orange, page texel blue (gap dark, margin light, far purple)."""
    H, W = fp["covered"].shape
    out = np.zeros((H, W, 3), np.uint8)
    page = fp["covered"] & ~fp["in_mask"]
    for sel, colour in ((fp["covered"], (128, 0, 160)), (page & fp["margin"], (140, 190, 255)),
                        (page & fp["gap"], (20, 60, 200)), (fp["in_mask"], (255, 150, 0)),
                        (fp["in_mask"] & fp["drawn"], (200, 200, 200))):
        out[sel] = colour
    return out


def run_item(item: dict) -> dict:
    """One drawing × motion: the per-origin counts, the openings and the figure's candidates."""
    # The evaluation's own frames on its own canvas: the same pixels it measured.
    ch, name, _, animator, anim, _, offset, size = drive_item(item)
    T = len(anim.frames)
    renderer = animator.renderer(size)
    fp = Footprint(renderer, animator.mesh, ch.texture, ch.mask, animator.underlay)
    row = {"character": ch.name, "motion": name, "set": item["set"], "frames": 0, "frames_with_cracks": 0,
           "frames_over_rest": 0, "rest_cracks": FrameMeasures(ch.texture, ch.mask, ch.keypoints).rest_cracks,
           "cracks": 0, "crack_px": 0, "mixed": 0, "opening_tear": 0, "opening_tear_px": 0, "thinned_edge_px": 0,
           "underlay_px": 0, "beyond_px": 0, "page_far_beyond_px": 0}
    for o in ORIGINS:
        row[o], row[f"{o}_px"] = 0, 0
    for k in PAGE_KINDS:
        row[f"page_{k}"], row[f"page_{k}_px"] = 0, 0
    openings, best = [], {}
    for t in range(0, T, item["step"]):
        V = anim.frames[t] + offset
        img = renderer.render(V, anim.orders[t])
        n, labels = crack_labels(img)
        row["frames"] += 1
        row["frames_with_cracks"] += int(n > 0)
        row["frames_over_rest"] += int(n > row["rest_cracks"])
        if not n:
            continue
        f = fp(V, anim.orders[t], cv2.dilate((labels > 0).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0)
        c = classify(labels, n, f)
        row["cracks"] += n
        row["crack_px"] += int((labels > 0).sum())
        row["mixed"] += int(c["mixed"].sum())
        row["underlay_px"] += int(c["underlay"].sum())
        row["thinned_edge_px"] += int(c["edge"].sum())
        row["beyond_px"] += int(c["beyond"].sum())
        row["page_far_beyond_px"] += int(c["far_beyond"].sum())
        for i, o in enumerate(ORIGINS):
            row[o] += int((c["origin"] == i).sum())
            row[f"{o}_px"] += int(c[o].sum())
        for i, k in enumerate(PAGE_KINDS):
            row[f"page_{k}"] += int(((c["origin"] == 1) & (c["page_kind"] == i)).sum())
            row[f"page_{k}_px"] += int(c[k].sum())
        size_px = np.bincount(labels.ravel(), minlength=n + 1)[1:]
        is_open = c["origin"] == 0
        row["opening_tear"] += int(c["tear"].sum())
        row["opening_tear_px"] += int(c["opening"][c["tear"]].sum())
        if is_open.any():
            openings.append({"t": t, "cracks": int(is_open.sum()), "tears": int(c["tear"].sum()),
                             "px": int(size_px[is_open].sum()), "uncovered_px": int(c["opening"].sum())})
        white = None
        for k in range(n):
            key = _row_name(int(c["origin"][k]), int(c["page_kind"][k]))
            if key in best and best[key]["px"] >= size_px[k]:
                continue
            ys, xs = np.nonzero(labels == k + 1)
            cy, cx = int(round(ys.mean())), int(round(xs.mean()))
            box = np.zeros(labels.shape, bool)
            box[max(cy - CROP, 0):cy + CROP + 1, max(cx - CROP, 0):cx + CROP + 1] = True
            white = over_white(img) if white is None else white
            best[key] = {"kind": key, "px": int(size_px[k]), "t": t, "character": ch.name, "motion": name,
                         "set": item["set"], "frame": _crop(white, cy, cx, 255),
                         "crack": _crop(labels == k + 1, cy, cx, False),
                         "footprint": _crop(footprint_colours(fp(V, anim.orders[t], box)), cy, cx, 0)}
    return {"row": row, "openings": [{"character": ch.name, "motion": name, "set": item["set"], **o}
                                     for o in openings], "examples": list(best.values())}


def figure(examples: list[dict], path: Path) -> list[dict]:
    """Per origin (rows) up to :data:`EXAMPLES` of the largest cracks, from distinct drawings; returns
    the examples shown."""
    from matplotlib.figure import Figure

    kinds = [o for o in ("opening", "page-margin", "page-gap", "page-far", "thinned")
             if any(e["kind"] == o for e in examples)]
    shown = []
    fig = Figure(figsize=(3 * 3 * EXAMPLES * 0.75, 2.6 * max(len(kinds), 1)), dpi=100)
    for r, kind in enumerate(kinds):
        picked, seen = [], set()
        for e in sorted((e for e in examples if e["kind"] == kind), key=lambda e: (-e["px"], e["character"])):
            if e["character"] not in seen:
                picked.append(e)
                seen.add(e["character"])
            if len(picked) == EXAMPLES:
                break
        shown += picked
        for j, e in enumerate(picked):
            red = e["frame"].copy()
            red[e["crack"]] = (255, 0, 0)
            for k, (img, what) in enumerate(((e["frame"], "frame"), (red, "crack"), (e["footprint"], "footprint"))):
                ax = fig.add_subplot(len(kinds), 3 * EXAMPLES, r * 3 * EXAMPLES + 3 * j + k + 1)
                ax.imshow(np.repeat(np.repeat(img, ZOOM, 0), ZOOM, 1), interpolation="nearest")
                ax.set_xticks([])
                ax.set_yticks([])
                if k == 0:
                    ax.set_title(f"{kind}: {e['character']}\n{e['motion']} t={e['t']} ({e['px']} px)",
                                 fontsize=7, loc="left")
                else:
                    ax.set_title(what, fontsize=7)
    fig.suptitle("Crack origins: the frame, the crack the measure counts (red), and the topmost texel "
                 "(grey drawn, orange in the mask but alpha < 128, light blue page margin, dark blue page gap, "
                 "purple far page, black no triangle); ±20 px, ×6", fontsize=8)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png")
    return shown


def totals(rows: pd.DataFrame) -> dict:
    """Sums of every count column per set."""
    num = rows.drop(columns=["character", "motion", "set"])
    out = {}
    for s, d in rows.groupby("set"):
        tot = {k: int(v) for k, v in num.loc[d.index].sum().items() if k != "rest_cracks"}
        tot["items"] = int(len(d))
        tot["share_frames_with_cracks"] = tot["frames_with_cracks"] / max(tot["frames"], 1)
        out[s] = tot
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, required=True, nargs="+", help="data folders (drawings and motions)")
    ap.add_argument("--params", default="params.yaml", help="its reshape_eval section names what is run")
    ap.add_argument("--out", type=Path, default=Path("reports"))
    ap.add_argument("--step", type=int, default=1, help="every STEP-th frame (1: all)")
    a = ap.parse_args(argv)
    params = params_mod.load(a.params)

    def get(key, default):
        return checked(params, f"reshape_eval.{key}", default)

    roots = [str(Path(r).resolve()) for r in a.data]
    common = {"data": roots, "n_vertices": get("n_vertices", 800), "max_frames": get("max_frames", 240),
              "subkeys_per_limb": get("subkeys_per_limb", 4), "step": max(a.step, 1)}
    items = [{**common, "character": c, "motion": m, "set": s}
             for s, chars in (("tuning", get("characters", [])), ("heldout", get("heldout", [])))
             for c in chars for m in get("motions", [])]
    t0 = time.perf_counter()
    rows, openings, examples, refused = [], [], [], []
    for item in items:
        t1 = time.perf_counter()
        try:
            res = run_item(item)
        except InputError as exc:
            refused.append(f"{item['character']} x {item['motion']}: {exc}")
            continue
        rows.append(res["row"])
        openings += res["openings"]
        examples += res["examples"]
        r = res["row"]
        print(f"crack_origins: {item['character']} x {item['motion']}: {r['frames']} frames, {r['cracks']} cracks "
              f"(opening {r['opening']}, page {r['page']}, thinned {r['thinned']}), "
              f"{time.perf_counter() - t1:.0f} s", file=sys.stderr, flush=True)
    if not rows:
        print(f"crack_origins: {a.params}: reshape_eval: no drawing x motion could be run", file=sys.stderr)
        return 2
    table = pd.DataFrame(rows)
    write_csv(a.out / "reshape_crack_origins.csv", table)
    shown = figure(examples, a.out / "figures" / "crack_origins.png")
    write_json(a.out / "reshape_crack_origins.json", {
        "question": __doc__.splitlines()[0], "sets": totals(table), "openings": openings, "refused": refused,
        "frame_step": common["step"], "method": "ours",
        "figure_examples": [{k: e[k] for k in ("kind", "character", "motion", "set", "t", "px")} for e in shown],
        "seconds": round(time.perf_counter() - t0, 1),
        "command": "python -m experiments.crack_origins " + shlex.join(argv if argv is not None else sys.argv[1:])})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
