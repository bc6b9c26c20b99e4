"""Hostile, broken and careless inputs on the user's commands: each class refused in one line, or read.

One test (or a few) per class of failure an input corpus found in ``nnsf bvh-info``,
``nnsf animate``, ``nnsf styles``, ``nnsf translate``/``reshape`` output folders, the
``results`` spec and the shared readers (YAML, JSON, images):

1 a BVH header's bounds checked before anything is allocated (nodes, hierarchy size,
  Frames x channels, Frame Time); 2 BVH text as editors write it (byte-order marks,
  UTF-16, CR line ends) read, control characters in names refused; 3 the motion block
  parsed in pieces and forward kinematics in blocks, same numbers; 4 library warnings
  kept off the error path; 5 a key given twice (YAML, JSON) refused; 6 option errors on
  one line; 7 a user's folder never swapped away, outputs never onto inputs; 8 ids
  from labels and aliases are safe names; 9 link loops are a line, not a crash;
  10 the results spec reads nothing outside reports/ and builds no giant cell;
  11 a full disk while writing frames names the frame.

Every case runs ``nnsf.cli.main`` in this process (or the reader it reaches) on real
files, and asserts exit 2, one ``error:`` line naming the file and the field, no
traceback and nothing written.
"""
from __future__ import annotations

import json
import os
import resource
import signal
import time
from pathlib import Path

import numpy as np
import pytest

from nnsf.errors import InputError

from test_bvh import _tiny_human
from test_hardening import _assert_one_line


def _one_line(code: int, err: str, *needles: str) -> str:
    """:func:`test_hardening._assert_one_line` on stderr without ``nnsf animate``'s progress lines."""
    return _assert_one_line(code, "\n".join(line for line in err.strip().splitlines()
                                             if not line.startswith("animate: ")), *needles)


def _run(capsys, *argv) -> tuple[int, str]:
    from nnsf.cli import main

    capsys.readouterr()
    code = main([str(a) for a in argv])
    return code, capsys.readouterr().err


def _human(frames: int = 12, variant: int = 0) -> str:
    """The tiny human of test_bvh with ``frames`` frames of a little motion."""
    text = _tiny_human(variant=variant)
    head, motion = text.split("MOTION\n")
    n = len(motion.strip().splitlines()[2].split())
    rows = []
    for f in range(frames):
        v = np.zeros(n)
        v[1], v[2], v[4], v[8] = 90.0, 3.0 * f, 5 * np.sin(f / 5 + variant), 20 * np.sin(f / 4)
        rows.append(" ".join(f"{x:g}" for x in v))
    return head + f"MOTION\nFrames: {frames}\nFrame Time: 0.0333333\n" + "\n".join(rows) + "\n"


# --------------------------------------------------------------------------- 1. BVH bounds before allocation
def _deep(n: int) -> str:
    out = ["HIERARCHY", "ROOT J0", "{", "OFFSET 0 0 0", "CHANNELS 3 Xposition Yposition Zposition"]
    for i in range(1, n):
        out += [f"JOINT J{i}", "{", "OFFSET 0 1 0", "CHANNELS 1 Zrotation"]
    out += ["}"] * n + ["MOTION", "Frames: 1", "Frame Time: 0.03", " ".join(["0"] * (n + 2))]
    return "\n".join(out) + "\n"


@pytest.mark.parametrize("case, field", [
    ("20000 nested joints", "expected a hierarchy of at most 10000 joints and End Sites"),
    ("a 12 MB hierarchy", "HIERARCHY: expected a hierarchy of at most 10000000 characters"),
    ("Frames: 10^8", "line 108: expected Frames x channels of at most 50000000 values"),
    ("Frame Time: 1e-300", "line 109: expected Frame Time: a number of seconds >= 0.0001"),
])
def test_a_bvh_header_is_bounded_before_anything_is_allocated(tmp_path, capsys, case, field):
    """Each is refused from the header in well under a second (before: minutes, or gigabytes)."""
    path = tmp_path / "hostile.bvh"
    good = _human()
    if case == "20000 nested joints":
        path.write_text(_deep(20_000))
    elif case == "a 12 MB hierarchy":
        path.write_text(good.replace("JOINT Spine", "JOINT " + "S" * 12_000_000, 1))
    elif case == "Frames: 10^8":
        path.write_text(good.replace("Frames: 12", "Frames: 100000000"))
    else:
        path.write_text(good.replace("Frame Time: 0.0333333", "Frame Time: 1e-300"))
    started = time.perf_counter()
    code, err = _run(capsys, "bvh-info", path)
    assert time.perf_counter() - started < 3.0
    _one_line(code, err, f"{path}: ", field)


