"""Safety: no pickles from disk, YAML only through safe_load, paths in annotation and
config files stay inside their root, servers bind to the loopback interface.
"""
from __future__ import annotations

import ast
import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import PROJECT
from nnsf.errors import InputError

#: The code that ships: the library and the orchestration.
PACKAGES = ("nnsf", "flows")
#: Modules whose ``load``/``loads`` unpickle (or execute) what they read.
UNSAFE_MODULES = {"pickle", "cPickle", "_pickle", "dill", "cloudpickle", "joblib", "torch",
                  "marshal", "shelve", "jsonpickle"}
#: Of those, the ones that are only about (un)pickling, so importing them at all is flagged;
#: joblib and torch are flagged only for their ``load``.
PICKLE_ONLY = UNSAFE_MODULES - {"joblib", "torch"}
LOADERS = {"load", "loads", "Unpickler"}
UNSAFE_YAML = {"load", "load_all", "unsafe_load", "unsafe_load_all", "full_load", "full_load_all"}


def unsafe_loads(source: str, filename: str = "<source>") -> list[str]:
    """Every place in Python ``source`` that could unpickle or run code from a file.

    Flags: importing an unpickling module; ``<module>.load(s)`` of one; pandas
    ``read_pickle``; ``yaml.load`` and friends (``safe_load`` is fine);
    ``np.load`` without ``allow_pickle=False``; any ``allow_pickle=True``.
    """
    found = []
    tree = ast.parse(source, filename)
    for node in ast.walk(tree):
        where = f"{filename}:{getattr(node, 'lineno', '?')}"
        if isinstance(node, ast.Import):
            found += [f"{where}: import {a.name}" for a in node.names
                      if a.name.split(".")[0] in PICKLE_ONLY]
        elif isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in UNSAFE_MODULES:
            if (node.module.split(".")[0] in PICKLE_ONLY
                    or any(a.name in LOADERS for a in node.names)):
                found.append(f"{where}: from {node.module} import ...")
        elif isinstance(node, ast.Call):
            func = node.func
            name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            owner = func.value.id if (isinstance(func, ast.Attribute)
                                      and isinstance(func.value, ast.Name)) else ""
            kw = {k.arg: k.value for k in node.keywords}
            if owner in UNSAFE_MODULES and name in LOADERS:
                found.append(f"{where}: {owner}.{name}")
            if name == "read_pickle":
                found.append(f"{where}: read_pickle")
            if owner == "yaml" and name in UNSAFE_YAML:
                found.append(f"{where}: yaml.{name}")
            if owner in ("np", "numpy") and name == "load":
                flag = kw.get("allow_pickle")
                if not (isinstance(flag, ast.Constant) and flag.value is False):
                    found.append(f"{where}: np.load without allow_pickle=False")
            flag = kw.get("allow_pickle")
            if isinstance(flag, ast.Constant) and flag.value is True:
                found.append(f"{where}: allow_pickle=True")
    return found


def test_the_scanner_finds_every_kind_of_unsafe_load():
    planted = """
import pickle
from dill import loads
from joblib import Parallel
from joblib import load
import yaml, numpy as np, pandas as pd
yaml.load(open('a.yaml'))
yaml.full_load('x')
yaml.safe_load('fine: 1')
np.load('a.npy')
np.load('b.npz', allow_pickle=False)
np.load('c.npz', allow_pickle=True)
pd.read_pickle('t.pkl')
pickle.loads(b'')
"""
    found = unsafe_loads(planted)
    assert [f.split(": ", 1)[1] for f in found] == [
        "import pickle", "from dill import ...", "from joblib import ...", "yaml.load", "yaml.full_load",
        "np.load without allow_pickle=False", "np.load without allow_pickle=False",
        "allow_pickle=True", "read_pickle", "pickle.loads"]


def test_no_code_loads_pickles_or_unsafe_yaml():
    files = [p for pkg in PACKAGES for p in sorted((PROJECT / pkg).rglob("*.py"))]
    assert len(files) > 20
    found = []
    for path in files:
        found += unsafe_loads(path.read_text(), str(path.relative_to(PROJECT)))
    assert found == []


