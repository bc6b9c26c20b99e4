"""Depth order of a character's parts, stable over time (docs/method.md §14, the paper's Fig. 10).

Parts are :data:`nnsf.reshape.parts.PARTS` (torso, head, the eight limb segments).  A frame's
order lists part ids **back to front**; the renderer draws them in that order.  A part's depth is
the mean camera depth of its key points (larger is farther), from the source motion's 3-D joints
(:func:`nnsf.datasets.bvh_source.load_clip` gives ``depth`` ``(F, 17)``).  The constraints "a is
behind b" come from depths further apart than a hysteresis band (a pair within it keeps its
previous relation) and from the fixed annotations (:data:`ALWAYS`, :data:`_CHAIN`); the order is
their topological sort, ties kept in the previous frame's order, a cycle broken by the farthest
part.  Without depth, :func:`default_order` gives one static order.
"""
from __future__ import annotations

import numpy as np

from nnsf.errors import InputError
from nnsf.reshape.parts import PARTS, PART_BONES, PART_INDEX
from nnsf.skeleton import N_JOINTS

N_PARTS = len(PARTS)

#: Key points whose mean depth is a part's depth.
PART_JOINTS: tuple[tuple[int, ...], ...] = tuple(
    tuple(sorted({j for a, b, p in PART_BONES if p == part for j in (a, b)})) for part in range(N_PARTS))

#: Fixed annotations (behind, in front): the head over the torso.
ALWAYS: tuple[tuple[int, int], ...] = ((PART_INDEX["torso"], PART_INDEX["head"]),)
#: Each lower limb segment is over its upper one unless the source says clearly otherwise.
_CHAIN = tuple((PART_INDEX[a], PART_INDEX[b]) for a, b in (
    ("l_upper_arm", "l_forearm"), ("r_upper_arm", "r_forearm"), ("l_thigh", "l_shin"), ("r_thigh", "r_shin")))


def default_order() -> np.ndarray:
    """A static back-to-front order ``(10,)`` for clips without depth: torso, head, then each leg and
    arm, upper segment before lower (a child segment is drawn over its parent)."""
    names = ("torso", "head", "l_thigh", "l_shin", "r_thigh", "r_shin",
             "l_upper_arm", "l_forearm", "r_upper_arm", "r_forearm")
    return np.array([PART_INDEX[n] for n in names], dtype=np.int64)


def part_depths(joint_depth: np.ndarray) -> np.ndarray:
    """Per-part depth ``(T, 10)`` from key-point depths ``(T, 17)`` (mean over each part's key points)."""
    z = np.asarray(joint_depth, dtype=np.float64)
    if z.ndim != 2 or z.shape[1] != N_JOINTS:
        raise InputError("depth", "shape", f"(frames, {N_JOINTS}) key-point depths", f"{z.shape}")
    return np.stack([z[:, list(js)].mean(axis=1) for js in PART_JOINTS], axis=1)


def _sort(behind: np.ndarray, prev_rank: np.ndarray, z: np.ndarray, hard: np.ndarray | None = None) -> np.ndarray:
    """Topological sort of ``behind[a, b]`` (a must be drawn before b), ties by ``prev_rank``.

    A cycle is broken by drawing the farthest remaining part that no ``hard``
    constraint (annotations) holds back.
    """
    P = len(prev_rank)
    remaining = np.ones(P, dtype=bool)
    order = []
    for _ in range(P):
        blocked = (behind[remaining][:, remaining]).any(axis=0)  # has a remaining part behind it
        idx = np.flatnonzero(remaining)
        free = idx[~blocked]
        if len(free):
            nxt = free[np.argmin(prev_rank[free])]
        else:  # a cycle: draw the farthest remaining part first
            cand = idx
            if hard is not None:
                held = hard[remaining][:, remaining].any(axis=0)
                cand = idx[~held] if (~held).any() else idx
            nxt = cand[np.argmax(z[cand])]
        order.append(int(nxt))
        remaining[nxt] = False
    return np.array(order, dtype=np.int64)


def part_overlaps(frames: np.ndarray, triangles: np.ndarray, parts: np.ndarray) -> np.ndarray:
    """Which parts overlap in the image, ``(T, 10, 10)`` bool, from deformed vertices ``(T, n, 2)``.

    Two parts overlap when their axis-aligned bounding boxes (over the vertices of their triangles)
    intersect: a cheap, conservative test (only pairs that may overlap need a depth order).
    """
    V = np.asarray(frames, dtype=np.float64)
    T = len(V)
    lo = np.full((T, N_PARTS, 2), np.inf)
    hi = np.full((T, N_PARTS, 2), -np.inf)
    for p in range(N_PARTS):
        idx = np.unique(triangles[parts == p])
        if len(idx):
            lo[:, p] = V[:, idx].min(axis=1)
            hi[:, p] = V[:, idx].max(axis=1)
    sep = ((lo[:, :, None] > hi[:, None, :]) | (lo[:, None, :] > hi[:, :, None])).any(axis=-1)
    out = ~sep & np.isfinite(lo).all(-1)[:, :, None] & np.isfinite(lo).all(-1)[:, None, :]
    idx = np.arange(N_PARTS)
    out[:, idx, idx] = False
    return out


