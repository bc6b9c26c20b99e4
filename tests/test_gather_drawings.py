"""scripts/gather_drawings.py: every gathered drawing has its joints file, and files are read by blob id."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
import gather_drawings  # noqa: E402

from nnsf.safe_yaml import read_yaml  # noqa: E402


def test_every_gathered_drawing_has_a_joints_yaml_that_names_it():
    for kind, name, *_ in gather_drawings.DRAWINGS:
        doc = read_yaml(ROOT / "tests" / "data" / "drawings" / f"{name}.yaml")
        assert doc["image"] == f"{name}/texture.png"
        assert (doc.get("mask") == f"{name}/mask.png") == name.startswith("gopher_sketch")


@pytest.mark.slow
def test_a_file_is_read_by_its_blob_id_and_a_missing_one_stops_with_its_path(tmp_path):
    git = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-C", str(tmp_path)]
    subprocess.run(git + ["init", "-q"], check=True)
    (tmp_path / "a.png").write_bytes(b"not really a png\x00\x01")
    subprocess.run(git + ["add", "a.png"], check=True)
    subprocess.run(git + ["commit", "-qm", "a"], check=True)
    commit = subprocess.run(git + ["rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()
    blob = subprocess.run(git + ["rev-parse", "HEAD:a.png"], capture_output=True, text=True).stdout.strip()
    data, sha = gather_drawings.git_blob(tmp_path / ".git", commit, "a.png", blob)
    assert data == b"not really a png\x00\x01" and sha == blob
    assert gather_drawings.git_blob(tmp_path / ".git", commit, "a.png", None) == (data, sha)
    with pytest.raises(SystemExit, match="b.png"):
        gather_drawings.git_blob(tmp_path / ".git", commit, "b.png", None)
