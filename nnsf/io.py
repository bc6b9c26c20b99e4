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
import math
import os
import re
import shutil
import sys
import tempfile
import threading
import zipfile
import zlib
from glob import escape as glob_escape
from pathlib import Path
from typing import Iterator, Mapping

import numpy as np
import pandas as pd

from nnsf.errors import InputError, exception_line
from nnsf.errors import read_bytes, read_text  # noqa: F401  (re-exported: readers beside the writers)
from nnsf.safe_yaml import parse_yaml, read_yaml  # noqa: F401  (re-exported: the one YAML reader)
from nnsf.schema import Context, Rule, check


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


#: Largest total of array bytes an ``.npz`` read back may declare (checked on its headers, before reading).
MAX_NPZ_BYTES = 2_000_000_000
#: Most arrays in one ``.npz`` read back.
MAX_NPZ_ARRAYS = 10_000


def _npy_header(fh) -> tuple[np.dtype, tuple, bool, int]:
    """``(dtype, shape, fortran_order, data offset)`` of an open ``.npy`` stream (reads the header only)."""
    version = np.lib.format.read_magic(fh)
    if version == (1, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_1_0(fh)
    elif version == (2, 0):
        shape, fortran, dtype = np.lib.format.read_array_header_2_0(fh)
    else:
        raise ValueError(f"unsupported .npy format version {version}")
    return dtype, tuple(shape), fortran, fh.tell()


def read_npz(path, schema: Mapping | None = None, max_bytes: int = MAX_NPZ_BYTES,
             what: str = "file of arrays without pickled objects") -> dict[str, np.ndarray]:
    """Read every array of an ``.npz`` into memory, checked before anything is allocated.

    The zip directory and every member's ``.npy`` header are read first: each
    member must be one ``.npy`` array without Python objects (never
    unpickled), whose header's dtype and shape account for exactly the bytes
    the member holds, and all of them together at most ``max_bytes``.  With
    a ``schema`` (``{name: nnsf.schema.Array}``), names it does not list are
    refused, required ones must be present, and each header must follow its
    rule (dtype kind, shape, named sizes shared between arrays); after
    reading, the rules' value checks (finite values, labels) run too.  Every
    failure is an :class:`InputError` naming ``path`` and the array.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", f"an existing .npz {what}")
    ctx = Context()
    try:
        with zipfile.ZipFile(path) as zf:
            infos = zf.infolist()
            if len(infos) > MAX_NPZ_ARRAYS:
                raise InputError(path, "file", f"an .npz of at most {MAX_NPZ_ARRAYS} arrays", f"{len(infos)} members")
            headers: dict[str, tuple] = {}
            total = 0
            for info in infos:
                name = info.filename[:-4] if info.filename.endswith(".npy") else None
                if name is None or info.is_dir():
                    raise InputError(path, info.filename, "a .npy array (the only members of an .npz)")
                if name in headers:
                    raise InputError(path, name, "each array once", "a second member of that name")
                with zf.open(info) as fh:
                    dtype, shape, _, offset = _npy_header(fh)
                if dtype.hasobject:
                    raise InputError(path, name, "an array without Python objects (never unpickled)", str(dtype))
                nbytes = math.prod(shape) * dtype.itemsize
                if info.file_size - offset != nbytes:
                    raise InputError(path, name, f"the {nbytes} data bytes its header ({dtype}, shape {shape}) "
                                     "declares", f"{info.file_size - offset} bytes")
                total += nbytes
                if total > max_bytes:
                    raise InputError(path, "file", f"an .npz of at most {max_bytes} bytes of arrays",
                                     f"more than {max_bytes} bytes")
                headers[name] = (dtype, shape, info)
            if schema is not None:
                unknown = [n for n in headers if n not in schema]
                if unknown:
                    raise InputError(path, unknown[0], "only the arrays " + ", ".join(schema), "an unknown array")
                for name, rule in schema.items():
                    if name in headers:
                        rule.check_header(path, name, headers[name][0], headers[name][1], ctx)
                    elif rule.required:
                        raise InputError(path, name, rule.expected, "missing")
            arrays = {}
            for name, (_, _, info) in headers.items():
                with zf.open(info) as fh:
                    arrays[name] = np.lib.format.read_array(fh, allow_pickle=False)
    except InputError:
        raise
    except (ValueError, OSError, EOFError, zipfile.BadZipFile, zipfile.LargeZipFile, NotImplementedError) as exc:
        raise InputError(path, "file", f"a readable .npz {what}",
                         reason=exception_line(exc)) from None
    if schema is not None:
        for name, a in arrays.items():
            schema[name].check(path, name, a, ctx)
    return arrays


#: Largest JSON file read (bytes): annotations, labels and reports are far smaller.
MAX_JSON_BYTES = 64_000_000


def read_json(path, rule: Rule | None = None) -> dict:
    """Read a JSON object, naming the file on failure; checked against ``rule`` when given.

    Every failure is an :class:`InputError` naming ``path``: missing or
    unreadable file, more than :data:`MAX_JSON_BYTES`, not UTF-8, not JSON,
    nested deeper than Python's parser allows, not an object at the top, or
    (with a ``rule``, e.g. an :class:`nnsf.schema.Record`) a field outside it.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing JSON file")
    text = read_text(path, MAX_JSON_BYTES, "a JSON file")
    try:
        obj = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InputError(path, f"line {exc.lineno}", "valid JSON", reason=exc.msg) from None
    except ValueError as exc:      # a number Python will not convert (an integer of 5000 digits)
        raise InputError(path, "file", "valid JSON numbers", reason=str(exc)) from None
    except RecursionError:
        raise InputError(path, "file", "JSON nested at most a few hundred levels deep") from None
    if not isinstance(obj, dict):
        raise InputError(path, "top level", "a JSON object", type(obj).__name__)
    return obj if rule is None else check(path, rule, obj)


# --------------------------------------------------------------------------- images read back
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
#: Most pixels an image read back may have, checked on its header before anything is decoded
#: (10000 x 10000; nnsf/__init__.py gives OpenCV the same bound for every format it decodes).
MAX_IMAGE_PIXELS = 100_000_000
#: PNG colour types and the bit depths each allows (PNG specification, IHDR).
_PNG_DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}