# --------------------------------------------------------------------------- 2. BVH text as editors write it
@pytest.mark.parametrize("encode", [
    lambda t: ("\ufeff" + t).encode("utf-8"),
    lambda t: t.encode("utf-16"),
    lambda t: t.replace("\n", "\r").encode(),
    lambda t: t.replace("\n", "\r\n").encode(),
])
def test_byte_order_marks_and_line_ends_are_read_like_plain_text(tmp_path, encode):
    from nnsf.datasets.bvh import parse_bvh, read_bvh

    text = _human()
    path = tmp_path / "clip.bvh"
    path.write_bytes(encode(text))
    got, want = read_bvh(path), parse_bvh(text)
    assert got.names == want.names and np.array_equal(got.motion, want.motion)


def test_a_joint_name_with_control_characters_is_refused(tmp_path, capsys):
    path = tmp_path / "ansi.bvh"
    path.write_text(_human().replace("JOINT Spine", "JOINT Sp\x1b[31mine"))
    _one_line(*_run(capsys, "bvh-info", path), f"{path}: line 6: expected a joint name of printable characters")


# --------------------------------------------------------------------------- 3. pieces and blocks, same numbers
def test_the_motion_block_is_parsed_in_pieces_with_the_same_rows_and_line_numbers(monkeypatch):
    from nnsf.datasets import bvh as bvh_mod

    text = _human(frames=40)
    whole = bvh_mod.parse_bvh(text)
    monkeypatch.setattr(bvh_mod, "_CHUNK_CHARS", 300)          # a piece of a few rows
    pieces = bvh_mod.parse_bvh(text)
    assert np.array_equal(whole.motion, pieces.motion)
    lines = text.splitlines()
    bad = lines.index("MOTION") + 3 + 33                       # the 34th motion row, in a later piece
    lines[bad] = lines[bad].replace("0", "nan", 1)
    with pytest.raises(InputError, match=rf"line {bad + 1}: expected finite motion values"):
        bvh_mod.parse_bvh("\n".join(lines) + "\n")


def test_forward_kinematics_in_blocks_gives_the_whole_clips_key_points(monkeypatch):
    from nnsf.datasets import bvh_source
    from nnsf.datasets.bvh import forward_kinematics, parse_bvh
    from nnsf.datasets.bvh_skeletons import FAMILIES, keypoints_3d

    bvh = parse_bvh(_human(frames=30), "clip.bvh")
    fam = FAMILIES["bandai-namco"]
    P, G = forward_kinematics(bvh, end_sites=True, return_rotations=True)
    monkeypatch.setattr(bvh_source, "FK_BLOCK", 7 * len(bvh.names))   # blocks of 7 frames
    assert np.allclose(bvh_source.keypoints_of(bvh, fam), keypoints_3d(bvh, P, G, fam), rtol=0, atol=1e-9)


# --------------------------------------------------------------------------- 4. warnings off the error path
def test_numpy_overflow_warnings_never_join_the_error_line(tmp_path, capsys):
    import sys
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):   # as Python does outside pytest
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))

    path = tmp_path / "huge.bvh"
    path.write_text(_human().replace("OFFSET 0 15 0", "OFFSET 1e308 1e308 1e308", 1))
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.showwarning = show
        _one_line(*_run(capsys, "bvh-info", path), f"{path}: ")


# --------------------------------------------------------------------------- 5. a key given twice
JOINT_MAP = """joints:
  pelvis: [UpperLeg_L, UpperLeg_R]
  r_hip: UpperLeg_R
  r_knee: LowerLeg_R
  r_ankle: Foot_R
  l_hip: UpperLeg_L
  l_knee: LowerLeg_L
  l_ankle: Foot_L
  spine: Spine
  thorax: Neck
  neck: Head
  head_top: end(Head)
  l_shoulder: UpperArm_L
  l_elbow: LowerArm_L
  l_wrist: Hand_L
  r_shoulder: UpperArm_R
  r_elbow: LowerArm_R
  r_wrist: Hand_R
"""


