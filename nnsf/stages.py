"""The pipeline's stages as plain functions from files to files.

Each stage takes the parsed ``params.yaml`` dict and explicit paths, writes
its outputs atomically, and returns a :class:`StageResult` that the Prefect
flows (``flows/``) log to MLflow.  The CLI (``nnsf <stage>``) calls the same
functions.  Paths default to the layout of ``dvc.yaml``.

A stage reads only the parameters dvc.yaml lists for it, so DVC's caching
stays correct; bad parameters or inputs raise :class:`nnsf.errors.InputError`
before anything is written.
"""
from __future__ import annotations

import itertools
import os
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from threadpoolctl import threadpool_limits

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.io import atomic_dir, read_json, read_npz, write_csv, write_json, write_npz
from nnsf.params import require, source_of
from nnsf.skeleton import N_FEATURES, Unifier, to_points

# Default locations, mirrored exactly by dvc.yaml.
RAW_DIR = Path("data/raw")               # keypoints.csv (pixels), characters.json (ground truth)
FEATURES_DIR = Path("data/features")     # features.csv (unified, >= 0), unifier.json
MODEL_PATH = Path("models/nnsf.npz")     # U, V, W, class names, objective history
FRAMES_DIR = Path("data/frames")         # rendered clips: PNG frames, annotation.json, truth.npz
TRACKS_DIR = Path("data/tracks")         # tracked control points per clip (curves.npz)
TRACKED_DIR = Path("data/tracked")       # key points from the tracked curves (the frames source)
REPORTS = Path("reports")
FEATURES_CSV = FEATURES_DIR / "features.csv"


@dataclass
class StageResult:
    """What a stage did: parameters used, scalar metrics, files for people.

    ``params`` and ``metrics`` are flat ``{name: scalar}`` dicts ready for
    ``mlflow.log_params`` / ``log_metrics``; ``artifacts`` are files (figures,
    tables) worth attaching to the run.
    """

    params: dict = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    artifacts: list[Path] = field(default_factory=list)
    #: Sub-results to log as one nested MLflow run each (e.g. one per method
    #: of an evaluation), by run name.
    runs: dict[str, "StageResult"] = field(default_factory=dict)


# ---------------------------------------------------------------- helpers
def _nnsf_params(params: dict) -> dict:
    """NNSF keyword arguments from the ``nnsf`` section (rank excluded)."""
    return {
        "alpha": float(require(params, "nnsf.alpha")),
        "beta": float(require(params, "nnsf.beta")),
        "class_in_loop": bool(require(params, "nnsf.class_in_loop")),
        "tol": float(require(params, "nnsf.tol")),
        "init": require(params, "nnsf.init"),
    }


def _check_rank(params: dict, rank: int, field_name: str) -> None:
    if rank > N_FEATURES:
        raise InputError(source_of(params), field_name,
                         f"a rank of at most the number of features ({N_FEATURES})", rank)


def _read_features(path) -> pd.DataFrame:
    return contract.read_table(path, non_negative=True)


def _label_column(params: dict) -> str:
    return require(params, "nnsf.label")


def _need_several(table: pd.DataFrame, column: str, source, purpose: str, at_least: int = 2) -> None:
    """InputError unless ``table[column]`` holds at least ``at_least`` distinct values.

    A cross-validated precision over one class is 1.0 whatever the model
    does, and a grouped CV over one clip has nothing to hold out: such data
    is refused, naming the column and what it holds, instead of giving a
    perfect score.
    """
    values = pd.unique(table[column])
    if len(values) < at_least:
        raise InputError(source, column, f"at least {at_least} distinct {column} values {purpose}",
                         reason=f"found {len(values)}: {', '.join(map(str, values[:3]))}")


# ---------------------------------------------------------------- stages
def frames(params: dict, out_dir=FRAMES_DIR, mapper=None) -> StageResult:
    """Render the ``frames`` section's clips as cartoon frames with ground truth.

    See :func:`nnsf.frames.stage.render_frames`; ``mapper`` fans out over clips.
    """
    from nnsf.frames.stage import render_frames

    return render_frames(params, out_dir=out_dir, mapper=mapper)


