"""Declarative rules for what a file read back may hold: each field's type, shape and bounds.

A file the product reads back (a model, a tracker's arrays, a report another
stage wrote) is checked against a rule before any of it is used, and anything
else is one :class:`~nnsf.errors.InputError` naming the file and the field.
A reader declares its format as data, e.g.::

    TRACKS = {
        "control": Array("f", ("T", "C", "P", 2)),
        "curve_names": Array("U", ("C",)),
        "n_points": Array("iu", ("C",), required=False),
    }

and adding a field to a format is adding an entry.

* :class:`Array` -- an array: dtype kinds (``numpy.dtype.kind`` letters),
  a shape rule of exact sizes (``2``), named sizes (``"C"``: the same wherever
  that name appears in one file) and ``None`` (any size), and optionally a
  label set (``labels="styles"``: its values, unique, name a set that
  :class:`Map` keys must equal).  :meth:`Array.check_header` applies the rule
  to a ``.npy`` header, before the data is read.
* JSON-like values: :class:`Str`, :class:`Int`, :class:`Num`, :class:`Bool`,
  :data:`NULL`, :class:`Opt` (the rule or ``None``), :class:`List`,
  :class:`Tuple` (fixed length), :class:`Map` (string or tuple keys) and
  :class:`Record` (named fields, each required or optional; unknown fields
  refused).

Every rule's :meth:`Rule.check` takes the file, the dotted field name and the
value, and a ``Context`` shared by one file's checks (named sizes and label
sets seen so far).  Rules never ``repr`` a whole value: messages use
:func:`nnsf.errors.summarize`.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from nnsf.errors import InputError

#: Names of numpy dtype kinds, for messages.
KIND_NAMES = {"f": "float", "i": "integer", "u": "unsigned integer", "U": "unicode string", "b": "boolean",
              "c": "complex", "S": "byte string"}


@dataclass
class Context:
    """What one file's checks have seen: named sizes (``{"C": 7}``) and label sets (``{"styles": {...}}``)."""

    dims: dict[str, int] = field(default_factory=dict)
    labels: dict[str, frozenset] = field(default_factory=dict)


def _join(parent: str, name) -> str:
    if isinstance(name, int):
        return f"{parent}[{name}]"
    return f"{parent}.{name}" if parent else str(name)


class Rule:
    """One field's rule; subclasses define :meth:`check` and :attr:`expected`."""

    expected = "a value"

    def check(self, source, name: str, value, ctx: Context | None = None):
        """``value`` if it follows the rule (some rules convert, e.g. a list to a tuple); else InputError."""
        raise NotImplementedError

    def fail(self, source, name, value, expected: str | None = None, reason: str | None = None):
        raise InputError(source, name or "top level", expected or self.expected, _shown(value), reason=reason)


def _shown(value):
    if isinstance(value, np.ndarray):
        return f"a {value.dtype} array of shape {value.shape}"
    return value if value is not None else "null"


def _kinds_text(kinds: str) -> str:
    return " or ".join(dict.fromkeys(KIND_NAMES.get(k, k) for k in kinds))


@dataclass(frozen=True)
class Array(Rule):
    """An array of a dtype kind (``"f"``, ``"iu"``, ``"U"``, ...) and a shape rule.

    ``shape``: one entry per axis, an int (that size), a str (a named size,
    the same wherever the name appears in the file) or None (any size).
    ``finite``: every value finite (float arrays).  ``labels``: the values
    are unique strings naming a label set (see :class:`Map`).  ``below``:
    integer values are indices into the named size (``0 <= v < size``).
    ``max_items`` bounds the number of elements.
    """

    kinds: str
    shape: tuple = ()
    required: bool = True
    finite: bool = False
    labels: str | None = None
    below: str | None = None
    max_items: int = 50_000_000

    @property
    def expected(self) -> str:
        dims = ", ".join("any" if d is None else str(d) for d in self.shape)
        return f"a {_kinds_text(self.kinds)} array of shape ({dims})" if self.shape else \
            f"a {_kinds_text(self.kinds)} scalar (0-d array)"

    def check_header(self, source, name: str, dtype: np.dtype, shape: tuple, ctx: Context) -> None:
        """The rule on a ``.npy`` header (before any data is read)."""
        got = f"a {dtype} array of shape {tuple(shape)}"
        if dtype.hasobject or dtype.fields is not None or dtype.kind not in self.kinds:
            raise InputError(source, name, self.expected, got)
        if len(shape) != len(self.shape):
            raise InputError(source, name, self.expected, got)
        if math.prod(shape) > self.max_items:
            raise InputError(source, name, f"{self.expected} of at most {self.max_items} elements", got)
        for axis, (want, have) in enumerate(zip(self.shape, shape)):
            if want is None:
                continue
            if isinstance(want, str):
                bound = ctx.dims.setdefault(want, int(have))
                if bound != have:
                    raise InputError(source, name, f"{self.expected} with {want} = {bound} on axis {axis} "
                                     "(as elsewhere in the file)", got)
            elif want != have:
                raise InputError(source, name, self.expected, got)

    def check(self, source, name, value, ctx=None):
        ctx = ctx if ctx is not None else Context()
        if not isinstance(value, np.ndarray):
            self.fail(source, name, value)
        self.check_header(source, name, value.dtype, value.shape, ctx)
        if self.finite and value.dtype.kind in "fc" and not np.isfinite(value).all():
            self.fail(source, name, value, self.expected + " of finite values",
                      reason=f"{int((~np.isfinite(value)).sum())} values are NaN or infinite")
        if self.below is not None and self.below in ctx.dims and value.size \
                and (value.min() < 0 or value.max() >= ctx.dims[self.below]):
            self.fail(source, name, value, f"{self.expected} of indices in [0, {self.below} = "
                      f"{ctx.dims[self.below]})", reason=f"values from {value.min()} to {value.max()}")
        if self.labels is not None:
            items = [str(v) for v in value.ravel()]
            if len(set(items)) != len(items):
                self.fail(source, name, value, self.expected + " of distinct labels")
            ctx.labels[self.labels] = frozenset(items)
        return value


