"""The frames stages: render a small set, key points from (oracle) tracks, failures per clip."""
from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.frames.stage import render_frames
from nnsf.roto.stage import keypoints_from_tracks
from nnsf.io import read_json, read_npz, write_npz
from nnsf.skeleton import to_points

PARAMS = {"seed": 1, "unify": {"margin": 0.5},
          "frames": {"characters": 2, "motions": ["walk", "wave"], "clips_per_cell": 1, "frames": 6,
                     "size": 96, "keyframe_every": 0, "control_points": 5}}


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("stage") / "frames"
    seen = []

    def mapper(fn, items):                 # a plain mapper that records the fan-out
        seen.extend(items)
        return [fn(i) for i in items]

    res = render_frames(PARAMS, out, mapper=mapper)
    assert len(seen) == 4 and res.metrics["clips"] == 4
    return out


def _oracle_tracks(frames_dir, tracks_dir):
    """Tracks equal to the true control points: what a perfect tracker writes."""
    for clip in pd.read_csv(frames_dir / "index.csv")["clip"]:
        tr = read_npz(frames_dir / clip / "truth.npz")
        write_npz(tracks_dir / clip / "curves.npz", control=tr["control"], curve_names=tr["side_names"])


def test_index_and_folders(frames_dir):
    index = pd.read_csv(frames_dir / "index.csv")
    assert list(index.columns) == ["clip", "character", "motion", "folder", "frames"]
    assert list(index["clip"]) == ["bruno-walk-00", "bruno-wave-00", "pip-walk-00", "pip-wave-00"]
    for f in index["folder"]:
        assert len(list((frames_dir / f).glob("frame_*.png"))) == 6
        assert (frames_dir / f / "annotation.json").is_file()


def test_keypoints_from_oracle_tracks_feed_features(frames_dir, tmp_path):
    from nnsf.stages import features

    _oracle_tracks(frames_dir, tmp_path / "tracks")
    res = keypoints_from_tracks(PARAMS, frames_dir, tmp_path / "tracks", tmp_path / "raw")
    table = contract.read_table(tmp_path / "raw" / "keypoints.csv")
    assert res.metrics["frames"] == len(table) == 24
    for clip, rows in table.groupby("clip"):
        truth = read_npz(frames_dir / clip / "truth.npz")["keypoints"]
        err = np.linalg.norm(to_points(contract.features(rows)) - truth, axis=-1)
        assert err.max() < 0.3, (clip, err.max())
    info = read_json(tmp_path / "raw" / "characters.json")
    assert info["source"] == "frames" and set(info["clips"]) == set(table["clip"]) and not info["failed"]
    features(PARAMS, tmp_path / "raw", tmp_path / "features")        # consumed unchanged
    assert (tmp_path / "features" / "features.csv").is_file()


def test_bad_tracks_fail_by_clip_and_keep_the_others(frames_dir, tmp_path):
    tracks = tmp_path / "tracks"
    _oracle_tracks(frames_dir, tracks)
    (tracks / "pip-walk-00" / "curves.npz").unlink()                             # missing
    z = read_npz(tracks / "bruno-wave-00" / "curves.npz")
    write_npz(tracks / "bruno-wave-00" / "curves.npz", control=z["control"][:3],
              curve_names=z["curve_names"])                                     # wrong length
    with pytest.raises(InputError) as err:
        keypoints_from_tracks(PARAMS, frames_dir, tracks, tmp_path / "raw")
    msg = str(err.value)
    assert "pip-walk-00" in msg and "bruno-wave-00" in msg and "2 failed" in msg
    table = contract.read_table(tmp_path / "raw" / "keypoints.csv")
    assert sorted(table["clip"].unique()) == ["bruno-walk-00", "pip-wave-00"]
    failed = read_json(tmp_path / "raw" / "characters.json")["failed"]
    assert "curves.npz" in failed["pip-walk-00"] and "control" in failed["bruno-wave-00"]


def test_all_clips_failing_writes_nothing(frames_dir, tmp_path):
    (tmp_path / "tracks").mkdir()
    with pytest.raises(InputError, match="at least one clip with usable tracks"):
        keypoints_from_tracks(PARAMS, frames_dir, tmp_path / "tracks", tmp_path / "raw")
    assert not (tmp_path / "raw").exists()


def test_keyframes_must_match_the_annotation(frames_dir, tmp_path):
    tracks = tmp_path / "tracks"
    _oracle_tracks(frames_dir, tracks)
    z = read_npz(tracks / "pip-wave-00" / "curves.npz")
    control = z["control"].copy()
    control[0, 3, 1] += 2.0                       # keyframe 0 moved: not a hard constraint any more
    write_npz(tracks / "pip-wave-00" / "curves.npz", control=control, curve_names=z["curve_names"])
    with pytest.raises(InputError, match=r"pip-wave-00.*control\[0, 3\]"):
        keypoints_from_tracks(PARAMS, frames_dir, tracks, tmp_path / "raw")


def test_bad_params_and_index(tmp_path):
    bad = {**PARAMS, "frames": {**PARAMS["frames"], "motions": ["walk", "moonwalk"]}}
    with pytest.raises(InputError, match="frames.motions"):
        render_frames(bad, tmp_path / "f")
    assert not (tmp_path / "f").exists()
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "index.csv").write_text("clip,character,motion,folder,frames\nx,a,b,../x,3\n")
    with pytest.raises(InputError, match=r"index.csv: folder \(row 1\)"):
        keypoints_from_tracks(PARAMS, tmp_path / "g", tmp_path / "t", tmp_path / "r")
