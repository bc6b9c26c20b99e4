"""The pipeline's stages as plain functions from files to files.

Each stage takes the parsed ``params.yaml`` dict and explicit paths, writes
its outputs atomically, and returns a :class:`StageResult` that the Prefect
flows (``flows/``) log to MLflow.  The CLI (``nnsf <stage>``) calls the same
functions.  Paths default to the layout of ``dvc.yaml``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

# Default locations, mirrored exactly by dvc.yaml.
RAW_DIR = Path("data/raw")               # keypoints.csv (pixels), characters.json (ground truth)
FEATURES_DIR = Path("data/features")     # features.csv (unified, >= 0), unifier.json
MODEL_PATH = Path("models/nnsf.npz")     # U, V, W, class names, objective history
REPORTS = Path("reports")


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


def data(params: dict, out_dir=RAW_DIR) -> StageResult:
    """Produce the raw key-point table for ``dataset.name`` into ``out_dir``."""
    raise NotImplementedError


def features(params: dict, raw_dir=RAW_DIR, out_dir=FEATURES_DIR) -> StageResult:
    """Unify raw key points to the template: ``features.csv`` and ``unifier.json``."""
    raise NotImplementedError


def factorize(params: dict, features_csv=FEATURES_DIR / "features.csv", model=MODEL_PATH,
              reports=REPORTS) -> StageResult:
    """Fit NNSF on all frames; write the model and ``reports/factorize.json``."""
    raise NotImplementedError


def evaluate(params: dict, features_csv=FEATURES_DIR / "features.csv", reports=REPORTS) -> StageResult:
    """10-fold grouped CV: precision vs rank for every method; metrics, plot data, figure."""
    raise NotImplementedError


def isomap(params: dict, model=MODEL_PATH, features_csv=FEATURES_DIR / "features.csv",
           reports=REPORTS) -> StageResult:
    """ISOMAP of V: residual-variance curve, intrinsic dimension, 3D embedding figure."""
    raise NotImplementedError


def sweep_grid(params: dict) -> list[dict]:
    """The α/β/rank points of ``sweep``: a list of ``{"alpha", "beta", "rank"}`` dicts."""
    raise NotImplementedError


def sweep_point(params: dict, point: dict, features_csv=FEATURES_DIR / "features.csv",
                figure_dir=None) -> StageResult:
    """Cross-validate NNSF at one sweep point (``sweep.folds`` folds)."""
    raise NotImplementedError
