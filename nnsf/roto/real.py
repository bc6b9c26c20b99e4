"""Tracking on real cartoon frames, scored against their alpha silhouettes.

The frames are RGBA PNGs with an exact alpha, one folder per character,
``<data>/<character>/<frame>.png``; the keyframe annotations (format v1,
formats §2.2) are hand-made files ``<annotations>/<character>.annotation.json``
naming the frames, and every annotated character is tracked.  Frames are
composited over a plain white background (as :func:`nnsf.frames.clips.read_clip`
does) before tracking.  Score: the share of tracked outline samples within
``tol`` px of the silhouette boundary (where a limb lies over the body its
true edge is a colour edge, not the silhouette, so no tracker reaches 1;
the annotated keyframes' own score is the ceiling to compare with).

The score only looks from the tracked curves to the silhouette, so a curve
shrunk onto the part of the outline it matches best scores well.  Two
figures guard against that: the **coverage**, the silhouette length within
``tol`` px of the tracked curves in an in-between frame over the same
length for the annotated curves in the keyframes (≈ 1 when the tracks cover
as much outline as the annotation; lower when they shrink), and the
**length ratio**, the in-between frames' mean control-polygon length over
the keyframes' (:func:`nnsf.roto.metrics.length_ratio`).
"""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pandas as pd
from scipy.spatial import cKDTree

from nnsf.roto import curves
from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.io import read_image, write_csv, write_json
from nnsf.params import TRACKERS
from nnsf.roto.figures import roto_overlay
from nnsf.roto.metrics import polyline_projection, length_ratio
from nnsf.roto.snap import resolve_target
from nnsf.roto.solve import interpolate_clip, keyframe_curves, track_clip

#: the rows of the real-frame reports: the three trackers and the do-nothing floor
REPORTED = ("ours", "agarwala", "lk", "linear")
#: px from the silhouette that count as on it, by default
TOL = 1.5
_UP = 4  # upsampling factor for the sub-pixel silhouette boundary


