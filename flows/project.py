"""Where the project's files and local stores live.

Everything is resolved to absolute paths from the project root, so a stage
gives the same answer whatever its working directory, and so MLflow never
writes into a cwd-relative ``mlruns``/``mlartifacts``.
"""
from __future__ import annotations

import os
from pathlib import Path

#: The file that marks a project root (DVC runs every stage from there).
MARKER = "dvc.yaml"


def root(start: str | os.PathLike | None = None) -> Path:
    """The project root: the nearest folder at or above ``start`` with a dvc.yaml.

    ``start`` defaults to the working directory, which DVC sets to the root for
    every stage.  Inside a DVC experiment workspace (``dvc exp run --queue`` or
    ``--temp`` runs in ``<root>/.dvc/tmp/exps/...``) the answer is the real
    project, so MLflow runs from queued experiments land in the one store
    instead of vanishing with the temporary copy.
    """
    here = Path(start or os.getcwd()).resolve()
    parts = here.parts
    for i in range(len(parts) - 3):
        if parts[i:i + 3] == (".dvc", "tmp", "exps"):
            return Path(*parts[:i])
    for folder in (here, *here.parents):
        if (folder / MARKER).is_file():
            return folder
    return here


def loaded_files(start: str | os.PathLike | None = None) -> set[str]:
    """The project's module files (``nnsf/…``, ``flows/…``, relative POSIX paths) loaded in this process.

    ``start`` is the project root (default: the folder above ``flows/``).
    """
    import sys

    base = Path(start).resolve() if start is not None else Path(__file__).resolve().parents[1]
    files = set()
    for module in list(sys.modules.values()):
        path = getattr(module, "__file__", None)
        if not path:
            continue
        try:
            rel = Path(path).resolve().relative_to(base)
        except ValueError:
            continue
        if rel.parts[0] in ("nnsf", "flows"):
            files.add(rel.as_posix())
    return files


def mlflow_uri(project: Path | None = None) -> str:
    """The MLflow tracking URI: ``$MLFLOW_TRACKING_URI`` or the project's sqlite file.

    MLflow 3.17's file store refuses to work, and a relative sqlite path
    depends on the cwd, hence an absolute ``sqlite:////abs/path/mlflow.db``.
    """
    uri = os.environ.get("MLFLOW_TRACKING_URI")
    if uri:
        return uri
    return "sqlite:///" + str((project or root()) / "mlflow.db")


def mlflow_artifacts(project: Path | None = None) -> str:
    """The artifact location (an absolute ``file://`` URI) for new experiments."""
    return ((project or root()) / "mlartifacts").as_uri()


def prefect_home(project: Path | None = None) -> Path:
    """Prefect's home for servers this project starts: ``<root>/.prefect``.

    Kept inside the project so the run history of ``python -m flows repro``
    survives and can be browsed later (docs/operations.md).
    """
    return (project or root()) / ".prefect"
