"""The results document: every table of ``docs/results.md`` made from a report file.

The tables are declared in ``docs/results.yaml`` (:data:`SPEC`), one entry per
table; this module only reads, selects and formats.  No number of the document
is written by hand: each cell is a template such as ``"{precision_mean:.3f}"``
filled from one row of the table's ``source`` (a CSV or JSON file under
``reports/``), and every table names the command that rewrites its source.
Reports of data outside the repository (``nnsf reshape-eval --data``, the
held-out evaluation of a BVH folder) are committed files like any other
source, so the same writer reads them.  A table without ``command`` shares
the command of the table before it with the same source.

A table entry (every key but ``columns``/``pivot`` optional)::

    - section: Recognition            # the document's ## heading the table goes under
      title: Precision against rank   # its ### heading
      source: reports/precision_vs_rank.csv
      command: dvc repro evaluate     # what rewrites the source
      caption: one paragraph, no numbers (they come from the source)
      records: methods                # JSON only: dotted path to the rows (see below)
      depth: 1                        # JSON: levels of nested objects flattened into one key
      split_key: [style, method]      # the key split on "/" into these columns
      where: {method: [nnsf, nmf]}    # keep only these rows
      order: {key: [nnsf, nmf]}       # these rows first, in this order; the others after them
      columns:                        # [header, template] per column ...
        - [method, "{key}"]
        - [precision, "{precision_mean:.3f} ± {precision_sd:.3f}"]
      pivot:                          # ... or one column per value of ``columns``
        rows: rank
        columns: method
        cell: "{precision_mean:.3f} ± {precision_sd:.3f}"
        marks: [{text: "*", when: [rank_used, "<", rank]}]

JSON ``records``: a dotted key path to an object of objects (one row each,
its key in the column ``key``), a list of objects, or a mapping
``{column: path}`` of objects of scalars sharing their keys (one row per key,
one column per path).  Without ``records`` the top-level object is one row.

Templates name fields only (no attribute or index access, no conversion):
a spec file never runs code.  A field that is missing or not a number where
the format wants one fails the stage with one line naming the table.
"""
from __future__ import annotations

import math
import numbers
import re
import string
from dataclasses import dataclass, field
from pathlib import Path

import pandas as pd
from nnsf.errors import InputError
from nnsf.io import atomic_path, read_json
from nnsf.pipeline import REPORTS, StageResult, check_outputs
from nnsf.safe_yaml import read_yaml

SPEC = Path("docs/results.yaml")
DOCUMENT = Path("docs/results.md")
#: Largest spec file read.
MAX_SPEC_BYTES = 1_000_000
#: What an empty cell shows: the field is missing from its row, or not a number.
MISSING = "—"
_FIELD = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")
_OPS = {"<": lambda a, b: a < b, ">": lambda a, b: a > b, "==": lambda a, b: a == b,
        "!=": lambda a, b: a != b}
_TABLE_KEYS = {"section", "title", "source", "command", "caption", "records", "depth", "split_key",
               "where", "order", "columns", "pivot"}


@dataclass
class Row:
    """One source row: its values by field, and where each value sits in the source file.

    A locator is ``("json", [key, ...])`` or ``("csv", row index, column)``.
    """

    values: dict
    where: dict = field(default_factory=dict)


@dataclass
class Printed:
    """One number as printed: its table, cell, text and the source value it came from."""

    table: int
    row: int
    column: int
    text: str
    source: str
    locator: tuple
    format_spec: str


# ---------------------------------------------------------------- the spec
def read_spec(path: Path = SPEC) -> list[dict]:
    """The table entries of a results spec, checked (one line naming the entry on failure)."""
    spec = read_yaml(path, MAX_SPEC_BYTES, "a YAML results spec")
    tables = spec.get("tables") if isinstance(spec, dict) else None
    if not isinstance(tables, list) or not tables:
        raise InputError(path, "tables", "a list of table entries", spec)
    for i, table in enumerate(tables):
        _check_table(path, f"tables[{i}]", table)
    return tables


