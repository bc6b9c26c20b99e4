"""Reading drawn characters: every format, joints off the drawing, sizes, the mask from the paper and
the character YAML's choices."""
from __future__ import annotations

import struct
import subprocess
import sys
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from nnsf.errors import InputError
from stick_figure import stick_figure
from nnsf.reshape.character import Character, mask_from_border
from nnsf.reshape.formats import read_character, write_character
from nnsf.safe_yaml import read_yaml
from nnsf.skeleton import JOINT_INDEX as J, JOINTS

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
REPO = Path(__file__).resolve().parents[1]
AD_NAMES = {"root": "pelvis", "hip": "pelvis", "torso": "thorax", "neck": "neck",
            "right_shoulder": "r_shoulder", "right_elbow": "r_elbow", "right_hand": "r_wrist",
            "left_shoulder": "l_shoulder", "left_elbow": "l_elbow", "left_hand": "l_wrist",
            "right_hip": "r_hip", "right_knee": "r_knee", "right_foot": "r_ankle",
            "left_hip": "l_hip", "left_knee": "l_knee", "left_foot": "l_ankle"}


def _needs(path: Path):
    if not path.exists():
        pytest.skip(f"shared data not found: {path}")


@pytest.fixture(scope="module")
def figure() -> Character:
    return stick_figure(height=300)


def _ad_folder(folder: Path, figure: Character, moved: dict | None = None) -> Path:
    """An AnimatedDrawings folder holding ``figure``; ``moved``: joints to put elsewhere."""
    folder.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(folder / "texture.png"), cv2.cvtColor(figure.texture, cv2.COLOR_RGBA2BGRA))
    assert cv2.imwrite(str(folder / "mask.png"), figure.mask.astype(np.uint8) * 255)
    joints = {k: figure.keypoints[J[v]].round().tolist() for k, v in AD_NAMES.items()}
    joints.update(moved or {})
    skel = [{"name": k, "loc": v, "parent": None} for k, v in joints.items()]
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(
        {"height": figure.mask.shape[0], "width": figure.mask.shape[1], "skeleton": skel}))
    return folder


# --------------------------------------------------------------------------- AnimatedDrawings

def test_an_animated_drawings_folder_maps_16_joints_to_our_17(tmp_path, figure):
    ch = read_character(_ad_folder(tmp_path / "ad", figure))
    kp = ch.keypoints
    np.testing.assert_allclose(kp[J["l_wrist"]], figure.keypoints[J["l_wrist"]].round())
    np.testing.assert_allclose(kp[J["spine"]], 0.5 * (kp[J["pelvis"]] + kp[J["thorax"]]))
    # head_top continues thorax -> neck inside the mask, beyond the neck.
    up = kp[J["neck"]] - kp[J["thorax"]]
    assert np.dot(kp[J["head_top"]] - kp[J["neck"]], up) > 0 and ch.mask[tuple(np.rint(kp[J["head_top"]][::-1]).astype(int))]


def test_a_joint_a_few_pixels_off_is_moved_on_with_a_note_one_far_off_is_refused(tmp_path, figure):
    foot = figure.keypoints[J["l_ankle"]]
    rows = np.flatnonzero(figure.mask.any(axis=1))
    height = rows[-1] - rows[0] + 1
    below = rows[-1] + 4                          # 4 px below the drawing's lowest row
    ch = read_character(_ad_folder(tmp_path / "near", figure, {"left_foot": [float(foot[0]), float(below)]}))
    assert any("skeleton.left_foot.loc" in n and "moved onto" in n for n in ch.notes), ch.notes
    assert ch.mask[int(ch.keypoints[J["l_ankle"]][1]), int(ch.keypoints[J["l_ankle"]][0])]
    far = rows[-1] + 0.1 * height
    with pytest.raises(InputError) as err:
        read_character(_ad_folder(tmp_path / "far", figure, {"left_foot": [float(foot[0]), float(far)]}))
    msg = str(err.value)
    assert "skeleton.left_foot.loc" in msg and "px outside it" in msg and "5 % of the figure's height" in msg


def test_the_shared_drawings_that_need_it_are_snapped_or_refused():
    _needs(DATA / "drawings-extra" / "postava")
    ch = read_character(DATA / "drawings-extra" / "postava")
    assert any("foot" in n and "moved onto" in n for n in ch.notes)
    with pytest.raises(InputError, match=r"crayon_dad/char_cfg.yaml: skeleton.left_foot.loc: .*4\d\.\d px outside"):
        read_character(DATA / "drawings-extra" / "crayon_dad")
    # The hand-made joints of the project read it (the drawing's path inside the data folder).
    fixed = read_character(REPO / "tests" / "data" / "drawings" / "crayon_dad.yaml", root=DATA)
    assert fixed.keypoints.shape == (17, 2)


