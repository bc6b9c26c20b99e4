"""Publishing a stage's output files together: staged, committed by a journal, moved, then a manifest.

A stage such as ``evaluate`` writes several files into folders it shares
with other stages (``reports/``, ``reports/plots/``, ``reports/figures/``),
so one folder cannot be swapped in.  :func:`publishing` makes the set change
as one unit instead:

1. the stage writes every output under ``<reports>/.<stage>.staging/`` with
   the paths it will have under its root (``reports`` itself, or a folder
   above it when the set spans folders: ``factorize`` also writes
   ``models/nnsf.npz``), each file atomically (:mod:`nnsf.io`).  The
   staging folder is locked (``flock``) while its stage runs;
2. **commit**: ``<staging>/.commit.json`` lists every staged file with its
   SHA-256, written atomically.  Before this point the published set is
   untouched; after it the new set will be completed;
3. the old manifest ``<reports>/<stage>.manifest.json`` is removed, and each
   staged file is renamed onto its place;
4. the manifest (the journal's list) is written **last**, then the staging
   folder removed.

:func:`recover` finishes or discards an interrupted publication (a staging
folder whose lock nobody holds): without a journal it is removed (the old
set stands); with one it is rolled forward (steps 3-4, idempotent).  It runs
at the start of every publication, at the start of **every** ``nnsf`` and
``python -m flows`` command (:func:`recover_all`, on ``reports/``), and in
:func:`verify`, the reader's check.  So after a kill at any point, the
files are the old set or the new set as soon as any command of the project
starts.  Between such a kill inside step 3 (a few renames) and that next
command, a reader outside the project (an editor, ``dvc metrics show``)
can find a mix on disk; it is marked by the missing manifest and the
staging folder with its journal beside it.  A publication in progress is
never touched (its lock is held), and a killed one's lock is released by
the kernel.  The manifest holds no times, so reruns are byte-identical.
"""
from __future__ import annotations

import contextlib
import errno
import hashlib
import os
import shutil
import tempfile
from pathlib import Path
from typing import Iterator

from nnsf.errors import InputError
from nnsf.io import WriteError, write_error, read_json, renamed_write_error, write_json
from nnsf.schema import Map, Optional, Record, Str

JOURNAL = ".commit.json"
#: Where the stages publish (``nnsf.pipeline.REPORTS``); recovered by every command.
REPORTS = Path("reports")
_SUFFIX = ".staging"


def manifest_path(reports, stage: str) -> Path:
    """``<reports>/<stage>.manifest.json``: the published set of ``stage`` and its hashes."""
    return Path(reports) / f"{stage}.manifest.json"


def staging_path(reports, stage: str) -> Path:
    """``<reports>/.<stage>.staging``: where ``stage`` writes its next set."""
    return Path(reports) / f".{stage}{_SUFFIX}"


def _sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


#: A journal (``.commit.json``) and a manifest, as :func:`publishing` writes them.
JOURNAL_RULE = Record({
    "stage": Str(max_len=100),
    "root": Optional(Str(max_len=4096)),
    "files": Map(Str(max_len=64), key=Str(max_len=4096, empty=False)),
})


def read_journal(path: Path, reports: Path, stage: str) -> dict:
    """A journal or manifest read back, checked before any of its paths is used.

    Besides :data:`JOURNAL_RULE`: it is ``stage``'s; its ``root`` is the
    reports folder or the folder above it (the only roots :func:`publishing`
    makes for the project's stages); every file is a relative path without
    ``..`` that stays inside that root once symbolic links are resolved.  A
    journal is a file in the project, so whoever can write one must not be
    able to move files anywhere else by it.
    """
    journal = read_json(path, JOURNAL_RULE)
    if journal["stage"] != stage:
        raise InputError(path, "stage", f"{stage!r} (the stage whose file this is)", journal["stage"])
    reports_real = Path(reports).resolve()
    root = Path(reports) / journal.get("root", ".")
    root_real = root.resolve()
    if root_real not in (reports_real, reports_real.parent):
        raise InputError(path, "root", "the reports folder or the folder that holds it",
                         journal.get("root"))
    for rel in journal["files"]:
        parts = rel.replace("\\", "/").split("/")
        if rel.startswith(("/", "~")) or ".." in parts or any(p.startswith(".") or not p for p in parts) \
                or not (root / rel).resolve().is_relative_to(root_real):
            raise InputError(path, f"files.{rel}", "a relative path inside the stage's root folder "
                             "(no '..', no hidden parts, symbolic links resolved)")
    return journal


