"""The correction loop (nnsf.roto.correct): CVAT export/import, re-solving touched intervals only,
the simulated user, and bad corrections files through ``nnsf roto --corrections``."""
from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
import yaml

from nnsf.cli import main
from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.frames.cvat import read_cvat_video
from nnsf.frames.stage import render_frames
from nnsf.roto.tracks import read_tracks
from nnsf.io import read_npz
from nnsf.roto.correct import (
    KEYFRAME_ATTRIBUTE, export_clips, export_cvat, read_corrections, read_cvat_curves, retrack, simulate_user,
    solve_intervals, stored,
)
from nnsf.roto.metrics import project_to_polyline
from nnsf.roto.solve import ClipTracker, TrackOptions, keyframe_curves
from nnsf.roto.stage import track_clips
from nnsf.roto.toy import draw_polygons, rect, segment_controls

ROOT = Path(__file__).resolve().parents[1]
TRACK = {"method": "ours", "w_velocity": 3.0, "w_length": 1.0, "w_length_anchor": 4.0,
         "w_curvature": 1.0, "w_edge": 1.0, "w_sketch": 100.0, "w_colour": 100.0, "window": 3,
         "samples": 12, "levels": 2, "max_iter": 15, "init": "linear", "lk_end": "blend",
         "eval_clips": 1, "edit_tol_px": 2.0, "max_edits": 3}
FRAMES = {"characters": 1, "motions": ["walk"], "clips_per_cell": 1, "frames": 9, "size": 128,
          "keyframe_every": 4, "control_points": 5}


def _box_clip(T=17):
    """A box moving on a curved path; curves l_forearm.a (its top edge) and l_forearm.b (its right edge)."""
    t = np.arange(T)
    xs = 60 + 50 * np.sin(t / (T - 1) * np.pi)                 # not linear in t
    polys = [rect(x, 90 + 0.8 * i, 50, 70) for i, x in enumerate(xs)]
    frames = np.stack([draw_polygons((192, 192), [p], [(200, 60, 50)]) for p in polys])
    truth = np.stack([np.stack([segment_controls(p[0], p[1], 64), segment_controls(p[1], p[2], 64)])
                      for p in polys])                          # (T, 2, 64, 2)
    keys = (0, 8, 16)
    ann = {"keyframes": [{"frame": k, "curves": {"l_forearm.a": segment_controls(polys[k][0], polys[k][1], 4),
                                                 "l_forearm.b": segment_controls(polys[k][1], polys[k][2], 4)}}
                         for k in keys]}
    return frames, ann, truth


@pytest.fixture(scope="module")
def box():
    frames, ann, truth = _box_clip()
    names, kfs = keyframe_curves(ann)
    tracker = ClipTracker(frames, "ours", TrackOptions(max_nfev=10))
    control = solve_intervals(tracker, names, kfs, np.full((len(frames), 2, 4, 2), np.nan))
    return frames, ann, truth, names, kfs, tracker, control


def test_cvat_export_round_trip_is_exact_to_the_stored_precision(box, tmp_path):
    frames, ann, truth, names, kfs, tracker, control = box
    path = export_cvat(tmp_path / "clip.xml", control, names, [4, 4], list(kfs), "box-clip", (192, 192))
    polys, marked = read_cvat_curves(path, "box-clip", names, [4, 4], len(frames))
    assert sorted(polys) == list(range(len(frames))) and marked == set(kfs)
    for f, cur in polys.items():
        for i, n in enumerate(names):
            assert np.array_equal(cur[n], stored(control[f, i]))     # bit-exact after rounding
            assert np.abs(cur[n] - control[f, i]).max() <= 0.005 + 1e-12
    # CVAT's own importer of the project reads it too (every tracked frame is a CVAT keyframe)
    ann2 = read_cvat_video(path)
    assert ann2.clip == "box-clip" and ann2.image_size == (192, 192) and len(ann2.frames) == 17
    assert ann2.keyframe_indices == list(range(17))
    np.testing.assert_array_equal(ann2.keyframes[5].curves["l_forearm.b"], stored(control[5, 1]))
    # an unedited file has nothing to correct
    assert read_corrections(path, "box-clip", names, [4, 4], control, list(kfs)) == {}