def test_numbered_arms_and_quadrupeds():
    _needs(DATA / "animated-drawings" / "characters" / "char6")
    five = read_character(DATA / "animated-drawings" / "characters" / "char5")
    assert len(five.extra_limbs) == 4 and {a["side"] for a in five.extra_limbs} == {"l", "r"}
    assert sum("drives the" in n for n in five.notes) == 2
    assert read_character(DATA / "animated-drawings" / "characters" / "char6").body == "quadruped"


@pytest.mark.parametrize("change, field", [
    (lambda c: c["skeleton"].pop(3), "skeleton: expected the 16 joints"),
    (lambda c: c["skeleton"][0].update(loc=[1, 2, 3]), "skeleton.root.loc: expected [x, y]"),
    (lambda c: c["skeleton"][0].update(loc=[[1] * 10 ** 5, 2]), "skeleton.root.loc: expected [x, y]"),
    (lambda c: c["skeleton"][0].update(loc=["1", 2]), "skeleton.root.loc"),
    (lambda c: c.update(skeleton=[c["skeleton"][0]] * 300), "skeleton: expected a list of 1..256 joints"),
    (lambda c: c.update(width=7), "width"),
])
def test_a_bad_char_cfg_is_one_error_naming_the_field(tmp_path, figure, change, field):
    folder = _ad_folder(tmp_path / "ad", figure)
    cfg = yaml.safe_load((folder / "char_cfg.yaml").read_text())
    change(cfg)
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError) as err:
        read_character(folder)
    assert field in str(err.value)


def test_yaml_is_read_through_one_function_that_refuses_tags(tmp_path):
    p = tmp_path / "x.yaml"
    p.write_text("a: !!python/object:os.system {}\n")
    with pytest.raises(InputError, match="x.yaml: line 1: expected YAML without tags that build Python objects"):
        read_yaml(p)
    # Every reader of the package goes through nnsf.safe_yaml (tests/test_ops_safety.py checks the project).
    assert not [f.name for f in (REPO / "nnsf" / "reshape").glob("*.py") if "import yaml" in f.read_text()]


# --------------------------------------------------------------------------- PNG, YAML, JSON

def _png_with_yaml(folder: Path, figure: Character, **extra) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    assert cv2.imwrite(str(folder / "hero.png"), cv2.cvtColor(figure.texture, cv2.COLOR_RGBA2BGRA))
    doc = {"joints": {j: [float(x), float(y)] for j, (x, y) in zip(JOINTS, figure.keypoints)}, **extra}
    (folder / "hero.yaml").write_text(yaml.safe_dump(doc))
    return folder / "hero.png"


def test_a_png_with_its_character_yaml_and_its_choices(tmp_path, figure):
    png = _png_with_yaml(tmp_path / "c", figure, arms="drawing", head="torso", depth=["left_arm over torso"])
    ch = read_character(png)
    np.testing.assert_allclose(ch.keypoints, figure.keypoints)
    assert (ch.arms, ch.head) == ("drawing", "torso") and len(ch.depth) == 1
    assert read_character(tmp_path / "c" / "hero.yaml").name == "hero"


@pytest.mark.parametrize("extra, field", [({"arms": "wave"}, "arms: expected motion or drawing"),
                                          ({"depth": ["tail over torso"]}, "depth[0]"),
                                          ({"image": "../x.png"}, "image: expected a relative path")])
def test_bad_character_yaml_choices_name_the_field(tmp_path, figure, extra, field):
    _png_with_yaml(tmp_path / "c", figure, **extra)
    with pytest.raises(InputError) as err:
        read_character(tmp_path / "c" / "hero.yaml")
    assert field in str(err.value)


def test_json_round_trip(tmp_path, figure):
    ch = read_character(write_character(figure, tmp_path / "fig.json"))
    np.testing.assert_array_equal(ch.texture, figure.texture)
    np.testing.assert_allclose(ch.keypoints, figure.keypoints, atol=1e-3)   # the JSON keeps 3 decimals


