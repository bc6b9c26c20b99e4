"""Errors that reach the user as one readable line.

Every stage turns bad input into an :class:`InputError` that names the file,
the field and what was expected; the CLI prints ``str(error)`` and exits
non-zero instead of showing a traceback.

The offending value is shown as a bounded summary (:func:`summarize`: its
type, length and first items), never as ``repr`` of the whole value: a
YAML alias bomb or a million-item list costs no more to report than a
number.  A ``reason`` (why the value is wrong, e.g. a parser's message) is
kept whole up to :data:`REASON_LIMIT` characters; only the quoted value is
cut.

:func:`read_bytes` and :func:`read_text` read a file with every failure
(missing, no permission, too large, not decodable) mapped to an
:class:`InputError` naming it; they live here, with the standard library
only, so that checking ``params.yaml`` imports nothing heavy
(:mod:`nnsf.io` re-exports them).
"""
from __future__ import annotations

import argparse
import numbers
from pathlib import Path

#: Characters of a quoted value shown in a message.
VALUE_LIMIT = 80
#: Characters of a reason kept in a message (one line; long enough for a nested error).
REASON_LIMIT = 600


def terminate_as_interrupt(signum, frame):
    """A SIGTERM handler that raises :class:`KeyboardInterrupt`: a job stopped by a scheduler,
    ``timeout`` or a cancelled run unwinds as Ctrl-C does, its ``finally`` blocks run (a
    temporary server stopped, a render's frame file removed) and the user gets one line."""
    raise KeyboardInterrupt


def _cut(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def summarize(value, limit: int = VALUE_LIMIT, _depth: int = 0) -> str:
    """A one-line description of ``value`` of at most about ``limit`` characters.

    Scalars are shown as their ``repr`` (strings cut to ``limit``); lists,
    tuples and mappings as their type, length and first items (nested
    containers one level deep).  The cost is bounded by ``limit``, not by the
    size of ``value``: only the items shown are visited, and no ``repr`` of a
    container is ever built.
    """
    if value is None or isinstance(value, (bool, numbers.Number)):
        return _cut(repr(value), limit)
    if isinstance(value, str):
        if len(value) <= limit:
            return repr(value)
        return repr(value[: max(limit - 20, 8)]) + f"... ({len(value)} characters)"
    if isinstance(value, (bytes, bytearray)):
        return f"{type(value).__name__} of length {len(value)}"
    if isinstance(value, (list, tuple, dict, set, frozenset)):
        name = type(value).__name__
        n = len(value)
        if _depth >= 1:
            return f"a {name} of {n} item{'s' if n != 1 else ''}"
        if isinstance(value, dict):
            items = [kv for kv, _ in zip(value.items(), range(3))]
        elif isinstance(value, (list, tuple)):
            items = list(value[:3])
        else:  # sets have no order worth showing
            items = []
        shown = []
        budget = limit
        for item in items:
            if isinstance(value, dict):
                k, v = item
                text = f"{summarize(k, 30, 1)}: {summarize(v, 30, 1)}"
            else:
                text = summarize(item, 30, 1)
            budget -= len(text) + 2
            if budget < 0:
                break
            shown.append(text)
        more = ", ..." if n > len(shown) else ""
        body = (" " + ("{" if isinstance(value, dict) else "[") + ", ".join(shown) + more
                + ("}" if isinstance(value, dict) else "]")) if shown else ""
        return f"a {name} of {n} item{'s' if n != 1 else ''}" + (f":{body}" if body else "")
    return f"a {type(value).__name__}"


def one_line(text, limit: int = REASON_LIMIT) -> str:
    """``text`` on one line (newlines joined with ' | '), cut to ``limit`` characters."""
    text = str(text)
    parts = [p.strip() for p in text[: limit * 2].splitlines() if p.strip()]
    return _cut(" | ".join(parts), limit)


def exception_line(exc: BaseException, with_type: bool = True) -> str:
    """An exception on one line: ``Type: first line of its message`` (or the first line alone)."""
    msg = str(exc).strip().splitlines()
    if not msg:
        return type(exc).__name__
    return f"{type(exc).__name__}: {msg[0]}" if with_type else msg[0]


class OneLineParser(argparse.ArgumentParser):
    """``argparse`` with the project's one-line errors: a bad option is ``error: <prog>: <what>``
    and exit 2, without the usage block (``--help`` shows it).  Sub-parsers inherit it."""

    def error(self, message):
        self.exit(2, f"error: {self.prog}: {one_line(message)} (see {self.prog} --help)\n")


class InputError(ValueError):
    """Bad input: a file, a field in it, and what was expected there.

    Parameters
    ----------
    source : str or path-like
        The file (or other input, e.g. ``"params.yaml"``) that is wrong.
    field : str
        The field, column or key inside it, e.g. ``"nnsf.alpha"`` or ``"x3"``.
    expected : str
        What the field should hold, e.g. ``"a number >= 0"``.
    got : object, optional
        What was found instead; shown after the expectation as a bounded
        summary (:func:`summarize`).
    reason : str, optional
        Why it is wrong (e.g. a parser's or the operating system's message),
        kept whole up to :data:`REASON_LIMIT` characters, on one line.
    """

    def __init__(self, source, field: str, expected: str, got=None, reason: str | None = None):
        self.source = str(source)
        self.field = field
        self.expected = expected
        self.got = got
        self.reason = reason
        msg = f"{self.source}: {field}: expected {expected}"
        if got is not None:
            msg += f", got {summarize(got)}"
        if reason:
            msg += f" ({one_line(reason)})"
        super().__init__(msg)


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
