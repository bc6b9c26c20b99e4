"""What is reproducible, to what tolerance (docs/operations.md, "Reproducibility").

* **On one machine** with the pinned stack the pipeline writes the same bytes every time, whatever
  the number of BLAS threads: test_ops_repro repeats the small pipeline's cold repro in a second
  clone with two OpenBLAS threads instead of one and requires the same dvc.lock hashes.
* **On another machine** the bytes may differ (a float sum ends in other last bits on another CPU
  or BLAS kernel, and a fit stopped by a tolerance may run a different number of iterations), so
  dvc.lock and the binary outputs may change; the numbers of the reports agree within
  :data:`TOLERANCE`.  This module compares the small pipeline's reports, made on the machine that
  runs the tests, with the reference committed in ``tests/data/small_reports/`` (made on the
  development machine) at that tolerance.  On the development machine it also catches a change of
  the results; if the change is meant, refresh the reference with
  ``NNSF_REFRESH_REFERENCE=1 .venv/bin/python -m pytest tests/test_determinism.py``.

Versioned reports hold no wall times and no iteration counts (MLflow keeps both).
"""
from __future__ import annotations

import json
import math
import os
import shutil
from pathlib import Path

import pandas as pd
import pytest

#: Two numbers agree when |a - b| <= TOLERANCE * max(1, |a|, |b|): the third decimal of a score.
TOLERANCE = 1e-3
REFERENCE = Path(__file__).parent / "data" / "small_reports"
#: The reports compared: the recognition experiments and the tracker scores of the small pipeline.
COMPARED = ("metrics.json", "precision_vs_rank.csv", "cv_folds.csv", "factorize.json", "isomap.json",
            "sweep.csv", "sweep.json", "roto_eval.json", "plots/precision_vs_rank.csv",
            "plots/recon_error_vs_rank.csv", "plots/isomap_residual.csv")


def _close(a, b) -> bool:
    if isinstance(a, bool) or isinstance(b, bool) or not all(isinstance(v, (int, float)) for v in (a, b)):
        return a == b or (a != a and b != b)  # NaN in both
    if math.isnan(a) or math.isnan(b):
        return math.isnan(a) and math.isnan(b)
    return abs(a - b) <= TOLERANCE * max(1.0, abs(a), abs(b))


def _json_differences(a, b, where: str) -> list[str]:
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{where}: keys {sorted(set(a) ^ set(b))} in one only"]
        return [d for k in sorted(a) for d in _json_differences(a[k], b[k], f"{where}.{k}")]
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return [f"{where}: {len(a)} items against {len(b)}"]
        return [d for i, (x, y) in enumerate(zip(a, b)) for d in _json_differences(x, y, f"{where}[{i}]")]
    return [] if _close(a, b) else [f"{where}: {a!r} against {b!r}"]


def differences(ours: Path, reference: Path, names=COMPARED) -> list[str]:
    """Every number (or text) of the reports in ``ours`` that differs from ``reference`` beyond the tolerance."""
    found = []
    for name in names:
        a, b = ours / name, reference / name
        if not a.is_file() or not b.is_file():
            found.append(f"{name}: missing in {'ours' if not a.is_file() else 'the reference'}")
        elif a.suffix == ".json":
            found += _json_differences(json.loads(a.read_text()), json.loads(b.read_text()), name)
        else:
            x, y = pd.read_csv(a), pd.read_csv(b)
            if list(x.columns) != list(y.columns) or len(x) != len(y):
                found.append(f"{name}: columns {list(x.columns)} × {len(x)} rows against "
                             f"{list(y.columns)} × {len(y)}")
                continue
            found += [f"{name} row {i} {col}: {u!r} against {v!r}" for col in x.columns
                      for i, (u, v) in enumerate(zip(x[col].tolist(), y[col].tolist())) if not _close(u, v)]
    return found


def _write(folder: Path, name: str, text: str) -> None:
    (folder / name).parent.mkdir(parents=True, exist_ok=True)
    (folder / name).write_text(text)


def test_numbers_within_the_tolerance_agree_and_beyond_it_do_not(tmp_path):
    """The comparison itself: a change in the 5th digit passes, one in the 2nd digit, a changed
    label, an extra key and a missing row fail."""
    ours, ref = tmp_path / "ours", tmp_path / "ref"
    _write(ref, "a.json", json.dumps({"p": 0.612345, "k": 16, "m": {"x": [1.0, 2.0]}, "label": "motion"}))
    _write(ref, "b.csv", "method,rank,precision\nnnsf,4,0.187\nnmf,4,0.144\n")
    _write(ours, "a.json", json.dumps({"p": 0.612349, "k": 16, "m": {"x": [1.0, 2.0000001]}, "label": "motion"}))
    _write(ours, "b.csv", "method,rank,precision\nnnsf,4,0.18701\nnmf,4,0.144\n")
    assert differences(ours, ref, ("a.json", "b.csv")) == []
    for name, text in (("a.json", json.dumps({"p": 0.62, "k": 16, "m": {"x": [1.0, 2.0]}, "label": "motion"})),
                       ("a.json", json.dumps({"p": 0.612345, "k": 16, "m": {"x": [1.0, 2.0]}, "label": "style"})),
                       ("a.json", json.dumps({"p": 0.612345, "k": 16, "m": {"x": [1.0, 2.0]}, "label": "motion",
                                              "n_iter": 13})),
                       ("b.csv", "method,rank,precision\nnnsf,4,0.187\n")):
        _write(ours, name, text)
        assert differences(ours, ref, ("a.json", "b.csv")), text
        _write(ours, "a.json", (ref / "a.json").read_text())
        _write(ours, "b.csv", (ref / "b.csv").read_text())


def test_versioned_reports_hold_no_iteration_counts_or_times(small_pipeline):
    for name in COMPARED:
        path = small_pipeline.reports / name
        keys = set(json.loads(path.read_text())) if path.suffix == ".json" else set(pd.read_csv(path).columns)
        assert not keys & {"n_iter", "seconds", "stage_seconds", "fit_seconds"}, name


def test_the_small_pipelines_reports_match_the_reference_within_the_tolerance(small_pipeline):
    if os.environ.get("NNSF_REFRESH_REFERENCE"):
        shutil.rmtree(REFERENCE, ignore_errors=True)
        for name in COMPARED:
            (REFERENCE / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(small_pipeline.reports / name, REFERENCE / name)
        pytest.skip(f"wrote the reference {REFERENCE}")
    assert differences(small_pipeline.reports, REFERENCE) == []
