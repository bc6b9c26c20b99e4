"""Atomic, pickle-free file output and validated input.

Outputs are written to a temporary file in the destination folder and renamed
into place, so a killed stage never leaves a file that looks finished.  Arrays
go to ``.npz`` and are read back with ``allow_pickle=False``; tables go to CSV.

Every floating-point number these writers put in a file is rounded to
:data:`DIGITS` significant digits (JSON, CSV and the float arrays of ``.npz``).
Sums and products come out in the last bits differently on another CPU, BLAS
kernel or thread count (a metric of 0.07895747601148273 on one machine,
...272 on the next); rounded, most of them are the same bytes.  Rounding
cannot make that certain: a value next to a boundary of its last digit, or a
fit whose stopping tolerance lets the noise change its iteration count, still
differs in its last digits on another machine.  What is reproducible, and to
what tolerance, is stated in docs/operations.md ("Reproducibility") and
tested by tests/test_determinism.py.

Reports (JSON, CSV, annotations) also write any value below :data:`ZERO` in
magnitude as 0: such a value is what is left of an exact zero after
round-off (a rigid mesh's ARAP energy of 1.8e-22 px², a width drift of
5e-14), and its digits are all noise, which significant digits cannot
remove.  Arrays (``.npz``) keep tiny values: there they are mostly products
that keep their relative precision (NNSF's multiplicative updates).
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


def write_error(path: Path, exc: OSError) -> WriteError:
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

#: Significant digits of every float written by this module (see the module docstring).
DIGITS = 6
#: Report values smaller than this in magnitude are round-off of an exact zero and written as 0.
#: Every quantity we report (px, px², template units, ratios, seconds) is far above it when real.
ZERO = 1e-12


def round_float(x: float, digits: int = DIGITS) -> float:
    """``x`` rounded to ``digits`` significant digits (correctly rounded decimal; inf/nan kept).

    ``|x| < ZERO`` gives 0.0 (round-off of an exact zero; also no ``-0.0``).
    """
    x = float(x)
    if not np.isfinite(x):
        return x
    return 0.0 if abs(x) < ZERO else float(f"{x:.{digits}g}")


def round_floats(obj, digits: int = DIGITS):
    """A copy of a JSON-like ``obj`` with every float (Python or numpy) rounded; arrays to lists."""
    if isinstance(obj, bool) or obj is None or isinstance(obj, (str, int, np.integer, np.bool_)):
        return obj.item() if isinstance(obj, np.generic) else obj
    if isinstance(obj, (float, np.floating)):
        return round_float(obj, digits)
    if isinstance(obj, np.ndarray):
        return round_floats(obj.tolist(), digits)
    if isinstance(obj, Mapping):
        return {k: round_floats(v, digits) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [round_floats(v, digits) for v in obj]
    return obj


def round_array(a: np.ndarray, digits: int = DIGITS) -> np.ndarray:
    """A float array rounded to ``digits`` significant digits, element-wise; other dtypes as they are.

    Scales each value by a power of ten so that its ``digits`` leading digits
    are left of the point, rounds half to even and scales back.  Only exactly
    rounded IEEE operations touch the values, so the same input gives the same
    bits on every machine.  The result need not be the double nearest to the
    decimal (for files read by numpy that does not matter; JSON and CSV use
    correctly rounded decimals).
    """
    a = np.asarray(a)
    if a.dtype.kind not in "fc":
        return a
    if a.dtype.kind == "c":
        return round_array(a.real, digits) + 1j * round_array(a.imag, digits)
    out = a.copy()
    x = a.astype(np.float64)
    mag = np.abs(x)
    # Values below 1e-290 (none in our outputs but exact zeros) are left alone: their scale
    # factor would overflow.
    todo = np.isfinite(x) & (mag >= 1e-290)
    x, mag = x[todo], mag[todo]
    # The decimal exponent from frexp's exact binary one (log10 could differ in its last bit
    # between CPUs): floor((e - 1) log10 2) is the exponent or one below it.
    exp10 = np.floor((np.frexp(mag)[1] - 1) * np.log10(2.0)).astype(np.int64)
    exp10 += mag >= _pow10(exp10 + 1)
    shift = digits - 1 - exp10
    up = shift >= 0
    scaled = np.where(up, x * _pow10(shift), x / _pow10(-shift))
    rounded = np.round(scaled)
    out[todo] = np.where(up, rounded / _pow10(shift), rounded * _pow10(-shift)).astype(a.dtype)
    return out


#: 10**k as the double nearest to it (Python rounds int -> float correctly), k = 0 .. 308.
_POW10 = np.array([float(10 ** k) for k in range(309)])


def _pow10(e: np.ndarray) -> np.ndarray:
    """10.0**e for integer arrays, e >= -308, from the exact table (no libm ``pow``)."""
    e = np.asarray(e, dtype=np.int64)
    return np.where(e >= 0, _POW10[np.clip(e, 0, 308)], 1.0 / _POW10[np.clip(-e, 0, 308)])


def check_writable(folder: str | os.PathLike) -> Path:
    """Fail with one line naming ``folder`` unless files can be created in it; returns it.

    Creates nothing that stays: the folder's nearest existing ancestor must be
    a folder (not a file), and a probe file made in it is removed at once.
    The probe, not ``os.access``, decides, because ``root`` passes every
    permission check but still cannot write to a read-only file system.
    """
    folder = Path(folder)
    existing = folder
    while not existing.exists() and existing != existing.parent:
        if existing.is_symlink():  # a dangling link cannot be made a folder
            break
        existing = existing.parent
    expected = "a folder that can be created and written"
    if not existing.is_dir():
        raise InputError(folder, "output folder", expected,
                         f"{existing} is a file" if existing.exists() or existing.is_symlink()
                         else f"{existing} does not exist")
    try:
        fd, probe = tempfile.mkstemp(prefix=".nnsf-write-probe.", dir=existing)
    except OSError as exc:
        raise InputError(folder, "output folder", expected, f"{existing}: {exc.strerror}") from None
    os.close(fd)
    os.unlink(probe)
    return folder


def _unwritable(path: Path, exc: OSError) -> InputError:
    """The one-line error for an output that cannot be created (permissions, a file in the way)."""
    return WriteError(path.parent, "output folder", "a folder that can be created and written",
                      exc.strerror or str(exc))


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
    except OSError as exc:  # no permission, a file where a folder should be, read-only
        raise _unwritable(path, exc) from None
    try:
        yield tmp
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise write_error(path, exc) from None
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
    except OSError as exc:  # no permission, a file where a folder should be, read-only
        raise _unwritable(path, exc) from None
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
            raise write_error(path, exc) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    _drop_stale(path)


def write_json(path, obj: Mapping, digits: int = DIGITS) -> None:
    """Write ``obj`` as indented JSON (sorted keys, floats to ``digits`` significant digits), atomically."""
    text = json.dumps(round_floats(obj, digits), indent=2, sort_keys=True, default=_json_default)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n")


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")


def write_csv(path, frame: pd.DataFrame, digits: int = DIGITS) -> None:
    """Write a table as CSV without the index, floats to ``digits`` significant digits, atomically.

    Float values below :data:`ZERO` in magnitude are written as 0.
    """
    float_format = f"%.{digits}g"
    floats = frame.select_dtypes(include="floating").columns
    if len(floats):
        frame = frame.copy()
        for col in floats:  # round-off of exact zeros, and -0.0, written as 0
            values = frame[col].to_numpy(dtype=np.float64, copy=True)
            values[np.abs(values) < ZERO] = 0.0
            frame[col] = values
    with atomic_path(path) as tmp:
        frame.to_csv(tmp, index=False, float_format=float_format, lineterminator="\n")


def write_npz(path, digits: int | None = DIGITS, **arrays: np.ndarray) -> None:
    """Write arrays to an uncompressed ``.npz``, atomically.  No object arrays.

    Float arrays are rounded to ``digits`` significant digits (:func:`round_array`;
    ``None`` keeps every bit) so that the file, and DVC's hash of it, is the
    same on every machine.
    """
    for name, a in arrays.items():
        if np.asarray(a).dtype == object:
            raise TypeError(f"{name}: object arrays cannot be stored without pickle")
    if digits is not None:
        arrays = {name: round_array(a, digits) for name, a in arrays.items()}
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