def test_yaml_is_read_by_the_one_bounded_safe_loader_everywhere():
    """Every YAML read in the shipped code goes through ``nnsf.safe_yaml`` (a ``yaml.SafeLoader``
    with bounds); elsewhere ``yaml`` is only written."""
    import yaml

    from nnsf.safe_yaml import BoundedLoader

    uses, readers = [], 0
    for pkg in PACKAGES:
        for path in (PROJECT / pkg).rglob("*.py"):
            if path.name == "safe_yaml.py":
                continue
            text = path.read_text()
            uses += re.findall(r"\byaml\.(\w+)\(", text)
            readers += len(re.findall(r"\b(read_yaml|parse_yaml)\(", text))
    assert readers >= 3, "expected at least the params, char_cfg and joints readers"
    assert set(uses) <= {"safe_dump", "safe_dump_all", "dump"}, uses
    assert issubclass(BoundedLoader, yaml.SafeLoader)


# -- paths inside annotation and config files ---------------------------------------------

@pytest.fixture
def character_file(tmp_path):
    from stick_figure import stick_figure
    from nnsf.reshape.formats import write_character

    folder = tmp_path / "chars"
    folder.mkdir()
    path = write_character(stick_figure(height=120), folder / "stick.json")
    # A real image outside the root, so only the containment rule can reject it.
    (tmp_path / "outside.png").write_bytes((folder / "stick.texture.png").read_bytes())
    return path


@pytest.mark.parametrize("field", ["texture", "mask"])
@pytest.mark.parametrize("bad", ["../outside.png", "sub/../../outside.png", "ABSOLUTE"])
def test_character_file_paths_cannot_escape_the_folder(character_file, field, bad):
    from nnsf.reshape.formats import read_character

    obj = json.loads(character_file.read_text())
    obj[field] = str(character_file.parent.parent / "outside.png") if bad == "ABSOLUTE" else bad
    character_file.write_text(json.dumps(obj))
    with pytest.raises(InputError) as err:
        read_character(character_file)
    assert err.value.field == field and str(character_file) in str(err.value)


def test_character_file_paths_inside_the_folder_still_load(character_file):
    from nnsf.reshape.formats import read_character

    obj = json.loads(character_file.read_text())
    (character_file.parent / "sub").mkdir()
    (character_file.parent / "sub" / "t.png").write_bytes(
        (character_file.parent / obj["texture"]).read_bytes())
    obj["texture"] = "sub/../sub/t.png"  # a '..' that stays inside is harmless here
    character_file.write_text(json.dumps(obj))
    assert read_character(character_file).name == "stick"


def test_animated_drawings_config_is_read_with_safe_load(tmp_path):
    """A YAML tag that would construct a Python object is refused, not executed."""
    from nnsf.reshape.formats import read_character as load_animated_drawings

    folder = tmp_path / "char"
    folder.mkdir()
    marker = tmp_path / "executed"
    (folder / "char_cfg.yaml").write_text(
        f"height: !!python/object/apply:os.system ['touch {marker}']\nwidth: 10\n")
    with pytest.raises(InputError) as err:
        load_animated_drawings(folder)
    assert "char_cfg.yaml" in str(err.value)
    assert not marker.exists()


def _annotation(frames: list[str]) -> dict:
    return {"format": "nnsf.annotation", "version": 1, "clip": "c", "character": "a",
            "motion": "walk", "frames": frames, "image_size": [8, 8], "keyframes": []}


@pytest.mark.parametrize("bad", ["../frame.png", "a/../../frame.png", "/etc/passwd",
                                 "~/frame.png", "C:\\frames\\f.png", "..\\frame.png"])
def test_annotation_frame_paths_cannot_escape_the_clip_folder(bad):
    from nnsf.frames import annotation as frames_mod

    with pytest.raises(InputError) as err:
        frames_mod.from_dict(_annotation(["frame_0000.png", bad]), source="clip.json")
    assert err.value.field == "frames[1]" and "clip.json" in str(err.value)


def test_annotation_frame_symlink_out_of_the_clip_folder_is_refused(tmp_path):
    from nnsf.frames import annotation, clips
    import cv2
    import numpy as np

    folder = tmp_path / "clip"
    folder.mkdir()
    cv2.imwrite(str(folder / "f0.png"), np.zeros((8, 8, 3), np.uint8))
    cv2.imwrite(str(tmp_path / "secret.png"), np.zeros((8, 8, 3), np.uint8))
    (folder / "f1.png").symlink_to(tmp_path / "secret.png")
    ann = annotation.Annotation(clip="c", character="a", motion="walk", frames=["f0.png", "f1.png"],
                                image_size=(8, 8), keyframes=[], source="clip.json")
    with pytest.raises(InputError) as err:
        clips.frame_paths(folder, ann)
    assert err.value.field == "frames[1]"