def _check_table(path, where: str, table) -> None:
    if not isinstance(table, dict):
        raise InputError(path, where, "a mapping", table)
    unknown = sorted(set(table) - _TABLE_KEYS)
    if unknown:
        raise InputError(path, f"{where}.{unknown[0]}", f"one of {sorted(_TABLE_KEYS)}")
    for key in ("section", "title", "source"):
        if not isinstance(table.get(key), str) or not table[key].strip():
            raise InputError(path, f"{where}.{key}", "a non-empty string", table.get(key))
    if not isinstance(table.get("command", "-"), str):
        raise InputError(path, f"{where}.command", "a string", table.get("command"))
    source = Path(table["source"])
    if source.is_absolute() or ".." in source.parts or source.parts[:1] != (REPORTS.name,) \
            or source.suffix not in (".csv", ".json"):
        raise InputError(path, f"{where}.source", "a .csv or .json path under reports/", table["source"])
    if ("columns" in table) == ("pivot" in table):
        raise InputError(path, where, "either columns or pivot")
    templates = []
    if "columns" in table:
        cols = table["columns"]
        if not isinstance(cols, list) or not cols or not all(
                isinstance(c, list) and len(c) == 2 and all(isinstance(s, str) for s in c) for c in cols):
            raise InputError(path, f"{where}.columns", "a list of [header, template] pairs", cols)
        templates = [c[1] for c in cols]
    else:
        pivot = table["pivot"]
        if not isinstance(pivot, dict) or not all(isinstance(pivot.get(k), str) for k in ("rows", "columns", "cell")):
            raise InputError(path, f"{where}.pivot", "a mapping with rows, columns and cell (strings)", pivot)
        templates = [pivot["cell"]]
        for j, mark in enumerate(pivot.get("marks", [])):
            ok = isinstance(mark, dict) and isinstance(mark.get("text"), str) \
                and isinstance(mark.get("when"), list) and len(mark["when"]) == 3 \
                and mark["when"][1] in _OPS
            if not ok:
                raise InputError(path, f"{where}.pivot.marks[{j}]",
                                 "{text: STR, when: [FIELD, OP, FIELD]} with OP one of < > == !=", mark)
    for template in templates:
        try:
            fields(template)
        except ValueError as exc:
            raise InputError(path, f"{where}.columns", "templates of plain {field:format} names",
                             template, reason=str(exc)) from None
    for key in ("where", "order"):
        value = table.get(key, {})
        if not isinstance(value, dict) or not all(isinstance(v, list) for v in value.values()):
            raise InputError(path, f"{where}.{key}", "a mapping of column -> list of values", value)


def fields(template: str) -> list[tuple[str, str]]:
    """``(field, format spec)`` of each replacement field of ``template``.

    Only plain names: ``{a.b}``, ``{a[0]}``, ``{a!r}`` and nested fields are
    refused (ValueError), so a template cannot reach into an object.
    """
    out = []
    for _, name, spec, conversion in string.Formatter().parse(template):
        if name is None:
            continue
        if not _FIELD.match(name) or conversion is not None or "{" in (spec or ""):
            raise ValueError(f"{{{name}}}: expected a plain field name")
        out.append((name, spec or ""))
    return out


# ---------------------------------------------------------------- the sources
def read_rows(root: Path, table: dict) -> list[Row]:
    """The rows of a table's source, filtered and ordered by its ``where``."""
    path = root / table["source"]
    if path.suffix == ".csv":
        rows = _csv_rows(path)
    else:
        rows = _json_rows(path, table)
    if table.get("split_key"):
        names = table["split_key"]
        for row in rows:
            parts = str(row.values.get("key", "")).split("/")
            if len(parts) != len(names):
                raise InputError(path, f"key {row.values.get('key')!r}",
                                 f"{len(names)} parts split on '/' ({', '.join(names)})")
            for name, part in zip(names, parts):
                row.values[name] = part
    for column, allowed in table.get("where", {}).items():
        keep = {str(v) for v in allowed}
        rows = [r for r in rows if str(r.values.get(column)) in keep]
    for column, first in table.get("order", {}).items():
        rank = {str(v): i for i, v in enumerate(first)}
        rows.sort(key=lambda r: rank.get(str(r.values.get(column)), len(rank)))  # stable
    return rows


