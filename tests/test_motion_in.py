"""Motion from outside the project: `nnsf bvh-info`, `--joint-map`, `nnsf styles` from any folder
and its reader report, style names, `animate --keypoints` and progress lines (issue 44).

Every refusal is checked the same way: exit 2, one line on stderr naming the file and the field,
no traceback, nothing written.  Files of ../shared/data are read when present (skipped otherwise).
"""
from __future__ import annotations

import io
import json
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

from nnsf import cli
from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.skeleton import JOINT_INDEX

from test_bvh import ALIEN, ALIEN_MAP, _tiny_human, bvh_text, iclone_joints

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
SKELETONS = DATA / "bvh-skeletons"
PROJECT = Path(__file__).resolve().parents[1]

#: Each file of ../shared/data/bvh-skeletons and the family it belongs to (its README).
SKELETON_FAMILIES = {
    "cmu-motionbuilder/cmu_12_01_walk.bvh": "cmu-motionbuilder",
    "cmu-motionbuilder/01_01.bvh": "cmu-motionbuilder",
    "3dsmax-style/bvh_test2.bvh": "3dsmax",
    "3dsmax-style/test_mocapbank.bvh": "3dsmax",
    "3dsmax-style/Boxing_Toes.bvh": "3dsmax",
    "mixamo/test_freebvh.bvh": "mixamo",
    "cmu-daz/29_01.bvh": "daz",
}


def run_cli(argv, capsys):
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


def refused(capsys, argv, source, field, *needles, nothing=()):
    """Exit 2, one stderr line ``error: <source>: <field>: ...`` with ``needles``, no traceback,
    and none of the paths ``nothing`` left behind."""
    code, out, err = run_cli(argv, capsys)
    assert code == 2, (code, err)
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert err.startswith(f"error: {source}: {field}: "), err
    for n in needles:
        assert str(n) in err, (n, err)
    for p in nothing:
        assert not Path(p).exists(), p
    return out, err


# --------------------------------------------------------------------------- bvh-info
@pytest.mark.parametrize("rel, family", sorted(SKELETON_FAMILIES.items()))
def test_bvh_info_reads_every_skeleton_file_with_its_family(rel, family, capsys):
    path = SKELETONS / rel
    if not path.is_file():
        pytest.skip(f"{path} not found (../shared/data absent)")
    code, out, err = run_cli(["bvh-info", path], capsys)
    assert code == 0, err
    assert f"\nfamily: {family}, score 1.00" in out or f"\nfamily: {family}, score 0.9" in out, out
    assert "hierarchy: " in out and "\nkey points:\n  pelvis" in out
    assert "\nview: " in out and "frames: " in out
    if rel.endswith("Boxing_Toes.bvh"):
        assert "note: " in out and "Frames: says 3069" in out
    # The CMU conversions begin with the skeleton's bind pose, which the motion leaves out.
    assert ("frame 0 is the skeleton's bind pose" in out) == rel.startswith(("cmu-motionbuilder/", "cmu-daz/")), out


def test_bvh_info_on_an_iclone_rig(tmp_path, capsys):
    p = tmp_path / "cc.bvh"
    p.write_text(bvh_text(iclone_joints(), n_frames=40))
    code, out, err = run_cli(["bvh-info", p], capsys)
    assert code == 0, err
    assert "\nfamily: iclone" in out and "  thorax     CC_Base_NeckTwist01" in out
    assert "CC_Base_L_ForearmTwist01" in out            # listed in the hierarchy, not mapped


def test_made_up_names_refused_with_candidates_then_accepted_with_a_joint_map(tmp_path, capsys):
    bvh = tmp_path / "alien.bvh"
    bvh.write_text(_tiny_human(ALIEN))
    out, err = refused(capsys, ["bvh-info", bvh], bvh, "joint names", "candidates: ", "--joint-map")
    assert "OberschenkelL" in out and "family: none" in out       # the hierarchy is still shown
    jm = tmp_path / "alien.yaml"
    jm.write_text(ALIEN_MAP)
    code, out, err = run_cli(["bvh-info", bvh, "--joint-map", jm], capsys)
    assert code == 0, err
    assert "family: joint map alien.yaml" in out and "  pelvis     mid(OberschenkelL, OberschenkelR)" in out
    # animate: refused without the map (nothing written), rendered with it
    video = tmp_path / "out" / "a.gif"
    refused(capsys, ["animate", "--character", "pip", "--motion", bvh, "--out", video, "--vertices", "150"],
            bvh, "joint names", "candidates: ", nothing=[video, video.parent / "a_sheet.png"])
    code, out, err = run_cli(["animate", "--character", "pip", "--motion", bvh, "--out", video, "--vertices",
                              "150", "--joint-map", jm, "--workers", "1"], capsys)
    assert code == 0, err
    assert video.is_file()


