"""Hostile and careless input: no hang, no silent typo, one bad file fails alone, nothing runs or escapes.

One test (or a few) per class of the bad-input probes:
1 alias bomb, 2 unreadable annotation, 3 misspelt keys, 4 infinite/absurd
values, 5 the params file named, 6 degenerate data, 7 BVH symlinks, 8 error
reasons kept, 9 disk full.  Class 10 (a killed evaluate) is in
test_hardening_publish.py.  Round two: 11 a model file is data (no code named
in it runs; every field by its schema), 12 ids are names, never paths (every
writer; links resolved; ``nnsf check`` = the stages), 13 bounds before
allocation (YAML, npz headers, image headers), 14 tracking-server faults
(closed ports, a locked or corrupt mlflow.db), 15 no silent drops (CVAT
corrections), 16 one line on stderr (decoders' messages).  Everything runs
real code on real files, real servers' absence and real locks; disk full is a
real kernel error (a tiny tmpfs, or RLIMIT_FSIZE).
"""
from __future__ import annotations

import copy
import json
import os
import re
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
    # Refused by the YAML reader itself, before any value is built, naming the key it is under.
    assert message.startswith(f"{path}: evaluate.ranks: expected YAML of at most"), message
    assert "once its aliases are expanded" in message and len(message) < 400
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
    from nnsf.reshape.stage import stage_params as _params

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
    from nnsf.reshape.stage import stage_params as _params

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
    for k, (motion, style) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (folder / f"ds_{motion}_{style}_001.bvh").write_text(_tiny_human(variant=k + 1))
    outside = tmp_path / "secret" / "capture.bvh"
    outside.parent.mkdir()
    outside.write_text(_tiny_human(variant=7))
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


# =========================================================================== round two
# 11 a model file is data, 12 ids are names, 13 bounds before allocation, 14 tracking-server
# faults, 15 no silent drops, 16 one line on stderr.

def _assert_one_line(code: int, err: str, *needles: str) -> str:
    """In-process twin of :func:`one_error_line` (``nnsf.cli.main`` and captured stderr)."""
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])
    return lines[0]


# --------------------------------------------------------------------------- 11. a model file is data
@pytest.fixture(scope="module")
def style_model(tmp_path_factory) -> Path:
    from nnsf.datasets import contract, synthetic
    from nnsf.factor.style_model import fit_model, unify_table

    raw = contract.validate(synthetic.generate(characters=2, clips_per_cell=1, frames=12, seed=0), "syn")
    raw = raw[raw["motion"].isin(["walk", "wave"])].reset_index(drop=True)
    table, unifier = unify_table(raw, 0.5)
    path = tmp_path_factory.mktemp("model") / "styles.npz"
    fit_model([(None, table, unifier)], dict(n_components=3, max_iter=20, align_iter=5, random_state=0), path)
    return path