def track(params: dict, frames_dir=FRAMES_DIR, tracks_dir=TRACKS_DIR, tracked_dir=TRACKED_DIR,
          mapper=None) -> StageResult:
    """Track every clip's side contours, then derive its key points (the ``frames`` source).

    Writes ``<tracks_dir>/<clip>/curves.npz`` (:func:`nnsf.track.stage.track_clips`)
    and ``<tracked_dir>/keypoints.csv`` + ``characters.json`` in the
    feature-matrix contract, pixels (:func:`nnsf.frames.stage.keypoints_from_tracks`),
    which the data stage reads with ``dataset.name: frames`` and
    ``dataset.path: data/tracked``.  ``mapper`` fans out over clips.
    """
    from nnsf.frames.stage import keypoints_from_tracks
    from nnsf.track.stage import track_clips

    tracked = track_clips(params, frames_dir=frames_dir, out_dir=tracks_dir, mapper=mapper)
    points = keypoints_from_tracks(params, frames_dir=frames_dir, tracks_dir=tracks_dir,
                                   out_dir=tracked_dir, mapper=mapper)
    return StageResult(params=tracked.params,
                       metrics={**tracked.metrics, **{f"keypoints_{k}": v for k, v in points.metrics.items()}})


def tracking(params: dict, frames_dir=FRAMES_DIR, reports=REPORTS, mapper=None) -> StageResult:
    """Score ours, Agarwala's and Lucas-Kanade tracking against the rendered ground truth (docs/method.md §15.6).

    See :func:`nnsf.track.stage.evaluate_tracking`: ``reports/tracking.json``,
    ``reports/tracking.csv``, ``reports/figures/tracking_overlay.png``.
    """
    from nnsf.track.stage import evaluate_tracking

    return _publish("tracking", reports, "tracking.json",
                    lambda out: evaluate_tracking(params, frames_dir=frames_dir, reports=out, mapper=mapper))


def heldout(params: dict, keypoints_csv=RAW_DIR / "keypoints.csv", reports=REPORTS, mapper=None) -> StageResult:
    """Leave-one-cell-out style translation against the hidden real clips (docs/method.md §15.5).

    Reads the raw key points (pixels), not the features stage's unified table:
    that unifier saw every clip, hidden cells included, so each cell is
    unified again from its remaining clips only.  See
    :func:`nnsf.evaluate.translation.heldout`; ``mapper`` fans out over cells.
    """
    from nnsf.evaluate.translation import heldout as run

    return _publish("heldout", reports, "heldout.json",
                    lambda out: run(params, features_csv=keypoints_csv, reports=out, mapper=mapper))


def _publish(stage: str, reports, report: str, write, root=None) -> StageResult:
    """``write(staging)`` inside :func:`nnsf.publish.publishing`: the files it writes are one set.

    Returns its result with the artifacts at their published paths.  A stage
    that reports failed items (clips, cells) writes its report, then raises
    an :class:`InputError`: if ``report`` (a path relative to the staging
    folder) was written, the set is published before the error goes on.
    """
    from nnsf.publish import final_paths, publishing

    late = None
    root = Path(reports if root is None else root)
    with publishing(reports, stage, root=root) as out:
        try:
            result = write(out)
        except InputError as err:
            if not (out / report).is_file():
                raise
            late = err
    if late is not None:
        raise late
    result.artifacts = final_paths(result.artifacts, out, root)
    for child in result.runs.values():
        child.artifacts = final_paths(child.artifacts, out, root)
    return result


TRANSLATION_DIR = REPORTS / "translation"

#: The folders each stage writes into (the parents of its dvc.yaml outs, and the
#: outs that are folders).  The commands check them before any work starts, so an
#: unwritable output fails in a second with one line, not after the stage's work.
OUTPUT_FOLDERS = {
    "frames": (FRAMES_DIR,),
    "track": (TRACKS_DIR, TRACKED_DIR),
    "tracking": (REPORTS, REPORTS / "figures"),
    "data": (RAW_DIR,),
    "features": (FEATURES_DIR,),
    "factorize": (MODEL_PATH.parent, REPORTS, REPORTS / "figures"),
    "evaluate": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "isomap": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "sweep": (REPORTS, REPORTS / "figures" / "sweep"),
    "heldout": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "translate": (TRANSLATION_DIR,),
    "reshape": (REPORTS / "reshape",),
    "styles": (MODEL_PATH.parent,),
    "animate": (REPORTS / "animate",),
}


