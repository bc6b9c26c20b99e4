"""Atomic, pickle-free file output and validated input.

Outputs are written to a temporary file in the destination folder and renamed
into place, so a killed stage never leaves a file that looks finished.  Arrays
go to ``.npz`` and are read back with ``allow_pickle=False``; tables go to CSV.
"""
from __future__ import annotations

import contextlib
import errno
import json
import os
import shutil
import tempfile
from glob import escape as glob_escape
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import pandas as pd

from nnsf.errors import InputError
from nnsf.errors import read_bytes, read_text  # noqa: F401  (re-exported: readers beside the writers)


class WriteError(InputError):
    """An output could not be written (disk full, no permission, ...): names the file.

    An :class:`InputError` so that the CLI reports it as one line with exit
    code 2 and per-clip stages keep their other clips.
    """


def _write_error(path: Path, exc: OSError) -> WriteError:
    code = errno.errorcode.get(exc.errno, "") if exc.errno else ""
    what = {"ENOSPC": "free space on its disk", "EDQUOT": "free space in the disk quota",
            "EFBIG": "a file size the system allows", "EACCES": "permission to write it",
            "EPERM": "permission to write it", "EROFS": "a writable file system"}.get(
        code, "a writable location")
    return WriteError(path, "write", what, reason=f"{exc.strerror or exc}{f' [{code}]' if code else ''}")


def renamed_write_error(exc: "WriteError", tmp: Path, final: Path) -> "WriteError":
    """``exc`` naming the file under ``final`` instead of the temporary folder ``tmp``.

    Outputs written inside a staging folder would otherwise be reported by
    their temporary name, which the user never sees.
    """
    src = exc.source
    if src == str(tmp) or src.startswith(str(tmp) + os.sep):
        src = str(final) + src[len(str(tmp)):]
    return WriteError(src, exc.field, exc.expected, exc.got, reason=exc.reason)


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; rename it onto ``path`` on success.

    On any exception the temporary file is removed and ``path`` is untouched.
    ``suffix`` defaults to ``path``'s own suffix so that libraries that pick a
    format from the file name (matplotlib, OpenCV) still do the right thing.
    An ``OSError`` while writing (disk full, file too large, no permission)
    becomes a :class:`WriteError` naming ``path``.
    """
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(
            prefix=f".{path.name}.", suffix=path.suffix if suffix is None else suffix, dir=path.parent
        )
        os.close(fd)
        tmp = Path(tmp)
        os.chmod(tmp, 0o644)  # mkstemp's 0600 would make the finished file private
    except OSError as exc:
        raise _write_error(path, exc) from None
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _write_error(path, exc) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    _drop_stale(path)


def _drop_stale(path: Path) -> None:
    """Remove temporaries of ``path`` left by a writer that was killed (SIGKILL skips cleanup).

    They are named ``.<name>.<random>…`` beside ``path``; one output has one
    writer at a time (DVC locks the stage), so any such sibling is stale.
    """
    for stale in path.parent.glob(f".{glob_escape(path.name)}.*"):
        if stale.is_dir() and not stale.is_symlink():
            shutil.rmtree(stale, ignore_errors=True)
        else:
            stale.unlink(missing_ok=True)


@contextlib.contextmanager
def atomic_dir(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary folder beside ``path``; swap it in for ``path`` on success."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{path.name}.", dir=path.parent))
        os.chmod(tmp, 0o755)  # mkdtemp's 0700 would make the finished folder private
    except OSError as exc:
        raise _write_error(path, exc) from None
    try:
        try:
            yield tmp
        except WriteError as exc:
            raise renamed_write_error(exc, tmp, path) from None
        try:
            if path.exists():
                old = Path(tempfile.mkdtemp(prefix=f".{path.name}.old.", dir=path.parent))
                os.replace(path, old / "x")
                os.replace(tmp, path)
                shutil.rmtree(old, ignore_errors=True)
            else:
                os.replace(tmp, path)
        except OSError as exc:
            raise _write_error(path, exc) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _drop_stale(path)


def write_json(path, obj: Mapping) -> None:
    """Write ``obj`` as indented JSON (sorted keys, stable across runs), atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(obj, indent=2, sort_keys=True, default=_json_default) + "\n")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_csv(path, frame: pd.DataFrame, float_format: str | None = "%.10g") -> None:
    """Write a table as CSV without the index, atomically."""
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=float_format, lineterminator="\n")


def write_npz(path, **arrays: np.ndarray) -> None:
    """Write arrays to an uncompressed ``.npz``, atomically.  No object arrays."""
    for name, a in arrays.items():
        if np.asarray(a).dtype == object:
            raise TypeError(f"{name}: object arrays cannot be stored without pickle")
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez(fh, **arrays)


def read_npz(path) -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` into memory; never unpickles."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing .npz file")
    try:
        with np.load(path, allow_pickle=False) as z:
            return {k: z[k] for k in z.files}
    except (ValueError, OSError) as exc:
        raise InputError(path, "file", "a readable .npz archive without pickled objects", reason=str(exc)) from None


#: Largest JSON file read (bytes): annotations, labels and reports are far smaller.
MAX_JSON_BYTES = 64_000_000


def read_json(path) -> dict:
    """Read a JSON object, naming the file on failure.

    Every failure is an :class:`InputError` naming ``path``: missing or
    unreadable file, more than :data:`MAX_JSON_BYTES`, not UTF-8, not JSON,
    nested deeper than Python's parser allows, or not an object at the top.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing JSON file")
    text = read_text(path, MAX_JSON_BYTES, "a JSON file")
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"line {exc.lineno}", "valid JSON", reason=exc.msg) from None
    except RecursionError:
        raise InputError(path, "file", "JSON nested at most a few hundred levels deep") from None
    if not isinstance(obj, dict):
        raise InputError(path, "top level", "a JSON object", type(obj).__name__)
    return obj