def png_header(data: bytes, source, field: str = "file", max_pixels: int = MAX_IMAGE_PIXELS) -> tuple[int, int]:
    """``(width, height)`` of the PNG ``data`` (read from ``source``), its structure checked first.

    Checks, before any pixel is decoded: the signature; a first ``IHDR`` chunk
    of 13 bytes with a valid colour type and bit depth; a size of at most
    ``max_pixels``; then every chunk's length (inside the file) and CRC, at
    least one ``IDAT`` and a final ``IEND``.  A truncated or damaged file, or
    a header claiming a huge image, is an :class:`InputError` naming
    ``source`` and ``field``, instead of a decoder's message on stderr or an
    allocation of the claimed size.
    """
    expected = "a complete PNG file"
    if not data.startswith(PNG_SIGNATURE):
        raise InputError(source, field, expected, reason="no PNG signature")
    pos, n, first, seen = len(PNG_SIGNATURE), len(data), True, set()
    width = height = 0
    while True:
        if pos + 8 > n:
            raise InputError(source, field, f"{expected} (ending in an IEND chunk)",
                             reason=f"truncated: {n} bytes, a chunk header expected at byte {pos}")
        length = int.from_bytes(data[pos:pos + 4], "big")
        kind = data[pos + 4:pos + 8]
        end = pos + 12 + length
        if length > 2**31 - 1 or end > n:
            raise InputError(source, field, f"{expected} (ending in an IEND chunk)",
                             reason=f"truncated: chunk {kind!r} at byte {pos} needs {end} bytes, the file has {n}")
        if zlib.crc32(data[pos + 4:pos + 8 + length]) != int.from_bytes(data[end - 4:end], "big"):
            raise InputError(source, field, expected, reason=f"chunk {kind!r} at byte {pos} is damaged (CRC)")
        if first:
            if kind != b"IHDR" or length != 13:
                raise InputError(source, field, expected, reason="the first chunk is not a 13-byte IHDR")
            width = int.from_bytes(data[pos + 8:pos + 12], "big")
            height = int.from_bytes(data[pos + 12:pos + 16], "big")
            depth, colour = data[pos + 16], data[pos + 17]
            if depth not in _PNG_DEPTHS.get(colour, ()):
                raise InputError(source, field, expected, reason=f"colour type {colour} with bit depth {depth}")
            if not (0 < width and 0 < height and width * height <= max_pixels):
                raise InputError(source, field, f"a PNG of at most {max_pixels} pixels (header checked before "
                                 "decoding)", f"{width}x{height}")
            first = False
        seen.add(kind)
        pos = end
        if kind == b"IEND":
            break
    if b"IDAT" not in seen:
        raise InputError(source, field, expected, reason="no image data (IDAT chunk)")
    return width, height