@pytest.mark.parametrize("change, words", [
    (lambda t: t + "  r_knee: Hips\n", "line 19: expected each key once in a mapping (it is also on line 4) ('r_knee')"),
    (lambda t: t + "joints:\n  pelvis: Hips\n", "line 19: expected each key once in a mapping (it is also on line 1)"),
    (lambda t: t.replace("[UpperLeg_L, UpperLeg_R]", "[Hips, Hips]"), "joints.pelvis: expected a joint name"),
])
def test_a_key_point_mapped_twice_is_refused_not_overwritten(tmp_path, capsys, change, words):
    bvh = tmp_path / "clip.bvh"
    bvh.write_text(_human())
    jm = tmp_path / "map.yaml"
    jm.write_text(change(JOINT_MAP))
    _one_line(*_run(capsys, "bvh-info", bvh, "--joint-map", jm), f"{jm}: {words}")
    _one_line(*_run(capsys, "animate", "--character", "pip", "--motion", bvh, "--joint-map", jm,
                    "--out", tmp_path / "a.gif"), str(jm))
    assert not (tmp_path / "a.gif").exists()


def test_yaml_merge_keys_may_still_be_overridden():
    from nnsf.safe_yaml import parse_yaml

    assert parse_yaml("b: &x {k: 1, j: 2}\nc:\n  <<: *x\n  k: 3\n", "m.yaml") == \
        {"b": {"k": 1, "j": 2}, "c": {"k": 3, "j": 2}}


def test_a_json_key_given_twice_is_refused_by_every_json_reader(tmp_path):
    from nnsf.datasets.bvh_source import read_folder
    from nnsf.io import read_json

    path = tmp_path / "a.json"
    path.write_text('{"style": "sad", "style": "happy"}')
    with pytest.raises(InputError, match=r"a\.json: file: expected JSON objects with each key once, got 'style'"):
        read_json(path)
    folder = tmp_path / "clips"
    folder.mkdir()
    for k, (m, s) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (folder / f"ds_{m}_{s}_001.bvh").write_text(_human(variant=k))
    (folder / "ds_walk_happy_001.json").write_text('{"style": "sad", "style": "happy", "content": "walk"}')
    _, report = read_folder(folder, fps=15)
    assert any("ds_walk_happy_001.json: file: expected JSON objects with each key once" in r for r in report)


def test_yaml_with_a_nul_character_is_one_line(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "p.yaml").write_text("seed: 1\n\x00\n")
    _one_line(*_run(capsys, "check", "--params", "p.yaml"), "p.yaml: ", "special characters are not allowed")


# --------------------------------------------------------------------------- 6. option errors on one line
@pytest.mark.parametrize("argv, words", [
    (["animate", "--character", "pip", "--motion", "m.bvh", "--fps", "abc"], "argument --fps: invalid float value"),
    (["animate", "--character", "pip", "--motion", "m.bvh", "--workers", "two"], "argument --workers: invalid int"),
    (["bogus"], "invalid choice: 'bogus'"),
])
def test_a_bad_option_is_one_line_without_the_usage_block(capsys, argv, words):
    from nnsf.cli import main

    with pytest.raises(SystemExit) as exit_:
        main(argv)
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and len(err.strip().splitlines()) == 1, err
    assert err.startswith("error: nnsf") and words in err and "usage:" not in err


# --------------------------------------------------------------------------- 7. the user's folders and inputs
def test_an_existing_folder_of_the_users_files_is_never_swapped_for_frames(tmp_path, capsys):
    folder = tmp_path / "Documents"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious")
    _one_line(*_run(capsys, "animate", "--character", "pip", "--motion", "synthetic:ollie/walk/4", "--out", folder),
              f"{folder}: --out: expected a new or empty folder, or one holding only frame_NNNN.png", "notes.txt")
    assert (folder / "notes.txt").read_text() == "precious"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["Documents"]


@pytest.mark.parametrize("command, marker", [("translate", "translation.json"), ("reshape", "metrics.json")])
def test_translate_and_reshape_never_replace_a_folder_of_the_users_files(tmp_path, capsys, monkeypatch, command,
                                                                        marker):
    import shutil

    project = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(tmp_path)
    shutil.copy(project / "params.yaml", tmp_path / "params.yaml")
    folder = tmp_path / "mine"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious")
    _one_line(*_run(capsys, command, "--out", folder), f"{folder}: --out: ", f"({marker})", "notes.txt")
    assert (folder / "notes.txt").read_text() == "precious"