def _staged_files(staging: Path) -> list[str]:
    """Relative POSIX paths of the finished staged files (temporaries and the journal excluded)."""
    out = []
    for p in staging.rglob("*"):
        rel = p.relative_to(staging)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts):
            out.append(rel.as_posix())
    return sorted(out)


# -- the lock: held by the process that writes a staging folder ------------------------------

def _lock(folder: Path, wait: bool) -> int | None:
    """An open descriptor of ``folder`` with an exclusive ``flock``; None if busy (``wait`` False).

    The lock belongs to the open descriptor: a killed holder's lock is
    released by the kernel, so a folder nobody holds was left by a dead run.
    """
    import fcntl

    while True:
        try:
            fd = os.open(folder, os.O_RDONLY | os.O_DIRECTORY)
        except (FileNotFoundError, NotADirectoryError):
            return None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            os.close(fd)
            return None
        # The holder we waited for may have removed the folder (and another run made
        # a new one at the same path): the lock counts only on the folder still there.
        try:
            same = os.path.samestat(os.fstat(fd), os.stat(folder))
        except FileNotFoundError:
            os.close(fd)
            return None
        if same:
            return fd
        os.close(fd)


def _move(src: Path, dst: Path) -> None:
    try:
        dst.parent.mkdir(parents=True, exist_ok=True)
        os.replace(src, dst)
    except OSError as exc:
        if exc.errno != errno.EXDEV:
            raise write_error(dst, exc) from None
        # Another file system (a linked folder): copy beside the target, then rename.
        fd, tmp = tempfile.mkstemp(prefix=f".{dst.name}.", dir=dst.parent)
        os.close(fd)
        shutil.copyfile(src, tmp)
        os.replace(tmp, dst)
        os.unlink(src)


def _roll_forward(reports: Path, stage: str, journal: dict) -> None:
    """Steps 3-4: move the journal's files into place, then write the manifest (idempotent)."""
    staging = staging_path(reports, stage)
    root = reports / journal.get("root", ".")
    manifest_path(reports, stage).unlink(missing_ok=True)
    for rel in journal["files"]:
        src = staging / rel
        if src.exists():
            _move(src, root / rel)
    write_json(manifest_path(reports, stage), journal)
    shutil.rmtree(staging, ignore_errors=True)


def _settle(reports: Path, stage: str, staging: Path) -> str:
    """Finish (journal present) or drop (absent) the staging folder we hold the lock of."""
    journal_file = staging / JOURNAL
    if staging.name != staging_path(reports, stage).name or not journal_file.is_file():
        shutil.rmtree(staging, ignore_errors=True)
        return "discarded"
    _roll_forward(reports, stage, read_journal(journal_file, reports, stage))
    return "completed"


def recover(reports, stage: str, wait: bool = False) -> str:
    """Finish or discard an interrupted publication of ``stage`` under ``reports``.

    Returns ``"none"`` (nothing was interrupted), ``"discarded"`` (killed
    before the commit: the staged files are dropped, the old set stands),
    ``"completed"`` (killed after it: the new set is moved into place) or
    ``"busy"`` (a run of the stage is publishing now; with ``wait`` True,
    wait for it instead).
    """
    reports = Path(reports)
    result = "none"
    # The staging folder, and folders of runs killed before they could rename theirs into place.
    candidates = [staging_path(reports, stage)]
    if reports.is_dir():
        prefix = staging_path(reports, stage).name + "."
        candidates += sorted(p for p in reports.iterdir() if p.name.startswith(prefix))
    for staging in candidates:
        if not staging.exists():
            continue
        fd = _lock(staging, wait)
        if fd is None:
            if staging.exists():
                result = "busy"
            continue
        try:
            done = _settle(reports, stage, staging)
        finally:
            os.close(fd)
        if staging == candidates[0]:
            result = done
    return result