def depth_orders(part_z: np.ndarray, hysteresis: float, pairs=None) -> np.ndarray:
    """Back-to-front part orders ``(T, 10)`` from part depths ``(T, 10)`` (module docstring).

    hysteresis : depth difference (source units) needed to set or flip a pair; a lower segment
        stays over its upper segment unless it is farther by more than twice this.
    pairs : optional ``(T, 10, 10)`` bool, the pairs that overlap in the
        image (:func:`part_overlaps`); only those take their order from the
        depth, the others keep the previous frame's (an order change between
        parts that do not overlap is invisible and only adds flips).
    """
    z = np.asarray(part_z, dtype=np.float64)
    T, P = z.shape
    if P != N_PARTS:
        raise InputError("depth", "parts", f"{N_PARTS} parts", P)
    if not np.isfinite(z).all():
        t = int(np.argwhere(~np.isfinite(z))[0, 0])
        raise InputError("depth", f"frame {t}", "finite depths", "NaN/Inf")
    rank = np.empty(P, dtype=np.int64)
    rank[default_order()] = np.arange(P)
    rel = rank[:, None] < rank[None, :]  # rel[a, b]: a currently behind b
    out = np.empty((T, P), dtype=np.int64)
    for t in range(T):
        d = z[t][:, None] - z[t][None, :]  # > 0: a farther than b
        new = np.where(d > hysteresis, True, np.where(d < -hysteresis, False, rel))
        rel = new if pairs is None else np.where(pairs[t], new, rel)
        hard = np.zeros((P, P), dtype=bool)
        for a, b in _CHAIN:  # upper segment behind lower unless clearly the other way
            farther_lower = z[t, b] - z[t, a] > 2 * hysteresis
            rel[a, b], rel[b, a] = not farther_lower, farther_lower
            hard[a, b], hard[b, a] = not farther_lower, farther_lower
        for a, b in ALWAYS:
            rel[a, b], rel[b, a] = True, False
            hard[a, b], hard[b, a] = True, False
        np.fill_diagonal(rel, False)
        order = _sort(rel, rank, z[t], hard)
        rank[order] = np.arange(P)
        # The drawn order is the new state: pairs keep it while within the tie band.
        rel = rank[:, None] < rank[None, :]
        out[t] = order
    return out


def order_ranks(orders: np.ndarray) -> np.ndarray:
    """Rank of each part per frame ``(T, 10)`` (0 = drawn first, farthest) from orders ``(T, 10)``."""
    orders = np.asarray(orders)
    ranks = np.empty_like(orders)
    np.put_along_axis(ranks, orders, np.arange(orders.shape[1])[None].repeat(len(orders), 0), axis=1)
    return ranks


def depth_metric(orders: np.ndarray, part_z: np.ndarray, margin: float, pairs=None) -> dict[str, float]:
    """docs/method.md §15.7: agreement of the drawn pairwise order with the source depth, and order flips.

    orders ``(T, 10)``; part_z ``(T, 10)``; a pair counts in a frame when the source separates it by
    more than ``margin`` (source units).  ``pairs``: optional ``(T, 10, 10)`` bool of the pairs that
    matter (e.g. overlap in the image); default all.  Returns ``depth_agreement`` (share of counted
    (frame, pair) cases drawn in the source's order; NaN with none), ``depth_pairs`` (how many were
    counted), ``order_flips`` (changes of a pair's relative order between consecutive frames, summed
    over pairs; with ``pairs``, only pairs that overlap in both frames) and
    ``order_flips_per_100_frames``.
    """
    ranks = order_ranks(orders)
    z = np.asarray(part_z, dtype=np.float64)
    iu = np.triu_indices(z.shape[1], k=1)
    dz = (z[:, :, None] - z[:, None, :])[:, iu[0], iu[1]]  # > 0: a farther
    behind = (ranks[:, :, None] < ranks[:, None, :])[:, iu[0], iu[1]]  # a drawn before b
    count = np.abs(dz) > margin
    if pairs is not None:
        count &= np.asarray(pairs, dtype=bool)[:, iu[0], iu[1]]
    agree = behind == (dz > 0)
    n = int(count.sum())
    changed = behind[1:] != behind[:-1]
    if pairs is not None:  # only flips between parts overlapping in both frames are visible
        pp = np.asarray(pairs, dtype=bool)[:, iu[0], iu[1]]
        changed &= pp[1:] & pp[:-1]
    flips = int(changed.sum()) if len(behind) > 1 else 0
    return {"depth_agreement": float(agree[count].mean()) if n else float("nan"), "depth_pairs": n,
            "order_flips": flips, "order_flips_per_100_frames": 100.0 * flips / max(len(z) - 1, 1)}