def _csv_rows(path: Path) -> list[Row]:
    if not path.is_file():
        raise InputError(path, "file", "an existing CSV report")
    try:
        frame = pd.read_csv(path, keep_default_na=True)
    except (ValueError, OSError) as exc:
        raise InputError(path, "file", "a CSV table", reason=str(exc)) from None
    rows = []
    for i, record in enumerate(frame.to_dict("records")):
        values = {k: (None if isinstance(v, float) and math.isnan(v) else v) for k, v in record.items()}
        rows.append(Row({**values, "key": i}, {k: ("csv", i, k) for k in record}))
    return rows


def _node(doc, path: str, source: Path):
    node = doc
    for part in [p for p in path.split(".") if p]:
        if not isinstance(node, dict) or part not in node:
            raise InputError(source, path, "a key path of the report")
        node = node[part]
    return node


def _json_rows(path: Path, table: dict) -> list[Row]:
    doc = read_json(path)
    records = table.get("records")
    if records is None:
        return [Row(dict(doc), {k: ("json", (k,)) for k in doc})]
    if isinstance(records, dict):
        columns = {name: _node(doc, p, path) for name, p in records.items()}
        keys: list = []
        for name, node in columns.items():
            if not isinstance(node, dict):
                raise InputError(path, records[name], "an object of scalars")
            keys += [k for k in node if k not in keys]
        rows = []
        for key in keys:
            values = {"key": key, **{name: node.get(key) for name, node in columns.items()}}
            where = {name: ("json", tuple(records[name].split(".")) + (key,)) for name in columns}
            rows.append(Row(values, where))
        return rows
    base = tuple(p for p in str(records).split(".") if p)
    node = _node(doc, str(records), path)
    items = list(enumerate(node)) if isinstance(node, list) else list(node.items()) if isinstance(node, dict) else None
    if items is None:
        raise InputError(path, str(records), "an object or a list of objects")
    depth = int(table.get("depth", 1))
    rows = []
    for key, value in _flatten(items, depth, path, str(records)):
        keys = tuple(key)
        rows.append(Row({**value, "key": "/".join(map(str, keys))},
                        {k: ("json", base + keys + (k,)) for k in value}))
    return rows


def _flatten(items, depth: int, path: Path, where: str):
    for key, value in items:
        if not isinstance(value, dict):
            raise InputError(path, f"{where}.{key}", "an object")
        if depth > 1:
            for sub, inner in _flatten(value.items(), depth - 1, path, f"{where}.{key}"):
                yield (key, *sub), inner
        else:
            yield (key,), value


# ---------------------------------------------------------------- rendering
def _cell(template: str, row: Row, where: str, source: str) -> tuple[str, list[tuple[str, tuple, str]]]:
    """``template`` filled from ``row``; also ``(text, locator, format spec)`` of each number printed."""
    out, printed = [], []
    for literal, name, spec, _ in string.Formatter().parse(template):
        out.append(literal)
        if name is None:
            continue
        value = row.values.get(name)
        if value is None or (isinstance(value, float) and math.isnan(value)):
            if name not in row.values and name != "key":
                raise InputError(source, f"{name}", f"a field the table {where!r} shows")
            out.append(MISSING)
            continue
        if isinstance(value, bool) or not isinstance(value, numbers.Real):
            if spec:
                raise InputError(source, name, f"a number (the table {where!r} formats it as {spec!r})", value)
            out.append(str(value))
            continue
        text = format(value, spec)
        out.append(text)
        if name in row.where:
            printed.append((text, row.where[name], spec))
    return "".join(out), printed


