"""Hostile and careless input (issue 18): no hang, no silent typo, one bad file fails alone.

One test (or a few) per class of the bad-input probe:
1 alias bomb, 2 unreadable annotation, 3 misspelt keys, 4 infinite/absurd
values, 5 the params file named, 6 degenerate data, 7 BVH symlinks, 8 error
reasons kept, 9 disk full.  Class 10 (a killed evaluate) is in
test_hardening_publish.py.  Everything runs real code on real files; disk
full is a real kernel error (a tiny tmpfs, or RLIMIT_FSIZE).
"""
from __future__ import annotations

import copy
import json
import os
import resource
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from nnsf.errors import InputError
from nnsf.params import SCHEMA, Params, load, validate

PROJECT = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((PROJECT / "params.yaml").read_text())


def _env() -> dict:
    env = dict(os.environ, PYTHONPATH=str(PROJECT), PYTHONDONTWRITEBYTECODE="1")
    env.pop("NNSF_DEBUG", None)
    return env


def nnsf(*args, cwd, timeout=120, preexec_fn=None) -> subprocess.CompletedProcess:
    """The ``nnsf`` command of this checkout, run as a real process."""
    return subprocess.run([sys.executable, "-m", "nnsf.cli", *map(str, args)], cwd=cwd, env=_env(),
                          capture_output=True, text=True, timeout=timeout, preexec_fn=preexec_fn)


def write_params(path: Path, params: dict | str) -> Path:
    path.write_text(params if isinstance(params, str) else yaml.safe_dump(params, sort_keys=False))
    return path


def with_value(key: str, value) -> dict:
    p = copy.deepcopy(BASE)
    node = p
    *head, last = key.split(".")
    for part in head:
        node = node[part]
    node[last] = value
    return p


def one_error_line(res: subprocess.CompletedProcess) -> str:
    lines = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr
    assert len(lines) == 1 and lines[0].startswith("error: "), res.stderr
    assert "Traceback" not in res.stderr
    return lines[0]


# --------------------------------------------------------------------------- 1. alias bomb

def _bomb_value() -> str:
    """A flow-style YAML value whose expansion has 9^10 leaves: nine levels of nine aliases.

    ``yaml.safe_load`` builds it at once (aliases are shared references);
    anything that walks or ``repr``s it whole never ends.
    """
    text = "&l0 [1, 2, 3, 4, 5, 6, 7, 8, 9]"
    for level in range(1, 9):
        text = f"&l{level} [{text}, " + ", ".join([f"*l{level - 1}"] * 8) + "]"
    return f"[{text}, " + ", ".join(["*l8"] * 8) + "]"


@pytest.mark.slow  # starts a fresh `python -c` and `nnsf check` as a process
def test_alias_bomb_is_answered_in_under_a_second_with_one_line(tmp_path):
    base = (PROJECT / "params.yaml").read_text()
    text = base.replace("  ranks: [2, 4, 8, 12, 16, 24, 34]", "  ranks: " + _bomb_value())
    assert text != base and len(text) - len(base) < 1500
    path = tmp_path / "bomb.yaml"
    path.write_text(text)
    # In a fresh process, the time of load() alone (the hang was in building the message).
    code = textwrap.dedent(f"""
        import time
        from nnsf.params import load
        from nnsf.errors import InputError
        t = time.perf_counter()
        try:
            load({str(path)!r})
        except InputError as e:
            print(time.perf_counter() - t)
            print(e)
        """)
    res = subprocess.run([sys.executable, "-c", code], env=_env(), capture_output=True, text=True, timeout=60)
    seconds, message = res.stdout.splitlines()[:2]
    assert float(seconds) < 1.0, seconds
    assert message.startswith(f"{path}: evaluate.ranks: expected a non-empty list"), message
    assert "got a list of 9 items: [a list of 9 items" in message and len(message) < 400
    line = one_error_line(nnsf("check", "--params", path, cwd=tmp_path, timeout=60))
    assert "evaluate.ranks" in line


def test_yaml_nested_thousands_deep_is_one_line(tmp_path):
    path = write_params(tmp_path / "deep.yaml", "seed: " + "[" * 20000 + "]" * 20000 + "\n")
    with pytest.raises(InputError, match="nested"):
        load(path)


