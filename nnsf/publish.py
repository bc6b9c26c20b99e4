"""Publishing a stage's output files together: staged, committed by a journal, moved, then a manifest.

A stage such as ``evaluate`` writes several files into folders it shares
with other stages (``reports/``, ``reports/plots/``, ``reports/figures/``),
so one folder cannot be swapped in.  :func:`publishing` makes the set change
as one unit instead:

1. the stage writes every output under ``<root>/.<stage>.staging/`` with the
   paths it will have under ``root`` (each file atomically, :mod:`nnsf.io`);
2. **commit**: ``<staging>/.commit.json`` lists every staged file with its
   SHA-256, written atomically.  Before this point the published set is
   untouched; after it the new set will be completed;
3. the old manifest ``<root>/<stage>.manifest.json`` is removed, and each
   staged file is renamed onto its place;
4. the manifest (the journal's list) is written **last**, then the staging
   folder removed.

:func:`recover` finishes or discards an interrupted publication: a staging
folder without a journal is removed (the old set stands), one with a
journal is rolled forward (steps 3-4, idempotent).  Every publication starts
with it, and :func:`verify` (the reader's check) runs it before checking
that each file the manifest lists is present with its hash.  So after a kill
at any point, the files are the old set or the new set once anything reads
or rewrites them; in the short window of step 3 the files on disk are mixed
but the manifest is absent, so no reader that checks it takes them for a
finished set.  The manifest holds no times, so reruns are byte-identical.
"""
from __future__ import annotations

import contextlib
import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Iterator

from nnsf.errors import InputError
from nnsf.io import WriteError, _write_error, renamed_write_error, write_json

JOURNAL = ".commit.json"


def manifest_path(root, stage: str) -> Path:
    """``<root>/<stage>.manifest.json``: the published set of ``stage`` and its hashes."""
    return Path(root) / f"{stage}.manifest.json"


def staging_path(root, stage: str) -> Path:
    """``<root>/.<stage>.staging``: where ``stage`` writes its next set."""
    return Path(root) / f".{stage}.staging"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _staged_files(staging: Path) -> list[str]:
    """Relative POSIX paths of the finished staged files (temporaries and the journal excluded)."""
    out = []
    for p in staging.rglob("*"):
        rel = p.relative_to(staging)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            out.append(rel.as_posix())
    return sorted(out)


def _roll_forward(root: Path, stage: str, journal: dict) -> None:
    """Steps 3-4: move the journal's files into place, then write the manifest (idempotent)."""
    staging = staging_path(root, stage)
    manifest_path(root, stage).unlink(missing_ok=True)
    for rel in journal["files"]:
        src, dst = staging / rel, root / rel
        if src.exists():
            try:
                dst.parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, dst)
            except OSError as exc:
                raise _write_error(dst, exc) from None
    write_json(manifest_path(root, stage), journal)
    shutil.rmtree(staging, ignore_errors=True)


def recover(root, stage: str) -> str:
    """Finish or discard an interrupted publication of ``stage`` under ``root``.

    Returns ``"none"`` (nothing was interrupted), ``"discarded"`` (killed
    before the commit: the staged files are dropped, the old set stands) or
    ``"completed"`` (killed after it: the new set is moved into place).
    """
    root = Path(root)
    staging = staging_path(root, stage)
    if not staging.exists():
        return "none"
    journal_file = staging / JOURNAL
    if not journal_file.is_file():
        shutil.rmtree(staging, ignore_errors=True)
        return "discarded"
    journal = json.loads(journal_file.read_text())
    _roll_forward(root, stage, journal)
    return "completed"


@contextlib.contextmanager
def publishing(root, stage: str) -> Iterator[Path]:
    """Yield the staging folder of ``stage``; publish everything written there as one set.

    Write each output to ``staging / <path relative to root>``.  On an
    exception nothing is published and the previous set stays as it was.
    """
    root = Path(root)
    recover(root, stage)
    staging = staging_path(root, stage)
    staging.mkdir(parents=True, exist_ok=True)
    try:
        try:
            yield staging
        except WriteError as exc:  # name the file the user will look for, not its staged copy
            raise renamed_write_error(exc, staging, root) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    files = _staged_files(staging)
    journal = {"stage": stage, "files": {rel: _sha256(staging / rel) for rel in files}}
    write_json(staging / JOURNAL, journal)          # the commit point
    _roll_forward(root, stage, journal)


def verify(root, stage: str) -> dict[str, Path]:
    """The published files of ``stage`` (relative path -> path), checked against its manifest.

    Runs :func:`recover` first.  Raises :class:`InputError` naming the
    manifest when it is missing or a file it lists is absent or differs from
    its hash (a set that is not one run's whole output).
    """
    root = Path(root)
    recover(root, stage)
    mpath = manifest_path(root, stage)
    if not mpath.is_file():
        raise InputError(mpath, "file", f"the manifest of the {stage} stage's outputs "
                         f"(rerun the {stage} stage)")
    from nnsf.io import read_json

    manifest = read_json(mpath)
    files = manifest.get("files")
    if not isinstance(files, dict):
        raise InputError(mpath, "files", "a mapping of output paths to SHA-256 hashes")
    out = {}
    for rel, digest in files.items():
        p = root / rel
        if not p.is_file():
            raise InputError(mpath, rel, "a file of this set, present", reason="missing")
        if _sha256(p) != digest:
            raise InputError(mpath, rel, "the file this manifest lists (same SHA-256)",
                             reason="it was written by another run")
        out[rel] = p
    return out