def _rewrite_model(src: Path, out: Path, change) -> Path:
    """A copy of a model file with ``change(meta, arrays)`` applied (a hostile or damaged file)."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"][()]))
    change(meta, arrays)
    arrays["meta"] = np.array(json.dumps(meta))
    np.savez(out, **arrays)
    return out


def _json_spec(value):
    return {"kind": "json", "value": value}


def _code_running_payload(target: Path) -> dict:
    """The estimator spec of the hostile file: ``nnsf.io.write_json(path=target, obj={})`` if the class were imported."""
    return {"kind": "estimator", "class": "nnsf.io.write_json",
            "params": {"kind": "dict", "items": [["path", _json_spec(str(target))],
                                                 ["obj", {"kind": "dict", "items": []}]]},
            "attrs": {}}


def test_a_model_naming_code_to_run_is_refused_and_writes_nothing(style_model, tmp_path, capsys, monkeypatch):
    from nnsf.cli import main

    target = tmp_path / "written-by-the-model.json"
    for where in ("nested", "top"):
        def change(meta, arrays, where=where):
            if where == "nested":
                meta["views"][0]["state"]["nnsf_"] = _code_running_payload(target)
            else:
                meta["class"] = "nnsf.io.write_json"
        bad = _rewrite_model(style_model, tmp_path / f"{where}.npz", change)
        monkeypatch.chdir(tmp_path)
        code = main(["animate", "--character", "pip", "--motion", "synthetic:ollie/walk/6", "--style", "bruno",
                     "--model", str(bad), "--out", str(tmp_path / "out.gif")])
        field = "meta.views[0].state.nnsf_.class" if where == "nested" else "meta.class"
        _assert_one_line(code, capsys.readouterr().err, str(bad), field, "nnsf.io.write_json")
        assert not target.exists() and not (tmp_path / "out.gif").exists()
        assert not list(tmp_path.glob("*.gif")) and not list(tmp_path.glob(".out*"))


@pytest.mark.parametrize("case, field", [
    ("unknown attribute", "meta.views[0].state.evil_: expected a fitted attribute of StyleTranslator"),
    ("unknown parameter", "meta.views[0].params.path: expected a parameter of StyleTranslator"),
    ("nested unknown parameter", "meta.views[0].state.nnsf_.params.fit: expected a parameter of NNSF"),
    ("bad parameter value", "meta.views[0].params: expected parameters StyleTranslator accepts"),
    ("wrong kind", "meta.views[0].state.styles_: expected an encoded array"),
    ("wrong shape", "meta.views[0].state.style_bases_.bruno (array a"),
    ("array used twice", "expected an array referred to once"),
    ("unreferenced array", "array a999: expected an array the model's metadata refers to"),
    ("unknown meta field", "meta.run_this: expected one of the fields format, version"),
    ("style keys", "meta.views[0].state.style_offsets_: expected keys that are exactly the styles"),
    ("infinite basis", "values are NaN or infinite"),
    ("deep nesting", "meta.views[0].state.clips_.bruno|walk[0]: expected an encoded array, got 'list'"),
    ("meta styles", "meta.styles: expected the styles of meta.views[0].state.styles_"),
    ("unifier", "meta.views[0].unifier.offset: expected a list of 2 to 2 items"),
    ("row index", "meta.views[0].state.frame_rows_ (array a"),
    ("atom count", "meta.views[0].state.nnsf_.attrs.n_components_: expected n_components = 3"),
    ("two-line view", 'meta.views[0].view: expected a string of at most 100 printable characters, got "side\\n'),
])
def test_every_field_of_a_model_file_is_checked_against_its_schema(style_model, tmp_path, case, field):
    from nnsf.factor.style_model import StyleModel

    def key(meta, attr, label):
        return dict(meta["views"][0]["state"][attr]["items"])[label]["key"]

    def change(meta, arrays):
        state = meta["views"][0]["state"]
        if case == "unknown attribute":
            state["evil_"] = _json_spec(1)
        elif case == "unknown parameter":
            meta["views"][0]["params"]["items"].append(["path", _json_spec("/tmp/x")])
        elif case == "nested unknown parameter":
            state["nnsf_"]["params"]["items"].append(["fit", _json_spec(1)])
        elif case == "bad parameter value":
            meta["views"][0]["params"]["items"] = [[k, _json_spec("bogus") if k == "basis" else v]
                                       for k, v in meta["views"][0]["params"]["items"]]
        elif case == "wrong kind":
            state["styles_"] = _json_spec(["bruno"])
        elif case == "wrong shape":
            arrays[key(meta, "style_bases_", "bruno")] = np.zeros((5, 34))
        elif case == "array used twice":
            state["style_offsets_"]["items"][1][1]["key"] = key(meta, "style_offsets_", "bruno")
        elif case == "unreferenced array":
            arrays["a999"] = np.zeros(3)
        elif case == "unknown meta field":
            meta["run_this"] = "nnsf.cli.main"
        elif case == "style keys":
            state["style_offsets_"]["items"][1][0] = "someone-else"
        elif case == "infinite basis":
            k = key(meta, "style_bases_", "bruno")
            arrays[k] = np.full_like(arrays[k], np.inf)
        elif case == "deep nesting":
            spec = _json_spec(1.0)
            for _ in range(40):
                spec = {"kind": "list", "items": [spec]}
            state["clips_"]["items"][0][1] = spec
        elif case == "meta styles":
            meta["styles"] = ["bruno", "mallory"]
        elif case == "unifier":
            meta["views"][0]["unifier"]["offset"] = [0.0] * 1000
        elif case == "row index":
            arrays[state["frame_rows_"]["key"]][0] = 10**6       # a row the shared weights do not have
        elif case == "two-line view":
            meta["views"][0]["view"] = "side\nerror: a line of the model's own"
        elif case == "atom count":
            state["nnsf_"]["attrs"]["n_components_"] = {"kind": "json", "value": 7, "type": "int"}
    bad = _rewrite_model(style_model, tmp_path / "bad.npz", change)
    with pytest.raises(InputError) as err:
        StyleModel.load(bad)
    assert str(err.value).startswith(f"{bad}: ") and field in str(err.value), str(err.value)
    assert "\n" not in str(err.value)


def test_an_npz_header_is_checked_before_anything_is_allocated(tmp_path):
    """A member whose header claims 8 TB (or holds Python objects) is refused from the header alone."""
    import zipfile

    from nnsf.io import read_npz

    header = np.lib.format.header_data_from_array_1_0(np.zeros(3))
    header["shape"] = (10**12,)
    buf = __import__("io").BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    path = tmp_path / "liar.npz"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("U.npy", buf.getvalue() + np.zeros(3).tobytes())
    with pytest.raises(InputError, match=r"liar\.npz: U: expected the 8000000000000 data bytes its header"):
        read_npz(path)
    objects = tmp_path / "objects.npz"
    np.savez(objects, x=np.array([{"a": 1}], dtype=object))
    with pytest.raises(InputError, match=r"objects\.npz: x: expected an array without Python objects"):
        read_npz(objects)
    from nnsf.roto.tracks import TRACKS

    strange = tmp_path / "curves.npz"
    np.savez(strange, control=np.zeros((3, 2, 4, 2)), curve_names=np.array(["a.a", "a.b", "c.a"]))
    with pytest.raises(InputError, match=r"curves\.npz: curve_names: expected a unicode string array of "
                                         r"shape \(C\) with C = 2"):
        read_npz(strange, TRACKS)
    np.savez(strange, control=np.zeros((3, 2, 4, 2)), curve_names=np.array(["a.a", "a.b"]), run=np.zeros(1))
    with pytest.raises(InputError, match=r"curves\.npz: run: expected only the arrays control, curve_names"):
        read_npz(strange, TRACKS)


def test_saving_an_attribute_the_schema_lacks_is_refused_before_writing(style_model, tmp_path):
    from nnsf.factor.translate import StyleTranslator

    tr = StyleTranslator.load(style_model)
    tr.brand_new_ = np.zeros(3)
    with pytest.raises(TypeError, match=r"StyleTranslator\.brand_new_ has no entry in "
                                        r"nnsf\.factor\.model_file\.STATE"):
        tr.save(tmp_path / "m.npz")
    assert not list(tmp_path.iterdir())


# --------------------------------------------------------------------------- 12. ids are names, never paths
@pytest.mark.parametrize("name, ok", [
    ("bruno-walk-00", True), ("dataset-1_walk_normal_001", True), ("Ünïcode clip (2)", True),
    ("../../../../x", False), ("..", False), (".hidden", False), ("a/b", False), ("a\\b", False),
    ("-rf", False), ("x" * 101, False), ("", False), ("nul", False), ("COM1.txt", False), ("tab\there", False),
    ("trailing.", False), (3, False),
])
def test_an_id_becomes_a_file_name_only_if_it_is_a_safe_name(name, ok):
    from nnsf.names import safe_name

    if ok:
        assert safe_name(name, "f.csv", "clip") == name
    else:
        with pytest.raises(InputError, match=r"^f\.csv: clip: expected a name of 1 to 100 letters"):
            safe_name(name, "f.csv", "clip")


@pytest.fixture(scope="module")
def tracked_project(tmp_path_factory) -> Path:
    """A project folder with rendered and tracked frames (two short clips)."""
    from nnsf.frames.stage import render_frames
    from nnsf.roto.stage import track_clips

    root = tmp_path_factory.mktemp("ids")
    params = copy.deepcopy(BASE)
    params["frames"].update(characters=1, motions=["walk", "wave"], clips_per_cell=1, frames=5, size=96,
                            keyframe_every=4, control_points=4)
    params["roto"].update(TRACK)
    (root / "params.yaml").write_text(yaml.safe_dump(params))
    render_frames(params, root / "data" / "frames")
    track_clips(params, root / "data" / "frames", root / "data" / "tracks")
    return root


def _escaping_copy(project: Path, dest: Path, clip_id: str = "../../../../x") -> Path:
    """A copy of ``project`` whose first clip id (index.csv and annotation.json) is ``clip_id``."""
    import shutil

    shutil.copytree(project, dest)
    frames = dest / "data" / "frames"
    index = pd.read_csv(frames / "index.csv", dtype=str, keep_default_na=False)
    first = index.loc[0, "clip"]
    index.loc[0, "clip"] = clip_id
    index.to_csv(frames / "index.csv", index=False)
    ann = json.loads((frames / first / "annotation.json").read_text())
    ann["clip"] = clip_id
    (frames / first / "annotation.json").write_text(json.dumps(ann))
    return dest


def _files(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("args", [["roto"], ["roto", "--export-cvat", "cvat"],
                                  ["roto", "--corrections", "cvat/any.xml", "--clip", "../../../../x"]])
def test_a_path_escaping_clip_id_is_refused_by_every_writer(tracked_project, tmp_path, monkeypatch, capsys, args):
    from nnsf.cli import main

    work = _escaping_copy(tracked_project, tmp_path / "deep" / "er" / "p")
    (work / "cvat").mkdir()
    (work / "cvat" / "any.xml").write_text("<annotations><version>1.1</version></annotations>")
    before = _files(tmp_path)
    monkeypatch.chdir(work)
    code = main([str(a) for a in args])
    _assert_one_line(code, capsys.readouterr().err, "data/frames/index.csv: clip (row 1): expected a name",
                     "'../../../../x'")
    assert _files(tmp_path) == before                   # nothing written anywhere, inside or out
    assert not (tmp_path / "x").exists() and not (tmp_path / "x.xml").exists()


def test_a_clip_folder_linked_out_of_the_project_is_refused(tracked_project, tmp_path):
    """The writers resolve links: a tracks/<clip> or a frames/<clip> that is a link to elsewhere is refused."""
    import shutil

    from nnsf.roto.correct import export_clips
    from nnsf.frames.clips import read_index

    work = tmp_path / "p"
    shutil.copytree(tracked_project, work)
    clip = sorted(p.name for p in (work / "data" / "tracks").iterdir() if p.is_dir())[0]
    outside = tmp_path / "outside"
    shutil.move(work / "data" / "tracks" / clip, outside)
    (work / "data" / "tracks" / clip).symlink_to(outside)
    with pytest.raises(InputError, match=r"index\.csv: clip: expected a path that stays inside .*tracks "
                                         r"\(symbolic links resolved\)"):
        export_clips(work / "data" / "frames", work / "data" / "tracks", work / "cvat")
    frames = work / "data" / "frames"
    shutil.move(frames / clip, tmp_path / "frames-outside")
    (frames / clip).symlink_to(tmp_path / "frames-outside")
    with pytest.raises(InputError, match=r"index\.csv: folder \(row 1\): expected a folder inside the frame set"):
        read_index(frames)


def test_the_reshape_outputs_are_named_by_safe_names_before_any_work(tmp_path):
    from nnsf import stages
    from nnsf.datasets import contract, synthetic

    table = contract.validate(synthetic.generate(characters=2, clips_per_cell=1, frames=4, seed=0), "syn")
    table = table[table["clip"] == table["clip"].iloc[0]].assign(clip="../../../../x")
    motion = tmp_path / "motion.csv"
    contract.write_table(motion, table)
    with pytest.raises(InputError, match=rf"^{motion}: clip: expected a name"):
        stages.reshape(Params(with_value("reshape.character", "bruno")), motion_csv=motion,
                       out_dir=tmp_path / "out")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["motion.csv"]


@pytest.mark.parametrize("key, value", [
    ("animate.character", "../../../../etc"), ("animate.motion", "/etc/passwd"),
    ("reshape.character", "chars/../../etc/x.json"), ("reshape.clip", "../x"),
    ("reshape_eval.characters", ["char1", "../../etc"]),
    ("frames.motions", ["walk", "moonwalk"]),                     # checked against the generator
    ("translation.basis", "refit"),                               # consensus needs the aligned basis
    ("reshape.subkeys_per_limb", 0),                              # method ours needs subkeys
])
def test_nnsf_check_applies_the_stages_rules(tmp_path, monkeypatch, capsys, key, value):
    from nnsf.cli import main

    monkeypatch.chdir(tmp_path)
    path = write_params(tmp_path / "p.yaml", with_value(key, value))
    field = {"translation.basis": "translation.synthesis"}.get(key, key)
    _assert_one_line(main(["check", "--params", str(path)]), capsys.readouterr().err, f"{path}: {field}: expected")


def test_a_params_path_is_checked_after_resolving_links(tmp_path, monkeypatch, capsys):
    """``animate.character: mine/c.json`` whose folder links out of the project: refused by check and stage alike."""
    from nnsf import stages
    from nnsf.cli import main

    project = tmp_path / "project"
    (project / "models").mkdir(parents=True)
    (tmp_path / "elsewhere").mkdir()
    (project / "mine").symlink_to(tmp_path / "elsewhere")
    (project / "link").symlink_to(tmp_path / "elsewhere")
    monkeypatch.chdir(project)
    for value in ("mine/c.json", "link"):
        path = write_params(project / "params.yaml", with_value("animate.character", value))
        line = _assert_one_line(main(["check"]), capsys.readouterr().err, "params.yaml: animate.character")
        with pytest.raises(InputError) as err:
            stages.animate(load("params.yaml"), model=project / "models" / "styles.npz", out_dir=project / "out")
        assert line == f"error: {err.value}"
    assert sorted(p.name for p in project.iterdir()) == ["link", "mine", "models", "params.yaml"]


# --------------------------------------------------------------------------- 13. bounds before allocation
def _ad_folder(folder: Path, loc: str) -> Path:
    """An AnimatedDrawings folder whose first joint's ``loc`` is the YAML text ``loc``."""
    folder.mkdir(parents=True)
    img = np.zeros((64, 64, 4), np.uint8)
    img[8:56, 8:56] = 255
    import cv2

    cv2.imwrite(str(folder / "texture.png"), img)
    cv2.imwrite(str(folder / "mask.png"), img[..., 3])
    (folder / "char_cfg.yaml").write_text(f"width: 64\nheight: 64\nskeleton:\n  - name: root\n    loc: {loc}\n"
                                          "    parent: null\n")
    return folder