@pytest.mark.parametrize("command", ["bvh-info", "animate"])
def test_a_bad_joint_map_is_one_line_naming_the_map(tmp_path, capsys, command):
    bvh = tmp_path / "alien.bvh"
    bvh.write_text(_tiny_human(ALIEN))
    jm = tmp_path / "typo.yaml"
    jm.write_text(ALIEN_MAP.replace("r_knee: UnterschenkelR", "r_knee: Unterschenkel_R"))
    argv = ["bvh-info", bvh] if command == "bvh-info" else \
        ["animate", "--character", "pip", "--motion", bvh, "--out", tmp_path / "x.mp4"]
    refused(capsys, argv + ["--joint-map", jm], jm, "joints.r_knee", f"joints of {bvh}", "UnterschenkelR",
            nothing=[tmp_path / "x.mp4"])
    jm.write_text("joints: [1, 2]\n")
    refused(capsys, argv + ["--joint-map", jm], jm, "joints", "a mapping of key points",
            nothing=[tmp_path / "x.mp4"])


@pytest.mark.parametrize("case, field, words", [
    ("frame_time", "Frame Time", "a clip of at most 600000 frames"),
    ("flat", "skeleton", "thorax = Neck and neck = Head"),
    ("frames", "line 114", "9 motion lines as Frames: says (file truncated?)"),
])
def test_animate_refuses_a_bad_motion_file_in_one_line(tmp_path, capsys, case, field, words):
    text = _tiny_human()
    text = {"frame_time": text.replace("Frame Time: 0.0333333", "Frame Time: 100000"),
            "flat": text.replace("OFFSET 0 6 0", "OFFSET 0 0 0"),
            "frames": text.replace("Frames: 4", "Frames: 9")}[case]
    bvh = tmp_path / "m.bvh"
    bvh.write_text(text)
    out = tmp_path / "o" / "a.mp4"
    refused(capsys, ["animate", "--character", "pip", "--motion", bvh, "--out", out, "--keypoints",
                     tmp_path / "o" / "k.csv"], bvh, field, words,
            nothing=[out, out.with_name("a_sheet.png"), tmp_path / "o" / "k.csv"])
    refused(capsys, ["bvh-info", bvh], bvh, field, words)


# --------------------------------------------------------------------------- animate --keypoints, progress
def test_animate_writes_the_styled_keypoints_in_the_contract(tmp_path, capsys):
    bvh = tmp_path / "cc.bvh"
    bvh.write_text(bvh_text(iclone_joints(), n_frames=12))
    csv = tmp_path / "kp.csv"
    code, out, err = run_cli(["animate", "--character", "pip", "--motion", bvh, "--out", tmp_path / "a.gif",
                              "--keypoints", csv, "--vertices", "150", "--workers", "1"], capsys)
    assert code == 0, err
    table = contract.read_table(csv)
    assert set(table["clip"]) == {"cc"} and set(table["character"]) == {"none"} and len(table) == 12
    P = contract.features(table).reshape(-1, 17, 2)
    assert (P[:, JOINT_INDEX["head_top"], 1] < P[:, JOINT_INDEX["pelvis"], 1]).all()   # y down, upright
    # the file is a motion nnsf reads back
    code, out, err = run_cli(["animate", "--character", "pip", "--motion", csv, "--out", tmp_path / "b.gif",
                              "--vertices", "150", "--workers", "1"], capsys)
    assert code == 0, err
    refused(capsys, ["animate", "--character", "pip", "--motion", bvh, "--out", tmp_path / "c.gif",
                     "--keypoints", tmp_path / "kp.txt"], tmp_path / "kp.txt", "--keypoints", ".csv",
            nothing=[tmp_path / "c.gif"])


def test_phases_beat_while_they_run_and_stay_quiet_when_quick():
    from nnsf.animate.progress import Phases

    buf = io.StringIO()
    ph = Phases("job", every=0.05, stream=buf)
    with ph.phase("quick"):
        pass
    with ph.phase("slow", "waiting"):
        for k in range(3):
            ph.step(k + 1, 3, "frames")
            time.sleep(0.06)
    lines = buf.getvalue().splitlines()
    assert not any("quick" in line for line in lines)
    assert any(line.startswith("job: slow: waiting ...") and "/3 frames" in line for line in lines), lines
    assert lines[-1].startswith("job: slow done in ")
    assert set(ph.seconds) == {"quick", "slow"} and ph.seconds["slow"] >= 0.18
    silent = io.StringIO()
    quiet = Phases("job", enabled=False, every=0.01, stream=silent)
    with quiet.phase("slow"):
        time.sleep(0.05)
    assert silent.getvalue() == "" and quiet.seconds["slow"] > 0