def _edit(path: Path, frame: int, label: str, pts: np.ndarray, out: Path) -> Path:
    tree = ET.parse(path)
    for tr in tree.getroot().iter("track"):
        if tr.get("label") == label:
            for sh in tr.iter("polyline"):
                if sh.get("frame") == str(frame):
                    sh.set("points", ";".join(f"{x:.2f},{y:.2f}" for x, y in pts))
    tree.write(out, encoding="utf-8", xml_declaration=True)
    return out


def test_a_correction_resolves_only_the_intervals_it_touches(box, tmp_path):
    frames, ann, truth, names, kfs, tracker, control = box
    path = export_cvat(tmp_path / "clip.xml", control, names, [4, 4], list(kfs), "box-clip", (192, 192))
    fixed = segment_controls(truth[4, 0, 0], truth[4, 0, -1], 4) + [0.0, 0.4]
    edited = _edit(path, 4, "l_forearm.a", fixed, tmp_path / "edited.xml")
    fixes = read_corrections(edited, "box-clip", names, [4, 4], control, list(kfs))
    assert sorted(fixes) == [4]
    np.testing.assert_array_equal(fixes[4]["l_forearm.a"], stored(fixed))
    np.testing.assert_array_equal(fixes[4]["l_forearm.b"], control[4, 1])  # untouched curve kept as tracked
    new, new_kfs, todo = retrack(tracker, names, kfs, control, fixes)
    assert todo == [(0, 4), (4, 8)] and sorted(new_kfs) == [0, 4, 8, 16]
    # the untouched interval is bit-identical, the touched one changed and meets the correction
    assert np.array_equal(new[8:], control[8:])
    assert not np.array_equal(new[1:4], control[1:4])
    np.testing.assert_array_equal(new[4, 0], stored(fixed))
    # and it is what tracking from the enlarged keyframe set gives for those intervals
    fresh = solve_intervals(tracker, names, new_kfs, np.full_like(control, np.nan), only={(0, 4)})
    np.testing.assert_allclose(new[:5], fresh[:5], atol=1e-9)


def test_the_simulated_user_loop_terminates_with_its_count(box):
    frames, ann, truth, names, kfs, tracker, control = box
    blind = ClipTracker(frames, "agarwala", TrackOptions(edge=0.0, max_nfev=5))
    res = simulate_user(blind, names, kfs, truth, [4, 4], tol=2.0, max_rounds=50)
    inbetween = 17 - 3
    assert res["left"] == 0 and 0 < res["edits"] <= inbetween * 8
    assert 1 <= res["rounds"] <= res["corrected_frames"] <= inbetween
    d, _ = project_to_polyline(res["control"], truth)
    assert d.max() <= 2.0 + 1e-9
    # the count is reproducible: the same loop again gives the same figures
    again = simulate_user(blind, names, kfs, truth, [4, 4], tol=2.0, max_rounds=50)
    assert (again["edits"], again["rounds"], again["corrected_frames"]) == \
        (res["edits"], res["rounds"], res["corrected_frames"])
    # a tolerance nothing meets still ends: every in-between frame corrected, in at most 4 rounds
    # per 7-frame interval (halving), and no point is left
    strict = simulate_user(blind, names, kfs, truth, [4, 4], tol=1e-9, max_rounds=50)
    assert strict["left"] == 0 and strict["corrected_frames"] == inbetween
    assert strict["rounds"] <= 7 and sorted(strict["keyframes"]) == list(range(17))