def test_an_alias_bomb_in_char_cfg_is_one_line_in_under_a_second(tmp_path, capsys):
    from time import perf_counter

    from nnsf.cli import main
    from nnsf.reshape.formats import read_character

    folder = _ad_folder(tmp_path / "bomb", _bomb_value())
    assert (folder / "char_cfg.yaml").stat().st_size < 1500
    started = perf_counter()
    with pytest.raises(InputError) as err:
        read_character(folder)
    seconds = perf_counter() - started
    assert seconds < 1.0, seconds
    assert str(err.value).startswith(f"{folder}/char_cfg.yaml: skeleton[0].loc: expected YAML of at most")
    code = main(["animate", "--character", str(folder), "--motion", "synthetic:ollie/walk/6",
                 "--out", str(tmp_path / "a.gif")])
    _assert_one_line(code, capsys.readouterr().err, "char_cfg.yaml: skeleton[0].loc")
    assert not (tmp_path / "a.gif").exists()


@pytest.mark.parametrize("text, words", [
    ("a: &x [1, *x]\n", "line 1: expected YAML without an alias inside its own anchor"),
    ("a0: &a0 {k: 1}\n" + "".join(f"a{i}: &a{i} {{<<: [{', '.join([f'*a{i - 1}'] * 9)}]}}\n"
                                  for i in range(1, 10)), "<<: expected YAML of at most"),
    ("a: " + "[" * 200 + "]" * 200 + "\n", "line 1: expected YAML nested at most 64 levels deep"),
    ("a: !!python/object/apply:os.system ['true']\n", "expected YAML without tags that build Python objects"),
    ("a: " + "1" * 5000 + "\n", "line 1: expected valid YAML values (ValueError: Exceeds the limit"),
    ("a:\n  when: 2001-13-45\n", "line 2: expected valid YAML values (ValueError: month must be in 1..12)"),
])
def test_yaml_that_would_expand_recurse_or_build_objects_is_refused_at_once(tmp_path, text, words):
    from nnsf.io import read_yaml

    path = tmp_path / "joints.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=re.escape(words)) as err:
        read_yaml(path)
    assert str(err.value).startswith(f"{path}: ")