def check_outputs(stage: str, folders=None) -> None:
    """Raise :class:`InputError` naming the first of ``stage``'s output folders that cannot be written.

    ``folders`` replaces :data:`OUTPUT_FOLDERS` (commands given ``--out``).
    """
    from nnsf.io import check_writable

    for folder in (OUTPUT_FOLDERS.get(stage, ()) if folders is None else folders):
        check_writable(folder)


def translate(params: dict, features_csv=FEATURES_CSV, out_dir=TRANSLATION_DIR,
              content_clip=None, style=None) -> StageResult:
    """One clip's motion performed in another style (docs/method.md §8), to ``out_dir``.

    ``content_clip`` and ``style`` default to ``translation.content_clip`` and
    ``translation.style``; ``auto`` picks the first clip (sorted by name) and
    the last style, other than the clip's own, that has no clip of that
    content yet, else the last other style.  Writes ``translated_features.csv``
    (template units), ``translated_pixels.csv``, ``translation.gif``,
    ``translation_strip.png`` and ``translation.json``.
    """
    from nnsf.evaluate.translation import translate as run

    clip = str(content_clip if content_clip is not None else require(params, "translation.content_clip"))
    target = str(style if style is not None else require(params, "translation.style"))
    if clip == "auto" or target == "auto":
        table = contract.read_table(features_csv)
        clips = table.drop_duplicates("clip").set_index("clip").sort_index()
        if clip == "auto":
            clip = str(clips.index[0])
        if target == "auto" and clip in clips.index:
            own, content = clips.loc[clip, "character"], clips.loc[clip, "motion"]
            others = sorted(set(clips["character"]) - {own})
            if not others:
                raise InputError(features_csv, "character", "at least two styles to translate between")
            have = set(clips.loc[clips["motion"] == content, "character"])
            missing = [c for c in others if c not in have]
            target = str((missing or others)[-1])
    return run(params, features_csv=features_csv, unifier_json=Path(features_csv).parent / "unifier.json",
               content_clip=clip, style=target, out_dir=out_dir)


STYLES_MODEL = Path("models/styles.npz")


def styles(params: dict, features_csv=FEATURES_CSV, out=STYLES_MODEL) -> StageResult:
    """Fit the style translator (``translation.*``) on every clip and save it (``models/styles.npz``).

    The model file (:mod:`nnsf.factor.style_model`) holds the translator,
    the training characters' unifier (``unifier.json`` beside
    ``features_csv``) and the feature table's SHA-256; ``nnsf animate`` and
    :func:`nnsf.translate` apply it to new motion.
    """
    from nnsf.evaluate.translation import _check_translator, translator_params
    from nnsf.factor.style_model import dataset_view, file_sha256, fit_model

    tp = translator_params(params)
    _check_translator(params, tp)
    features_csv = Path(features_csv)
    table = contract.read_table(features_csv, non_negative=True)
    unifier = read_unifier(features_csv.parent)
    started = time.perf_counter()
    tr = fit_model(table, unifier, tp, out, features_sha256=file_sha256(features_csv),
                   source=str(features_csv), view=dataset_view(params))
    seconds = time.perf_counter() - started
    return StageResult(
        params={f"translation_{k}": v for k, v in tp.items()},
        metrics={"styles": len(tr.styles_), "contents": len(tr.contents_), "frames": len(table),
                 "fit_seconds": round(seconds, 3)},
        artifacts=[Path(out)])


ANIMATE_DIR = REPORTS / "animate"


