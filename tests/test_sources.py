"""The data stage's three sources (``dataset.name``): synthetic, bvh and frames.

The bvh case reads a handful of real Bandai-Namco clips from ``../shared/data``
(skipped with a reason when absent) through the stage function, then checks
the features stage accepts the result unchanged.
"""
from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nnsf import stages
from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.params import Params, validate

PROJECT = Path(__file__).resolve().parents[1]
BANDAI = PROJECT.parent / "shared" / "data" / "bandai-namco-1"

BASE = {
    "seed": 0,
    "dataset": {
        "name": "synthetic",
        "path": "nnsf/datasets",
        "synthetic": {"characters": 2, "clips_per_cell": 1, "frames": 6, "noise_px": 0.0},
        "bvh": {"fps": 15, "azimuth": 0.0, "elevation": 0.0, "facing": "normalise", "center": True,
                "complete_grid": True},
    },
    "unify": {"margin": 0.5},
}


def params_with(**dataset) -> Params:
    p = copy.deepcopy(BASE)
    p["dataset"].update(dataset)
    return Params(validate(p))


def test_bvh_source_reads_labelled_clips_and_feeds_the_features_stage(tmp_path):
    if not (BANDAI / "data").is_dir():
        pytest.skip(f"Bandai-Namco data not found at {BANDAI}")
    folder = tmp_path / "bvh"
    folder.mkdir()
    chosen = [f"dataset-1_{m}_{s}_001" for m in ("walk", "run") for s in ("normal", "happy")]
    partial = "dataset-1_bow_normal_001"   # bow only in one of the two styles: dropped
    for stem in chosen + [partial]:
        for ext in (".bvh", ".json"):
            shutil.copy(BANDAI / "data" / (stem + ext), folder / (stem + ext))
    (folder / "notes.json").write_text("{}")  # a label file without motion: reported, skipped

    result = stages.data(params_with(name="bvh", path=str(folder)), out_dir=tmp_path / "raw")
    table = contract.read_table(tmp_path / "raw" / "keypoints.csv")
    assert sorted(table["clip"].unique()) == sorted(chosen)
    assert set(table["character"]) == {"normal", "happy"}   # style plays the character
    assert set(table["motion"]) == {"walk", "run"}          # content plays the motion
    assert result.metrics["clips"] == 4 and result.metrics["skipped_or_warned"] >= 1
    described = json.loads((tmp_path / "raw" / "characters.json").read_text())
    assert described["source"] == "bvh" and any("notes.json" in line for line in described["report"])
    assert any("dropped motion 'bow'" in line for line in described["report"])
    # 15 fps from 30 fps halves the frame count of every clip (± 1 for the end).
    per_clip = table.groupby("clip").size()
    assert (per_clip > 10).all()

    stages.features(params_with(name="bvh", path=str(folder)), raw_dir=tmp_path / "raw",
                    out_dir=tmp_path / "features")
    feats = contract.read_table(tmp_path / "features" / "features.csv", non_negative=True)
    assert len(feats) == len(table)
    assert feats[list(contract.COLUMNS[4:])].to_numpy().min() >= 0.5 - 1e-9


def test_bvh_source_names_a_missing_folder(tmp_path, monkeypatch):
    # Relative: the message shortens long values, and pytest-xdist's temporary paths are long.
    monkeypatch.chdir(tmp_path)
    missing = Path("nowhere")
    with pytest.raises(InputError) as err:
        stages.data(params_with(name="bvh", path=str(missing)), out_dir=tmp_path / "raw")
    assert "dataset.path" in str(err.value) and "nowhere" in str(err.value)
    assert not (tmp_path / "raw").exists()


def test_frames_source_takes_the_tracked_key_points(tmp_path):
    synthetic_raw = tmp_path / "synthetic"
    stages.data(params_with(), out_dir=synthetic_raw)
    tracks = tmp_path / "tracks"
    tracks.mkdir()
    shutil.copy(synthetic_raw / "keypoints.csv", tracks / "keypoints.csv")
    stages.data(params_with(name="frames", path=str(tracks)), out_dir=tmp_path / "raw")
    got = pd.read_csv(tmp_path / "raw" / "keypoints.csv")
    want = pd.read_csv(synthetic_raw / "keypoints.csv")
    pd.testing.assert_frame_equal(got, want)
    described = json.loads((tmp_path / "raw" / "characters.json").read_text())
    assert described["source"] == "frames" and len(described["clips"]) == want["clip"].nunique()


def test_frames_source_without_tracks_says_to_run_the_track_stage(tmp_path):
    (tmp_path / "tracks").mkdir()
    with pytest.raises(InputError) as err:
        stages.data(params_with(name="frames", path=str(tmp_path / "tracks")), out_dir=tmp_path / "raw")
    assert "keypoints.csv" in str(err.value) and "roto" in str(err.value)
    assert not (tmp_path / "raw").exists()


@pytest.mark.parametrize("field,value,expected", [
    ("name", "mocap", "one of synthetic, bvh, frames"),
    ("path", "", "a non-empty string"),
])
def test_bad_dataset_fields_are_named(field, value, expected):
    p = copy.deepcopy(BASE)
    p["dataset"][field] = value
    with pytest.raises(InputError) as err:
        validate(p, "params.yaml")
    assert f"dataset.{field}" in str(err.value) and expected in str(err.value)


def test_bvh_camera_fields_are_checked():
    p = copy.deepcopy(BASE)
    p["dataset"]["bvh"]["facing"] = "sideways"
    with pytest.raises(InputError, match="dataset.bvh.facing"):
        validate(p, "params.yaml")
    p["dataset"]["bvh"]["facing"] = "none"
    p["dataset"]["bvh"]["fps"] = 0
    with pytest.raises(InputError, match="dataset.bvh.fps"):
        validate(p, "params.yaml")
    assert np.isfinite(validate(copy.deepcopy(BASE))["dataset"]["bvh"]["fps"])