def silhouette_boundary(alpha: np.ndarray, level: float = 127.5) -> np.ndarray:
    """Sub-pixel boundary points (M, 2) (x, y px, pixel centres at integers) of alpha > level.

    The alpha map is upsampled ×4 bilinearly and its iso-line traced with
    ``cv2.findContours``: boundary points about 0.25 px apart and accurate
    to about that.
    """
    a = np.asarray(alpha, np.float32)
    H, W = a.shape
    # pad so that a silhouette touching the border still gets a closed boundary
    up = cv2.resize(np.pad(a, 1), ((W + 2) * _UP, (H + 2) * _UP), interpolation=cv2.INTER_LINEAR)
    mask = (up > level).astype(np.uint8)
    cs, _ = cv2.findContours(mask, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    if not cs:
        return np.zeros((0, 2))
    pts = np.concatenate([c.reshape(-1, 2) for c in cs]).astype(np.float64)
    return (pts + 0.5) / _UP - 0.5 - 1.0


def score_silhouette(control: np.ndarray, alpha: np.ndarray, tol: float = 1.5,
                     n_samples: int = 32) -> float:
    """Share of outline samples within ``tol`` px of the silhouette boundary.

    control : (N, P, 2) control points of one frame's curves (NaN-padded
              rows/curves are skipped) — or (T, N, P, 2) with ``alpha (T, H, W)``.
    alpha   : (H, W) alpha (0..255) of the frame (or (T, H, W)).
    """
    control = np.asarray(control, np.float64)
    alpha = np.asarray(alpha)
    if control.ndim == 4:
        hits = [_hits(c, a, tol, n_samples) for c, a in zip(control, alpha)]
        h = np.concatenate(hits)
        return float(h.mean()) if h.size else float("nan")
    h = _hits(control, alpha, tol, n_samples)
    return float(h.mean()) if h.size else float("nan")


def covered_boundary(control: np.ndarray, alpha: np.ndarray, tol: float = 1.5,
                     n_samples: int = 64) -> float:
    """Silhouette outline length (px) within ``tol`` px of one frame's curves.

    control : (N, P, 2) control points (NaN-padded rows/curves skipped);
    alpha : (H, W).  Each curve is sampled as a polyline of ``n_samples``
    points; the boundary points (about 0.25 px apart, see
    :func:`silhouette_boundary`) closer than ``tol`` to any curve are counted
    and weighted by their spacing along the traced boundary.
    """
    pts = silhouette_boundary(alpha)
    if len(pts) < 2:
        return 0.0
    # length element of each boundary point: half its two neighbour gaps (contours are
    # closed; at a jump between contours the gap is capped at the nominal spacing)
    gap = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    gap = np.where(gap > 2.0 / _UP, 1.0 / _UP, gap)
    ds = 0.5 * (np.concatenate([gap, [gap[-1]]]) + np.concatenate([[gap[0]], gap]))
    near = np.zeros(len(pts), bool)
    for c in np.asarray(control, np.float64):
        ok = np.isfinite(c).all(-1)
        if ok.sum() < 2:
            continue
        poly = curves.sample(c[: int(ok.sum())], n_samples)
        lo, hi = poly.min(0) - tol, poly.max(0) + tol
        box = np.flatnonzero(((pts >= lo) & (pts <= hi)).all(1) & ~near)
        if box.size:
            d = polyline_projection(pts[box], poly)[0]
            near[box[d <= tol]] = True
    return float(ds[near].sum())


def coverage(control: np.ndarray, alpha: np.ndarray, keyframes, tol: float = 1.5) -> float:
    """Covered outline of the in-between frames over that of the annotated keyframes.

    control : (T, N, P, 2) with the keyframes' rows equal to the annotation;
    alpha : (T, H, W); keyframes : frame indices.  The mean over in-between
    frames of :func:`covered_boundary` divided by its mean over the keyframes.
    """
    kf = np.zeros(len(control), bool)
    kf[list(keyframes)] = True
    cov = np.array([covered_boundary(c, a, tol) for c, a in zip(control, alpha)])
    ref = cov[kf].mean() if kf.any() else float("nan")
    return float(cov[~kf].mean() / ref) if ref > 0 and (~kf).any() else float("nan")


def _hits(control, alpha, tol, n_samples) -> np.ndarray:
    tree = cKDTree(silhouette_boundary(alpha))
    out = []
    for c in control:
        ok = np.isfinite(c).all(-1)
        if ok.sum() < 2:
            continue
        s = curves.sample(c[: int(ok.sum())], n_samples)
        d, _ = tree.query(s)
        out.append(d <= tol)
    return np.concatenate(out) if out else np.zeros(0, bool)


def read_rgba(folder: Path, names: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Frames composited over white (T, H, W, 3) uint8 RGB and their alpha (T, H, W) uint8."""
    rgb, alpha = [], []
    for n in names:
        img = read_image(Path(folder) / n)
        if img.ndim != 3 or img.shape[2] != 4:
            raise InputError(Path(folder) / n, "file", "a readable RGBA PNG")
        a = img[..., 3:4].astype(np.float32) / 255.0
        comp = np.rint(img[..., :3].astype(np.float32) * a + 255.0 * (1 - a)).astype(np.uint8)
        rgb.append(cv2.cvtColor(comp, cv2.COLOR_BGR2RGB))
        alpha.append(img[..., 3])
    return np.stack(rgb), np.stack(alpha)


def annotated_names(annotations_dir) -> list[str]:
    """The characters of an annotation folder: the stems of its ``<name>.annotation.json``."""
    return sorted(p.name.removesuffix(".annotation.json")
                  for p in Path(annotations_dir).glob("*.annotation.json"))


def track_frames(data_root, annotations_dir, methods=TRACKERS, names=None,
                 tol: float = TOL, **options) -> tuple[pd.DataFrame, dict]:
    """Run the trackers on annotated frame folders and score them against the silhouettes.

    data_root : the folder of ``<character>/`` frame folders; annotations_dir :
    folder with ``<character>.annotation.json``; names : the characters to
    track (default: every annotated one).  Returns a table (character, tracker, score over the in-between
    frames, keyframe score = the annotation's own score, coverage and
    length ratio, see the module notes) and
    ``{(character, tracker): (T, N, P, 2) control}`` for figures.  The
    method ``"linear"`` is no tracker: the keyframes interpolated linearly
    (:func:`nnsf.roto.solve.interpolate_clip`), the floor a tracker must beat.
    """
    rows, tracked = [], {}
    for ch in annotated_names(annotations_dir) if names is None else names:
        ann = read_annotation(Path(annotations_dir) / f"{ch}.annotation.json")
        frames, alpha = read_rgba(Path(data_root) / ch, ann.frames)
        score_trackers(ch, ann, frames, alpha, methods, tol, options, rows, tracked)
    return pd.DataFrame(rows), tracked


def score_trackers(name, ann, frames, alpha, methods, tol: float, options: dict, rows: list, tracked: dict) -> None:
    """Track one annotated character with every method and score it against its silhouettes.

    Appends one row per method to ``rows`` (see :func:`track_frames`) and the
    control points to ``tracked[(name, method)]``.  ``"linear"`` is the
    keyframes interpolated linearly, the floor a tracker must beat.  The
    ``snap`` column says what snap "ours" ended with (``none`` for the
    others): ``snap_to: auto`` resolved from the keyframes, with the
    ``stroke_share`` it was decided by.
    """
    inb = np.ones(len(frames), bool)
    inb[ann.keyframe_indices] = False
    snap, share = resolve_target(options.get("snap", 0.0), options.get("snap_to", "profile"), frames,
                                 keyframe_curves(ann)[1])
    for m in methods:
        control = interpolate_clip(ann, len(frames)) if m == "linear" else \
            track_clip(frames, ann, m, **options)
        tracked[(name, m)] = control
        rows.append({"character": name, "tracker": m,
                     "score": score_silhouette(control[inb], alpha[inb], tol),
                     "keyframe_score": score_silhouette(control[~inb], alpha[~inb], tol),
                     "coverage": coverage(control, alpha, ann.keyframe_indices, tol),
                     "length_ratio": length_ratio(control, ann.keyframe_indices),
                     "frames": int(inb.sum()), "snap": (snap or "none") if m == "ours" else "none",
                     "stroke_share": share if m == "ours" and share is not None else float("nan")})


def silhouette_summary(table, tol: float) -> dict:
    """Per tracker, the means over characters of a silhouette-scored table.

    ``table`` has one row per (character, tracker) with ``score`` (share of
    outline samples within ``tol`` px of the silhouette), ``coverage``,
    ``length_ratio`` and ``keyframe_score`` (the annotated keyframes' own
    score: the ceiling).  Returns the JSON summary of the real-frame reports.
    """
    by = table.groupby("tracker")
    return {
        "tol_px": tol,
        "characters": sorted(table["character"].unique()),
        "trackers": {m: float(g["score"].mean()) for m, g in by},
        "coverage": {m: float(g["coverage"].mean()) for m, g in by},
        "length_ratio": {m: float(g["length_ratio"].mean()) for m, g in by},
        "ceiling": float(table.groupby("character")["keyframe_score"].first().mean()),
        # what "ours" ended with per character (snap_to: auto decides from the keyframes)
        "snap": ({r.character: r.snap for r in table[table["tracker"] == "ours"].itertuples()}
                 if "snap" in table else {}),
    }


def write_silhouette_report(table, tracked: dict, tol: float, annotations_dir, out_dir, stem: str,
                            wanted: str, frames_of, label: str, upscale: int = 1) -> dict:
    """Write a real-frame report: ``<stem>.csv``, ``<stem>.json`` and ``figures/<stem>.png``.

    ``table``/``tracked`` as :func:`score_trackers` fills them; ``wanted`` says
    what an empty table lacked (the :class:`InputError`'s expectation);
    ``frames_of(name, annotation)`` reads the first character's frames
    ``(T, H, W, 3)``, drawn ``upscale`` times larger (nearest pixel; curves
    mapped with pixel centres at integers).  Returns the JSON summary.
    """
    if table.empty:
        raise InputError(annotations_dir, "annotations", wanted)
    out_dir = Path(out_dir)
    summary = silhouette_summary(table, tol)
    write_csv(out_dir / f"{stem}.csv", table)
    write_json(out_dir / f"{stem}.json", summary)
    first = summary["characters"][0]
    ann = read_annotation(Path(annotations_dir) / f"{first}.annotation.json")
    frames = frames_of(first, ann)
    shown = {m: c for (ch, m), c in tracked.items() if ch == first and m != "linear"}
    if upscale != 1:
        frames = np.stack([cv2.resize(f, (f.shape[1] * upscale, f.shape[0] * upscale),
                                      interpolation=cv2.INTER_NEAREST) for f in frames])
        # pixel centres at integers: x_big = (x + 0.5)·upscale - 0.5
        shown = {m: (c + 0.5) * upscale - 0.5 for m, c in shown.items()}
    inb = [t for t in range(len(frames)) if t not in set(ann.keyframe_indices)]
    show = [inb[i] for i in np.unique(np.linspace(0, len(inb) - 1, 4).round().astype(int))]
    roto_overlay(frames, shown, None, show, out_dir / "figures" / f"{stem}.png", crop_margin=200,
                 title=f"{first} ({label}): tracked outlines between keyframes {ann.keyframe_indices}")
    return summary


def frames_report(data_root, annotations_dir, out_dir, stem: str = "roto_frames", tol: float = TOL,
                  **options) -> dict:
    """Track annotated frame folders with the three trackers and write the report files.

    Writes ``<out_dir>/<stem>.csv`` (character × tracker scores, plus the
    ``linear`` interpolation of the keyframes as the floor),
    ``<out_dir>/<stem>.json`` (per tracker: mean score over the characters
    under ``trackers``, mean coverage and length ratio under ``coverage`` and
    ``length_ratio``, and the mean keyframe ceiling) and
    ``<out_dir>/figures/<stem>.png`` (the tracked outlines of the first
    character on four in-between frames).  Returns the JSON summary.
    """
    data_root, out_dir = Path(data_root), Path(out_dir)
    if not data_root.is_dir():
        raise InputError(data_root, "folder", "a folder of <character>/ frame folders")
    table, tracked = track_frames(data_root, annotations_dir, methods=REPORTED, tol=tol, **options)
    return write_silhouette_report(
        table, tracked, tol, annotations_dir, out_dir, stem,
        "at least one <character>.annotation.json for a character in " + str(data_root),
        lambda name, ann: read_rgba(data_root / name, ann.frames)[0], data_root.name)
