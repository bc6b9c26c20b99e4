"""The stages of the datasets package: ``data`` (a motion source's raw key points) and ``features``.

``data`` writes the feature-matrix contract in pixels from ``dataset.name``'s
source (the synthetic generator, a BVH folder, or the key points tracked
from frames); ``features`` unifies them to the template (Eq. 4,
docs/method.md §4).
"""
from __future__ import annotations

from pathlib import Path

import pandas as pd

from nnsf.datasets import bvh_source, contract, synthetic, views
from nnsf.errors import InputError
from nnsf.io import atomic_dir, write_json
from nnsf.datasets.joint_map import read_joint_map
from nnsf.params import checked, get, require, source_of
from nnsf.pipeline import FEATURES_DIR, RAW_DIR, StageResult
from nnsf.skeleton import Unifier, to_points


def data(params: dict, out_dir=RAW_DIR) -> StageResult:
    """Produce the raw key-point table for ``dataset.name`` into ``out_dir``.

    Writes ``keypoints.csv`` (the contract, pixel coordinates) and
    ``characters.json`` (what the source knows about its characters: the
    generator's ground truth, or the BVH files read and skipped).

    Sources (``dataset.name``):

    - ``synthetic``: the embedded generator (``dataset.synthetic``);
    - ``bvh``: every labelled BVH clip of the folder ``dataset.path``,
      projected to 2D (``dataset.bvh``); style = character, content = motion;
    - ``frames``: the key points the roto stage derived from rendered
      or drawn frames, ``<dataset.path>/keypoints.csv``.
    """
    name = require(params, "dataset.name")
    if name == "bvh":
        return _data_bvh(params, out_dir)
    if name == "frames":
        return _data_frames(params, out_dir)
    seed = int(require(params, "seed"))
    kw = {
        "characters": int(require(params, "dataset.synthetic.characters")),
        "clips_per_cell": int(require(params, "dataset.synthetic.clips_per_cell")),
        "frames": int(require(params, "dataset.synthetic.frames")),
        "noise_px": float(require(params, "dataset.synthetic.noise_px")),
        "seed": seed,
    }
    table = contract.validate(synthetic.generate(**kw), "synthetic generator")
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "keypoints.csv", table)
        write_json(tmp / "characters.json", synthetic.describe(**kw))
    return StageResult(
        params={"dataset": name, **{f"synthetic_{k}": v for k, v in kw.items()}},
        metrics=_table_counts(table),
    )


def _table_counts(table: pd.DataFrame) -> dict:
    return {"frames": len(table), "clips": table["clip"].nunique(),
            "characters": table["character"].nunique(), "motions": table["motion"].nunique()}


def _dataset_folder(params: dict) -> Path:
    path = Path(require(params, "dataset.path"))
    if not path.is_dir():
        raise InputError(source_of(params), "dataset.path",
                         f"an existing folder for dataset {require(params, 'dataset.name')!r}",
                         str(path))
    return path


def _data_bvh(params: dict, out_dir) -> StageResult:
    folder = _dataset_folder(params)
    kw = {
        "fps": float(require(params, "dataset.bvh.fps")),
        "azimuth": float(require(params, "dataset.bvh.azimuth")),
        "elevation": float(require(params, "dataset.bvh.elevation")),
        "facing": require(params, "dataset.bvh.facing"),
        "center": bool(require(params, "dataset.bvh.center")),
    }
    joint_map = checked(params, "dataset.bvh.joint_map", None)
    if joint_map is not None:
        # A user's mapping for a skeleton no built-in family reads (docs/formats.md §3.3).
        kw["family"] = read_joint_map(joint_map)
    view = _bvh_view(params)
    if view is not None:
        if view == "auto":
            # One view for the whole folder (a style model needs every clip
            # seen alike): the one the clips move most in, summed.
            front, _ = bvh_source.read_folder(folder, **{**kw, "azimuth": 0.0, "elevation": 0.0},
                                              depth=True)
            xy = contract.features(front).reshape(len(front), -1, 2)
            depth = front[list(bvh_source.DEPTH_COLUMNS)].to_numpy(float)
            var = {v: 0.0 for v in views.VIEWS}
            for _, rows in front.groupby("clip", sort=False).indices.items():
                for v, x in views.view_variances(xy[rows], depth[rows]).items():
                    var[v] += x
            view = max(views.VIEWS, key=lambda v: (var[v], -list(views.VIEWS).index(v)))
        kw["azimuth"] = views.VIEWS[view]
    table, report = bvh_source.read_folder(folder, **kw)
    if joint_map is not None:
        kw["family"] = joint_map            # described by its file
    if view is not None:
        kw["view"] = view
    if require(params, "dataset.bvh.complete_grid"):
        table, dropped = complete_grid(table)
        report = report + [f"dropped motion {m!r}: present in {n} of "
                           f"{table['character'].nunique()} styles (dataset.bvh.complete_grid)"
                           for m, n in dropped]
        kw["complete_grid"] = True
    clips = table.groupby("clip", sort=True).agg(character=("character", "first"),
                                                  motion=("motion", "first"), frames=("frame", "size"))
    described = {
        "source": "bvh",
        "path": str(require(params, "dataset.path")),
        "options": kw,
        "clips": {c: {"character": r.character, "motion": r.motion, "frames": int(r.frames)}
                  for c, r in clips.iterrows()},
        "report": report,
    }
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "keypoints.csv", table)
        write_json(tmp / "characters.json", described)
    return StageResult(
        params={"dataset": "bvh", "dataset_path": str(folder), **{f"bvh_{k}": v for k, v in kw.items()}},
        metrics={**_table_counts(table), "skipped_or_warned": len(report)},
    )