# --------------------------------------------------------------------------- 3. misspelt keys

@pytest.mark.slow  # starts `nnsf` as a process
def test_three_misspelt_keys_are_all_named_with_suggestions(tmp_path):
    p = copy.deepcopy(BASE)
    p["nnsf"]["aplha"] = p["nnsf"].pop("alpha")
    p["evaluate"]["foldz"] = p["evaluate"].pop("folds")
    p["seeed"] = p.pop("seed")
    path = write_params(tmp_path / "typos.yaml", p)
    line = one_error_line(nnsf("check", "--params", path, cwd=tmp_path))
    assert str(path) in line
    for wrong, right in (("nnsf.aplha", "nnsf.alpha"), ("evaluate.foldz", "evaluate.folds"), ("seeed", "seed")):
        assert f"{wrong} (did you mean {right}?)" in line, line


@pytest.mark.slow  # starts `nnsf` as a process
def test_the_project_params_pass_and_every_key_is_in_the_schema(tmp_path):
    res = nnsf("check", cwd=PROJECT)
    assert res.returncode == 0 and res.stdout.strip() == "params.yaml: ok", res.stderr
    assert "frames.motions" in SCHEMA           # a free-form field, now validated too


@pytest.mark.parametrize("key, value", [
    ("frames.motions", ["walk", "walk"]),          # names, each once
    ("frames.motions", 0),                         # or a count >= 1
    ("frames.motions", ["walk", 3]),
    ("reshape_eval.characters", ["char1", 5]),     # names must be strings
    ("reshape_eval.arms", {"char5": "sideways"}),  # motion or drawing per character
    ("reshape.arms", "sideways"),
    ("reshape_eval.head", {"char3": "nod"}),     # motion or torso per character
    ("reshape.head", "nod"),
    ("reshape.formats", ["gif", "gif", "png", "mp4"]),
])
def test_free_form_fields_are_still_validated(key, value):
    with pytest.raises(InputError, match=key.replace(".", r"\.")):
        validate(with_value(key, value))


def test_motion_names_are_checked_against_the_generator_by_the_frames_stage():
    from nnsf.frames.stage import frames_params

    for value in (["walk", "moonwalk"], 99):
        with pytest.raises(InputError, match=r"frames\.motions: expected a count"):
            frames_params(Params(with_value("frames.motions", value)))


def test_a_section_that_is_not_a_mapping_is_named():
    p = copy.deepcopy(BASE)
    p["nnsf"] = 5
    with pytest.raises(InputError, match="nnsf: expected a mapping of nnsf"):
        validate(p)


# --------------------------------------------------------------------------- 4. infinite and absurd values

@pytest.mark.slow  # starts `nnsf` as a process
@pytest.mark.parametrize("key, value", [
    ("nnsf.beta", float("inf")), ("nnsf.alpha", float("nan")), ("reshape.fps", float("inf")),
    ("reshape.fps", 500), ("roto.w_sketch", float("inf")), ("dataset.bvh.azimuth", float("-inf")),
])
def test_infinite_and_out_of_range_numbers_fail_the_check(tmp_path, key, value):
    path = write_params(tmp_path / "p.yaml", with_value(key, value))
    line = one_error_line(nnsf("check", "--params", path, cwd=tmp_path))
    assert f"{path}: {key}: expected a finite number in [" in line


def test_the_stage_applies_the_same_range_as_the_check():
    from nnsf.reshape.stage import _params

    for fps in (500, float("inf"), 0.5):
        params = Params(with_value("reshape.fps", fps))
        with pytest.raises(InputError) as stage_err:
            _params(params)
        with pytest.raises(InputError) as check_err:
            validate(with_value("reshape.fps", fps))
        assert stage_err.value.expected == check_err.value.expected == SCHEMA["reshape.fps"][1]
    assert _params(Params(with_value("reshape.fps", 120)))["fps"] == 120


def test_factorize_refuses_an_infinite_beta_naming_the_field(tmp_path):
    from nnsf import stages

    params = Params(with_value("nnsf.beta", float("inf")))
    params.source = "mine.yaml"
    with pytest.raises(InputError, match=r"^mine\.yaml: nnsf\.beta: expected a finite number"):
        stages.factorize(params, features_csv=tmp_path / "absent.csv", model=tmp_path / "m.npz",
                         reports=tmp_path / "reports")


