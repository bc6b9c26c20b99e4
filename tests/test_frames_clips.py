"""Reading clip folders: good clips, and each kind of bad folder or file."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import from_dict, write_annotation
from nnsf.frames.clips import read_clip


def _clip(folder, n=3, size=(40, 30)):
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (n, size[1], size[0], 3), dtype=np.uint8)
    for t in range(n):
        cv2.imwrite(str(folder / f"frame_{t:04d}.png"), cv2.cvtColor(frames[t], cv2.COLOR_RGB2BGR))
    ann = from_dict({
        "format": "nnsf.annotation", "version": 1, "clip": "c", "character": "s", "motion": "m",
        "frames": [f"frame_{t:04d}.png" for t in range(n)], "image_size": list(size),
        "keyframes": [{"frame": 0, "curves": {"head.a": [[1, 1], [2, 2]]}}]}, folder / "annotation.json")
    write_annotation(ann, folder / "annotation.json")
    return frames, ann


def test_reads_frames_in_rgb(tmp_path):
    frames, ann = _clip(tmp_path / "c")
    got = read_clip(tmp_path / "c", ann)
    assert got.dtype == np.uint8 and got.shape == (3, 30, 40, 3)
    np.testing.assert_array_equal(got, frames)
    np.testing.assert_array_equal(read_clip(tmp_path / "c", tmp_path / "c" / "annotation.json"), frames)
    np.testing.assert_array_equal(read_clip(tmp_path / "c"), frames)      # no annotation: by name


def test_annotation_referencing_a_missing_frame(tmp_path):
    _, ann = _clip(tmp_path / "c")
    (tmp_path / "c" / "frame_0001.png").unlink()
    with pytest.raises(InputError, match=r"annotation.json: frames\[1\].*'frame_0001.png' does not exist"):
        read_clip(tmp_path / "c", ann)


def test_frames_of_different_sizes(tmp_path):
    _, ann = _clip(tmp_path / "c")
    cv2.imwrite(str(tmp_path / "c" / "frame_0002.png"), np.zeros((30, 41, 3), np.uint8))
    with pytest.raises(InputError, match=r"frame_0002.png: image size: expected 40x30 .* got '41x30'"):
        read_clip(tmp_path / "c", ann)
    with pytest.raises(InputError, match=r"frame_0002.png: image size.*size of frame_0000.png"):
        read_clip(tmp_path / "c")


def test_truncated_png(tmp_path):
    _, ann = _clip(tmp_path / "c")
    p = tmp_path / "c" / "frame_0001.png"
    p.write_bytes(p.read_bytes()[:-40])
    with pytest.raises(InputError, match=r"frame_0001.png: frames\[1\]: expected a complete PNG.*truncated"):
        read_clip(tmp_path / "c", ann)


def test_unreadable_image(tmp_path):
    _, ann = _clip(tmp_path / "c")
    (tmp_path / "c" / "frame_0000.png").write_bytes(b"not an image at all")
    with pytest.raises(InputError, match=r"frame_0000.png: frames\[0\]: expected an image OpenCV can decode"):
        read_clip(tmp_path / "c", ann)


def test_empty_clip_folder(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match=r"empty: frames: expected a clip folder holding frame images.*empty folder"):
        read_clip(tmp_path / "empty")
    with pytest.raises(InputError, match="existing clip folder"):
        read_clip(tmp_path / "absent")


def test_symlink_escaping_the_folder(tmp_path):
    _, ann = _clip(tmp_path / "c")
    outside = tmp_path / "secret.png"
    cv2.imwrite(str(outside), np.zeros((30, 40, 3), np.uint8))
    (tmp_path / "c" / "frame_0001.png").unlink()
    (tmp_path / "c" / "frame_0001.png").symlink_to(outside)
    with pytest.raises(InputError, match=r"frames\[1\].*inside the clip's folder"):
        read_clip(tmp_path / "c", ann)