@pytest.mark.parametrize("case, words", [
    ("keypoints onto the motion", "--keypoints: expected an output path apart from the --motion input"),
    ("keypoints a folder", "--keypoints: expected a CSV file name (a folder is in the way)"),
    ("video a folder", "--out: expected a GIF file name (a folder is in the way)"),
])
def test_animate_outputs_are_checked_against_its_inputs_before_any_work(tmp_path, capsys, case, words):
    from nnsf.datasets import contract, synthetic

    motion = tmp_path / "motion.csv"
    table = contract.validate(synthetic.generate(characters=1, clips_per_cell=1, frames=6, seed=0), "syn")
    contract.write_table(motion, table[table["clip"] == table["clip"].iloc[0]])
    before = motion.read_bytes()
    out, keypoints = tmp_path / "a.gif", tmp_path / "k.csv"
    if case == "keypoints onto the motion":
        keypoints = motion
    elif case == "keypoints a folder":
        keypoints.mkdir()
    else:
        out.mkdir()
    code, err = _run(capsys, "animate", "--character", "pip", "--motion", motion, "--out", out,
                     "--keypoints", keypoints)
    _one_line(code, err, words)
    assert "rendered" not in err and motion.read_bytes() == before
    assert not (tmp_path / "a_sheet.png").exists() and (case == "video a folder" or not out.exists())


def test_styles_writes_its_model_only_to_an_npz_file(tmp_path, capsys):
    clip = tmp_path / "data" / "ds_walk_happy_001.bvh"
    clip.parent.mkdir()
    clip.write_text(_human())
    before = clip.read_bytes()
    _one_line(*_run(capsys, "styles", "--data", clip.parent, "--out", clip),
              f"{clip}: --out: expected a .npz file name for the model")
    assert clip.read_bytes() == before


def test_a_frame_number_beyond_int64_is_named_not_wrapped(tmp_path):
    from nnsf.datasets import contract, synthetic

    table = contract.validate(synthetic.generate(characters=1, clips_per_cell=1, frames=4, seed=0), "syn")
    table = table.astype({"frame": object})
    table.loc[1, "frame"] = 10**30
    with pytest.raises(InputError, match=r"m\.csv: frame: expected whole numbers from 0 to 1000000000, got "
                                         r"'1000000000000000000000000000000 at row 2'"):
        contract.validate(table, "m.csv")


# --------------------------------------------------------------------------- 8. labels and aliases are names
@pytest.mark.parametrize("alias, words", [
    (["x=happy", "X=sad"], "--alias: X: expected each alias once (letter case ignored), got 'x=happy and X=sad'"),
    (["a\nb=sad"], "--alias: alias: expected an alias that is a name of 1 to 100 letters"),
    (["\x1b[2J=sad"], "--alias: alias: expected an alias that is a name"),
])
def test_an_alias_given_twice_or_unprintable_is_refused(tmp_path, capsys, monkeypatch, alias, words):
    from nnsf.factor import stage

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(stage, "styles_by_hand", lambda *a, **k: pytest.fail("the model was fitted"))
    args = [a for text in alias for a in ("--alias", text)]
    (tmp_path / "data").mkdir()
    code, err = _run(capsys, "styles", "--data", tmp_path / "data", "--out", tmp_path / "m.npz", *args)
    _one_line(code, err, words)
    assert not (tmp_path / "m.npz").exists()


@pytest.mark.parametrize("style", ["hap\npy", "\x1b[31mred", "../../etc", "s" * 500])
def test_a_label_that_is_no_safe_name_is_a_skipped_label_with_its_reason(tmp_path, style):
    from nnsf.datasets.bvh_source import read_folder

    folder = tmp_path / "clips"
    folder.mkdir()
    for k, (m, s) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (folder / f"ds_{m}_{s}_001.bvh").write_text(_human(variant=k))
    (folder / "ds_walk_happy_001.json").write_text(json.dumps({"style": style, "content": "walk"}))
    table, report = read_folder(folder, fps=15)
    assert set(table["character"]) == {"happy", "sad"}
    assert any("ds_walk_happy_001.json: style: expected a label that is a name of 1 to 100" in r for r in report)


# --------------------------------------------------------------------------- 9. link loops
def test_a_link_loop_in_a_clip_folder_is_a_report_line_not_a_crash(tmp_path):
    from nnsf.datasets.bvh_source import read_folder
    from nnsf.names import inside

    folder = tmp_path / "clips"
    folder.mkdir()
    for k, (m, s) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (folder / f"ds_{m}_{s}_001.bvh").write_text(_human(variant=k))
    os.symlink("ds_loop_sad_001.bvh", folder / "ds_loop_sad_001.bvh")
    os.symlink(folder, folder / "ds_jump_sad_001.bvh")
    table, report = read_folder(folder, fps=15)
    assert len(set(table["clip"])) == 4
    for name in ("ds_loop_sad_001.bvh", "ds_jump_sad_001.bvh"):
        assert any(f"{name}: file: expected a regular .bvh file" in r for r in report), report
    os.symlink("loop", tmp_path / "loop")
    assert inside(tmp_path, "loop") == tmp_path / "loop"       # no RuntimeError: the caller's checks decide