def test_animate_reports_progress_in_every_long_phase(tmp_path, capsys, monkeypatch):
    from nnsf.animate import progress

    # Every phase "long": a heartbeat far shorter than the phases of this small job.
    monkeypatch.setattr(progress, "HEARTBEAT", 1e-3)
    code, out, err = run_cli(["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--out",
                              tmp_path / "a.gif", "--vertices", "150", "--workers", "1"], capsys)
    assert code == 0, err
    for phase in ("load", "mesh", "deform", "render", "encode"):      # translate: with a style
        assert f"animate: {phase} done in" in err, (phase, err)


# --------------------------------------------------------------------------- nnsf styles anywhere
def _clip_folder(root: Path) -> Path:
    d = root / "clips"
    d.mkdir()
    k = 0
    for motion in ("walk", "run", "jump"):
        for style in ("happy", "sad"):
            k += 1
            (d / f"ds_{motion}_{style}_001.bvh").write_text(_tiny_human(variant=k))
    return d


def test_styles_runs_in_any_folder_with_the_package_defaults_and_prints_the_report(tmp_path, capsys,
                                                                                  monkeypatch):
    d = _clip_folder(tmp_path)
    (d / "broken.json").write_text('{"content": "walk", "style": ')                  # garbled label
    (d / "ds_kick_x_001.bvh").write_text(_tiny_human(variant=20))                     # two labels disagree
    (d / "a.json").write_text(json.dumps({"content": "kick", "style": "happy", "bvh": "ds_kick_x_001.bvh"}))
    (d / "b.json").write_text(json.dumps({"content": "kick", "style": "sad", "bvh": "ds_kick_x_001.bvh"}))
    (d / "ds_walk_happy_002.bvh").write_bytes((d / "ds_walk_happy_001.bvh").read_bytes())   # a copy
    outside = tmp_path / "elsewhere" / "take.bvh"
    outside.parent.mkdir()
    outside.write_text(_tiny_human(variant=21))
    (d / "ds_run_sad_002.bvh").symlink_to(outside)                                     # leaves the folder
    work = tmp_path / "anywhere"
    work.mkdir()
    monkeypatch.chdir(work)
    code, out, err = run_cli(["styles", "--data", d, "--out", "m.npz", "--alias", "gloomy=sad"], capsys)
    assert code == 0, err
    lines = err.splitlines()
    assert lines[0].startswith(f"styles: no params.yaml in {work}; used the package defaults")
    assert any("broken.json: line 1" in line for line in lines), err
    assert any("ds_kick_x_001.bvh: labels:" in line and "a.json" in line and "b.json" in line for line in lines)
    assert any("ds_walk_happy_002.bvh: file: expected a clip of its own, got a byte-identical copy" in line
               for line in lines), err
    assert any("ds_run_sad_002.bvh: file: expected a .bvh file inside the dataset folder" in line
               for line in lines), err
    assert "styles: wrote m.npz (2 styles, 3 contents, 3 view(s))" in out
    from nnsf.factor.style_model import StyleModel

    m = StyleModel.load(work / "m.npz")
    assert m.meta["aliases"] == {"gloomy": "sad"}
    assert m.check_style("GLOOMY") == "sad" and m.check_style("Happy") == "happy"
    # an alias for a style the data lacks: refused before fitting, nothing written
    refused(capsys, ["styles", "--data", d, "--out", "n.npz", "--alias", "old=elderly"], "--alias",
            "alias.old", "a style of the model: happy, sad", nothing=[work / "n.npz"])
    refused(capsys, ["styles", "--data", d, "--out", "n.npz", "--alias", "oops"], "--alias", "alias",
            "NAME=STYLE", nothing=[work / "n.npz"])
    # an explicit --params that is missing is still an error
    refused(capsys, ["styles", "--data", d, "--params", "nope.yaml"], "nope.yaml", "file", "params.yaml")


def test_the_package_defaults_agree_with_the_projects_params():
    from nnsf import params

    defaults = yaml.safe_load(params.DEFAULTS_FILE.read_text())
    project = yaml.safe_load((PROJECT / "params.yaml").read_text())

    def walk(node, ref, prefix=""):
        for k, v in node.items():
            assert k in ref, f"{prefix}{k} is not in params.yaml"
            if isinstance(v, dict):
                walk(v, ref[k], f"{prefix}{k}.")
            else:
                assert v == ref[k], f"{prefix}{k}: defaults.yaml says {v!r}, params.yaml {ref[k]!r}"
    walk(defaults, project)
    # and they are what `nnsf styles` reads: the translation settings and the BVH reader's
    from nnsf.factor.style_model import translator_params

    assert translator_params(params.load_defaults()) == translator_params(params.load(PROJECT / "params.yaml"))