@pytest.mark.slow  # starts `nnsf` as a process
@pytest.mark.parametrize("key", ["dataset.synthetic.clips_per_cell", "dataset.synthetic.frames", "frames.frames"])
def test_absurd_sizes_are_refused_with_a_memory_estimate(tmp_path, key):
    path = write_params(tmp_path / "p.yaml", with_value(key, 1_000_000_000))
    line = one_error_line(nnsf("check", "--params", path, cwd=tmp_path))
    assert f"{key}: expected an integer in [" in line and "of memory" in line
    assert "would need about" in line and ("TB" in line or "PB" in line), line


def test_sizes_within_their_bounds_but_too_big_together_are_refused():
    p = with_value("dataset.synthetic.clips_per_cell", 1000)
    p["dataset"]["synthetic"]["characters"] = 12
    with pytest.raises(InputError) as err:
        validate(p)
    msg = str(err.value)
    assert "dataset.synthetic: expected sizes that fit in 4.0 GB of memory" in msg
    assert "12 x 15 x 1000 x 24 = 4320000 key-point rows, about 4.3 GB" in msg


# --------------------------------------------------------------------------- 5. the params file named

@pytest.mark.slow  # starts `nnsf` as a process
def test_reshape_errors_name_the_params_file_given(tmp_path):
    from nnsf.reshape.stage import _params

    other = write_params(tmp_path / "other.yaml", with_value("reshape.method", "ours"))
    params = load(other)
    params["reshape"]["method"] = "method-of-my-own"      # after the check, as a caller may
    with pytest.raises(InputError, match=rf"^{tmp_path}/other\.yaml: reshape\.method"):
        _params(params)
    line = one_error_line(nnsf("reshape", "--params", other, "--character", "nosuch",
                               "--motion", tmp_path / "none.csv", "--out", tmp_path / "out", cwd=tmp_path))
    assert line.startswith(f"error: {other}: reshape.character"), line
    assert "params.yaml" not in line


# --------------------------------------------------------------------------- 8. reasons kept

def test_summaries_are_bounded_and_reasons_are_kept():
    from nnsf.errors import summarize

    big = list(range(10**6))
    assert summarize(big) == "a list of 1000000 items: [0, 1, 2, ...]"
    reason = "the first problem: " + "x" * 300 + " END"
    err = InputError("f.yaml", "k", "a thing", "v" * 500, reason=reason)
    text = str(err)
    assert text.endswith(reason + ")") and "(500 characters)" in text and len(text) < 800


def test_no_readable_bvh_clip_message_keeps_its_reason(tmp_path):
    from nnsf.datasets.bvh import read_bvh
    from nnsf.datasets.bvh_source import read_folder

    folder = tmp_path / ("a-rather-long-folder-name-for-motion-capture-clips" * 2)
    folder.mkdir()
    bad = folder / "ds_walk_happy_001.bvh"
    bad.write_text("HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 3 Xposition Yposition Wobble\n}\n")
    with pytest.raises(InputError) as inner:
        read_bvh(bad)
    with pytest.raises(InputError) as outer:
        read_folder(folder)
    assert str(inner.value) in str(outer.value), str(outer.value)
    assert "\n" not in str(outer.value)


# --------------------------------------------------------------------------- 2. unreadable annotation

TRACK = {"method": "ours", "w_velocity": 3.0, "w_length": 1.0, "w_length_anchor": 4.0, "w_curvature": 1.0,
         "w_edge": 1.0, "w_sketch": 100.0, "w_colour": 100.0, "window": 3, "samples": 8, "levels": 1,
         "max_iter": 5, "init": "linear", "lk_end": "blend", "eval_clips": 1, "edit_tol_px": 2.0,
         "max_edits": 3}
FRAMES = {"seed": 3, "frames": {"characters": 1, "motions": ["walk", "wave", "jump"], "clips_per_cell": 1,
                                "frames": 5, "size": 96, "keyframe_every": 4, "control_points": 4},
          "roto": TRACK}