def animate(params: dict, model=STYLES_MODEL, out_dir=ANIMATE_DIR) -> StageResult:
    """The ``animate:`` block: a character performing a motion in a style (:mod:`nnsf.animation`).

    Writes, atomically as one folder ``out_dir``: ``animation.mp4``,
    ``animation.gif``, ``animation_sheet.png`` (as ``animate.output`` lists)
    and ``animate.json`` (what was made; no wall times, those go to MLflow).
    Character and motion paths must be relative and stay inside the project.
    """
    from nnsf.animation import animate_files
    from nnsf.datasets.views import check_view

    src = source_of(params)
    spec = {k: require(params, f"animate.{k}") for k in
            ("character", "motion", "style", "view", "fps", "n_vertices", "max_frames", "output")}
    for key in ("character", "motion"):
        text = str(spec[key])
        if not text.startswith("synthetic:") and ("/" in text or "." in text):
            p = Path(text)
            if p.is_absolute() or ".." in p.parts:
                raise InputError(src, f"animate.{key}", "a relative path inside the project", text)
    check_view(spec["view"], src, "animate.view")
    out_dir = Path(out_dir)
    with atomic_dir(out_dir) as tmp:
        outputs = {kind: tmp / name for kind, name in (("mp4", "animation.mp4"), ("gif", "animation.gif"),
                                                       ("sheet", "animation_sheet.png"))
                   if kind in spec["output"]}
        res = animate_files(spec["character"], spec["motion"], style=spec["style"], model=model,
                            view=spec["view"], fps=spec["fps"], n_vertices=int(spec["n_vertices"]),
                            max_frames=int(spec["max_frames"]), outputs=outputs, progress=False)
        write_json(tmp / "animate.json", {
            "character": res.character, "motion": res.motion, "style": res.style, "view": res.view,
            "frames": res.frames, "fps": res.fps, "files": sorted(p.name for p in res.files.values())})
    return StageResult(
        params={f"animate.{k}": (",".join(v) if isinstance(v, list) else v) for k, v in spec.items()},
        metrics={"frames": res.frames, **{f"seconds_{k}": round(v, 3) for k, v in res.seconds.items()}},
        artifacts=[out_dir / p.name for p in res.files.values()] + [out_dir / "animate.json"])


def reshape(params: dict, motion_csv=TRANSLATION_DIR / "translated_features.csv",
            out_dir=REPORTS / "reshape", character_path=None) -> StageResult:
    """A drawn character performing one clip of ``motion_csv`` (docs/method.md §10-§14), to ``out_dir``.

    By default the translate stage's output, on ``reshape.character``.  See
    :func:`nnsf.reshape.stage.reshape`: PNG frames, GIF, MP4, a contact sheet
    and ``metrics.json``.
    """
    from nnsf.reshape.stage import reshape as run

    return run(params, motion_csv=motion_csv, character_path=character_path, out_dir=out_dir)


def data(params: dict, out_dir=RAW_DIR) -> StageResult:
    """Produce the raw key-point table for ``dataset.name`` into ``out_dir``.

    Writes ``keypoints.csv`` (the contract, pixel coordinates) and
    ``characters.json`` (what the source knows about its characters: the
    generator's ground truth, or the BVH files read and skipped).

    Sources (``dataset.name``):

    - ``synthetic``: the embedded generator (``dataset.synthetic``);
    - ``bvh``: every labelled BVH clip of the folder ``dataset.path``,
      projected to 2D (``dataset.bvh``); style = character, content = motion;
    - ``frames``: the key points the tracking stage derived from rendered
      or drawn frames, ``<dataset.path>/keypoints.csv``.
    """
    name = require(params, "dataset.name")
    if name == "bvh":
        return _data_bvh(params, out_dir)
    if name == "frames":
        return _data_frames(params, out_dir)
    from nnsf.datasets import synthetic

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
    from nnsf.datasets import bvh_source

    folder = _dataset_folder(params)
    kw = {
        "fps": float(require(params, "dataset.bvh.fps")),
        "azimuth": float(require(params, "dataset.bvh.azimuth")),
        "elevation": float(require(params, "dataset.bvh.elevation")),
        "facing": require(params, "dataset.bvh.facing"),
        "center": bool(require(params, "dataset.bvh.center")),
    }
    view = _bvh_view(params)
    if view is not None:
        from nnsf.datasets import views

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
    if view is not None:
        kw["view"] = view
    if require(params, "dataset.bvh.complete_grid"):
        table, dropped = _complete_grid(table)
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
    from nnsf.params import get

    try:
        return get(params, "dataset.bvh.view")
    except KeyError:
        return None


def _complete_grid(table: pd.DataFrame) -> tuple[pd.DataFrame, list[tuple[str, int]]]:
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
        raise InputError(src, "file", "the tracking stage's key points (run the track stage first)")
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


