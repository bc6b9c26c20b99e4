"""Errors that reach the user as one readable line.

Every stage turns bad input into an :class:`InputError` that names the file,
the field and what was expected; the CLI prints ``str(error)`` and exits
non-zero instead of showing a traceback.
"""
from __future__ import annotations


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
        What was found instead; shown after the expectation.
    """

    def __init__(self, source, field: str, expected: str, got=None):
        self.source = str(source)
        self.field = field
        self.expected = expected
        self.got = got
        msg = f"{self.source}: {field}: expected {expected}"
        if got is not None:
            text = repr(got)
            if len(text) > 80:
                text = text[:77] + "..."
            msg += f", got {text}"
        super().__init__(msg)