def interrupted(reports=REPORTS) -> list[str]:
    """The stages with a staging folder under ``reports`` (cheap: one directory listing)."""
    try:
        names = [e.name for e in os.scandir(reports) if e.name.startswith(".") and _SUFFIX in e.name]
    except OSError:
        return []
    return sorted({n[1:].split(_SUFFIX)[0] for n in names})


def recover_all(reports=REPORTS) -> list[str]:
    """:func:`recover` every stage with a staging folder under ``reports``; one note per action.

    What every command of the project does first, so a set interrupted by a
    kill is the old or the new one again before anything reads or writes.
    Publications in progress are left alone.
    """
    notes = []
    for stage in interrupted(reports):
        done = recover(reports, stage)
        if done == "completed":
            notes.append(f"{manifest_path(reports, stage)}: completed the {stage} stage's "
                         "interrupted publication (its new outputs are all in place)")
        elif done == "discarded":
            notes.append(f"{staging_path(reports, stage)}: removed the {stage} stage's unfinished "
                         "outputs (killed before they were complete; the previous outputs stand)")
    return notes


@contextlib.contextmanager
def publishing(reports, stage: str, root=None) -> Iterator[Path]:
    """Yield the staging folder of ``stage``; publish everything written there as one set.

    The staging folder mirrors ``root`` (default ``reports``; a folder that
    contains it, for a set that spans folders): write each output to
    ``staging / <its path relative to root>``.  On an exception nothing is
    published and the previous set stays as it was.  A second run of the same
    stage publishing at the same time waits for the first.
    """
    reports = Path(reports)
    root = reports if root is None else Path(root)
    rel_root = os.path.relpath(root, reports)
    recover(reports, stage, wait=True)
    staging = staging_path(reports, stage)
    try:
        reports.mkdir(parents=True, exist_ok=True)
        # Made and locked under a name of its own, then renamed: a staging folder
        # is never visible unlocked while its run lives.
        new = Path(tempfile.mkdtemp(prefix=staging.name + ".", dir=reports))
    except OSError as exc:
        raise write_error(staging, exc) from None
    fd = _lock(new, wait=False)
    try:
        try:
            os.rename(new, staging)
        except OSError:
            shutil.rmtree(new, ignore_errors=True)
            raise InputError(staging, "folder", f"no other run of the {stage} stage publishing "
                             "at the same time", "another run made it") from None
        try:
            try:
                yield staging
            except WriteError as exc:  # name the file the user will look for, not its staged copy
                raise renamed_write_error(exc, staging, root) from None
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        files = _staged_files(staging)
        journal = {"stage": stage, **({"root": Path(rel_root).as_posix()} if rel_root != "." else {}),
                   "files": {rel: _sha256(staging / rel) for rel in files}}
        write_json(staging / JOURNAL, journal)          # the commit point
        _roll_forward(reports, stage, journal)
    finally:
        if fd is not None:
            os.close(fd)


def final_paths(paths, staging: Path, root: Path) -> list[Path]:
    """``paths`` written under ``staging``, as the paths they have under ``root`` once published."""
    out = []
    for p in paths:
        p = Path(p)
        try:
            out.append(Path(root) / p.relative_to(staging))
        except ValueError:
            out.append(p)
    return out


def publish_stage(stage: str, reports, report, write, root=None):
    """``write(staging)`` inside :func:`publishing`: the files it writes are one set.

    Returns its result (a :class:`nnsf.pipeline.StageResult`) with the
    artifacts at their published paths.  A stage that reports failed items
    (clips, cells) writes its report, then raises an :class:`InputError`: if
    ``report`` (a path relative to the staging folder) was written, the set
    is published before the error goes on.
    """
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


def verify(reports, stage: str) -> dict[str, Path]:
    """The published files of ``stage`` (relative path -> path), checked against its manifest.

    Runs :func:`recover` first.  Raises :class:`InputError` naming the
    manifest when it is missing or a file it lists is absent or differs from
    its hash (a set that is not one run's whole output).
    """
    reports = Path(reports)
    recover(reports, stage, wait=True)
    mpath = manifest_path(reports, stage)
    if not mpath.is_file():
        raise InputError(mpath, "file", f"the manifest of the {stage} stage's outputs "
                         f"(rerun the {stage} stage)")
    manifest = read_journal(mpath, reports, stage)
    files = manifest["files"]
    root = reports / manifest.get("root", ".")
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