_stderr_lock = threading.Lock()
_stderr_users = [0, None, None]      # active blocks, saved descriptor 2, the temporary file


@contextlib.contextmanager
def captured_stderr() -> Iterator[list[str]]:
    """Send what C libraries write to file descriptor 2 (libpng, OpenCV) to a buffer while the block runs.

    Yields a list that receives the decoders' lines when the block ends (the
    caller puts them in an error's reason, or drops them).  Descriptor 2 is
    shared by the process, so overlapping blocks in several threads share one
    redirection (counted), and text that is not a decoder's (``libpng ...``,
    OpenCV's ``[ WARN``/``[ERROR``, libjpeg's ``Corrupt JPEG data``) is passed
    on to stderr.  A process without descriptor 2 runs the block as it is.
    """
    captured: list[str] = []
    with _stderr_lock:
        if _stderr_users[0] == 0:
            try:
                sys.stderr.flush()
            except (OSError, ValueError):
                pass
            try:
                saved = os.dup(2)
            except OSError:
                saved = None
            if saved is not None:
                tmp = tempfile.TemporaryFile()
                os.dup2(tmp.fileno(), 2)
                _stderr_users[1], _stderr_users[2] = saved, tmp
        _stderr_users[0] += 1
        start = os.lseek(2, 0, os.SEEK_CUR) if _stderr_users[2] is not None else 0
    try:
        yield captured
    finally:
        text = ""
        with _stderr_lock:
            tmp = _stderr_users[2]
            if tmp is not None:
                end = os.lseek(2, 0, os.SEEK_CUR)
                text = os.pread(tmp.fileno(), max(end - start, 0), start).decode("utf-8", "replace")
            _stderr_users[0] -= 1
            if _stderr_users[0] == 0 and tmp is not None:
                os.dup2(_stderr_users[1], 2)
                os.close(_stderr_users[1])
                tmp.close()
                _stderr_users[1] = _stderr_users[2] = None
        noise = re.compile(r"^(libpng (warning|error)|\[ ?(WARN|ERROR)|Corrupt JPEG data|Premature end of JPEG)")
        captured.extend(line for line in text.splitlines() if noise.match(line))
        passed = [line for line in text.splitlines() if line.strip() and not noise.match(line)]
        if passed:
            print("\n".join(passed), file=sys.stderr)


def decode_image(data: bytes, source, field: str = "file", flags: int | None = None,
                 max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Decode image bytes with OpenCV (``flags``: default ``IMREAD_UNCHANGED``); InputError if it cannot.

    A PNG is checked by :func:`png_header` first.  The decoder's own messages
    (``libpng error: ...``) never reach stderr: they become the error's reason.
    """
    import cv2

    if data.startswith(PNG_SIGNATURE):
        png_header(data, source, field, max_pixels)
    with captured_stderr() as noise:
        try:
            img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED if flags is None else flags) \
                if data else None
        except cv2.error as exc:   # e.g. a header beyond OPENCV_IO_MAX_IMAGE_PIXELS
            noise_text = exception_line(exc, with_type=False)
            raise InputError(source, field, f"an image of at most {max_pixels} pixels OpenCV can decode",
                             f"a file of {len(data)} bytes", reason=noise_text.split(") ", 1)[-1]) from None
    if img is None:
        raise InputError(source, field, "an image OpenCV can decode (PNG, JPEG, ...)",
                         f"an unreadable file of {len(data)} bytes", reason="; ".join(noise) or None)
    return img


#: Largest image file read (bytes).
MAX_IMAGE_BYTES = 512_000_000


def read_image(path, field: str = "file", flags: int | None = None, source=None) -> np.ndarray:
    """:func:`decode_image` of the file ``path`` (read whole, at most :data:`MAX_IMAGE_BYTES`).

    Errors name ``source`` (default ``path``) and ``field``.
    """
    path = Path(path)
    return decode_image(read_bytes(path, MAX_IMAGE_BYTES, "a readable image file"),
                        path if source is None else source, field, flags)