@dataclass(frozen=True)
class Str(Rule):
    """A string of at most ``max_len`` characters (non-empty unless ``empty``), one of ``choices`` if given.

    Only printable characters: a string read back may end up in a message or a
    note, which must stay one line (no newline, tab or terminal control code).
    """

    max_len: int = 1000
    choices: tuple | None = None
    empty: bool = True

    @property
    def expected(self) -> str:
        if self.choices:
            return "one of " + ", ".join(map(str, self.choices))
        return f"a {'' if self.empty else 'non-empty '}string of at most {self.max_len} printable characters"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, str) or len(value) > self.max_len or (not self.empty and not value) \
                or not value.isprintable():
            self.fail(source, name, value)
        if self.choices is not None and value not in self.choices:
            self.fail(source, name, value)
        return value


@dataclass(frozen=True)
class Int(Rule):
    """An integer (not a bool) in ``[lo, hi]``.

    ``dim``: the value is the named size ``dim`` (bound here if not yet seen,
    else equal to it); ``below``: the value is at most the named size ``below``
    (a row index's end, e.g.), when that size is known.
    """

    lo: int = -(2 ** 63)
    hi: int = 2 ** 63 - 1
    dim: str | None = None
    below: str | None = None

    @property
    def expected(self) -> str:
        return f"an integer in [{self.lo}, {self.hi}]"

    def check(self, source, name, value, ctx=None):
        ctx = ctx if ctx is not None else Context()
        if not isinstance(value, numbers.Integral) or isinstance(value, (bool, np.bool_)) \
                or not self.lo <= value <= self.hi:
            self.fail(source, name, value)
        if self.dim is not None and ctx.dims.setdefault(self.dim, int(value)) != value:
            self.fail(source, name, value, f"{self.dim} = {ctx.dims[self.dim]} (as the arrays of the file)")
        if self.below is not None and self.below in ctx.dims and value > ctx.dims[self.below]:
            self.fail(source, name, value, f"an integer in [{self.lo}, {self.below} = {ctx.dims[self.below]}]")
        return value


@dataclass(frozen=True)
class Num(Rule):
    """A finite real number (not a bool) in ``[lo, hi]``."""

    lo: float = -math.inf
    hi: float = math.inf

    @property
    def expected(self) -> str:
        return f"a finite number in [{self.lo:g}, {self.hi:g}]"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, numbers.Real) or isinstance(value, (bool, np.bool_)) \
                or not math.isfinite(value) or not self.lo <= value <= self.hi:
            self.fail(source, name, value)
        return value


@dataclass(frozen=True)
class Bool(Rule):
    expected = "true or false"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, bool):
            self.fail(source, name, value)
        return value


@dataclass(frozen=True)
class _Null(Rule):
    expected = "null"

    def check(self, source, name, value, ctx=None):
        if value is not None:
            self.fail(source, name, value)
        return value


NULL = _Null()


