"""A killed ``evaluate`` never leaves a mixed set of outputs (issue 18, class 10).

The stage's outputs are published together (:mod:`nnsf.publish`: staging
folder, commit journal, renames, manifest last).  The kill test SIGKILLs a
real ``evaluate`` process just before each of its file-system writes in turn
(``tests/kill_evaluate.py``) and checks what a reader then finds.
"""
from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from nnsf.errors import InputError

PROJECT = Path(__file__).resolve().parents[1]
MANIFEST = "evaluate.manifest.json"


@pytest.fixture(scope="module")
def features_csv(tmp_path_factory) -> Path:
    from nnsf import stages

    root = tmp_path_factory.mktemp("publish-features")
    params = yaml.safe_load((PROJECT / "params.yaml").read_text())
    params["dataset"]["synthetic"].update(characters=2, clips_per_cell=2, frames=6)
    stages.data(params, out_dir=root / "raw")
    stages.features(params, raw_dir=root / "raw", out_dir=root / "features")
    return root / "features" / "features.csv"


@pytest.fixture(scope="module")
def kill_runs(features_csv, tmp_path_factory) -> dict:
    work = tmp_path_factory.mktemp("kill-evaluate")
    out = work / "runs.json"
    env = dict(os.environ, PYTHONPATH=str(PROJECT))
    res = subprocess.run([sys.executable, str(PROJECT / "tests" / "kill_evaluate.py"), str(features_csv),
                          str(work / "reports"), str(out)], env=env, capture_output=True, text=True,
                         timeout=900)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(out.read_text())


def test_no_mixed_set_after_a_kill_at_any_write(kill_runs):
    old, new, runs = kill_runs["old"], kill_runs["new"], kill_runs["runs"]
    outputs = {"cv_folds.csv", "precision_vs_rank.csv", "plots/precision_vs_rank.csv",
               "plots/recon_error_vs_rank.csv", "figures/precision_vs_rank.png",
               "figures/reconstruction_vs_rank.png", "metrics.json"}
    assert all(old[f] != new[f] for f in ("cv_folds.csv", "metrics.json"))   # two different runs
    killed = [r for r in runs if r["killed"]]
    assert len(killed) >= 20 and not runs[-1]["killed"] and runs[-1]["after_kill"] == new
    for r in killed:
        # After recovery (what the next run or reader does first): exactly one run's set.
        assert r["after_recovery"] in (old, new), f"kill at write {r['k']}: mixed set after recovery"
    for r in killed:
        seen = r["after_kill"]
        # Right after the kill: the old set, the new set, or files without a manifest
        # (the renames of the new set under way), which no reader accepts.
        assert seen in (old, new) or MANIFEST not in seen, f"kill at write {r['k']}: mixed set with a manifest"
        assert r["verified"] == sorted(r["after_recovery"].keys() - {MANIFEST}), r.get("verify_error")
    assert set(old) == set(new) == outputs | {MANIFEST}
    # Kills on both sides of the commit point were tried, and each side resolved its way.
    assert {r["recovery"] for r in killed} >= {"discarded", "completed"}
    # (A kill inside the final clean-up finds the new set published and an empty staging folder.)
    assert all(r["after_recovery"] == (new if r["recovery"] == "completed" or r["after_kill"] == new else old)
               for r in killed)
    assert any(r["after_kill"] not in (old, new) for r in killed)   # the window the manifest guards
    rerun = next(r["rerun"] for r in killed if "rerun" in r)
    assert rerun == new                                               # rerun after a kill: same bytes


def test_the_manifest_is_checked_on_read(tmp_path, features_csv):
    from nnsf import stages
    from nnsf.params import Params
    from nnsf.publish import verify

    p = yaml.safe_load((PROJECT / "params.yaml").read_text())
    p["evaluate"].update(ranks=[2], methods=["nnsf"], folds=2, max_iter=5)
    p["nnsf"]["rank"] = 2
    reports = tmp_path / "reports"
    res = stages.evaluate(Params(copy.deepcopy(p)), features_csv=features_csv, reports=reports,
                          mapper=lambda fn, jobs: [fn(j) for j in jobs])
    files = verify(reports, "evaluate")
    assert sorted(files) == sorted(json.loads((reports / MANIFEST).read_text())["files"])
    assert all(Path(a).is_file() for a in res.artifacts)                 # final paths, not staged ones
    assert not (reports / ".evaluate.staging").exists()
    (reports / "metrics.json").write_text("{}\n")                       # a file of another run
    with pytest.raises(InputError, match=r"evaluate\.manifest\.json: metrics\.json: expected the file"):
        verify(reports, "evaluate")
    (reports / MANIFEST).unlink()
    with pytest.raises(InputError, match="manifest of the evaluate stage"):
        verify(reports, "evaluate")
