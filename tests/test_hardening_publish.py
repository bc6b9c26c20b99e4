"""A killed ``evaluate`` never leaves a mixed set of outputs.

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


@pytest.mark.slow  # runs tests/kill_evaluate.py, which forks and SIGKILLs evaluate at each write
def test_no_mixed_set_after_a_kill_at_any_write(kill_runs):
    old, new, runs = kill_runs["old"], kill_runs["new"], kill_runs["runs"]
    outputs = {"cv_folds.csv", "precision_vs_rank.csv", "plots/precision_vs_rank.csv",
               "plots/recon_error_vs_rank.csv", "figures/precision_vs_rank.png",
               "figures/reconstruction_vs_rank.png", "metrics.json"}
    assert all(old[f] != new[f] for f in ("cv_folds.csv", "metrics.json"))   # two different runs
    killed = [r for r in runs if r["killed"]]
    assert len(killed) >= 20 and not runs[-1]["killed"] and runs[-1]["after_kill"] == new
    for r in killed:
        # Once the next command of the project has started (here `nnsf check`; every nnsf
        # and `python -m flows` command settles publications first): exactly one run's set,
        # nothing staged left, and the manifest checks out.
        assert r["after_recovery"] in (old, new), f"kill at write {r['k']}: mixed set after the next command"
        assert r["hidden_left"] == [], (r["k"], r["hidden_left"])
        assert r["verified"] == sorted(r["after_recovery"].keys() - {MANIFEST}), r.get("verify_error")
        if r["recovery"] != "none":
            assert "nnsf: note: " in r["notes"] and r["notes"].count("\n") == 1, r["notes"]
    for r in killed:
        seen = r["after_kill"]
        # Right after the kill, before any command: the old set, the new set, or (a kill
        # among the renames) a mix that carries its own way out: no manifest, and the
        # commit journal of the new set beside it, which the next command completes.
        if seen not in (old, new):
            assert MANIFEST not in seen and r["recovery"] == "completed", \
                f"kill at write {r['k']}: a mixed set that the next command cannot complete"
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


# --------------------------------------------------------------------------- every published stage

def _write_set(out: Path, tag: str) -> None:
    """Two files in two folders of one set (``tag`` tells the runs apart)."""
    (out / "models").mkdir(parents=True, exist_ok=True)
    (out / "reports" / "figures").mkdir(parents=True, exist_ok=True)
    (out / "models" / "m.npz").write_text(f"model {tag}\n")
    (out / "reports" / "s.json").write_text(f'{{"run": "{tag}"}}\n')
    (out / "reports" / "figures" / "f.png").write_text(f"figure {tag}\n")


def _contents(root: Path) -> dict[str, str]:
    return {p.relative_to(root).as_posix(): p.read_text() for p in sorted(root.rglob("*"))
            if p.is_file() and not any(part.startswith(".") for part in p.relative_to(root).parts)}


def test_a_set_spanning_two_folders_is_completed_by_the_next_command(tmp_path, monkeypatch, capsys):
    """A kill among the renames of a set like factorize's (models/ and reports/): the next
    ``nnsf`` command completes it, and the manifest (under reports/) lists both folders."""
    from nnsf import cli
    from nnsf.publish import publishing, verify

    reports = tmp_path / "reports"
    with publishing(reports, "x", root=tmp_path) as out:
        _write_set(out, "old")
    old = _contents(tmp_path)
    manifest = json.loads((reports / "x.manifest.json").read_text())
    assert manifest["root"] == ".." and sorted(manifest["files"]) == [
        "models/m.npz", "reports/figures/f.png", "reports/s.json"]

    # The second run dies after its first rename: a real os.replace, then the "kill".
    real_replace, moved = os.replace, []

    def replace_then_die(src, dst):
        if moved and "staging" in str(src):
            raise KeyboardInterrupt  # the process ends here, as under SIGKILL
        moved.append(dst)
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace_then_die)
    with pytest.raises(KeyboardInterrupt):
        with publishing(reports, "x", root=tmp_path) as out:
            _write_set(out, "new")
    monkeypatch.setattr(os, "replace", real_replace)
    mixed = _contents(tmp_path)
    assert mixed != old and "x.manifest.json" not in str(mixed)   # the window: a mix, no manifest
    (tmp_path / "params.yaml").write_text((PROJECT / "params.yaml").read_text())
    monkeypatch.chdir(tmp_path)
    capsys.readouterr()
    assert cli.main(["check"]) == 0
    note = capsys.readouterr().err
    assert note.startswith("nnsf: note: reports/x.manifest.json: completed the x stage's"), note
    new = _contents(tmp_path)
    assert {k: v for k, v in new.items() if "old" in v and k != "params.yaml"} == {}
    assert sorted(verify(reports, "x")) == sorted(manifest["files"])
    assert not any(p.name.startswith(".x.") for p in reports.iterdir())


def test_a_publication_in_progress_is_left_alone(tmp_path):
    """Only a staging folder nobody holds is settled: a running stage keeps its lock."""
    from nnsf.publish import publishing, recover, recover_all, verify

    reports = tmp_path / "reports"
    with publishing(reports, "y") as out:
        (out / "a.csv").write_text("1\n")
        assert recover_all(reports) == [] and recover(reports, "y") == "busy"
        assert (out / "a.csv").is_file()                  # nothing was discarded under its feet
        (out / "b.csv").write_text("2\n")
    assert sorted(verify(reports, "y")) == ["a.csv", "b.csv"]


def test_flows_commands_settle_publications_first(tmp_path, monkeypatch, capsys):
    """`python -m flows <anything>` (here a wrong command, handled in this process) settles first."""
    from flows.__main__ import main
    from nnsf.publish import staging_path

    (tmp_path / "dvc.yaml").write_text("stages: {}\n")
    staged = staging_path(tmp_path / "reports", "evaluate")
    staged.mkdir(parents=True)
    (staged / "metrics.json").write_text("{}\n")          # killed before its commit journal
    monkeypatch.chdir(tmp_path)
    assert main(["no-such-command"]) == 2
    err = capsys.readouterr().err
    assert "removed the evaluate stage's unfinished outputs" in err, err
    assert list((tmp_path / "reports").iterdir()) == []


@pytest.mark.parametrize("stage", ["factorize", "evaluate", "isomap", "heldout", "roto_eval"])
def test_every_multi_file_report_stage_publishes_its_declared_outputs(stage):
    """The manifest is declared in dvc.yaml next to the stage's outs, and the stage's code
    writes through nnsf.publish (its manifest lists every other out: test_pipeline checks
    that on a real repro)."""
    spec = yaml.safe_load((PROJECT / "dvc.yaml").read_text())["stages"][stage]
    outs = [next(iter(e)) if isinstance(e, dict) else e for e in spec["outs"]]
    assert f"reports/{stage}.manifest.json" in outs
    assert "nnsf/publish.py" in spec["deps"]