def test_a_json_number_python_will_not_convert_is_one_line(tmp_path):
    from nnsf.io import read_json

    path = tmp_path / "unifier.json"
    path.write_text('{"margin": ' + "1" * 5000 + "}")
    with pytest.raises(InputError, match=r"unifier\.json: file: expected valid JSON numbers \(Exceeds the limit"):
        read_json(path)


# --------------------------------------------------------------------------- 14. tracking-server faults
def _closed_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]          # closed again when the socket is


@pytest.fixture
def flows_project(tmp_path, mlflow_template):
    from conftest import new_project

    root, env = new_project(tmp_path / "project", mlflow_template, None)
    env["NNSF_TRACKING_TIMEOUT"] = "3"
    return root, env


@pytest.mark.slow  # runs `python -m flows` as a process
@pytest.mark.parametrize("fault, needle", [
    ("mlflow port", "error: MLFLOW_TRACKING_URI: http://127.0.0.1:"),
    ("prefect port", "error: PREFECT_API_URL: http://127.0.0.1:"),
    ("locked db", "mlflow.db: file: expected an MLflow sqlite store"),
    ("corrupt db", "mlflow.db: file: expected an MLflow sqlite store"),
])
def test_a_tracking_fault_is_one_line_before_the_stage_works(flows_project, fault, needle):
    import sqlite3
    import time

    root, env = flows_project
    db = Path(env["MLFLOW_TRACKING_URI"][len("sqlite:///"):])
    lock = None
    if fault == "mlflow port":
        env["MLFLOW_TRACKING_URI"] = f"http://127.0.0.1:{_closed_port()}"
    elif fault == "prefect port":
        env["PREFECT_API_URL"] = f"http://127.0.0.1:{_closed_port()}/api"
    elif fault == "locked db":
        lock = sqlite3.connect(db)
        lock.execute("BEGIN EXCLUSIVE")
    else:
        db.write_bytes(b"this is not a database" * 100)
    started = time.perf_counter()
    try:
        res = subprocess.run([sys.executable, "-m", "flows", "data"], cwd=root, env=env, capture_output=True,
                             text=True, timeout=120)
    finally:
        if lock is not None:
            lock.close()
    seconds = time.perf_counter() - started
    line = one_error_line(res)
    assert needle in line and ("mlflow.db" not in needle or str(db) in line), line
    assert seconds < 10, seconds
    assert not (root / "data").exists()                # no work done, nothing written