def test_a_joint_map_in_params_reaches_the_bvh_dataset(tmp_path):
    import copy

    from nnsf import params as params_mod
    from nnsf import stages

    d = tmp_path / "clips"
    d.mkdir()
    for k, (m, s) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (d / f"ds_{m}_{s}_001.bvh").write_text(_tiny_human(ALIEN, variant=k))
    (d / "alien.yaml").write_text(ALIEN_MAP)
    p = params_mod.Params(copy.deepcopy(params_mod.load(PROJECT / "params.yaml")))
    p["dataset"].update(name="bvh", path=str(d))
    p["dataset"]["bvh"].update(joint_map=str(d / "alien.yaml"), complete_grid=False)
    res = stages.data(p, out_dir=tmp_path / "raw")
    assert res.metrics["clips"] == 4
    p["dataset"]["bvh"]["joint_map"] = None
    with pytest.raises(InputError, match="none of 4 could be read"):
        stages.data(p, out_dir=tmp_path / "raw2")


# --------------------------------------------------------------------------- style names
def test_style_names_fold_case_follow_aliases_and_suggest():
    from nnsf.factor.style_names import check_aliases, resolve_style

    styles = ["old", "proud", "happy", "Happy"]
    assert resolve_style("OLD", styles) == "old" and resolve_style("Happy", styles) == "Happy"
    assert resolve_style("elderly", styles, {"Elderly": "old"}) == "old"
    with pytest.raises(InputError, match=r"did you mean proud\?") as err:
        resolve_style("prod", styles, source="m.npz", field="--style")
    assert str(err.value).startswith("m.npz: --style: expected a style the model knows: old, proud")
    with pytest.raises(InputError, match="differ only in letter case: happy, Happy"):
        resolve_style("HAPPY", styles)
    with pytest.raises(InputError, match=r"did you mean elderly \(= old\)\?"):
        resolve_style("elderli", styles, {"elderly": "old"})
    assert check_aliases({"elderly": "old"}, styles) == {"elderly": "old"}
    for bad, field in (({"Old": "proud"}, "aliases.Old"), ({"x": "young"}, "aliases.x"), ({"": "old"}, "aliases")):
        with pytest.raises(InputError, match=field):
            check_aliases(bad, styles)


def test_animate_takes_a_style_in_any_case_and_suggests_a_near_name(tmp_path, capsys, monkeypatch):
    d = _clip_folder(tmp_path)
    monkeypatch.chdir(tmp_path)
    assert run_cli(["styles", "--data", d, "--out", "m.npz", "--alias", "cheerful=happy"], capsys)[0] == 0
    base = ["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--vertices", "150",
            "--workers", "1", "--model", "m.npz"]
    for name in ("HAPPY", "Cheerful"):
        code, out, err = run_cli(base + ["--style", name, "--out", tmp_path / f"{name}.gif"], capsys)
        assert code == 0, err
        assert "style happy" in err
    refused(capsys, base + ["--style", "hapy", "--out", tmp_path / "x.gif"], "m.npz", "--style",
            "did you mean happy", nothing=[tmp_path / "x.gif"])


def test_a_csv_motion_with_coinciding_key_points_is_named_not_a_value_error(tmp_path, capsys):
    from nnsf.datasets import synthetic

    table = contract.validate(synthetic.generate(characters=2, clips_per_cell=1, frames=8, seed=0), "syn")
    clip = sorted(table["clip"])[0]
    one = table[table["clip"] == clip].copy()
    s, t = JOINT_INDEX["spine"] + 1, JOINT_INDEX["thorax"] + 1
    one[f"x{t}"], one[f"y{t}"] = one[f"x{s}"], one[f"y{s}"]
    csv = tmp_path / "flat.csv"
    contract.write_table(csv, one)
    refused(capsys, ["animate", "--character", "pip", "--motion", csv, "--out", tmp_path / "a.gif"],
            csv, f"{clip}: spine, thorax", "spine and thorax coincide", nothing=[tmp_path / "a.gif"])


def test_styles_reads_a_folder_of_an_unknown_skeleton_with_a_joint_map(tmp_path, capsys, monkeypatch):
    d = tmp_path / "clips"
    d.mkdir()
    for k, (m, s) in enumerate((m, s) for m in ("walk", "run", "jump") for s in ("happy", "sad")):
        (d / f"ds_{m}_{s}_001.bvh").write_text(_tiny_human(ALIEN, variant=k))
    jm = tmp_path / "alien.yaml"
    jm.write_text(ALIEN_MAP)
    monkeypatch.chdir(tmp_path)
    # without the map every clip is skipped: one line naming the folder, the first reason given
    refused(capsys, ["styles", "--data", d, "--out", "m.npz"], d, "clips", "joint names", nothing=["m.npz"])
    code, out, err = run_cli(["styles", "--data", d, "--out", "m.npz", "--joint-map", jm], capsys)
    assert code == 0, err
    assert "styles: wrote m.npz (2 styles, 3 contents, 3 view(s))" in out