def _escape(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


_NUMERIC = re.compile(r"[-+]?\d")


def _align(body: list[list[str]], column: int) -> str:
    """Right-aligned (``---:``) when every filled cell of the column starts with a number."""
    cells = [row[column] for row in body if row[column] != MISSING]
    return "---:" if cells and all(_NUMERIC.match(c) for c in cells) else "---"


def render_table(root: Path, table: dict, index: int, command: str) -> tuple[list[str], list[Printed]]:
    """Markdown lines of one table (heading, caption, table, source line) and its printed numbers."""
    rows = read_rows(root, table)
    source = table["source"]
    if not rows:
        raise InputError(source, table["title"], "at least one row for the table")
    printed: list[Printed] = []
    if "columns" in table:
        headers = [h for h, _ in table["columns"]]
        body = []
        for i, row in enumerate(rows):
            cells = []
            for j, (_, template) in enumerate(table["columns"]):
                text, nums = _cell(template, row, table["title"], source)
                cells.append(text)
                printed += [Printed(index, i, j, t, source, loc, spec) for t, loc, spec in nums]
            body.append(cells)
    else:
        pivot = table["pivot"]
        row_keys = list(dict.fromkeys(r.values.get(pivot["rows"]) for r in rows))
        col_keys = list(dict.fromkeys(r.values.get(pivot["columns"]) for r in rows))
        by = {(r.values.get(pivot["rows"]), r.values.get(pivot["columns"])): r for r in rows}
        headers = [pivot["rows"]] + [str(c) for c in col_keys]
        body = []
        first = {}
        for r in rows:
            first.setdefault(r.values.get(pivot["rows"]), r)
        for i, rk in enumerate(row_keys):
            label, nums = _cell("{%s}" % pivot["rows"], first[rk], table["title"], source)
            cells = [label]
            printed += [Printed(index, i, 0, t, source, loc, spec) for t, loc, spec in nums]
            for j, ck in enumerate(col_keys, start=1):
                row = by.get((rk, ck))
                if row is None:
                    cells.append(MISSING)
                    continue
                text, nums = _cell(pivot["cell"], row, table["title"], source)
                for mark in pivot.get("marks", []):
                    a, op, b = mark["when"]
                    va, vb = row.values.get(a), row.values.get(b)
                    if va is not None and vb is not None and _OPS[op](va, vb):
                        text += mark["text"]
                cells.append(text)
                printed += [Printed(index, i, j, t, source, loc, spec) for t, loc, spec in nums]
            body.append(cells)
    lines = [f"### {table['title']}", ""]
    if table.get("caption"):
        lines += [" ".join(str(table["caption"]).split()), ""]
    lines.append("| " + " | ".join(_escape(h) for h in headers) + " |")
    lines.append("|" + "|".join(_align(body, j) for j in range(len(headers))) + "|")
    lines += ["| " + " | ".join(_escape(c) for c in cells) + " |" for cells in body]
    lines += ["", f"Source: `{source}`, made by `{' '.join(command.split())}`.", ""]
    return lines, printed


def render(root: Path = Path("."), spec: Path = SPEC) -> tuple[str, list[Printed]]:
    """The whole document and every number it prints, from the spec and the reports under ``root``."""
    root = Path(root)
    tables = read_spec(root / spec)
    lines = ["# Results", "",
             f"Written by the `results` stage (`nnsf/results.py`) from the reports named under each "
             f"table; the tables are declared in `{spec.as_posix()}`. Do not edit this file: "
             "`dvc repro results` (or `python -m flows repro`) rewrites it. The method behind each "
             "measure is in [method.md](method.md) and the files in [formats.md](formats.md).", ""]
    printed: list[Printed] = []
    section = None
    commands: dict[str, str] = {}
    for i, table in enumerate(tables):
        if table["section"] != section:
            section = table["section"]
            lines += [f"## {section}", ""]
        command = table.get("command") or commands.get(table["source"])
        if not command:
            raise InputError(spec, f"tables[{i}].command",
                             "a command (only a later table of the same source may leave it out)")
        commands[table["source"]] = command
        table_lines, nums = render_table(root, table, i, command)
        lines += table_lines
        printed += nums
    return "\n".join(lines).rstrip() + "\n", printed


def sources(root: Path = Path("."), spec: Path = SPEC) -> list[str]:
    """Every report file the document reads, in spec order."""
    return list(dict.fromkeys(t["source"] for t in read_spec(Path(root) / spec)))


def results(params: dict, spec: Path = SPEC, out: Path = DOCUMENT) -> StageResult:
    """The ``results`` stage: write ``docs/results.md`` from the reports (see the module notes)."""
    check_outputs("results")
    text, printed = render(Path("."), spec)
    with atomic_path(out) as tmp:
        tmp.write_text(text)
    return StageResult(params={"spec": spec.as_posix()},
                       metrics={"tables": len({p.table for p in printed}), "numbers": len(printed)},
                       artifacts=[out])