def factorize(params: dict, features_csv=FEATURES_CSV, model=MODEL_PATH, reports=REPORTS) -> StageResult:
    """Fit NNSF on all frames, labelled by ``nnsf.label``.

    Writes the model (``U``, ``V``, ``W``, classes, per-row labels, objective
    history) as ``.npz``, ``reports/factorize.json`` and two figures: the
    objective per iteration and the basis rows drawn as poses.
    """
    from nnsf.factor.figures import basis_figure, objective_figure
    from nnsf.factor.nnsf import NNSF

    rank = int(require(params, "nnsf.rank"))
    _check_rank(params, rank, "nnsf.rank")
    kw = _nnsf_params(params)
    max_iter = int(require(params, "nnsf.max_iter"))
    seed = int(require(params, "seed"))
    label = _label_column(params)
    table = _read_features(features_csv)
    X = contract.features(table)
    y = table[label].to_numpy()

    started = time.perf_counter()
    est = NNSF(rank, max_iter=max_iter, random_state=seed, **kw)
    # One BLAS thread: the products are thin (34 columns), and OpenBLAS's
    # spinning worker threads made this fit 10-40x slower on a 2-core
    # machine with anything else running.
    with threadpool_limits(limits=1, user_api="blas"):
        V = est.fit_weights(X, y)
    seconds = time.perf_counter() - started
    U, W = est.components_, est.class_map_
    with threadpool_limits(limits=1, user_api="blas"):
        encoded = est.transform(X)  # the training frames encoded as new ones are
    train_pred = est.classes_[np.argmax(encoded @ W, axis=1)]
    metrics = {
        "n_iter": est.n_iter_,
        "objective": float(est.objective_[-1]),
        "relative_error": est.reconstruction_err_ / float(np.linalg.norm(X)),
        "train_precision": _macro_precision(y, train_pred),
        "v_sparsity": float(np.mean(V < 1e-6 * V.max())),
    }
    # The model and the reports are published as one set (nnsf.publish), under the
    # folder that holds both; the manifest is reports/factorize.manifest.json.
    model, reports = Path(model), Path(reports)
    root = Path(os.path.commonpath([model.parent.absolute(), reports.absolute()]))

    def write(out: Path) -> StageResult:
        write_npz(
            out / model.absolute().relative_to(root), U=U, V=V, V_encoded=encoded, W=W,
            classes=est.classes_.astype(str), objective=est.objective_,
            clip=table["clip"].to_numpy(str), character=table["character"].to_numpy(str),
            motion=table["motion"].to_numpy(str), label=np.array(label),
        )
        staged = out / reports.absolute().relative_to(root)
        figs = [
            objective_figure(est.objective_, staged / "figures" / "objective.png"),
            basis_figure(U, V, staged / "figures" / "basis.png"),
        ]
        # Files hold only what the inputs determine; wall time goes to MLflow.
        write_json(staged / "factorize.json", {"rank": rank, "label": label, **metrics})
        return StageResult(
            params={"rank": rank, "max_iter": max_iter, "seed": seed, "label": label, **kw},
            metrics={**metrics, "fit_seconds": round(seconds, 3)}, artifacts=figs,
        )

    result = _publish("factorize", reports, reports.absolute().relative_to(root) / "factorize.json",
                      write, root=root)
    result.artifacts = [reports / Path(a).relative_to(reports.absolute()) for a in result.artifacts]
    return result


def _macro_precision(y_true, y_pred) -> float:
    from sklearn.metrics import precision_score
    return float(precision_score(y_true, y_pred, average="macro", zero_division=0))


