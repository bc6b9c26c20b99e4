"""The ground floor of the pipeline's stages: what every stage shares, and no stage.

Each sub-package owns its stages in its ``stage.py`` (see docs/architecture.md);
:mod:`nnsf.stages` is only the registry name -> function.  This module holds
what those stage modules have in common, and imports none of them:

* :class:`StageResult`, what a stage returns for the flows to log to MLflow;
* the default paths, mirrored exactly by ``dvc.yaml``, and the output folders
  each stage writes (:data:`OUTPUT_FOLDERS`, checked before any work by
  :func:`check_outputs`);
* the shared preambles: the ``nnsf`` section's keyword arguments, rank checks, the label column, "at least two distinct
  values" checks, the features stage's unifier;
* the fan-out helpers :func:`map_items` and :func:`failures` (a stage over
  clips or cells runs every item, then names the failed ones in one line).

A stage reads only the parameters dvc.yaml lists for it, so DVC's caching
stays correct; bad parameters or inputs raise :class:`nnsf.errors.InputError`
before anything is written.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd

from nnsf.errors import InputError
from nnsf.io import check_writable, read_json
from nnsf.params import require, source_of
from nnsf.schema import Array
from nnsf.skeleton import N_FEATURES, Unifier

# Default locations, mirrored exactly by dvc.yaml.
RAW_DIR = Path("data/raw")               # keypoints.csv (pixels), characters.json (ground truth)
FEATURES_DIR = Path("data/features")     # features.csv (unified, >= 0), unifier.json
MODEL_PATH = Path("models/nnsf.npz")     # U, V, W, class names, objective history
STYLES_MODEL = Path("models/styles.npz")  # the saved style translator (nnsf.factor.style_model)
FRAMES_DIR = Path("data/frames")         # rendered clips: PNG frames, annotation.json, truth.npz
TRACKS_DIR = Path("data/tracks")         # tracked control points per clip (curves.npz)
TRACKED_DIR = Path("data/tracked")       # key points from the tracked curves (the frames source)
REPORTS = Path("reports")
FEATURES_CSV = FEATURES_DIR / "features.csv"
TRANSLATION_DIR = REPORTS / "translation"
RESHAPE_DIR = REPORTS / "reshape"
ANIMATE_DIR = REPORTS / "animate"

#: The arrays of ``models/nnsf.npz`` (the factorize stage's fit: n frames, k atoms, d features,
#: c classes): what the stages reading it back accept.
NNSF_MODEL = {
    "U": Array("f", ("k", N_FEATURES)), "V": Array("f", ("n", "k")), "V_encoded": Array("f", ("n", "k"), finite=True),
    "W": Array("f", ("k", "c")), "classes": Array("U", ("c",)), "objective": Array("f", (None,)),
    "clip": Array("U", ("n",)), "character": Array("U", ("n",)), "motion": Array("U", ("n",)),
    "label": Array("U", ()),
}

#: The folders each stage writes into (the parents of its dvc.yaml outs, and the
#: outs that are folders).  The commands check them before any work starts, so an
#: unwritable output fails in a second with one line, not after the stage's work.
OUTPUT_FOLDERS = {
    "frames": (FRAMES_DIR,),
    "roto": (TRACKS_DIR, TRACKED_DIR),
    "roto_eval": (REPORTS, REPORTS / "figures"),
    "data": (RAW_DIR,),
    "features": (FEATURES_DIR,),
    "factorize": (MODEL_PATH.parent, REPORTS, REPORTS / "figures"),
    "evaluate": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "isomap": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "sweep": (REPORTS, REPORTS / "figures" / "sweep"),
    "heldout": (REPORTS, REPORTS / "plots", REPORTS / "figures"),
    "translate": (TRANSLATION_DIR,),
    "reshape": (RESHAPE_DIR,),
    "styles": (MODEL_PATH.parent,),
    "animate": (ANIMATE_DIR,),
    "results": (Path("docs"),),
}


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


def check_outputs(stage: str, folders=None) -> None:
    """Raise :class:`InputError` naming the first of ``stage``'s output folders that cannot be written.

    ``folders`` replaces :data:`OUTPUT_FOLDERS` (commands given ``--out``).
    """
    for folder in (OUTPUT_FOLDERS.get(stage, ()) if folders is None else folders):
        check_writable(folder)


# ---------------------------------------------------------------- shared preambles
def nnsf_params(params: dict) -> dict:
    """NNSF keyword arguments from the ``nnsf`` section (rank excluded)."""
    return {
        "alpha": float(require(params, "nnsf.alpha")),
        "beta": float(require(params, "nnsf.beta")),
        "class_in_loop": bool(require(params, "nnsf.class_in_loop")),
        "tol": float(require(params, "nnsf.tol")),
        "init": require(params, "nnsf.init"),
    }


def check_rank(params: dict, rank: int, field_name: str) -> None:
    """InputError unless ``rank`` is at most the number of features."""
    if rank > N_FEATURES:
        raise InputError(source_of(params), field_name,
                         f"a rank of at most the number of features ({N_FEATURES})", rank)


def label_column(params: dict) -> str:
    """The class label NNSF is fitted with (``nnsf.label``)."""
    return require(params, "nnsf.label")


def need_several(table: pd.DataFrame, column: str, source, purpose: str, at_least: int = 2) -> None:
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


def read_unifier(features_dir=FEATURES_DIR) -> Unifier:
    """The unifier fitted by the features stage (``unifier.json``)."""
    path = Path(features_dir) / "unifier.json"
    return Unifier.from_dict(read_json(path), path)


# ---------------------------------------------------------------- fan-out
def map_items(mapper, fn, items) -> list:
    """``fn`` over ``items``: in order here, or through the flows' ``mapper(fn, items)``."""
    return list(map(fn, items)) if mapper is None else list(mapper(fn, items))


def failures(failed: dict) -> str:
    """Failed item names, then each item's full error (InputError shortens ``got``)."""
    return ", ".join(failed) + ". " + " | ".join(f"{c}: {e}" for c, e in failed.items())