def _bvh_view(params: dict):
    """``dataset.bvh.view`` (None when absent or null: ``dataset.bvh.azimuth`` applies)."""
    try:
        return get(params, "dataset.bvh.view")
    except KeyError:
        return None


def complete_grid(table: pd.DataFrame) -> tuple[pd.DataFrame, list[tuple[str, int]]]:
    """Keep the motions that every style performs; return the table and what was dropped.

    A motion recorded in a few styles only cannot be told apart from those
    styles, and classes with a clip or two break grouped cross-validation.
    """
    styles_per_motion = table.groupby("motion")["character"].nunique()
    n_styles = table["character"].nunique()
    keep = styles_per_motion.index[styles_per_motion == n_styles]
    dropped = [(m, int(n)) for m, n in styles_per_motion.items() if n < n_styles]
    if len(keep) == 0:
        raise InputError("dataset", "dataset.bvh.complete_grid",
                         "at least one motion present in every style (or set it to false)")
    return table[table["motion"].isin(keep)].reset_index(drop=True), dropped


def _data_frames(params: dict, out_dir) -> StageResult:
    folder = _dataset_folder(params)
    src = folder / "keypoints.csv"
    if not src.is_file():
        raise InputError(src, "file", "the roto stage's key points (run the roto stage first)")
    table = contract.read_table(src)
    clips = table.groupby("clip", sort=True).agg(character=("character", "first"),
                                                  motion=("motion", "first"), frames=("frame", "size"))
    described = {
        "source": "frames",
        "path": str(require(params, "dataset.path")),
        "clips": {c: {"character": r.character, "motion": r.motion, "frames": int(r.frames)}
                  for c, r in clips.iterrows()},
    }
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "keypoints.csv", table)
        write_json(tmp / "characters.json", described)
    return StageResult(params={"dataset": "frames", "dataset_path": str(folder)},
                       metrics=_table_counts(table))


def features(params: dict, raw_dir=RAW_DIR, out_dir=FEATURES_DIR) -> StageResult:
    """Unify raw key points to the template (Eq. 4, docs/method.md §4).

    Writes ``features.csv`` (the contract in template units, every value ≥
    ``unify.margin``) and ``unifier.json`` (per-character bone ratios, root
    scale and the shared offset, enough to map features back to pixels).
    """
    margin = float(require(params, "unify.margin"))
    raw = contract.read_table(Path(raw_dir) / "keypoints.csv")
    points = to_points(contract.features(raw))
    try:
        unifier = Unifier(margin=margin).fit(points, raw["character"].to_numpy())
    except ValueError as exc:
        raise InputError(Path(raw_dir) / "keypoints.csv", "x1..y17", "a skeleton with non-zero bones",
                         reason=str(exc)) from None
    X = unifier.transform(points, raw["character"].to_numpy())
    table = raw.copy()
    table.loc[:, list(contract.COLUMNS[4:])] = X
    with atomic_dir(out_dir) as tmp:
        contract.write_table(tmp / "features.csv", table)
        write_json(tmp / "unifier.json", unifier.to_dict())
    return StageResult(
        params={"unify_margin": margin},
        metrics={"frames": len(table), "feature_min": float(X.min()), "feature_max": float(X.max())},
    )

