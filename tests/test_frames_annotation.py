"""Annotation format v1: round trip and every validation rule (docs/formats.md §2.2)."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import dumps, from_dict, read_annotation, write_annotation
from nnsf.skeleton import JOINTS


def _valid() -> dict:
    a = [[10.0, 10.0], [11.0, 20.0], [12.0, 30.0]]
    b = [[16.0, 10.0], [17.0, 20.0], [18.0, 30.0]]
    kp = {j: [50.0 + i, 60.0 + 2 * i] for i, j in enumerate(JOINTS)}
    return {
        "format": "nnsf.annotation", "version": 1, "clip": "c00_walk_00", "character": "c00",
        "motion": "walk", "frames": [f"frame_{t:04d}.png" for t in range(4)], "image_size": [64, 48],
        "keyframes": [
            {"frame": 3, "curves": {"l_forearm.a": copy.deepcopy(a), "l_forearm.b": copy.deepcopy(b)}},
            {"frame": 0, "curves": {"l_forearm.a": a, "l_forearm.b": b},
             "calibration": {"l_forearm": [a[0], b[0], a[-1], b[-1]]}, "keypoints": kp},
        ],
    }


def _write(tmp_path, obj) -> str:
    p = tmp_path / "ann.json"
    p.write_text(json.dumps(obj))
    return p


def test_round_trip_sorted_and_calibration_derived(tmp_path):
    ann = read_annotation(_write(tmp_path, _valid()))
    assert ann.keyframe_indices == [0, 3]
    np.testing.assert_array_equal(ann.keyframes[1].calibration["l_forearm"],
                                  [[10, 10], [16, 10], [12, 30], [18, 30]])
    assert ann.groups == ["l_forearm"] and ann.keyframes[1].keypoints is None
    out = write_annotation(ann, tmp_path / "sub" / "copy.json")
    again = read_annotation(out)
    assert again.to_dict() == ann.to_dict()
    assert dumps(again) == out.read_text()
    assert '[10.0, 10.0]' in out.read_text()         # pairs on one line


def _bad(obj, tmp_path, *fragments):
    path = _write(tmp_path, obj)
    with pytest.raises(InputError) as err:
        read_annotation(path)
    msg = str(err.value)
    assert str(path) in msg
    for f in fragments:
        assert f in msg, msg
    return msg


def test_keyframe_referencing_a_missing_frame(tmp_path):
    obj = _valid()
    obj["keyframes"][0]["frame"] = 4
    _bad(obj, tmp_path, "keyframes[0].frame", "the clip has 4 frames")


def test_curve_with_fewer_than_two_points(tmp_path):
    obj = _valid()
    obj["keyframes"][1]["curves"]["l_forearm.a"] = [[1.0, 2.0]]
    obj["keyframes"][1].pop("calibration")
    _bad(obj, tmp_path, 'keyframes[1].curves["l_forearm.a"]', "at least 2", "1 point")


@pytest.mark.parametrize("rel", ["../other/frame.png", "/etc/passwd", "a/../../x.png", "C:/x.png"])
def test_frame_path_escaping_the_folder(tmp_path, rel):
    obj = _valid()
    obj["frames"][2] = rel
    _bad(obj, tmp_path, "frames[2]")


def test_other_rules(tmp_path):
    cases = [
        (lambda o: o.update(version=2), "version"),
        (lambda o: o.update(format="x"), "format"),
        (lambda o: o["keyframes"][0]["curves"].update({"tail.a": [[0, 0], [1, 1]]}), 'curves["tail.a"]'),
        (lambda o: o["keyframes"][0]["curves"]["l_forearm.b"].__setitem__(1, [1.0, float("nan")]),
         'curves["l_forearm.b"][1]'),
        (lambda o: o["keyframes"][1]["calibration"]["l_forearm"].__setitem__(2, [14.0, 30.0]),
         'calibration["l_forearm"][2]'),
        (lambda o: o["keyframes"][0].update(frame=0), "keyframes[1].frame"),          # duplicate
        (lambda o: o["keyframes"][1]["keypoints"].pop("spine"), "missing spine"),
        (lambda o: o.update(image_size=[64]), "image_size"),
        (lambda o: o["frames"].__setitem__(1, "frame_0000.png"), "frames[1]"),
        (lambda o: o["keyframes"][0]["curves"].pop("l_forearm.b"), "keyframes[1].curves"),
        (lambda o: o["keyframes"][0]["curves"]["l_forearm.b"].append([3.0, 3.0]),
         'keyframes[1].curves["l_forearm.b"]'),
    ]
    for change, fragment in cases:
        obj = copy.deepcopy(_valid())
        change(obj)
        _bad(obj, tmp_path, fragment)


def test_write_refuses_invalid_and_leaves_nothing(tmp_path):
    ann = from_dict(_valid())
    ann.keyframes[0].curves["l_forearm.a"] = np.array([[1.0, 2.0]])
    with pytest.raises(InputError):
        write_annotation(ann, tmp_path / "x.json")
    assert list(tmp_path.iterdir()) == []
