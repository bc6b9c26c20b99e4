"""Every command with an output folder it cannot write: one line naming the folder, exit 2,
nothing left behind.

The tests run as root, for whom ``chmod`` stops nothing, so the folder is made
unwritable the way that stops root too: a regular file stands where the folder
(or one of its parents) should be.  The commands run in this process
(``nnsf.cli.main``, ``flows.__main__.main``): they fail before any stage
work, so no process needs to be started.
"""
from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from nnsf import cli, pipeline, stages
from nnsf.errors import InputError
from nnsf.io import atomic_dir, atomic_path, check_writable, write_json

PARAMS = Path(__file__).resolve().parents[1] / "params.yaml"

#: (command, folder made unwritable, extra arguments): every folder each stage writes
#: into, and the ``--out`` of the commands that take one.
CASES = [(stage, str(folder), []) for stage, folders in pipeline.OUTPUT_FOLDERS.items()
         if stage in cli.STAGES for folder in folders]
CASES += [(command, "blocked/out", ["--out", "blocked/out"])
          for command in ("translate", "reshape")]
# The evaluations on external data also need --data (any existing folder: the output check comes first).
CASES += [("reshape-eval", "blocked/out", ["--data", ".", "--out", "blocked/out"]),
          ("roto-real", "blocked/out", ["--data", ".", "--annotations", ".", "--out", "blocked/out"])]


def _files(root: Path) -> set[str]:
    return {p.relative_to(root).as_posix() for p in root.rglob("*")}


def _block(root: Path, folder: str) -> Path:
    """Put a regular file where ``folder`` should be (its parents are real folders)."""
    blocker = root / folder
    blocker.parent.mkdir(parents=True, exist_ok=True)
    blocker.write_text("a file, not a folder\n")
    return blocker


@pytest.mark.parametrize("command, folder, extra", CASES,
                         ids=[f"{c}-{f}" for c, f, _ in CASES])
def test_nnsf_command_with_an_unwritable_output_folder(command, folder, extra, tmp_path,
                                                       monkeypatch, capsys):
    (tmp_path / "params.yaml").write_text(PARAMS.read_text())
    # The file blocks the folder itself (or, for --out, its parent).
    _block(tmp_path, folder if "--out" not in extra else str(Path(folder).parent))
    before = _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = cli.main([command, *extra])
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"error: {folder}: output folder: "), lines
    assert "Traceback" not in err
    assert _files(tmp_path) == before  # nothing left behind, not even the probe


def test_flows_stage_command_with_an_unwritable_output_folder(tmp_path, monkeypatch, capsys):
    from flows.__main__ import main

    (tmp_path / "params.yaml").write_text(PARAMS.read_text())
    (tmp_path / "dvc.yaml").write_text("stages: {}\n")
    _block(tmp_path, "models")
    before = _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = main(["factorize"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: models: output folder: "), lines
    assert _files(tmp_path) == before


def test_output_folders_cover_every_declared_output():
    """pipeline.OUTPUT_FOLDERS holds the folder of every out, metric and plot in dvc.yaml."""
    spec = yaml.safe_load((PARAMS.parent / "dvc.yaml").read_text())["stages"]
    for name, stage in spec.items():
        folders = {Path(f) for f in pipeline.OUTPUT_FOLDERS[name]}
        for key in ("outs", "metrics", "plots"):
            for entry in stage.get(key) or []:
                path = Path(next(iter(entry)) if isinstance(entry, dict) else entry)
                assert path.parent in folders or path in folders, (name, path)


def test_writers_name_the_folder_when_a_file_is_in_the_way(tmp_path):
    _block(tmp_path, "reports")
    for write in (lambda: write_json(tmp_path / "reports" / "x.json", {"a": 1}),
                  lambda: atomic_path(tmp_path / "reports" / "y.csv").__enter__(),
                  lambda: atomic_dir(tmp_path / "reports" / "z").__enter__()):
        with pytest.raises(InputError, match="output folder") as err:
            write()
        assert str(tmp_path / "reports") in str(err.value)
    assert _files(tmp_path) == {"reports"}


def test_check_writable_accepts_a_folder_still_to_be_made_and_creates_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert check_writable(Path("a") / "b") == Path("a/b")
    assert list(tmp_path.iterdir()) == []
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="^file/sub: output folder: .*'file is a file'"):
        check_writable(Path("file") / "sub")


#: (arguments, the path a file is put at, the folder the error must name): the commands
#: whose output paths come from their own options.  Every input is valid (built-in
#: character and motion, the project's params), so without the up-front check each
#: would do its whole work (render every frame, re-track every clip) before failing.
OPTION_CASES = [
    (["styles", "--data", ".", "--out", "blocked/styles.npz"], "blocked", "blocked"),
    (["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--out", "blocked/a.mp4"],
     "blocked", "blocked"),
    (["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--out", "blocked/a.gif"],
     "blocked", "blocked"),
    (["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--out", "blocked/frames"],
     "blocked", "blocked"),  # the frames folder and its contact sheet beside it
    (["animate", "--character", "pip", "--motion", "synthetic:max/walk/6", "--out", "frames"],
     "frames", "frames"),
    (["roto", "--export-cvat", "blocked/cvat"], "blocked", "blocked/cvat"),
    (["roto", "--corrections", "fixed.xml"], "data/tracks", "data/tracks"),
    (["roto", "--corrections", "fixed.xml"], "data/tracked", "data/tracked"),
    (["roto", "--corrections", "fixed.xml", "--export-cvat", "cvat"], "cvat", "cvat"),
]


@pytest.mark.parametrize("args, blocked, named", OPTION_CASES,
                         ids=[f"{a[0]}-{'-'.join(a[1:])}-{b}" for a, b, _ in OPTION_CASES])
def test_command_with_an_unwritable_folder_from_its_options(args, blocked, named, tmp_path,
                                                            monkeypatch, capsys):
    (tmp_path / "params.yaml").write_text(PARAMS.read_text())
    if "--corrections" in args:
        (tmp_path / "fixed.xml").write_text("<annotations/>\n")
    _block(tmp_path, blocked)
    before = _files(tmp_path)
    monkeypatch.chdir(tmp_path)
    code = cli.main(args)
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"error: {named}: output folder: "), lines
    assert "Traceback" not in err
    assert _files(tmp_path) == before  # nothing rendered, tracked or half-written