def test_the_mask_from_the_paper_colour_keeps_white_inside_the_figure(tmp_path):
    img = np.full((120, 100, 3), 250, np.uint8)
    cv2.circle(img, (50, 60), 40, (20, 20, 20), 3)          # an outline; white inside
    cv2.line(img, (50, 20), (50, 100), (20, 20, 20), 2)
    rgba = cv2.cvtColor(img, cv2.COLOR_RGB2RGBA)
    m = mask_from_border(rgba)
    assert m[60, 30] and m[60, 70] and not m[5, 5] and not m[60, 95]
    # A PNG without alpha is refused with a pointer to the option, and read with it.
    assert cv2.imwrite(str(tmp_path / "d.png"), img)
    kp = {j: [50.0, 60.0] for j in JOINTS}
    kp.update(head_top=[50.0, 25.0], pelvis=[50.0, 90.0], thorax=[50.0, 40.0])
    (tmp_path / "d.yaml").write_text(yaml.safe_dump({"joints": kp}))
    with pytest.raises(InputError, match="d.png: alpha: .*--mask auto"):
        read_character(tmp_path / "d.png")
    assert read_character(tmp_path / "d.png", mask="auto").mask[60, 30]


def _png_header(path: Path, width: int, height: int) -> None:
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk + struct.pack(">I", zlib.crc32(chunk))
                     + b"\x00" * 64)


def test_a_huge_png_header_is_refused_before_decoding(tmp_path):
    _png_header(tmp_path / "huge.png", 20000, 20000)
    (tmp_path / "huge.yaml").write_text(yaml.safe_dump({"joints": {j: [1.0, 1.0] for j in JOINTS}}))
    with pytest.raises(InputError, match="huge.png: texture: expected a PNG of at most 100000000 pixels"):
        read_character(tmp_path / "huge.png")


@pytest.mark.slow  # starts `nnsf animate` as a process
def test_a_huge_png_is_one_line_on_stderr_without_libpng_noise(tmp_path):
    _png_header(tmp_path / "huge.png", 20000, 20000)
    (tmp_path / "huge.yaml").write_text(yaml.safe_dump({"joints": {j: [1.0, 1.0] for j in JOINTS}}))
    r = subprocess.run([sys.executable, "-m", "nnsf.cli", "animate", "--character", str(tmp_path / "huge.png"),
                        "--motion", "synthetic:ollie/walk/4", "--out", str(tmp_path / "a.gif")],
                       capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "huge.png: texture: expected a PNG of at most 100000000 pixels" in lines[0], r.stderr
    assert "20000x20000" in lines[0] and "libpng" not in r.stderr


def test_a_drawing_over_the_size_limit_is_downscaled_with_a_note(tmp_path, figure):
    png = _png_with_yaml(tmp_path / "c", figure)
    ch = read_character(png, max_size=0.02)                  # 20,000 px; the figure has ~100,000
    assert ch.mask.size <= 20_000 and any("downscaled" in n and "--max-size" in n for n in ch.notes)
    s = ch.mask.shape[0] / figure.mask.shape[0]
    np.testing.assert_allclose(ch.keypoints[J["pelvis"]], (figure.keypoints[J["pelvis"]] + 0.5) * s - 0.5, atol=1.5)
    assert read_character(png, max_size=0).mask.shape == figure.mask.shape


def test_a_piece_touching_the_silhouette_only_at_a_corner_is_dropped_with_a_note():
    """A zero-width link does not survive resampling: turned by 30° and grown by 10 %, two squares
    that touch at a corner render as two pieces (joined by one pixel's edge, they stay one), so the
    silhouette is one 4-connected component."""
    from nnsf.reshape.character import largest_component
    from nnsf.reshape.mesh import Mesh
    from nnsf.reshape.render import Renderer

    mask = np.zeros((24, 24), bool)
    mask[4:12, 4:12] = True                       # the body
    mask[12:16, 12:16] = True                     # touches it at one pixel corner only
    tex = np.dstack([np.full((24, 24, 3), 90, np.uint8), np.full((24, 24), 255, np.uint8)])
    uv = np.array([[0.0, 0.0], [23.0, 0.0], [23.0, 23.0], [0.0, 23.0]])
    mesh = Mesh(uv, np.array([[0, 1, 2], [0, 2, 3]]), np.zeros(2, np.int64), np.zeros(2, np.int64), 1.0)
    c, s = np.cos(np.pi / 6), np.sin(np.pi / 6)
    moved = 1.1 * (uv - 12) @ np.array([[c, s], [-s, c]]) + 16

    def pieces(m):
        drawn = Renderer(mesh, tex, m, (34, 34)).render(moved)[..., 3] >= 128
        return cv2.connectedComponents(drawn.astype(np.uint8), connectivity=8)[0] - 1

    assert cv2.connectedComponents(mask.astype(np.uint8), connectivity=8)[0] - 1 == 1     # one piece at rest
    assert pieces(mask) == 2
    bridged = mask.copy()
    bridged[12, 11] = True
    assert pieces(bridged) == 1
    kept, note = largest_component(mask, "m.png")
    assert kept.sum() == 64 and not kept[12:16, 12:16].any() and "dropped 16 px" in note