def test_a_store_failing_after_the_work_names_it_and_what_was_kept(tmp_path, monkeypatch):
    from flows.mlflow_runs import ExperimentLog
    from flows.tracking import recorded

    db = tmp_path / "mlflow.db"
    db.write_bytes(b"not a database" * 100)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{db}")
    with pytest.raises(InputError) as err:
        with recorded("features", [Path("data/features/features.csv")]):
            ExperimentLog("nnsf", root=tmp_path)
    msg = str(err.value)
    assert msg.startswith(f"{db}: run: expected the features stage's MLflow run recorded; its outputs were "
                          "written and are kept (data/features/features.csv)"), msg


def test_the_tracking_timeout_setting_is_checked(monkeypatch):
    from flows import tracking

    monkeypatch.setenv("NNSF_TRACKING_TIMEOUT", "forever")
    with pytest.raises(InputError, match="environment: NNSF_TRACKING_TIMEOUT: expected a number of seconds"):
        tracking.timeout()
    monkeypatch.setenv("NNSF_TRACKING_TIMEOUT", "2.5")
    assert tracking.timeout() == 2.5


# --------------------------------------------------------------------------- 15. no silent drops
def _cvat_file(project: Path, tmp_path: Path, change) -> tuple[Path, str]:
    import xml.etree.ElementTree as ET

    from nnsf.roto.correct import export_clips

    written = export_clips(project / "data" / "frames", project / "data" / "tracks", tmp_path / "cvat")
    path = written[0]
    tree = ET.parse(path)
    change(tree.getroot())
    tree.write(path, encoding="utf-8", xml_declaration=True)
    return path, path.stem


