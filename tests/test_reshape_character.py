"""Reading drawn characters (AnimatedDrawings folders, our JSON file) and their bad inputs."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.reshape.character import (
    HEAD_TOP_FRACTION, Character, MaskComponentsWarning, load_animated_drawings, load_character,
    points_in_mask, read_character, stick_figure, write_character,
)
from nnsf.skeleton import JOINT_INDEX as J

CHARACTERS = Path(__file__).resolve().parents[2] / "shared" / "data" / "animated-drawings" / "characters"


def _needs_data():
    if not (CHARACTERS / "char1" / "char_cfg.yaml").is_file():
        pytest.skip(f"AnimatedDrawings example characters not found at {CHARACTERS}")


@pytest.fixture(scope="module")
def figure() -> Character:
    return stick_figure(height=300)


def _write_png(path: Path, img: np.ndarray) -> None:
    assert cv2.imwrite(str(path), img)


def _json_character(folder: Path, figure: Character, **changes) -> Path:
    """Write ``figure`` as our JSON file, then patch JSON fields with ``changes``."""
    path = write_character(figure, folder / "fig.json")
    obj = json.loads(path.read_text())
    obj.update(changes)
    path.write_text(json.dumps(obj))
    return path


# --------------------------------------------------------------------------- AnimatedDrawings

def test_char1_maps_16_joints_to_17_keypoints():
    _needs_data()
    ch = load_animated_drawings(CHARACTERS / "char1")
    assert ch.name == "char1" and ch.mask.shape == (602, 508) and ch.texture.shape == (602, 508, 4)
    kp = ch.keypoints
    # Copies of AnimatedDrawings joints (char_cfg.yaml of char1).
    np.testing.assert_array_equal(kp[J["pelvis"]], [264, 397])
    np.testing.assert_array_equal(kp[J["thorax"]], [247, 232])
    np.testing.assert_array_equal(kp[J["neck"]], [231, 119])
    np.testing.assert_array_equal(kp[J["l_wrist"]], [449, 278])   # left_hand
    np.testing.assert_array_equal(kp[J["r_ankle"]], [138, 556])   # right_foot
    # Derived points.
    np.testing.assert_allclose(kp[J["spine"]], [(264 + 247) / 2, (397 + 232) / 2])
    up = kp[J["head_top"]] - kp[J["neck"]]
    d = np.array([231 - 247, 119 - 232], float)
    assert abs(up[0] * d[1] - up[1] * d[0]) < 1e-9 and up @ d > 0   # along torso→neck
    exit_at = np.linalg.norm(up) / HEAD_TOP_FRACTION
    assert points_in_mask(ch.mask, kp[J["head_top"]])
    assert not points_in_mask(ch.mask, kp[J["neck"]] + (exit_at + 1.0) * d / np.linalg.norm(d))
    assert points_in_mask(ch.mask, kp).all()


def test_every_biped_example_loads_and_multi_limbed_ones_are_rejected():
    _needs_data()
    for name in ("char1", "char2", "char3", "char4"):
        assert load_character(CHARACTERS / name).keypoints.shape == (17, 2)
    with pytest.raises(InputError) as err:
        load_animated_drawings(CHARACTERS / "char5")
    msg = str(err.value)
    assert "char_cfg.yaml" in msg and "skeleton" in msg and "right_shoulder1" in msg
    assert "several shoulders" in msg
    with pytest.raises(InputError, match="missing joints: .*right_shoulder"):
        load_animated_drawings(CHARACTERS / "char6" / "char_cfg.yaml")


def _ad_folder(tmp_path: Path, figure: Character, joints: dict | None = None) -> Path:
    """An AnimatedDrawings-style folder holding ``figure``."""
    folder = tmp_path / "ad"
    folder.mkdir()
    _write_png(folder / "texture.png", cv2.cvtColor(figure.texture, cv2.COLOR_RGBA2BGRA))
    _write_png(folder / "mask.png", figure.mask.astype(np.uint8) * 255)
    kp = figure.keypoints
    ours = {"root": "pelvis", "hip": "pelvis", "torso": "thorax", "neck": "neck",
            "right_shoulder": "r_shoulder", "right_elbow": "r_elbow", "right_hand": "r_wrist",
            "left_shoulder": "l_shoulder", "left_elbow": "l_elbow", "left_hand": "l_wrist",
            "right_hip": "r_hip", "right_knee": "r_knee", "right_foot": "r_ankle",
            "left_hip": "l_hip", "left_knee": "l_knee", "left_foot": "l_ankle"}
    joints = joints if joints is not None else {k: kp[J[v]].round().tolist() for k, v in ours.items()}
    skel = [{"name": k, "loc": v, "parent": None} for k, v in joints.items()]
    import yaml
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(
        {"height": figure.mask.shape[0], "width": figure.mask.shape[1], "skeleton": skel}))
    return folder


def test_animated_drawings_bad_inputs(tmp_path, figure):
    folder = _ad_folder(tmp_path, figure)
    assert load_character(folder).keypoints.shape == (17, 2)
    import yaml
    cfg = yaml.safe_load((folder / "char_cfg.yaml").read_text())
    # A missing joint.
    bad = dict(cfg, skeleton=[j for j in cfg["skeleton"] if j["name"] != "left_knee"])
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(bad))
    with pytest.raises(InputError, match=r"char_cfg.yaml: skeleton: .*missing joints: left_knee"):
        load_character(folder)
    # A joint outside the mask.
    bad = dict(cfg, skeleton=[dict(j, loc=[1, 1]) if j["name"] == "left_knee" else j for j in cfg["skeleton"]])
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(bad))
    with pytest.raises(InputError, match=r"char_cfg.yaml: keypoints.l_knee: expected a point inside the mask"):
        load_character(folder)
    # Size in the config disagrees with the images.
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(dict(cfg, width=7)))
    with pytest.raises(InputError, match="width"):
        load_character(folder)


# --------------------------------------------------------------------------- our JSON format

def test_json_round_trip(tmp_path, figure):
    path = write_character(figure, tmp_path / "hero.json")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hero.json", "hero.mask.png", "hero.texture.png"]
    back = read_character(path)
    assert back.name == figure.name
    # The JSON keeps every output's 6 significant digits (nnsf.io.DIGITS): 0.001 px at 100-999 px.
    np.testing.assert_allclose(back.keypoints, figure.keypoints, rtol=5.1e-6, atol=0)
    np.testing.assert_array_equal(back.mask, figure.mask)
    np.testing.assert_array_equal(back.texture, figure.texture)
    assert json.loads(path.read_text())["keypoints"]["head_top"] == pytest.approx(
        figure.keypoints[J["head_top"]].tolist(), rel=5.1e-6)


def test_json_paths_must_stay_in_the_folder(tmp_path, figure):
    inner = tmp_path / "inner"
    inner.mkdir()
    shutil.copy(write_character(figure, tmp_path / "outside.json").with_suffix(".texture.png"),
                tmp_path / "t.png")
    for rel in ("../t.png", str(tmp_path / "t.png")):
        path = _json_character(inner, figure, texture=rel)
        with pytest.raises(InputError, match=r"fig.json: texture: expected a (relative )?path"):
            read_character(path)


def test_json_missing_keypoints_and_bad_values(tmp_path, figure):
    path = _json_character(tmp_path, figure)
    obj = json.loads(path.read_text())
    del obj["keypoints"]["r_knee"]
    path.write_text(json.dumps(obj))
    with pytest.raises(InputError, match=r"fig.json: keypoints: .*missing r_knee"):
        read_character(path)
    obj["keypoints"]["r_knee"] = ["a", 3]
    path.write_text(json.dumps(obj))
    with pytest.raises(InputError, match=r"keypoints.r_knee: expected \[x, y\]"):
        read_character(path)
    obj["keypoints"]["r_knee"] = [-50.0, 10.0]
    path.write_text(json.dumps(obj))
    with pytest.raises(InputError, match=r"fig.json: keypoints.r_knee: expected a point inside the mask"):
        read_character(path)


def test_empty_mask_size_mismatch_and_components(tmp_path, figure):
    path = _json_character(tmp_path, figure)
    mask_path = tmp_path / "fig.mask.png"
    mask = figure.mask.astype(np.uint8) * 255
    _write_png(mask_path, np.zeros_like(mask))
    with pytest.raises(InputError, match=r"fig.json: mask: expected a silhouette .*empty mask"):
        read_character(path)
    _write_png(mask_path, mask[:-3])
    with pytest.raises(InputError, match=r"fig.json: mask: expected the texture's size 361x300"
                       if figure.mask.shape[1] == 361 else r"fig.json: mask: expected the texture's size"):
        read_character(path)
    speck = mask.copy()
    speck[2:6, 2:6] = 255   # a stray blob of ink away from the body
    _write_png(mask_path, speck)
    with pytest.warns(MaskComponentsWarning, match="kept the largest of 2 components"):
        ch = read_character(path)
    assert not ch.mask[2:6, 2:6].any() and ch.mask.sum() == figure.mask.sum()
    assert ch.notes and "dropped 16 px" in ch.notes[0]


def test_in_memory_character_is_validated(figure):
    kp = figure.keypoints.copy()
    kp[J["l_wrist"]] = [0.0, 0.0]
    with pytest.raises(InputError, match="keypoints.l_wrist"):
        Character("x", figure.texture, figure.mask, kp)
    with pytest.raises(InputError, match="mask"):
        Character("x", figure.texture, np.zeros_like(figure.mask), figure.keypoints)
