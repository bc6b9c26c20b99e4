"""The results document (docs/results.md) is what the reports say, number for number.

* the committed document is exactly what ``nnsf.results`` makes from the committed reports, so a
  report re-run without ``dvc repro results`` fails here;
* every number printed in a table equals the value of its report (read here with ``json`` and
  ``csv``, not the writer's loaders) to the digits printed, and a changed digit is caught;
* the ``results`` stage's deps in dvc.yaml are the spec and every report the spec names;
* a spec cannot reach into objects or outside ``reports/``.
"""
from __future__ import annotations

import csv
import dataclasses
import functools
import json
import re
import string
from pathlib import Path

import pytest
import yaml

from nnsf import results
from nnsf.errors import InputError

ROOT = Path(__file__).resolve().parents[1]
_NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def _tables(document: str) -> list[list[list[str]]]:
    """The body cells of every markdown table of ``document``, in order."""
    tables, current = [], None
    for line in document.splitlines():
        if line.startswith("|"):
            if current is None:
                current = []
                tables.append(current)
            current.append([c.strip() for c in line.strip().strip("|").split(" | ")])
        else:
            current = None
    return [t[2:] for t in tables]  # header and alignment rows dropped


@functools.lru_cache(maxsize=None)
def _report(source: str):
    path = ROOT / source
    if path.suffix == ".csv":
        with open(path, newline="") as fh:
            return list(csv.DictReader(fh))
    return json.loads(path.read_text())


def _report_value(source: str, locator: tuple):
    """The value a locator points at, read with the standard library."""
    if locator[0] == "csv":
        return _report(source)[locator[1]][locator[2]]
    node = _report(source)
    for key in locator[1]:
        node = node[int(key)] if isinstance(node, list) else node[key]
    return node


def mismatches(document: str, printed: list) -> list[str]:
    """Every printed number that is not in its cell of ``document`` or not its report's value."""
    tables, wrong = _tables(document), []
    for p in printed:
        try:
            cell = tables[p.table][p.row][p.column]
        except IndexError:
            wrong.append(f"table {p.table} has no cell ({p.row}, {p.column})")
            continue
        if p.text not in _NUMBER.findall(cell) and p.text not in cell:
            wrong.append(f"table {p.table} cell ({p.row}, {p.column}) {cell!r} lacks {p.text!r}")
            continue
        value = float(_report_value(p.source, p.locator))
        shown = float(p.text.rstrip("%"))
        if p.format_spec.endswith("%"):
            value *= 100
        decimals = len(p.text.rstrip("%").partition(".")[2]) if "e" not in p.text.lower() else None
        tolerance = 0.5 * 10.0 ** -decimals + 1e-9 if decimals is not None else 1e-5 * abs(value)
        if abs(shown - value) > tolerance:
            wrong.append(f"{p.source} {p.locator}: report {value!r}, document {p.text!r}")
    return wrong


@pytest.fixture(scope="module")
def rendered():
    return results.render(ROOT)


def test_the_document_is_what_the_reports_make(rendered):
    text, _ = rendered
    committed = (ROOT / results.DOCUMENT).read_text()
    assert committed == text, "docs/results.md is stale: run `dvc repro results` (python -m flows repro)"


def test_every_number_of_the_document_is_its_reports_value(rendered):
    _, printed = rendered
    assert len(printed) > 500 and len({p.source for p in printed}) == len(results.sources(ROOT))
    assert mismatches((ROOT / results.DOCUMENT).read_text(), printed) == []


def test_a_number_that_differs_from_its_report_is_caught(rendered):
    text, printed = rendered
    target = next(p for p in printed if p.format_spec.endswith("f") and "." in p.text)
    cells = _tables(text)[target.table][target.row]
    line = "| " + " | ".join(cells) + " |"
    wrong = target.text[:-1] + ("2" if target.text[-1] == "1" else "1")
    cells[target.column] = cells[target.column].replace(target.text, wrong, 1)
    changed = text.replace(line, "| " + " | ".join(cells) + " |", 1)
    assert changed != text
    assert mismatches(changed, printed)                                     # the cell lost its number
    assert mismatches(changed, [dataclasses.replace(target, text=wrong)])   # and the new one is not the report's