# -- servers bind to the loopback interface -------------------------------------------------

LOOPBACK = {"127.0.0.1", "localhost", "::1"}
#: Commands that start a listening server.
SERVER_COMMANDS = re.compile(r"\b(prefect server start|mlflow (?:server|ui)|dask[- ]scheduler)\b")


def _help_default_host(command: str) -> str | None:
    """The default of ``--host`` according to the tool's own ``--help``."""
    tool, *sub = command.split()
    exe = Path(sys.executable).with_name(tool)
    out = subprocess.run([str(exe), *sub, "--help"], capture_output=True, text=True, timeout=120,
                         env={"COLUMNS": "400", "PATH": str(exe.parent), "NO_COLOR": "1",
                              "MLFLOW_DISABLE_TELEMETRY": "true", "DO_NOT_TRACK": "1"})
    text = re.sub(r"\s+", " ", re.sub(r"[│╭╮╰╯─]", " ", out.stdout))
    # The option's own entry ("-h, --host HOST  ... (default: 127.0.0.1)" or
    # "--host TEXT ... [default: 127.0.0.1]"), not the usage examples above it.
    m = re.search(r"(?:-h, )?--host\s+[A-Z]+\b[^\[(]*?[\[(]default:?\s*['\"]?([\w.:]+)", text)
    return m.group(1) if m else None


@pytest.mark.slow  # runs each server command's --help
def test_every_documented_server_command_binds_to_loopback():
    """Each server command in the code blocks of the README and docs/ binds to loopback,
    explicitly or by default.

    (The commands the code itself runs are checked live below.)
    """
    lines = []
    for path in [PROJECT / "README.md", *sorted((PROJECT / "docs").glob("*.md"))]:
        blocks = re.findall(r"```[a-z]*\n(.*?)```", path.read_text(), re.DOTALL)
        lines += [(path.name, line.strip()) for block in blocks
                  for line in block.replace("\\\n", " ").splitlines()
                  if SERVER_COMMANDS.search(line) and not line.lstrip().startswith("#")]
    assert {doc for doc, _ in lines} >= {"README.md", "operations.md"}, "expected documented server commands"
    defaults: dict[str, str | None] = {}
    for doc, line in lines:
        host = re.search(r"--host[ =]+[\"']?([^\s\"']+)", line)
        if host:
            assert host.group(1) in LOOPBACK, (doc, line)
            continue
        command = SERVER_COMMANDS.search(line).group(1)
        if command not in defaults:
            defaults[command] = _help_default_host(command)
        assert defaults[command] in LOOPBACK, (doc, line, f"default host {defaults[command]}")


@pytest.mark.slow  # starts the session's Prefect server
def test_the_project_prefect_server_listens_on_loopback_only(prefect_api):
    import psutil

    port = int(prefect_api.rsplit(":", 1)[1].split("/")[0])
    listening = [c for c in psutil.net_connections(kind="inet")
                 if c.status == psutil.CONN_LISTEN and c.laddr.port == port]
    assert listening and {c.laddr.ip for c in listening} <= {"127.0.0.1", "::1"}


def test_the_server_helpers_default_to_loopback():
    import inspect

    from flows import prefect_server

    assert inspect.signature(prefect_server.running).parameters["host"].default == "127.0.0.1"
    assert inspect.signature(prefect_server.free_port).parameters["host"].default == "127.0.0.1"


def test_a_quick_test_that_starts_a_process_fails():
    """The guard of conftest.py: a test not marked slow cannot start a command or fork."""
    import os

    from conftest import _GUARDED

    try:
        with pytest.raises(RuntimeError, match="starts a process .*true.* but is not marked slow"):
            subprocess.run(["true"])
        with pytest.raises(RuntimeError, match=r"\(os\.fork\) but is not marked slow"):
            os.fork()
        assert len(_GUARDED["started"]) == 2
    finally:
        _GUARDED["started"].clear()   # this test provoked them on purpose