def _as_images_export(root):
    import xml.etree.ElementTree as ET

    for track in root.findall("track"):
        root.remove(track)
    image = ET.SubElement(root, "image", id="0", name="frame_0000.png", width="96", height="96")
    ET.SubElement(image, "polyline", label="l_forearm.a", points="1,2;3,4", occluded="0")


def _duplicate_label(root):
    tracks = root.findall("track")
    tracks[1].set("label", tracks[0].get("label"))


def _no_polyline(root):
    track = root.find("track")
    for shape in list(track):
        track.remove(shape)


def _all_outside(root):
    for shape in root.iter("polyline"):
        shape.set("outside", "1")


@pytest.mark.parametrize("change, words", [
    (_as_images_export, '<image>: expected a CVAT for video 1.1 export (<track> elements); this is a "CVAT '
                        'for images" export'),
    (lambda root: [root.remove(t) for t in root.findall("track")], "<track>: expected at least one <track>"),
    (_duplicate_label, "track id=1 label: expected each curve in one track; track id=0 has this label too"),
    (_no_polyline, "track id=0 label='"),
    (_all_outside, '<polyline>: expected at least one polyline inside the frame (outside="0")'),
])
def test_corrections_that_match_nothing_are_an_error(tracked_project, tmp_path, monkeypatch, capsys, change,
                                                     words):
    import shutil

    from nnsf.cli import main

    work = tmp_path / "p"
    shutil.copytree(tracked_project, work)
    xml, clip = _cvat_file(work, tmp_path, change)
    before = _files(work)
    monkeypatch.chdir(work)
    code = main(["roto", "--corrections", str(xml), "--clip", clip])
    _assert_one_line(code, capsys.readouterr().err, f"{xml}: ", words)
    assert _files(work) == before


