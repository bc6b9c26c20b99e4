"""Reading a file's bytes or text with every failure mapped to an :class:`InputError` naming it.

Standard library only, so that checking ``params.yaml`` imports nothing
heavy.  :mod:`nnsf.io` re-exports both readers.
"""
from __future__ import annotations

from pathlib import Path

from nnsf.errors import InputError


def read_bytes(path, max_bytes: int, what: str = "a readable file") -> bytes:
    """The bytes of ``path``; an :class:`InputError` naming it if missing, unreadable or too large.

    ``max_bytes`` bounds what is read into memory (the size is checked before
    reading).  Permissions and other ``OSError`` are reported with the
    system's reason.
    """
    path = Path(path)
    try:
        size = path.stat().st_size
        if size > max_bytes:
            raise InputError(path, "file size", f"{what} of at most {max_bytes} bytes", f"{size} bytes")
        with open(path, "rb") as fh:
            data = fh.read(max_bytes + 1)
    except OSError as exc:
        raise InputError(path, "file", what, reason=exc.strerror or str(exc)) from None
    if len(data) > max_bytes:  # grew while read (a pipe or a file being written)
        raise InputError(path, "file size", f"{what} of at most {max_bytes} bytes", f"more than {max_bytes} bytes")
    return data


def read_text(path, max_bytes: int, what: str = "a text file", encoding: str = "utf-8") -> str:
    """:func:`read_bytes` decoded with ``encoding``; an undecodable byte names file, line and column."""
    data = read_bytes(path, max_bytes, what)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputError(path, f"line {line}", f"{what} in {encoding.upper()}",
                         reason=f"byte 0x{data[exc.start]:02x} at offset {exc.start} cannot be decoded") from None
