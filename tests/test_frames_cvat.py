"""CVAT for video 1.1 import: the hand-written sample round-trips; bad exports are named."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.frames.cvat import import_cvat, read_cvat_video
from nnsf.skeleton import JOINT_INDEX

SAMPLE = Path(__file__).parent / "data" / "cvat" / "sample_video_1_1.xml"


def test_sample_round_trips(tmp_path):
    ann = import_cvat(SAMPLE, tmp_path / "ann.json", character="robot", motion="walk")
    back = read_annotation(tmp_path / "ann.json")
    assert back.to_dict() == ann.to_dict()
    assert back.clip == "robot_walk" and back.image_size == (256, 256)
    assert back.frames == [f"frame_{i:06d}.png" for i in range(6)]
    assert back.keyframe_indices == [0, 5]                 # frame 2 (keyframe="0") ignored
    assert back.curve_names == ["l_forearm.a", "l_forearm.b", "r_shin.a", "r_shin.b"]
    k0, k5 = back.keyframes
    np.testing.assert_array_equal(k0.curves["l_forearm.a"], [[147.0, 130.5], [149.8, 143.0], [152.9, 156.6]])
    np.testing.assert_array_equal(k5.curves["r_shin.b"], [[121.0, 190.5], [118.0, 209.5], [114.5, 228.5]])
    np.testing.assert_array_equal(k5.calibration["l_forearm"],
                                  [[149.5, 131.0], [155.25, 128.75], [158.25, 154.0], [164.0, 151.5]])
    assert k0.keypoints is not None and k5.keypoints is None   # outside="1" point ignored
    np.testing.assert_array_equal(k0.keypoints[JOINT_INDEX["l_elbow"]], [150.0, 130.0])
    np.testing.assert_array_equal(k0.keypoints[JOINT_INDEX["pelvis"]], [128.0, 150.0])


def test_overrides(tmp_path):
    ann = read_cvat_video(SAMPLE, clip="x", n_frames=8, image_size=(300, 200), frame_pattern="f{:03d}.png")
    assert ann.clip == "x" and ann.frames[-1] == "f007.png" and ann.image_size == (300, 200)


def _variant(tmp_path, old, new) -> Path:
    text = SAMPLE.read_text()
    assert old in text
    p = tmp_path / "bad.xml"
    p.write_text(text.replace(old, new, 1))
    return p


def test_unknown_label(tmp_path):
    p = _variant(tmp_path, 'label="r_shin.b"', 'label="r_tail.b"')
    with pytest.raises(InputError) as err:
        read_cvat_video(p)
    msg = str(err.value)
    assert str(p) in msg and "track id=3" in msg and "r_tail.b" in msg


def test_other_bad_exports(tmp_path):
    cases = [
        (('label="pelvis"', 'label="l_forearm.c"'), "track id=10"),
        (('<polyline frame="5" outside="0" occluded="0" keyframe="1" points="113.00',
          '<polyline frame="5" outside="1" occluded="0" keyframe="1" points="113.00'),
         "a keyframe at frame 5"),
        (('points="118.00,152.00"', 'points="118.00,152.00;1,2"'), "track id=11 label='r_hip' frame=0 points"),
        (('points="147.00,130.50;', 'points="147.00,nan;'), "track id=0"),
        (("<version>1.1</version>", "<version>2.0</version>"), "<version>"),
        (('<track id="17" label="spine" source="manual">', '<track id="17" label="l_forearm.a" source="manual">'),
         "track id=17"),
        (("</annotations>", "</annotation>"), "well-formed XML"),
    ]
    for (old, new), fragment in cases:
        p = _variant(tmp_path, old, new)
        with pytest.raises(InputError) as err:
            read_cvat_video(p)
        assert str(p) in str(err.value) and fragment in str(err.value), str(err.value)


def test_partial_keypoints_and_entities(tmp_path):
    text = SAMPLE.read_text()
    start = text.index('<track id="26"')
    end = text.index("</track>", start) + len("</track>")
    p = tmp_path / "partial.xml"
    p.write_text(text[:start] + text[end:])
    with pytest.raises(InputError, match="missing r_wrist"):
        read_cvat_video(p)
    p.write_text(text.replace("<annotations>", '<!DOCTYPE a [<!ENTITY x "y">]>\n<annotations>', 1))
    with pytest.raises(InputError, match="DOCTYPE"):
        read_cvat_video(p)
