"""Ids from user files become file names only through :func:`safe_name`, and paths only through :func:`inside`.

A clip, character, style or label id read from a file (``index.csv``, an
annotation, a motion table, a character file, params.yaml) is a *name*: it
may become one file or folder name, never a path.  The rule is to **refuse**,
not to rewrite: an id that is not a safe name is one
:class:`~nnsf.errors.InputError` naming the file and the field, because a
silent rewrite could map two ids onto one file, or surprise whoever looks
for the output by its id.  A safe name (:func:`safe_name`):

* is 1 to :data:`MAX_NAME` characters: letters and digits of any script, and
  ``- _ . + @ ( ) , =`` and space;
* starts with a letter, digit or ``_`` (so never ``.``, ``..``, a hidden
  file, a temporary of :mod:`nnsf.io`, or something read as an option), and
  does not end with a space or ``.``;
* is not a device name Windows reserves (``CON``, ``NUL``, ``COM1`` ...), so a
  project copied there keeps its files.

:func:`inside` joins safe names onto a folder and checks that the result
stays inside the folder once symbolic links are resolved (a clip folder that
is a link to elsewhere is refused like ``../x``).  Only the standard library
is used, so :mod:`nnsf.params` can apply the same rule (``nnsf check``).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

from nnsf.errors import InputError

#: Longest safe name (characters): with a suffix and :mod:`nnsf.io`'s temporary prefix it stays
#: under the 255 bytes a file name may have, even in a script of 2-byte characters.
MAX_NAME = 100
#: Punctuation a safe name may hold besides letters and digits.
PUNCTUATION = "-_.+@(),= "
#: What a safe name is, for messages.
EXPECTED = (f"a name of 1 to {MAX_NAME} letters, digits and {' '.join(PUNCTUATION.strip())} or spaces, "
            "starting with a letter, digit or _ (no / \\ or '..': an id becomes a file name, not a path)")
_RESERVED = {"CON", "PRN", "AUX", "NUL", *(f"COM{i}" for i in range(10)), *(f"LPT{i}" for i in range(10))}


def is_safe_name(value) -> bool:
    """True when ``value`` is a string that :func:`safe_name` accepts."""
    if not isinstance(value, str) or not 1 <= len(value) <= MAX_NAME:
        return False
    if not all(c.isalnum() or c in PUNCTUATION for c in value):
        return False
    if not (value[0].isalnum() or value[0] == "_") or value[-1] in " .":
        return False
    return re.split(r"[ .]", value, maxsplit=1)[0].upper() not in _RESERVED


def safe_name(value, source, field: str) -> str:
    """``value`` (an id from the file ``source``, field ``field``) if it is a safe file name, else InputError."""
    if not is_safe_name(value):
        raise InputError(source, field, EXPECTED, value)
    return value


def inside(folder, *names: str, source=None, field: str = "path") -> Path:
    """``folder / name / ...`` checked to stay inside ``folder`` once symbolic links are resolved.

    Each of ``names`` must be a safe name (:func:`safe_name`; ``source`` and
    ``field`` name where it came from, default ``folder``).  The folder and
    the path need not exist yet: the existing part of the path is resolved
    (a link anywhere along it, to anywhere outside ``folder``, is refused).
    """
    folder = Path(folder)
    where = folder if source is None else source
    for name in names:
        safe_name(name, where, field)
    path = folder.joinpath(*names)
    root = folder.resolve()
    if not path.resolve().is_relative_to(root):
        raise InputError(where, field, f"a path that stays inside {folder} (symbolic links resolved)",
                         os.fspath(path))
    return path