@dataclass(frozen=True)
class Opt(Rule):
    """``rule``, or ``None`` (JSON null)."""

    rule: Rule

    @property
    def expected(self) -> str:
        return f"{self.rule.expected}, or null"

    @property
    def required(self) -> bool:
        return getattr(self.rule, "required", True)

    def check(self, source, name, value, ctx=None):
        return None if value is None else self.rule.check(source, name, value, ctx)


@dataclass(frozen=True)
class List(Rule):
    """A list (or tuple) of ``item`` values, ``min_len`` to ``max_len`` long; returned as a list."""

    item: Rule
    max_len: int = 100_000
    min_len: int = 0

    @property
    def expected(self) -> str:
        return f"a list of {self.min_len} to {self.max_len} items"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, (list, tuple)) or not self.min_len <= len(value) <= self.max_len:
            self.fail(source, name, value)
        return [self.item.check(source, _join(name, i), v, ctx) for i, v in enumerate(value)]


@dataclass(frozen=True)
class Tuple(Rule):
    """A fixed-length list or tuple, one rule per position; returned as a tuple."""

    items: tuple

    @property
    def expected(self) -> str:
        return f"a list of {len(self.items)} items"

    def check(self, source, name, value, ctx=None):
        if not isinstance(value, (list, tuple)) or len(value) != len(self.items):
            self.fail(source, name, value)
        return tuple(r.check(source, _join(name, i), v, ctx) for i, (r, v) in enumerate(zip(self.items, value)))


@dataclass(frozen=True)
class Map(Rule):
    """A mapping of keys (``key`` rule: :class:`Str` by default, or a :class:`Tuple` of them) to ``value``s.

    ``keys``: the name of a label set (:attr:`Array.labels`) the keys must
    equal exactly (the first element of tuple keys, with ``key_index``).
    """

    value: Rule
    key: Rule = Str(max_len=1000)
    keys: str | None = None
    key_index: int | None = None
    max_len: int = 100_000

    @property
    def expected(self) -> str:
        return f"a mapping of at most {self.max_len} items" + (f" keyed by the {self.keys}" if self.keys else "")

    def check(self, source, name, value, ctx=None):
        ctx = ctx if ctx is not None else Context()
        if not isinstance(value, Mapping) or len(value) > self.max_len:
            self.fail(source, name, value)
        out = {}
        for k, v in value.items():
            key = self.key.check(source, _join(name, "<key>"), k, ctx)
            out[key] = self.value.check(source, _join(name, "|".join(key) if isinstance(key, tuple) else key), v, ctx)
        if self.keys is not None:
            want = ctx.labels.get(self.keys)
            have = {k[self.key_index] if self.key_index is not None else k for k in out}
            if want is not None and set(have) != set(want):
                extra = sorted(set(have) - set(want))[:3]
                missing = sorted(set(want) - set(have))[:3]
                self.fail(source, name, value, f"keys that are exactly the {self.keys}",
                          reason=f"unknown: {extra}, missing: {missing}")
        return out


@dataclass(frozen=True)
class Record(Rule):
    """A mapping with named fields: ``fields`` (each rule's ``required``, default True) in declaration order.

    Fields not declared are refused (``extra=True`` keeps them unchecked).
    :meth:`check` returns a dict of the declared fields present.
    """

    fields: Mapping[str, Rule]
    extra: bool = False

    @property
    def expected(self) -> str:
        return "a mapping with fields " + ", ".join(list(self.fields)[:6]) + (", ..." if len(self.fields) > 6 else "")

    def check(self, source, name, value, ctx=None):
        ctx = ctx if ctx is not None else Context()
        if not isinstance(value, Mapping):
            self.fail(source, name, value)
        if not self.extra:
            unknown = [k for k in value if k not in self.fields]
            if unknown:
                raise InputError(source, _join(name, str(unknown[0])),
                                 "one of the fields " + ", ".join(self.fields), "an unknown field")
        out = {}
        for key, rule in self.fields.items():
            if key not in value:
                if getattr(rule, "required", True):
                    raise InputError(source, _join(name, key), rule.expected, "missing")
                continue
            out[key] = rule.check(source, _join(name, key), value[key], ctx)
        if self.extra:
            out.update({k: v for k, v in value.items() if k not in self.fields})
        return out


@dataclass(frozen=True)
class Optional(Rule):
    """A :class:`Record` field that may be absent (``rule`` when present)."""

    rule: Rule
    required = False

    @property
    def expected(self) -> str:
        return self.rule.expected

    def check(self, source, name, value, ctx=None):
        return self.rule.check(source, name, value, ctx)


def check(source, rule: Rule, value: Any, name: str = "") -> Any:
    """``rule.check`` with a fresh :class:`Context`: the entry point for one file."""
    return rule.check(source, name, value, Context())