def test_the_cvat_importer_refuses_two_tracks_of_one_label(tracked_project, tmp_path):
    from nnsf.frames.cvat import read_cvat_video

    xml, _ = _cvat_file(tracked_project, tmp_path, _duplicate_label)
    with pytest.raises(InputError, match=r"track id=1 label: expected each label in one track; track id=0 has"):
        read_cvat_video(xml)


# --------------------------------------------------------------------------- 16. one line on stderr
def _png_chunk(kind: bytes, body: bytes) -> bytes:
    import struct
    import zlib

    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def _huge_png() -> bytes:
    """A 200-byte PNG whose header claims 20000 x 20000 RGB pixels."""
    import struct
    import zlib

    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0))
            + _png_chunk(b"IDAT", zlib.compress(b"\0" * 4000)) + _png_chunk(b"IEND", b""))


def _bad_deflate_png(width: int, height: int) -> bytes:
    """A PNG whose chunks are intact (CRCs right) but whose image data is not zlib: libpng's own error."""
    import struct

    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + _png_chunk(b"IDAT", b"not deflate data") + _png_chunk(b"IEND", b""))


@pytest.mark.parametrize("damage, words", [
    ("huge", "frames[2]: expected a PNG of at most 100000000 pixels (header checked before decoding), "
             "got '20000x20000'"),
    ("truncated", "frames[2]: expected a complete PNG file (ending in an IEND chunk) (truncated"),
    ("deflate", "frames[2]: expected an image OpenCV can decode (PNG, JPEG, ...)"),
])
def test_a_damaged_frame_is_exactly_one_line_on_stderr(tracked_project, tmp_path, monkeypatch, capfd, damage,
                                                       words):
    import shutil

    from nnsf.cli import main

    work = tmp_path / "p"
    shutil.copytree(tracked_project, work)
    clip = sorted(p for p in (work / "data" / "frames").iterdir() if p.is_dir())[0]
    frame = clip / "frame_0002.png"
    data = frame.read_bytes()
    frame.write_bytes({"huge": _huge_png(), "truncated": data[: len(data) // 2],
                       "deflate": _bad_deflate_png(96, 96)}[damage])
    monkeypatch.chdir(work)
    capfd.readouterr()
    code = main(["roto"])
    out, err = capfd.readouterr()                      # file descriptor 2: libpng writes there, not sys.stderr
    line = _assert_one_line(code, err, str(frame.relative_to(work)), words)
    assert "libpng" not in err.split(words)[0]
    if damage == "deflate":
        assert "IDAT" in line                          # the decoder's message, as the reason
    assert not (work / "data" / "tracks").exists() or (work / "data" / "tracks" / "failed.json").is_file()


@pytest.mark.slow  # a fresh process: OpenCV reads its pixel bound when cv2 is first imported
def test_any_format_claiming_a_huge_size_is_refused_from_its_header(tmp_path):
    """A 600-byte JPEG whose header says 20000 x 20000: refused at once, not 1.2 GB decoded in 9 s."""
    code = textwrap.dedent("""
        import sys, time
        from nnsf.io import read_image
        from nnsf.errors import InputError
        t = time.perf_counter()
        try:
            read_image(sys.argv[1], "frames[0]")
        except InputError as e:
            print(time.perf_counter() - t)
            print(e)
        """)
    import cv2

    ok, buf = cv2.imencode(".jpg", np.zeros((8, 8, 3), np.uint8))
    data = bytearray(buf.tobytes())
    sof = data.find(b"\xff\xc0")
    data[sof + 5:sof + 9] = (20000).to_bytes(2, "big") * 2
    path = tmp_path / "huge.jpg"
    path.write_bytes(bytes(data))
    res = subprocess.run([sys.executable, "-c", code, str(path)], env=_env(), capture_output=True, text=True,
                         timeout=60)
    seconds, message = res.stdout.splitlines()[:2]
    assert float(seconds) < 1.0 and res.stderr == "", (seconds, res.stderr)
    assert message.startswith(f"{path}: frames[0]: expected an image of at most 100000000 pixels"), message


def test_the_cvat_importer_refuses_a_track_without_a_keyframe(tracked_project, tmp_path):
    """A curve annotated on no keyframe would silently vanish from the annotation: refused instead."""
    from nnsf.frames.cvat import read_cvat_video

    def unmark(root):
        for shape in root.find("track").iter("polyline"):
            shape.set("keyframe", "0")
    xml, _ = _cvat_file(tracked_project, tmp_path, unmark)
    with pytest.raises(InputError, match=r"track id=0 label='.*': expected at least one <polyline> with "
                                         r'keyframe="1" and outside="0"'):
        read_cvat_video(xml)


def test_decoder_messages_stay_off_stderr_from_several_threads(capfd):
    """Overlapping decodes share one redirection of descriptor 2, restored when the last ends."""
    from concurrent.futures import ThreadPoolExecutor

    from nnsf.io import decode_image

    def decode(i):
        try:
            decode_image(_bad_deflate_png(8, 8), f"f{i}.png")
        except InputError as exc:
            return str(exc)
    with ThreadPoolExecutor(4) as pool:
        messages = list(pool.map(decode, range(16)))
    assert all("libpng error" in m for m in messages), messages
    os.write(2, b"after\n")
    assert capfd.readouterr().err == "after\n"


def test_adding_a_fitted_field_is_adding_its_rule(style_model, tmp_path, monkeypatch):
    """A new attribute (here one translator per view, a nested estimator) saves and loads once
    STATE has its rule, and is checked like every other field."""
    from nnsf.factor import model_file
    from nnsf.factor.translate import StyleTranslator
    from nnsf.schema import Map, Optional

    tr = StyleTranslator.load(style_model)
    tr.per_view_ = {"side": StyleTranslator.load(style_model)}
    monkeypatch.setitem(model_file.STATE[model_file.TRANSLATOR], "per_view_",
                        Optional(Map(model_file.Estimator(model_file.TRANSLATOR))))
    back = StyleTranslator.load(tr.save(tmp_path / "views.npz"))
    assert np.array_equal(back.per_view_["side"].style_bases_["bruno"], tr.style_bases_["bruno"])
    bad = _rewrite_model(tmp_path / "views.npz", tmp_path / "bad.npz", lambda meta, arrays: meta["views"][0]["state"][
        "per_view_"]["items"][0][1].update({"class": "nnsf.cli.main"}))
    with pytest.raises(InputError, match=r"meta\.views\[0\]\.state\.per_view_\.side\.class: expected "
                                         r"'nnsf\.factor\.translate\.StyleTranslator'"):
        StyleTranslator.load(bad)