# --------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def project(tmp_path_factory):
    root = tmp_path_factory.mktemp("correct-project")
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    params["frames"].update(FRAMES)
    params["roto"].update(TRACK)
    (root / "params.yaml").write_text(yaml.safe_dump(params))
    render_frames(params, root / "data" / "frames")
    track_clips(params, root / "data" / "frames", root / "data" / "tracks")
    export_clips(root / "data" / "frames", root / "data" / "tracks", root / "cvat")
    return root


def test_track_exports_cvat_and_takes_corrections_back(project, tmp_path, monkeypatch, capsys):
    import shutil

    work = tmp_path / "p"
    shutil.copytree(project, work)
    monkeypatch.chdir(work)
    assert main(["roto", "--export-cvat", "cvat"]) == 0
    clip = sorted(p.stem for p in (work / "cvat").glob("*.xml"))[0]
    xml = work / "cvat" / f"{clip}.xml"
    ann = read_annotation(work / "data" / "frames" / clip / "annotation.json")
    before, names, _ = read_tracks(work / "data" / "tracks" / clip / "curves.npz", ann)
    fixed = before[2, 0, :5] + [1.5, 0.0]
    _edit(xml, 2, names[0], fixed, xml)
    assert main(["roto", "--corrections", str(xml)]) == 0
    out = capsys.readouterr().out
    assert "corrected frames [2]" in out and "[(0, 2), (2, 4)]" in out
    z = read_npz(work / "data" / "tracks" / clip / "curves.npz")
    assert list(z["keyframes"]) == [0, 2, 4, 8]
    np.testing.assert_array_equal(z["control"][2, 0, :5], stored(fixed))
    assert np.array_equal(z["control"][4:], before[4:])           # interval (4, 8) untouched
    assert (work / "data" / "tracked" / "keypoints.csv").is_file()


@pytest.mark.parametrize("case, field", [
    ("other_clip", "<meta><task><name>"),
    ("frame_outside", "frame: expected a frame of the clip, 0..8"),
    ("unknown_label", "label: expected one of the clip's curves"),
])
def test_bad_corrections_files_exit_2_with_one_line(project, tmp_path, monkeypatch, capsys, case, field):
    import shutil

    work = tmp_path / "p"
    shutil.copytree(project, work)
    monkeypatch.chdir(work)
    xml = sorted((work / "cvat").glob("*.xml"))[0]
    before = (work / "data" / "tracks" / xml.stem / "curves.npz").read_bytes()
    tree = ET.parse(xml)
    root = tree.getroot()
    args = ["roto", "--corrections", str(xml)]
    if case == "other_clip":
        root.find("meta/task/name").text = "some-other-clip"
        args += ["--clip", xml.stem]
    elif case == "frame_outside":
        root.find("track/polyline[last()]").set("frame", "9")
    else:
        root.find("track").set("label", "tail.a")
    tree.write(xml, encoding="utf-8", xml_declaration=True)
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and err.startswith(f"error: {xml}: ") and field in err, err
    assert (work / "data" / "tracks" / xml.stem / "curves.npz").read_bytes() == before
    # without --clip, a file naming a clip the project does not have is refused the same way
    if case == "other_clip":
        assert main(["roto", "--corrections", str(xml)]) == 2
        err = capsys.readouterr().err.strip()
        assert "<meta><task><name>" in err and "some-other-clip" in err


def test_read_cvat_curves_names_a_bad_vertex_count(box, tmp_path):
    frames, ann, truth, names, kfs, tracker, control = box
    path = export_cvat(tmp_path / "clip.xml", control, names, [4, 4], list(kfs), "box-clip", (192, 192))
    bad = _edit(path, 3, "l_forearm.b", control[3, 1, :3], tmp_path / "bad.xml")
    with pytest.raises(InputError, match=r"bad\.xml: track id=1 frame=3 points: expected exactly 4"):
        read_cvat_curves(bad, "box-clip", names, [4, 4], len(frames))
    assert KEYFRAME_ATTRIBUTE in path.read_text()