def evaluate(params: dict, features_csv=FEATURES_CSV, reports=REPORTS, mapper=None) -> StageResult:
    """Grouped 10-fold CV: precision and reconstruction vs rank for every method.

    Writes ``reports/metrics.json`` (DVC metrics), the fold table
    ``reports/cv_folds.csv``, the summary ``reports/precision_vs_rank.csv``
    (mean ± sd), plot data ``reports/plots/{precision,recon_error}_vs_rank.csv``
    and the figures ``reports/figures/{precision,reconstruction}_vs_rank.png``.
    ``mapper(fn, jobs)`` fans the (method, rank, fold) fits out (see
    :func:`nnsf.evaluate.crossval.precision_vs_rank`).
    """
    from nnsf.evaluate.crossval import precision_vs_rank, summarise, wide
    from nnsf.evaluate.figures import precision_vs_rank_figure, reconstruction_figure
    from nnsf.publish import publishing

    ranks = [int(r) for r in require(params, "evaluate.ranks")]
    for r in ranks:
        _check_rank(params, r, "evaluate.ranks")
    methods = list(require(params, "evaluate.methods"))
    n_splits = int(require(params, "evaluate.folds"))
    max_iter = int(require(params, "evaluate.max_iter"))
    seed = int(require(params, "seed"))
    label = _label_column(params)
    kw = _nnsf_params(params)
    nnsf_rank = int(require(params, "nnsf.rank"))
    table = _read_features(features_csv)
    _need_several(table, "clip", features_csv, "to hold out in cross-validation grouped by clip")
    _need_several(table, label, features_csv, f"(nnsf.label: {label}): precision over one class is "
                  "1.0 for any model")
    X = contract.features(table)
    y = table[label].to_numpy()
    groups = table["clip"].to_numpy()
    styles = table["character"].to_numpy()
    gp_params, phase = _gp_settings(params, table, methods)
    try:
        folds_table = precision_vs_rank(
            X, y, groups, styles=styles, methods=methods, ranks=ranks, n_splits=n_splits,
            seed=seed, max_iter=max_iter, nnsf_params=kw, n_jobs=2, mapper=mapper,
            phase=phase, gp_params=gp_params,
        )
    except ValueError as exc:
        if "fold" in str(exc) or "clips" in str(exc):
            raise InputError(source_of(params), "evaluate.folds", "at most the number of clips per class",
                             reason=str(exc)) from None
        raise
    summary = summarise(folds_table)
    reports = Path(reports)
    # Wall times vary from run to run; they go to MLflow, not into the
    # versioned tables (whose hashes must depend on the inputs only).
    fit_seconds = float(folds_table["seconds"].sum())
    chance = 1.0 / len(np.unique(y))
    metrics = _evaluate_metrics(summary, nnsf_rank, label, n_splits, chance)
    # The files are published as one set (nnsf.publish: staged, committed,
    # moved, manifest reports/evaluate.manifest.json last): a killed run
    # never leaves some new files beside old ones.
    with publishing(reports, "evaluate") as out:
        write_csv(out / "cv_folds.csv", folds_table.drop(columns=["seconds"]))
        write_csv(out / "precision_vs_rank.csv", summary.drop(columns=["seconds_mean"], errors="ignore"))
        write_csv(out / "plots" / "precision_vs_rank.csv", wide(summary, "precision_mean"))
        write_csv(out / "plots" / "recon_error_vs_rank.csv", wide(summary, "recon_error_mean"))
        staged = [
            precision_vs_rank_figure(
                summary, out / "figures" / "precision_vs_rank.png", chance=chance,
                title=f"Held-out precision vs rank ({label} classes, {n_splits}-fold CV grouped by clip)"),
            reconstruction_figure(summary, out / "figures" / "reconstruction_vs_rank.png"),
        ]
        write_json(out / "metrics.json", metrics)
    figs = [reports / Path(f).relative_to(out) for f in staged]
    flat = {f"{m}_{k}": v for m, d in metrics["methods"].items() for k, v in d.items()
            if isinstance(v, (int, float))}
    flat["cv_fit_seconds"] = round(fit_seconds, 3)
    return StageResult(
        params={"ranks": ",".join(map(str, ranks)), "methods": ",".join(methods), "folds": n_splits,
                "max_iter": max_iter, "seed": seed, "label": label, "rank": nnsf_rank, **kw,
                **{f"gp_{k}": v for k, v in (gp_params or {}).items()}},
        metrics=flat, artifacts=figs + [reports / "precision_vs_rank.csv"],
    )


