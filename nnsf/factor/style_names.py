"""A style asked for by name: letter case ignored, a model's aliases followed, the nearest names suggested.

A style model knows its styles by the labels of its training data.  A user
types ``Old``, or ``elderly`` where another motion library calls the same
style ``old``: :func:`resolve_style` returns the model's own name for it.
An exact name wins; then a name equal to one style up to letter case; then
an alias (the model's ``aliases`` metadata, ``{alias: style}``, set with
``nnsf styles --alias elderly=old``); anything else is an
:class:`~nnsf.errors.InputError` listing the styles, with "did you mean"
when a name is close (:func:`difflib.get_close_matches`).
"""
from __future__ import annotations

import difflib
from typing import Iterable, Mapping

from nnsf.errors import InputError

__all__ = ["resolve_style", "check_aliases"]


def resolve_style(name, styles: Iterable[str], aliases: Mapping[str, str] | None = None,
                  source="<model>", field: str = "style") -> str:
    """The model's name for ``name`` (module docstring); :class:`InputError` naming ``source`` and ``field``."""
    styles = [str(s) for s in styles]
    text = str(name).strip()
    if text in styles:
        return text
    folded = text.casefold()
    same = [s for s in styles if s.casefold() == folded]
    if len(same) == 1:
        return same[0]
    if len(same) > 1:
        raise InputError(source, field, "a style named exactly (the model has several that differ only "
                         "in letter case: " + ", ".join(same) + ")", name)
    by_alias = {str(a).casefold(): str(s) for a, s in (aliases or {}).items()}
    if folded in by_alias:
        return by_alias[folded]
    known = {s.casefold(): s for s in styles} | {a: f"{a} (= {s})" for a, s in by_alias.items()}
    near = difflib.get_close_matches(folded, list(known), n=3, cutoff=0.6)
    listed = ", ".join(styles) + (("; aliases: " + ", ".join(f"{a}={s}" for a, s in sorted(by_alias.items())))
                                  if by_alias else "")
    raise InputError(source, field, "a style the model knows: " + listed, name,
                     reason=("did you mean " + " or ".join(known[n] for n in near) + "?") if near else None)


def check_aliases(aliases: Mapping, styles: Iterable[str], source="aliases", field: str = "aliases") -> dict[str, str]:
    """``aliases`` as ``{alias: style}`` once checked against the model's ``styles``.

    Every alias and style is a non-empty string, every target a style, and
    no alias is (up to letter case) a style of its own or another alias.
    Raises :class:`InputError` naming ``source`` and ``field`` (``meta.aliases`` in a model file).
    """
    styles = sorted({str(s) for s in styles})
    folded = {s.casefold() for s in styles}
    if not isinstance(aliases, Mapping):
        raise InputError(source, field, "a mapping of alias to style", aliases)
    out: dict[str, str] = {}
    seen: set[str] = set()
    for alias, style in aliases.items():
        if not (isinstance(alias, str) and alias.strip() and isinstance(style, str) and style.strip()):
            raise InputError(source, field, "alias and style names (non-empty strings)", {alias: style})
        alias, style = alias.strip(), style.strip()
        if style not in styles:
            raise InputError(source, f"{field}.{alias}", "a style of the model: " + ", ".join(styles), style)
        if alias.casefold() in folded or alias.casefold() in seen:
            raise InputError(source, f"{field}.{alias}", "a name that is not already a style or an alias",
                             alias)
        seen.add(alias.casefold())
        out[alias] = style
    return dict(sorted(out.items()))