def test_the_stage_reads_exactly_the_spec_and_its_reports():
    stage = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["results"]
    deps = {d for d in stage["deps"] if not d.startswith(("nnsf", "flows"))}
    assert deps == {results.SPEC.as_posix(), *results.sources(ROOT)}
    assert [next(iter(o)) for o in stage["outs"]] == [results.DOCUMENT.as_posix()]


@pytest.mark.parametrize("template", ["{a.__class__}", "{a[0]}", "{a!r}", "{a:{b}}"])
def test_a_template_names_plain_fields_only(template):
    with pytest.raises(ValueError):
        results.fields(template)


@pytest.mark.parametrize("change, field", [
    ({"source": "../secret.json"}, "tables[0].source"),
    ({"source": "data/raw/keypoints.csv"}, "tables[0].source"),
    ({"columns": [["x", "{x.__class__}"]]}, "tables[0].columns"),
    ({"colour": "red"}, "tables[0].colour"),
])
def test_a_bad_spec_entry_fails_naming_it(tmp_path, change, field):
    table = {"section": "s", "title": "t", "source": "reports/a.json", "command": "c",
             "columns": [["x", "{x}"]], **change}
    spec = tmp_path / "spec.yaml"
    spec.write_text(yaml.safe_dump({"tables": [table]}))
    with pytest.raises(InputError, match=re.escape(field)):
        results.read_spec(spec)


def test_rows_are_selected_ordered_split_and_pivoted(tmp_path):
    """A small report through every option: where, order, split_key, a pivot with a mark."""
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "r.json").write_text(json.dumps(
        {"by": {"a/x": {"v": 1.25, "n": 3}, "b/x": {"v": 2.5, "n": 2}, "a/y": {"v": 0.125, "n": 1}}}))
    (tmp_path / "reports" / "p.csv").write_text("m,k,k_used,v\nu,1,1,0.5\nu,2,1,0.5\nw,1,1,0.25\n")
    spec = {"tables": [
        {"section": "S", "title": "T", "source": "reports/r.json", "command": "make r", "records": "by",
         "split_key": ["group", "kind"], "where": {"kind": ["x"]}, "order": {"group": ["b"]},
         "columns": [["group", "{group}"], ["value", "{v:.2f}"], ["n", "{n}"]]},
        {"section": "S", "title": "P", "source": "reports/p.csv", "command": "make p",
         "pivot": {"rows": "k", "columns": "m", "cell": "{v:.1%}",
                   "marks": [{"text": "*", "when": ["k_used", "<", "k"]}]}}]}
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "results.yaml").write_text(yaml.safe_dump(spec))
    text, printed = results.render(tmp_path)
    tables = _tables(text)
    assert tables[0] == [["b", "2.50", "2"], ["a", "1.25", "3"]]
    assert tables[1] == [["1", "50.0%", "25.0%"], ["2", "50.0%*", results.MISSING]]
    assert "Source: `reports/p.csv`, made by `make p`." in text
    assert {(p.table, p.row, p.column, p.text) for p in printed} >= {(0, 0, 1, "2.50"), (1, 1, 1, "50.0%")}


def test_the_spec_types_no_result_by_hand():
    """Titles, captions and headers hold no decimal number (section marks such as §15.6 aside):
    every measured value of the document comes from a report."""
    typed = re.compile(r"(?<![§\d.])\d+\.\d+")
    for table in results.read_spec(ROOT / results.SPEC):
        texts = [table["title"], table.get("caption", "")]
        texts += [h for h, _ in table.get("columns", [])]
        texts += [literal for _, template in table.get("columns", []) for literal, *_ in
                  string.Formatter().parse(template)]
        assert not [t for t in texts if typed.search(t)], table["title"]
