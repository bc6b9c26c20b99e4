"""The tracking stages: track_clips (TRACKS format) and evaluate_tracking (reports)."""
from __future__ import annotations

import shutil

import numpy as np
import pandas as pd
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.frames.stage import render_frames
from nnsf.roto.tracks import read_tracks
from nnsf.io import read_json
from nnsf.roto.evaluation import evaluate_tracking
from nnsf.roto.stage import track_clips

TRACK = {"method": "ours", "w_velocity": 3.0, "w_length": 1.0, "w_length_anchor": 4.0, "w_curvature": 1.0, "w_edge": 1.0,
         "w_sketch": 100.0, "w_colour": 100.0, "window": 3, "samples": 12, "levels": 2,
         "max_iter": 15, "init": "linear", "lk_end": "blend", "eval_clips": 1,
         "edit_tol_px": 2.0, "max_edits": 3}
PARAMS = {"seed": 3, "frames": {"characters": 1, "motions": ["walk", "wave"], "clips_per_cell": 1,
                                "frames": 9, "size": 128, "keyframe_every": 4, "control_points": 5},
          "roto": TRACK}


@pytest.fixture(scope="module")
def frames_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("track-stage") / "frames"
    render_frames(PARAMS, out)
    return out


def test_track_clips_writes_tracks_the_keypoint_reader_accepts(frames_dir, tmp_path):
    seen = []

    def mapper(fn, items):
        seen.extend(i["clip"] for i in items)
        return [fn(i) for i in items]

    res = track_clips(PARAMS, frames_dir, tmp_path / "tracks", mapper=mapper)
    index = pd.read_csv(frames_dir / "index.csv")
    assert sorted(seen) == sorted(index["clip"]) and res.metrics["clips"] == len(index)
    for clip in index["clip"]:
        ann = read_annotation(frames_dir / clip / "annotation.json")
        control, names, n_points = read_tracks(tmp_path / "tracks" / clip / "curves.npz", ann)
        assert control.shape[:2] == (9, 20) and np.isfinite(control).all()
        truth = np.load(frames_dir / clip / "truth.npz")
        # tracked control points near the truth's fitted ones (synthetic clip, 4-frame intervals)
        idx = [list(truth["side_names"]).index(n) for n in names]
        err = np.linalg.norm(control - truth["control"][:, idx], axis=-1)
        assert np.median(err) < 1.5


def test_a_bad_clip_is_reported_and_the_others_are_kept(frames_dir, tmp_path):
    bad = tmp_path / "frames"
    shutil.copytree(frames_dir, bad)
    clips = list(pd.read_csv(bad / "index.csv")["clip"])
    png = bad / clips[0] / "frame_0003.png"
    png.write_bytes(png.read_bytes()[:200])                # truncated PNG
    with pytest.raises(InputError) as exc:
        track_clips(PARAMS, bad, tmp_path / "tracks")
    assert clips[0] in str(exc.value) and "frame_0003.png" in str(exc.value)
    assert not (tmp_path / "tracks" / clips[0]).exists()
    assert (tmp_path / "tracks" / clips[1] / "curves.npz").is_file()
    assert clips[0] in read_json(tmp_path / "tracks" / "failed.json")


def test_bad_track_params_name_the_field(frames_dir, tmp_path):
    for key, value in (("w_sketch", -1.0), ("window", 2.5), ("method", "snake"), ("init", "spline")):
        params = {**PARAMS, "roto": {**TRACK, key: value}}
        with pytest.raises(InputError, match=f"roto.{key}"):
            track_clips(params, frames_dir, tmp_path / "tracks")
    assert not (tmp_path / "tracks").exists()


def test_evaluate_tracking_writes_reports(frames_dir, tmp_path):
    reports = tmp_path / "reports"
    res = evaluate_tracking(PARAMS, frames_dir, reports)
    summary = read_json(reports / "roto_eval.json")["trackers"]
    assert set(summary) == {"ours", "agarwala", "lk"}
    for s in summary.values():
        assert s["mean_px"] >= 0 and s["p95_px"] >= s["mean_px"]
        assert 0 <= s["pck"] <= 1 and 0 <= s["edit_ratio"] <= 1 and s["clips"] == 1
    table = pd.read_csv(reports / "roto_eval.csv")
    assert sorted(table["tracker"]) == ["agarwala", "lk", "ours"]
    assert (reports / "figures" / "roto_overlay.png").stat().st_size > 10_000
    assert res.metrics["ours_mean_px"] == pytest.approx(summary["ours"]["mean_px"], rel=5.1e-6)  # 6 digits
    # deterministic: a second run writes the same bytes
    first = (reports / "roto_eval.json").read_bytes()
    evaluate_tracking(PARAMS, frames_dir, reports)
    assert (reports / "roto_eval.json").read_bytes() == first