# --------------------------------------------------------------------------- 10. the results spec
TABLE = 'tables:\n  - section: S\n    title: T\n    source: {src}\n    command: c\n    columns:\n      - [a, "{tmpl}"]\n'


@pytest.mark.parametrize("src, tmpl, words", [
    ("reports/ok.json", "{a:>999999999}", "results.yaml: tables[0].columns: expected templates of plain"),
    ("reports/ok.json", "{a:.999999999f}", "expected a number format such as .3f"),
    ("reports/evil.json", "{a:.2f}", "reports/evil.json: source: expected a report file inside reports/ (symbolic "
                                     "links resolved)"),
])
def test_a_results_spec_reads_nothing_outside_reports_and_builds_no_giant_cell(tmp_path, capsys, monkeypatch, src,
                                                                               tmpl, words):
    import shutil

    project = Path(__file__).resolve().parents[1]
    monkeypatch.chdir(tmp_path)
    shutil.copy(project / "params.yaml", tmp_path / "params.yaml")
    (tmp_path / "docs").mkdir()
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports" / "ok.json").write_text('{"a": 1.5}')
    (tmp_path / "secret.json").write_text('{"a": 42}')
    os.symlink(tmp_path / "secret.json", tmp_path / "reports" / "evil.json")
    (tmp_path / "docs" / "results.yaml").write_text(TABLE.replace("{src}", src).replace("{tmpl}", tmpl))
    _one_line(*_run(capsys, "results"), words)
    assert not (tmp_path / "docs" / "results.md").exists()


# --------------------------------------------------------------------------- 11. a full disk while writing frames
def test_a_frame_past_the_file_size_limit_names_the_frame_and_leaves_no_folder(tmp_path, capfd):
    from nnsf.reshape.video import write_png_frames

    images = np.random.default_rng(0).integers(0, 255, (3, 64, 64, 3), dtype=np.uint8)  # ~12 KB each
    old_handler = signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    old = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (4096, old[1]))
    try:
        with pytest.raises(InputError) as err:
            write_png_frames(tmp_path / "frames", images)
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, old)
        signal.signal(signal.SIGXFSZ, old_handler)
    assert str(err.value).startswith(f"{tmp_path}/frames/frame_0000.png: write: expected a file size the system "
                                     "allows (File too large [EFBIG])")
    assert "libpng" not in capfd.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_a_folder_of_thousands_of_bad_files_is_a_capped_report():
    from nnsf.cli import MAX_REPORT_LINES, capped

    report = [f"skipped: bad_{i}.bvh: file name: expected ..." for i in range(2000)] + ["warning: style 'x'"]
    lines = capped(report)
    assert len(lines) == MAX_REPORT_LINES + 2
    assert lines[-1] == f"skipped: {2000 - MAX_REPORT_LINES} more not shown" and "warning: style 'x'" in lines


@pytest.mark.parametrize("value, words", [
    ("nope.yaml", "nope.yaml: file: expected an existing joint-map YAML"),
    ("plain.yaml", "plain.yaml: top level: expected a mapping with a 'joints' mapping, got 'a str'"),
])
def test_nnsf_check_reads_the_joint_map_the_data_stage_reads(tmp_path, capsys, monkeypatch, value, words):
    import yaml

    project = Path(__file__).resolve().parents[1]
    params = yaml.safe_load((project / "params.yaml").read_text())
    params["dataset"]["bvh"]["joint_map"] = value
    monkeypatch.chdir(tmp_path)
    (tmp_path / "plain.yaml").write_text("secret-looking text, not a map\n")
    (tmp_path / "p.yaml").write_text(yaml.safe_dump(params))
    line = _one_line(*_run(capsys, "check", "--params", "p.yaml"), words)
    assert "secret" not in line                      # a file named by mistake is not quoted


@pytest.mark.parametrize("frames", ["1" + "0" * 30, "-5", "²"])
def test_a_frame_set_index_with_an_impossible_frame_count_is_refused(tmp_path, frames):
    from nnsf.frames.clips import read_index

    (tmp_path / "c1").mkdir()
    (tmp_path / "index.csv").write_text(f"clip,character,motion,folder,frames\nc1,bruno,walk,c1,{frames}\n")
    with pytest.raises(InputError, match=r"index\.csv: frames \(row 1\): expected a frame count from 1 to"):
        read_index(tmp_path)