def clip_phase(table: pd.DataFrame) -> np.ndarray:
    """Phase in [0, 1] of every row: its ``frame`` relative to its clip's first and last frame."""
    frame = table["frame"].to_numpy(float)
    by_clip = table.groupby("clip", sort=False)["frame"]
    lo = by_clip.transform("min").to_numpy(float)
    hi = by_clip.transform("max").to_numpy(float)
    return np.where(hi > lo, (frame - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0)


def _gp_settings(params: dict, table: pd.DataFrame, methods) -> tuple[dict | None, np.ndarray | None]:
    """``evaluate.gp`` settings and per-row phases when a GP baseline is requested, else (None, None).

    The subsample (``evaluate.gp.phase_bins`` bins per cell) cannot be larger
    than the data: every bin needs a frame even for a cell with one clip, so
    the bins may not outnumber the frames of the shortest clip.
    """
    if not any(m in ("mgpm", "cbgpm") for m in methods):
        return None, None
    bins = int(require(params, "evaluate.gp.phase_bins"))
    shortest = int(table.groupby("clip").size().min())
    if bins > shortest:
        raise InputError(source_of(params), "evaluate.gp.phase_bins",
                         f"at most the frames of the shortest clip ({shortest}); the GP models' "
                         "subsample cannot be larger than the data", bins)
    return {"phase_bins": bins, "max_iter": int(require(params, "evaluate.gp.max_iter"))}, clip_phase(table)


def _evaluate_metrics(summary: pd.DataFrame, nnsf_rank: int, label: str, folds: int, chance: float) -> dict:
    """metrics.json: per method the best precision and the values at ``nnsf.rank``."""
    out = {"label": label, "folds": folds, "chance_precision": chance, "methods": {}}
    for method, part in summary.groupby("method", sort=False):
        part = part.sort_values("rank")
        best = part.loc[part["precision_mean"].idxmax()]
        entry = {
            "best_precision": float(best["precision_mean"]),
            "best_rank": int(best["rank"]),
        }
        at = part[part["rank"] == nnsf_rank]
        if len(at):
            entry["precision_at_rank"] = float(at["precision_mean"].iloc[0])
            entry["precision_sd_at_rank"] = float(at["precision_sd"].iloc[0])
            entry["recon_error_at_rank"] = float(at["recon_error_mean"].iloc[0])
        for _, row in part.iterrows():
            entry[f"precision_k{int(row['rank'])}"] = float(row["precision_mean"])
        out["methods"][method] = entry
    return out


def isomap(params: dict, model=MODEL_PATH, features_csv=FEATURES_CSV, reports=REPORTS) -> StageResult:
    """ISOMAP of V (the paper's Fig. 6): residual variance and intrinsic dimension.

    The weights embedded are the training frames *encoded* with U fixed
    (``V_encoded``), the representation every new frame gets; the
    label-informed V of the fit collapses into class clusters when β is large.
    Rows are sampled evenly over characters (``isomap.samples``; ISOMAP
    needs O(n²) memory).  A disconnected neighbour graph is bridged by its
    closest pairs of points rather than by raising the neighbour count, which
    keeps the geodesics local.  Writes ``reports/isomap.json``, the curve
    ``reports/plots/isomap_residual.csv`` and ``reports/figures/isomap.png``
    (3D embedding coloured by character, residual-variance curve).
    """
    from nnsf.evaluate.figures import isomap_figure
    from nnsf.evaluate.isomap import intrinsic_dimension, residual_variance, stratified_sample

    samples = int(require(params, "isomap.samples"))
    neighbors = int(require(params, "isomap.neighbors"))
    max_dim = int(require(params, "isomap.max_dim"))
    seed = int(require(params, "seed"))
    from nnsf.publish import recover

    recover(reports, "factorize", wait=True)  # the model of a killed factorize: its set is settled first
    fitted = read_npz(model)
    for key in ("V_encoded", "character"):
        if key not in fitted:
            raise InputError(model, key, "an array written by the factorize stage")
    V, characters = fitted["V_encoded"], fitted["character"]
    rows = stratified_sample(characters, samples, seed)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", UserWarning)
        dims, rv, embedding = residual_variance(V[rows], n_neighbors=neighbors, max_dim=max_dim,
                                                disconnected="bridge")
    notes = [str(w.message) for w in caught if issubclass(w.category, UserWarning)]
    dim = intrinsic_dimension(dims, rv)
    result = {
        "intrinsic_dimension": int(dim),
        "residual_variance_at_intrinsic": float(rv[dim - 1]),
        "residual_variance_3d": float(rv[min(3, len(rv)) - 1]),
        "samples": int(len(rows)),
        "notes": notes,
    }

    def write(out: Path) -> StageResult:
        write_csv(out / "plots" / "isomap_residual.csv",
                  pd.DataFrame({"dim": dims, "residual_variance": rv}))
        fig = isomap_figure(embedding[:, :3], characters[rows], dims, rv, dim,
                            out / "figures" / "isomap.png",
                            title=f"ISOMAP of the NNSF weights V, frames encoded with U fixed "
                                  f"({len(rows)} frames, rank {V.shape[1]})")
        write_json(out / "isomap.json", result)
        return StageResult(
            params={"samples": samples, "neighbors": neighbors, "max_dim": max_dim, "seed": seed},
            metrics={k: v for k, v in result.items() if not isinstance(v, list)}, artifacts=[fig],
        )

    return _publish("isomap", reports, "isomap.json", write)


def sweep_grid(params: dict) -> list[dict]:
    """The α/β/rank points of ``sweep``: a list of ``{"alpha", "beta", "rank"}`` dicts."""
    ranks = [int(r) for r in require(params, "sweep.rank")]
    for r in ranks:
        _check_rank(params, r, "sweep.rank")
    return [
        {"alpha": float(a), "beta": float(b), "rank": r}
        for a, b, r in itertools.product(require(params, "sweep.alpha"), require(params, "sweep.beta"), ranks)
    ]


def sweep_point(params: dict, point: dict, features_csv=FEATURES_CSV, figure_dir=None) -> StageResult:
    """Cross-validate NNSF at one sweep point (``sweep.folds`` folds, grouped by clip).

    Metrics: mean and sd over folds of held-out macro precision and relative
    reconstruction error.  With ``figure_dir``, also draws the per-fold
    precision and the basis of a fit on all frames at this point.
    """
    from nnsf.evaluate.crossval import precision_vs_rank

    kw = _nnsf_params(params)
    kw.update(alpha=float(point["alpha"]), beta=float(point["beta"]))
    rank = int(point["rank"])
    _check_rank(params, rank, "sweep.rank")
    seed = int(require(params, "seed"))
    n_splits = int(require(params, "sweep.folds"))
    max_iter = int(require(params, "sweep.max_iter"))
    label = _label_column(params)
    table = _read_features(features_csv)
    _need_several(table, "clip", features_csv, "to hold out in cross-validation grouped by clip")
    _need_several(table, label, features_csv, f"(nnsf.label: {label}): precision over one class is "
                  "1.0 for any model")
    X = contract.features(table)
    y = table[label].to_numpy()
    folds_table = precision_vs_rank(
        X, y, table["clip"].to_numpy(), methods=["nnsf"], ranks=[rank], n_splits=n_splits, seed=seed,
        max_iter=max_iter, nnsf_params=kw, n_jobs=1,
    )
    prec = folds_table["precision"].to_numpy(float)
    err = folds_table["recon_error"].to_numpy(float)
    metrics = {
        "precision_mean": float(prec.mean()), "precision_sd": float(prec.std(ddof=1)) if len(prec) > 1 else 0.0,
        "recon_error_mean": float(err.mean()), "recon_error_sd": float(err.std(ddof=1)) if len(err) > 1 else 0.0,
        "seconds": float(folds_table["seconds"].sum()),
    }
    artifacts = []
    if figure_dir is not None:
        from nnsf.factor.figures import fold_figure
        name = f"sweep_a{kw['alpha']:g}_b{kw['beta']:g}_k{rank}.png"
        artifacts.append(fold_figure(folds_table, Path(figure_dir) / name,
                                     title=f"α = {kw['alpha']:g}, β = {kw['beta']:g}, rank {rank}"))
    return StageResult(params={"alpha": kw["alpha"], "beta": kw["beta"], "rank": rank,
                               "folds": n_splits, "max_iter": max_iter, "label": label},
                       metrics=metrics, artifacts=artifacts)


def read_model(path=MODEL_PATH) -> dict:
    """The factorize stage's output as arrays (``U``, ``V``, ``W``, ``classes``, ...)."""
    return read_npz(path)


def read_unifier(features_dir=FEATURES_DIR) -> Unifier:
    """The unifier fitted by the features stage."""
    path = Path(features_dir) / "unifier.json"
    d = read_json(path)
    try:
        return Unifier.from_dict(d)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(path, "characters", "a unifier written by the features stage", reason=str(exc)) from None