def test_an_unreadable_annotation_fails_its_clip_alone(tmp_path):
    from nnsf.frames.stage import render_frames
    from nnsf.io import read_json
    from nnsf.roto.stage import track_clips

    frames = tmp_path / "frames"
    render_frames(FRAMES, frames)
    clips = list(pd.read_csv(frames / "index.csv")["clip"])
    (frames / clips[0] / "annotation.json").write_bytes(b'{"version": 1, "clip": "\xff\xfe"}')
    (frames / clips[1] / "annotation.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(InputError) as err:
        track_clips(FRAMES, frames, tmp_path / "tracks")
    msg = str(err.value)
    assert f"{clips[0]}/annotation.json: line 1: expected a JSON file in UTF-8" in msg
    assert f"{clips[1]}/annotation.json: file: expected JSON nested at most" in msg
    assert (tmp_path / "tracks" / clips[2] / "curves.npz").is_file()
    assert sorted(read_json(tmp_path / "tracks" / "failed.json")) == sorted(clips[:2])


def test_json_reader_names_the_file_for_every_failure(tmp_path):
    from nnsf.io import read_json

    locked = tmp_path / "locked.json"
    locked.write_text("{}")
    locked.chmod(0)
    big = tmp_path / "big.json"
    with open(big, "wb") as fh:              # sparse: 70 MB long, nothing on disk
        fh.truncate(70_000_000)
    for path, words in ((tmp_path / "deep.json", "nested"), (big, "file size")):
        if path.name == "deep.json":
            path.write_text('{"a": ' + "[" * 50000 + "]" * 50000 + "}")
        with pytest.raises(InputError, match=words) as err:
            read_json(path)
        assert str(err.value).startswith(str(path))
    if os.geteuid() != 0:                    # root reads anything: no permission error to see
        with pytest.raises(InputError, match="Permission denied"):
            read_json(locked)


# --------------------------------------------------------------------------- 7. BVH symlinks

def test_a_bvh_link_leaving_the_dataset_folder_is_refused(tmp_path):
    from test_bvh import _tiny_human

    from nnsf.datasets.bvh_source import read_folder

    folder = tmp_path / "clips"
    folder.mkdir()
    for motion in ("walk", "run"):
        for style in ("happy", "sad"):
            (folder / f"ds_{motion}_{style}_001.bvh").write_text(_tiny_human())
    outside = tmp_path / "secret" / "capture.bvh"
    outside.parent.mkdir()
    outside.write_text(_tiny_human())
    (folder / "ds_jump_happy_001.bvh").symlink_to(outside)
    inside = folder / "sub"
    inside.mkdir()
    (inside / "ok.bvh").write_text(_tiny_human())
    (folder / "ds_jump_sad_001.bvh").symlink_to(inside / "ok.bvh")     # a link that stays inside: read
    table, report = read_folder(folder, fps=15)
    assert "ds_jump_happy_001" not in set(table["clip"])
    assert "ds_jump_sad_001" in set(table["clip"]) and "ds_walk_happy_001" in set(table["clip"])
    assert any("ds_jump_happy_001.bvh: file: expected a .bvh file inside the dataset folder" in line
               for line in report), report
    os.unlink(folder / "ds_jump_sad_001.bvh")
    for p in folder.glob("ds_*_00*.bvh"):
        if not p.is_symlink():
            p.unlink()
    with pytest.raises(InputError, match="inside the dataset folder"):
        read_folder(folder)


# --------------------------------------------------------------------------- 6. degenerate data

@pytest.fixture(scope="module")
def features_csv(tmp_path_factory) -> Path:
    from nnsf import stages

    root = tmp_path_factory.mktemp("hardening-features")
    params = with_value("dataset.synthetic.characters", 2)
    params["dataset"]["synthetic"].update(clips_per_cell=2, frames=6)
    stages.data(params, out_dir=root / "raw")
    stages.features(params, raw_dir=root / "raw", out_dir=root / "features")
    return root / "features" / "features.csv"


def _small_evaluate() -> dict:
    p = copy.deepcopy(BASE)
    p["evaluate"].update(ranks=[2], methods=["nnsf", "nmf"], folds=2, max_iter=5)
    p["nnsf"]["rank"] = 2
    return p


@pytest.mark.parametrize("keep, words", [
    ({"motion": ["walk"]}, "motion: expected at least 2 distinct motion values (nnsf.label: motion)"),
    ({"clip": "first"}, "clip: expected at least 2 distinct clip values"),
])
def test_evaluate_refuses_a_single_class_or_clip(tmp_path, features_csv, keep, words):
    from nnsf import stages
    from nnsf.datasets import contract

    table = contract.read_table(features_csv)
    if "motion" in keep:
        table = table[table["motion"].isin(keep["motion"])]
    else:
        table = table[table["clip"] == table["clip"].iloc[0]]
    path = tmp_path / "features.csv"
    contract.write_table(path, table)
    with pytest.raises(InputError) as err:
        stages.evaluate(Params(_small_evaluate()), features_csv=path, reports=tmp_path / "reports")
    assert str(err.value).startswith(f"{path}: {words}"), str(err.value)
    assert not (tmp_path / "reports").exists()
    with pytest.raises(InputError, match=words.split(" (")[0]):
        stages.sweep_point(Params(_small_evaluate()), {"alpha": 0.01, "beta": 1.0, "rank": 2},
                           features_csv=path)


@pytest.mark.slow  # starts `nnsf` as a process
def test_evaluate_command_exits_2_on_a_single_class(tmp_path, features_csv):
    from nnsf.datasets import contract

    table = contract.read_table(features_csv)
    (tmp_path / "data" / "features").mkdir(parents=True)
    contract.write_table(tmp_path / "data" / "features" / "features.csv", table[table["motion"] == "walk"])
    write_params(tmp_path / "params.yaml", _small_evaluate())
    line = one_error_line(nnsf("evaluate", cwd=tmp_path))
    assert "data/features/features.csv: motion: expected at least 2 distinct motion values" in line
    assert not (tmp_path / "reports" / "metrics.json").exists()


# --------------------------------------------------------------------------- 9. disk full

@pytest.mark.slow  # starts `nnsf` as a process
def test_a_write_past_the_file_size_limit_names_the_file(tmp_path):
    """A real write failure (EFBIG from RLIMIT_FSIZE) in the ``nnsf data`` command: one line, exit 2."""
    p = with_value("dataset.synthetic.characters", 2)
    p["dataset"]["synthetic"].update(clips_per_cell=1, frames=8)
    write_params(tmp_path / "params.yaml", p)

    def limit():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)   # the write then fails with EFBIG
        resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))

    line = one_error_line(nnsf("data", cwd=tmp_path, preexec_fn=limit))
    assert line.startswith("error: data/raw/keypoints.csv: write: expected a file size the system allows"), line
    assert "EFBIG" in line
    assert not (tmp_path / "data" / "raw").exists()
    assert not any(p.name.startswith(".raw.") for p in (tmp_path / "data").iterdir())


@pytest.fixture
def tiny_disk(tmp_path):
    """A 64 KB tmpfs mounted for the test (needs root; skipped otherwise)."""
    mnt = tmp_path / "tiny"
    mnt.mkdir()
    res = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mnt)],
                         capture_output=True, text=True)
    if res.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here ({res.stderr.strip() or res.returncode})")
    try:
        yield mnt
    finally:
        subprocess.run(["umount", str(mnt)], capture_output=True)


@pytest.mark.slow  # starts `mount` as a process
def test_disk_full_names_the_file(tiny_disk):
    from nnsf.io import write_json

    with pytest.raises(InputError) as err:          # nnsf.io.WriteError, an InputError
        write_json(tiny_disk / "reports" / "big.json", {"x": "y" * 200_000})
    msg = str(err.value)
    assert msg.startswith(f"{tiny_disk}/reports/big.json: write: expected free space on its disk")
    assert "ENOSPC" in msg
    assert not list((tiny_disk / "reports").iterdir())        # no temporary left behind
    write_params(tiny_disk / "params.yaml", with_value("dataset.synthetic.characters", 2))
    line = one_error_line(nnsf("data", cwd=tiny_disk))
    assert line.startswith("error: data/raw/keypoints.csv: write: expected free space on its disk"), line
