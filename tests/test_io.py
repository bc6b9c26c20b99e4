"""Atomic outputs: a failure leaves the old file (or nothing) in place, never a partial one."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.io import atomic_dir, atomic_path, read_json, read_npz, write_json, write_npz


def test_atomic_path_keeps_old_file_on_failure(tmp_path):
    target = tmp_path / "out.json"
    write_json(target, {"a": 1})
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed")
    assert read_json(target) == {"a": 1}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_atomic_dir_swaps_whole_folder(tmp_path):
    target = tmp_path / "raw"
    with atomic_dir(target) as tmp:
        (tmp / "a.txt").write_text("1")
    with pytest.raises(RuntimeError):
        with atomic_dir(target) as tmp:
            (tmp / "b.txt").write_text("2")
            raise RuntimeError("killed")
    assert sorted(p.name for p in target.iterdir()) == ["a.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw"]
    assert (target.stat().st_mode & 0o777) == 0o755


def test_npz_round_trip_without_pickle(tmp_path):
    path = tmp_path / "m.npz"
    write_npz(path, U=np.eye(3), names=np.array(["a", "b"]))
    back = read_npz(path)
    np.testing.assert_array_equal(back["U"], np.eye(3))
    assert back["names"].tolist() == ["a", "b"]
    with pytest.raises(TypeError, match="pickle"):
        write_npz(path, bad=np.array([{"x": 1}], dtype=object))
    with pytest.raises(InputError, match="existing .npz"):
        read_npz(tmp_path / "missing.npz")


def test_read_json_names_file_and_line(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{"a": 1,\n "b": }\n')
    with pytest.raises(InputError, match=r"bad.json: line 2: expected valid JSON"):
        read_json(path)


def test_a_killed_writers_temporary_is_removed_by_the_next_write(tmp_path):
    """SIGKILL skips cleanup; the next successful write of the same output removes what it left."""
    from nnsf.io import atomic_dir, write_json

    target = tmp_path / "metrics.json"
    stale = tmp_path / ".metrics.json.abc123.json"
    stale.write_text("half")
    other = tmp_path / ".other.json.abc123.json"      # another output's temporary stays
    other.write_text("x")
    write_json(target, {"a": 1})
    assert not stale.exists() and other.exists() and target.exists()

    stale_dir = tmp_path / ".tracks.xyz"
    stale_dir.mkdir()
    (stale_dir / "part.npz").write_bytes(b"half")
    with atomic_dir(tmp_path / "tracks") as tmp:
        (tmp / "a.txt").write_text("done")
    assert not stale_dir.exists() and (tmp_path / "tracks" / "a.txt").read_text() == "done"