# --------------------------------------------------------------------------- user overrides

#: Names a depth override may use: every part of :data:`PARTS`, and whole limbs.
PART_ALIASES: dict[str, tuple[int, ...]] = {
    **{name: (PART_INDEX[name],) for name in PARTS},
    "left_arm": (PART_INDEX["l_upper_arm"], PART_INDEX["l_forearm"]),
    "right_arm": (PART_INDEX["r_upper_arm"], PART_INDEX["r_forearm"]),
    "left_leg": (PART_INDEX["l_thigh"], PART_INDEX["l_shin"]),
    "right_leg": (PART_INDEX["r_thigh"], PART_INDEX["r_shin"]),
}


def parse_overrides(spec, n_frames: int, source="params.yaml", field="reshape.depth_overrides"):
    """User depth overrides, checked: ``[(over parts, under parts, first frame, last frame), ...]``.

    ``spec``: a list (or None) of items, each either a sentence ``"left_arm over torso from 12 to
    30"`` or a mapping ``{over: left_arm, under: torso, from: 12, to: 30}``; frames are 0-based and
    inclusive, within ``0 .. n_frames − 1``.  Names are :data:`PART_ALIASES` (a part, or
    ``left_arm`` etc. for both its segments).  Bad input raises :class:`InputError` naming the
    item's field.
    """
    if spec is None:
        return []
    if not isinstance(spec, list):
        raise InputError(source, field, "a list of overrides such as 'left_arm over torso from 12 to 30'", spec)
    names = ", ".join(PART_ALIASES)
    out = []
    for i, item in enumerate(spec):
        f = f"{field}[{i}]"
        if isinstance(item, str):
            words = item.split()
            if len(words) != 7 or words[1] != "over" or words[3] != "from" or words[5] != "to":
                raise InputError(source, f, "'<part> over <part> from <first frame> to <last frame>'", item)
            item = {"over": words[0], "under": words[2], "from": words[4], "to": words[6]}
            for k in ("from", "to"):
                try:
                    item[k] = int(item[k])
                except ValueError:
                    raise InputError(source, f"{f}.{k}", "a frame number", item[k]) from None
        if not isinstance(item, dict) or set(item) != {"over", "under", "from", "to"}:
            raise InputError(source, f, "a mapping with over, under, from, to (or a sentence)", item)
        for k in ("over", "under"):
            if item[k] not in PART_ALIASES:
                raise InputError(source, f"{f}.{k}", f"a part name ({names})", item[k])
        for k in ("from", "to"):
            v = item[k]
            if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < n_frames:
                raise InputError(source, f"{f}.{k}", f"a frame number in 0..{n_frames - 1} (the clip has "
                                 f"{n_frames} frames)", v)
        if item["from"] > item["to"]:
            raise InputError(source, f"{f}.to", f"a frame at or after from ({item['from']})", item["to"])
        over, under = PART_ALIASES[item["over"]], PART_ALIASES[item["under"]]
        if set(over) & set(under):
            raise InputError(source, f"{f}.under", "a part other than the one drawn over it", item["under"])
        out.append((over, under, int(item["from"]), int(item["to"])))
    return out


def apply_overrides(orders: np.ndarray, overrides) -> np.ndarray:
    """Orders ``(T, 10)`` with each override ``(over, under, t0, t1)`` enforced on frames t0..t1.

    In a frame where some ``over`` part is drawn before some ``under`` part, the ``over`` parts move
    (keeping their order among themselves) to just after the last ``under`` part; every other part
    keeps its place, and frames outside the range are untouched.  Overrides apply in list order.
    """
    out = np.array(orders, dtype=np.int64, copy=True)
    for over, under, t0, t1 in overrides:
        for t in range(t0, min(t1, len(out) - 1) + 1):
            o = list(out[t])
            pos = {p: k for k, p in enumerate(o)}
            if min(pos[p] for p in over) > max(pos[p] for p in under):
                continue
            moving = [p for p in o if p in over]
            rest = [p for p in o if p not in over]
            last = max(rest.index(p) for p in under)
            out[t] = rest[:last + 1] + moving + rest[last + 1:]
    return out
