"""BVH source: reader, forward kinematics, projection, resampling, skeleton
families and the folder reader (with the real Bandai-Namco and AnimatedDrawings
clips in ../shared/data when present)."""
from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from nnsf.datasets.bvh import forward_kinematics, parse_bvh, read_bvh
from nnsf.datasets.projection import detect_up_axis, project, resample, resample_times
from nnsf.datasets.bvh_detect import detect_family
from nnsf.datasets.bvh_skeletons import FAMILIES, family_from_mapping, keypoints_3d, parse_rule
from nnsf.datasets.bvh_source import (
    DEPTH_COLUMNS, labels_from_json, labels_from_name, load_clip, read_folder,
)
from nnsf.datasets.contract import features, validate
from nnsf.errors import InputError
from nnsf.skeleton import JOINT_INDEX, Unifier, to_points

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
BANDAI = DATA / "bandai-namco-1"
DRAWINGS_BVH = DATA / "animated-drawings" / "bvh"

needs_bandai = pytest.mark.skipif(not (BANDAI / "data").is_dir(),
                                  reason=f"Bandai-Namco data not found at {BANDAI}")
needs_drawings = pytest.mark.skipif(not DRAWINGS_BVH.is_dir(),
                                    reason=f"AnimatedDrawings BVH clips not found at {DRAWINGS_BVH}")

AXES = {"X": "Xrotation", "Y": "Yrotation", "Z": "Zrotation"}


def chain_bvh(order: str, frames: np.ndarray, root_pos: np.ndarray, pos_first: bool = True,
              frame_time: float = 1 / 30) -> str:
    """A 3-joint chain (root, mid, tip + End Site) with rotation order ``order``.

    frames : ``(F, 3, 3)`` angles (joint, channel in ``order``), degrees.
    """
    rot = " ".join(AXES[a] for a in order)
    root_ch = f"Xposition Yposition Zposition {rot}" if pos_first else f"{rot} Xposition Yposition Zposition"
    lines = [
        "HIERARCHY", "ROOT root", "{", "  OFFSET 0 0 0", f"  CHANNELS 6 {root_ch}",
        "  JOINT mid", "  {", "    OFFSET 0 2 0", f"    CHANNELS 3 {rot}",
        "    JOINT tip", "    {", "      OFFSET 1 0 0", f"      CHANNELS 3 {rot}",
        "      End Site", "      {", "        OFFSET 0 0 3", "      }", "    }", "  }", "}",
        "MOTION", f"Frames: {len(frames)}", f"Frame Time: {frame_time}",
    ]
    for f in range(len(frames)):
        vals = list(root_pos[f]) + list(frames[f, 0]) if pos_first else list(frames[f, 0]) + list(root_pos[f])
        vals += list(frames[f, 1]) + list(frames[f, 2])
        lines.append(" ".join(f"{v:.10g}" for v in vals))
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- forward kinematics

@pytest.mark.parametrize("order", ["ZYX", "XZY", "ZXY", "YXZ", "XYZ"])
@pytest.mark.parametrize("pos_first", [True, False])
def test_fk_matches_scipy_for_any_rotation_order(order, pos_first):
    rng = np.random.default_rng(7)
    F = 9
    ang = rng.uniform(-170, 170, size=(F, 3, 3))
    pos = rng.normal(size=(F, 3)) * 10
    bvh = parse_bvh(chain_bvh(order, ang, pos, pos_first), source="chain.bvh")
    assert bvh.names == ("root", "mid", "tip", "tip_end")
    P = forward_kinematics(bvh)
    assert P.shape == (F, 4, 3)
    offs = [np.array([0.0, 2, 0]), np.array([1.0, 0, 0]), np.array([0.0, 0, 3])]
    for f in range(F):
        # Oracle: intrinsic rotations in channel order (uppercase in scipy).
        R = [Rotation.from_euler(order, ang[f, j], degrees=True).as_matrix() for j in range(3)]
        G0, G1, G2 = R[0], R[0] @ R[1], R[0] @ R[1] @ R[2]
        p_mid = pos[f] + G0 @ offs[0]
        p_tip = p_mid + G1 @ offs[1]
        p_end = p_tip + G2 @ offs[2]
        np.testing.assert_allclose(P[f], [pos[f], p_mid, p_tip, p_end], atol=1e-9)
    # End Sites are optional extra points.
    assert forward_kinematics(bvh, end_sites=False).shape == (F, 3, 3)


def test_fk_known_rotations():
    # Root turned 90 degrees about z: the mid joint's (0, 2, 0) offset points along -x.
    ang = np.zeros((1, 3, 3))
    ang[0, 0] = [90, 0, 0]        # ZYX order: Z=90
    ang[0, 1] = [0, 0, -90]       # mid: X=-90 (leaves the tip's (1, 0, 0) offset alone)
    bvh = parse_bvh(chain_bvh("ZYX", ang, np.array([[1.0, 2.0, 3.0]])))
    P = forward_kinematics(bvh)[0]
    np.testing.assert_allclose(P[0], [1, 2, 3], atol=1e-12)
    np.testing.assert_allclose(P[1], [1 - 2, 2, 3], atol=1e-12)        # root + Rz90 (0,2,0)
    np.testing.assert_allclose(P[2], [-1, 2 + 1, 3], atol=1e-12)       # + Rz90 Rx-90 (1,0,0) = (0,1,0)
    # End Site (0,0,3) through Rz90 Rx-90: Rx(-90)(0,0,3) = (0,3,0); Rz90 -> (-3,0,0)
    np.testing.assert_allclose(P[3], [-4, 3, 3], atol=1e-12)


def test_position_channels_on_non_root_joint_replace_or_add():
    text = """HIERARCHY
ROOT a
{
  OFFSET 0 0 0
  CHANNELS 3 Xposition Yposition Zposition
  JOINT b
  {
    OFFSET 0 10 0
    CHANNELS 4 Yposition Zrotation Xposition Zposition
    End Site
    {
      OFFSET 1 0 0
    }
  }
}
MOTION
Frames: 1
Frame Time: 0.5
0 0 0   5 90 2 0
"""
    bvh = parse_bvh(text)
    assert bvh.fps == 2.0
    P = forward_kinematics(bvh)[0]
    np.testing.assert_allclose(P[1], [2, 5, 0], atol=1e-12)          # channels replace OFFSET
    np.testing.assert_allclose(P[2], [2, 6, 0], atol=1e-12)          # Rz90 (1,0,0) = (0,1,0)
    P = forward_kinematics(bvh, position_channels="add")[0]
    np.testing.assert_allclose(P[1], [2, 15, 0], atol=1e-12)


# --------------------------------------------------------------------------- projection

def _axes_points():
    # origin, +x, +y, +z
    return np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]]])


def test_front_and_side_projection_geometry():
    front = project(_axes_points())
    np.testing.assert_allclose(front.xy[0], [[0, 0], [1, 0], [0, -1], [0, 0]], atol=1e-12)
    np.testing.assert_allclose(front.depth[0], [0, 0, 0, -1], atol=1e-12)   # +z is nearer
    side = project(_axes_points(), azimuth=90)
    np.testing.assert_allclose(side.xy[0], [[0, 0], [0, 0], [0, -1], [-1, 0]], atol=1e-12)
    np.testing.assert_allclose(side.depth[0], [0, -1, 0, 0], atol=1e-12)    # camera on +x
    top = project(_axes_points(), elevation=90)
    np.testing.assert_allclose(top.depth[0], [0, 0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(top.xy[0, 1], [1, 0], atol=1e-12)
    # A Z-up world gives the same picture once told its up axis.
    zup = _axes_points()[:, :, [0, 2, 1]] * np.array([1, -1, 1])   # (x, y, z) -> (x, -z, y)
    np.testing.assert_allclose(project(zup, up="z").xy, front.xy, atol=1e-12)


def _figure(yaw_deg: np.ndarray, travel: np.ndarray) -> np.ndarray:
    """A stick body (pelvis, l/r hip, l/r shoulder, head, nose) facing +z,
    turned by yaw about y and moved by travel (F, 2) on the ground."""
    body = np.array([[0, 1, 0], [0.2, 1, 0], [-0.2, 1, 0], [0.25, 1.5, 0], [-0.25, 1.5, 0],
                     [0, 1.8, 0], [0, 1.7, 0.1]], dtype=float)
    th = np.deg2rad(yaw_deg)
    R = np.stack([np.stack([np.cos(th), 0 * th, np.sin(th)], -1), np.tile([0.0, 1, 0], (len(th), 1)),
                  np.stack([-np.sin(th), 0 * th, np.cos(th)], -1)], axis=1)
    P = np.einsum("fab,kb->fka", R, body)
    P[..., 0] += travel[:, None, 0]
    P[..., 2] += travel[:, None, 1]
    return P


def test_facing_normalisation_and_centering_undo_a_walk_in_circles():
    F = 60
    a = np.linspace(0, 2 * np.pi, F)
    yaw = np.rad2deg(a) + 90           # heading along the circle's tangent
    travel = np.stack([3 * np.cos(a), -3 * np.sin(a)], -1)
    P = _figure(yaw, travel)
    ref = project(_figure(np.zeros(1), np.zeros((1, 2))))
    pr = project(P, facing="normalise", across=(1, 2, 3, 4), root=0, center=True, window=1)
    np.testing.assert_allclose(pr.xy, np.broadcast_to(ref.xy, pr.xy.shape), atol=1e-9)
    np.testing.assert_allclose(pr.travel, travel, atol=1e-9)
    # Without normalisation the figure's width changes as it turns.
    raw = project(P, root=0, center=True, window=1)
    assert np.ptp(raw.xy[:, 1, 0] - raw.xy[:, 2, 0]) > 0.3
    # Smoothed heading: a straight walk with a swinging pelvis keeps its swing.
    swing = 10 * np.sin(np.linspace(0, 6 * np.pi, 90))
    walk = _figure(30 + swing, np.stack([np.linspace(0, 5, 90), np.zeros(90)], -1))
    pw = project(walk, facing="normalise", across=(1, 2, 3, 4), root=0, center=True, window=31)
    np.testing.assert_allclose(pw.travel[:, 0], np.linspace(0, 5, 90), atol=1e-9)
    assert np.ptp(pw.yaw) < 5                                # heading is smoothed ...
    assert np.ptp(pw.depth[:, 1] - pw.depth[:, 2]) > 0.05    # ... and the hip swing is kept


def test_detect_up_axis():
    P = _figure(np.zeros(3), np.zeros((3, 2)))
    assert detect_up_axis(P, 5, (1, 2)) == "y"
    assert detect_up_axis(P[..., [0, 2, 1]], 5, (1, 2)) == "z"


# --------------------------------------------------------------------------- resampling

def test_resample_30_to_15_halves_frames_and_keeps_endpoints():
    x = np.random.default_rng(0).normal(size=(129, 4, 3))
    y = resample(x, 30, 15)
    assert y.shape == (65, 4, 3)
    np.testing.assert_allclose(y, x[::2])                # exact decimation when it lines up
    x = np.random.default_rng(1).normal(size=(128, 2))
    y = resample(x, 30, 15)
    assert len(y) == 65 - 0 and abs(len(y) - 128 / 2) <= 1
    np.testing.assert_allclose(y[[0, -1]], x[[0, -1]])   # both endpoints kept
    # Linear motion is reproduced exactly at the new sample times.
    t = np.arange(128) / 30.0
    lin = np.stack([2 * t + 1, -t], -1)
    ts = resample_times(128, 30, 15) / 30.0
    np.testing.assert_allclose(resample(lin, 30, 15), np.stack([2 * ts + 1, -ts], -1), atol=1e-12)
    assert np.allclose(np.diff(ts), np.diff(ts)[0]) and abs(1 / np.diff(ts)[0] - 15) < 15 / 60
    # Upsampling and identity.
    assert len(resample(x, 30, 60)) == 255
    np.testing.assert_array_equal(resample(x, 30, 30), x)


# --------------------------------------------------------------------------- errors

GOOD_HEADER = """HIERARCHY
ROOT Hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  End Site
  {
    OFFSET 0 1 0
  }
}
MOTION
"""


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.mark.parametrize("body, line, words", [
    ("Frames: 5\nFrame Time: 0.1\n0 0 0 0 0 0\n0 0 0 0 0 0\n", 16, "5 motion lines"),
    ("Frames: 2\nFrame Time: 0.1\n0 0 0 0 0 0\n0 0 0 0 0\n", 15, "6 values per motion line"),
    ("Frames: 2\nFrame Time: 0.1\n0 0 0 0 0 0\n0 0 x1 0 0 0\n", 15, "numeric"),
    ("Frames: 1\nFrame Time: 0.1\n0 0 0 nan 0 0\n", 14, "finite"),
    ("Frames: 0\nFrame Time: 0.1\n", 12, "at least 1"),
    ("Frames: 1\nFrame Time: 0.1\n" + "0 0 0 0 0 0\n" * 4, 17, "1 motion lines as Frames: says (give or take 2)"),
])
def test_bad_motion_sections_name_file_and_line(tmp_path, body, line, words):
    p = _write(tmp_path, "bad.bvh", GOOD_HEADER + body)
    with pytest.raises(InputError) as err:
        read_bvh(p)
    msg = str(err.value)
    assert "\n" not in msg and "bad.bvh" in msg and f"line {line}:" in msg and words in msg, msg


def test_unknown_channel_names_file_and_line(tmp_path):
    p = _write(tmp_path, "chan.bvh", GOOD_HEADER.replace("Yrotation", "Wrotation") +
               "Frames: 1\nFrame Time: 0.1\n0 0 0 0 0 0\n")
    with pytest.raises(InputError, match=r"chan\.bvh: line 5: .*channel name.*Wrotation"):
        read_bvh(p)


def test_good_minimal_file_reads(tmp_path):
    p = _write(tmp_path, "ok.bvh", GOOD_HEADER + "Frames: 2\nFrame Time: 0.1\n\n1 2 3 0 0 0\n4 5 6 90 0 0\n")
    b = read_bvh(p)
    assert b.motion.shape == (2, 6) and b.motion.dtype == np.float64 and b.n_frames == 2
    np.testing.assert_allclose(forward_kinematics(b)[1, 1], [4 - 1, 5, 6], atol=1e-12)
    # Windows line ends, braces on the name's line, tabs after the colon.
    crlf = ("HIERARCHY\r\nROOT Hips {\r\n OFFSET 0 0 0\r\n CHANNELS 3 Xposition Yposition Zposition"
            "\r\n End Site { OFFSET 0 1 0 }\r\n}\r\nMOTION\r\nFrames:\t2\r\nFrame Time: 0.5\r\n"
            "1 2 3\r\n4 5 6\r\n")
    b = parse_bvh(crlf, "crlf.bvh")
    assert b.names == ("Hips", "Hips_end") and b.fps == 2.0
    np.testing.assert_allclose(forward_kinematics(b)[1], [[4, 5, 6], [4, 6, 6]])
    with pytest.raises(InputError, match=r"crlf\.bvh: line 11: expected numeric motion values, got 'six'"):
        parse_bvh(crlf.replace("4 5 6", "4 5 six"), "crlf.bvh")


# --------------------------------------------------------------------------- skeleton families

def _tiny_human(names: dict[str, str] | None = None, variant: int = 0) -> str:
    """A small Y-up human in the Bandai naming (optionally renamed); each ``variant`` leans a
    little more, so that clips of a test folder are not byte-identical copies of one take."""
    j = [("Hips", None, (0, 90, 0)), ("Spine", "Hips", (0, 15, 0)), ("Chest", "Spine", (0, 10, 0)),
         ("Neck", "Chest", (0, 15, 0)), ("Head", "Neck", (0, 6, 0)),
         ("UpperArm_L", "Chest", (18, 12, 0)), ("LowerArm_L", "UpperArm_L", (25, 0, 0)),
         ("Hand_L", "LowerArm_L", (22, 0, 0)),
         ("UpperArm_R", "Chest", (-18, 12, 0)), ("LowerArm_R", "UpperArm_R", (-25, 0, 0)),
         ("Hand_R", "LowerArm_R", (-22, 0, 0)),
         ("UpperLeg_L", "Hips", (9, -5, 0)), ("LowerLeg_L", "UpperLeg_L", (0, -40, 0)),
         ("Foot_L", "LowerLeg_L", (0, -40, 0)),
         ("UpperLeg_R", "Hips", (-9, -5, 0)), ("LowerLeg_R", "UpperLeg_R", (0, -40, 0)),
         ("Foot_R", "LowerLeg_R", (0, -40, 0))]
    names = names or {}
    children = {}
    for n, p, _ in j:
        children.setdefault(p, []).append(n)
    off = {n: o for n, _, o in j}
    out = ["HIERARCHY"]

    def emit(n, depth):
        pad = "  " * depth
        out.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {names.get(n, n)}")
        out.append(pad + "{")
        out.append(f"{pad}  OFFSET {' '.join(map(str, off[n]))}")
        out.append(f"{pad}  CHANNELS {6 if depth == 0 else 3} " +
                   ("Xposition Yposition Zposition " if depth == 0 else "") + "Zrotation Xrotation Yrotation")
        for c in children.get(n, []):
            emit(c, depth + 1)
        if n not in children:
            out.extend([pad + "  End Site", pad + "  {", pad + "    OFFSET 0 -3 0", pad + "  }"])
        out.append(pad + "}")

    emit("Hips", 0)
    n_ch = 6 + 3 * (len(j) - 1)
    rows = []
    for f in range(4):
        v = np.zeros(n_ch)
        v[1] = 90.0                # position channels replace the root's OFFSET
        v[2] = 10.0 * f            # walk towards +z
        v[4] = (5.0 + 0.5 * variant) * f  # lean
        rows.append(" ".join(f"{x:g}" for x in v))
    out += ["MOTION", "Frames: 4", "Frame Time: 0.0333333", *rows]
    return "\n".join(out) + "\n"


def test_tiny_human_maps_to_17_points_with_bandai_rules():
    bvh = parse_bvh(_tiny_human(), "tiny.bvh")
    fam = detect_family(bvh.names, "tiny.bvh")
    assert fam.name == "bandai-namco"
    P, G = forward_kinematics(bvh, return_rotations=True)
    K = keypoints_3d(bvh, P, G, fam)
    assert K.shape == (4, 17, 3)
    np.testing.assert_allclose(K[0, JOINT_INDEX["pelvis"]], [0, 85, 0])
    np.testing.assert_allclose(K[0, JOINT_INDEX["l_hip"]], [9, 85, 0])
    np.testing.assert_allclose(K[0, JOINT_INDEX["spine"]], [0, 110, 0])
    # head_top: 3 x the head's own 6-unit OFFSET up the head's axis.
    np.testing.assert_allclose(K[0, JOINT_INDEX["head_top"]], [0, 136 + 18, 0])
    np.testing.assert_allclose(K[0, JOINT_INDEX["r_wrist"]], [-65, 127, 0])


def test_unknown_skeleton_lists_missing_joints(tmp_path):
    text = _tiny_human({"UpperLeg_L": "LThigh", "LowerLeg_L": "LShin", "Foot_L": "LFoot"})
    p = _write(tmp_path, "alien.bvh", text)
    bvh = read_bvh(p)
    with pytest.raises(InputError) as err:
        detect_family(bvh.names, p)
    msg = str(err.value)
    assert "alien.bvh" in msg and "\n" not in msg
    for name in ("UpperLeg_L", "LowerLeg_L", "Foot_L", "pelvis", "l_hip", "l_knee", "l_ankle"):
        assert name in msg, msg
    # A user mapping fixes it.
    rules = dict(FAMILIES["bandai-namco"].table())
    rules.update(pelvis="mid(LThigh, UpperLeg_R)", l_hip="LThigh", l_knee="LShin", l_ankle="LFoot")
    fam = family_from_mapping(rules)
    clip = load_clip(p, family=fam, fps=None)
    assert clip.points.shape == (4, 17, 2)
    assert str(parse_rule("beyond(Neck, Head, 1.4)")) == "beyond(Neck, Head, 1.4)"
    with pytest.raises(ValueError):
        parse_rule("middle(A)")


@pytest.mark.parametrize("rel, family, up", [
    ("bandai-namco-1/data/dataset-1_walk_normal_001.bvh", "bandai-namco", "y"),
    ("animated-drawings/bvh/cmu1/jumping_jacks.bvh", "cmu-asf", "y"),
    ("animated-drawings/bvh/fair1/dab.bvh", "animated-drawings", "z"),
    ("animated-drawings/bvh/fair1/zombie.bvh", "animated-drawings", "z"),
    ("animated-drawings/bvh/rokoko/jesse_dance.bvh", "rokoko", "y"),
    ("bvh-skeletons/cmu-motionbuilder/cmu_12_01_walk.bvh", "cmu-motionbuilder", "y"),
    ("bvh-skeletons/cmu-motionbuilder/01_01.bvh", "cmu-motionbuilder", "y"),
    ("bvh-skeletons/3dsmax-style/bvh_test2.bvh", "3dsmax", "y"),
    ("bvh-skeletons/3dsmax-style/test_mocapbank.bvh", "3dsmax", "y"),
    ("bvh-skeletons/3dsmax-style/Boxing_Toes.bvh", "3dsmax", "y"),
    ("bvh-skeletons/mixamo/test_freebvh.bvh", "mixamo", "y"),
    ("bvh-skeletons/cmu-daz/29_01.bvh", "daz", "y"),
])
def test_family_detection_on_real_files(rel, family, up):
    if not (DATA / rel).is_file():
        pytest.skip(f"{DATA / rel} not found (../shared/data absent)")
    clip = load_clip(DATA / rel)
    assert clip.family == family and clip.up == up
    pts = clip.points
    # Upright in image axes: head top above the pelvis above the ankles (y down).
    head, pelvis = pts[:, JOINT_INDEX["head_top"], 1], pts[:, JOINT_INDEX["pelvis"], 1]
    ankles = pts[:, [JOINT_INDEX["l_ankle"], JOINT_INDEX["r_ankle"]], 1].max(axis=1)
    assert np.mean(head < pelvis) > 0.95 and np.mean(pelvis < ankles) > 0.95
    # Front view after facing normalisation: the body's left is on the image's right.
    lr = pts[:, JOINT_INDEX["l_hip"], 0] - pts[:, JOINT_INDEX["r_hip"], 0]
    assert np.mean(lr > 0) > 0.9


# --------------------------------------------------------------------------- the folder reader

def _label_folder(tmp_path) -> Path:
    d = tmp_path / "clips"
    d.mkdir()
    for k, (motion, style) in enumerate((m, s) for m in ("walk", "run") for s in ("happy", "sad")):
        (d / f"ds_{motion}_{style}_001.bvh").write_text(_tiny_human(variant=k + 1))
    return d


def test_folder_reports_bad_files_and_keeps_the_rest(tmp_path):
    d = _label_folder(tmp_path)
    good = _tiny_human()
    (d / "ds_walk_old_001.bvh").write_text(good.replace("Frames: 4", "Frames: 9"))   # truncated
    (d / "just-a-name.bvh").write_text(good)                                      # no labels
    (d / "ds_jump_giant_001.bvh").write_text(_tiny_human(variant=9))              # lone style
    (d / "ds_dance_happy_001.json").write_text(json.dumps({"content": "dance", "style": "happy"}))
    (d / "ds_kick_sad_002.json").write_text(json.dumps({"motion": "kick", "character": "sad",
                                                        "bvh": "../outside.bvh"}))
    (tmp_path / "outside.bvh").write_text(good)
    table, report = read_folder(d, fps=15)
    text = "\n".join(report)
    assert sorted(table["clip"].unique()) == sorted(
        [f"ds_{m}_{s}_001" for m in ("walk", "run") for s in ("happy", "sad")] + ["ds_jump_giant_001"])
    assert len(report) == 5, text
    assert "ds_walk_old_001.bvh: line" in text and "9 motion lines" in text
    assert "just-a-name.bvh: file name" in text
    assert "'giant' appears in one motion only (jump)" in text
    assert "ds_dance_happy_001.json" in text and "missing" in text
    assert "ds_kick_sad_002.json: bvh: expected a path inside the dataset folder" in text
    assert all("\n" not in line for line in report)
    # 4 frames at 30 fps -> 3 frames at 15 fps; labels from the names.
    assert (table.groupby("clip").size() == 3).all()
    row = table[table["clip"] == "ds_run_sad_001"].iloc[0]
    assert (row["motion"], row["character"]) == ("run", "sad")
    validate(table, d)


def test_labels_from_json_indices_and_name_pattern(tmp_path):
    d = tmp_path / "ds"
    (d / "cfg").mkdir(parents=True)
    (d / "cfg" / "content_label.txt").write_text("dataset-1_walk\ndataset-1_bow\n")
    (d / "cfg" / "style_label.txt").write_text("dataset-1_normal\ndataset-1_old\n")
    (d / "x.json").write_text(json.dumps({"content": 1, "style": 1}))
    (d / "x.bvh").write_text(_tiny_human())
    table, report = read_folder(d, fps=None)
    assert report == ["warning: style 'old' appears in one motion only (bow); its style cannot be "
                      "separated from that content"]
    assert set(zip(table["motion"], table["character"])) == {("bow", "old")}
    (d / "y.json").write_text(json.dumps({"content": 5, "style": 0}))
    from nnsf.datasets.bvh_source import label_lists
    with pytest.raises(InputError, match=r"y\.json: content: expected an index 0\.\.1"):
        labels_from_json(d / "y.json", d, label_lists(d))
    with pytest.raises(InputError, match=r"x\.bvh: file name: expected \{dataset\}_\{motion\}"):
        labels_from_name(d / "x.bvh")
    assert labels_from_name("dataset-1_walk-back_not-confident_001.bvh").motion == "walk-back"


def test_folder_without_any_readable_clip_raises(tmp_path):
    (tmp_path / "a.bvh").write_text("HIERARCHY\nROOT x\n{\n")
    with pytest.raises(InputError, match="at least one readable"):
        read_folder(tmp_path)


# --------------------------------------------------------------------------- the real data set

@pytest.fixture(scope="module")
def bandai():
    if not (BANDAI / "data").is_dir():
        pytest.skip(f"Bandai-Namco data not found at {BANDAI}")
    return read_folder(BANDAI, depth=True)


@needs_bandai
def test_bandai_bone_lengths_are_constant():
    files = sorted((BANDAI / "data").glob("*.bvh"))
    assert len(files) == 174
    worst = 0.0
    for f in files[::6]:
        bvh = read_bvh(f)
        P = forward_kinematics(bvh)
        # Bones below Hips (Hips itself carries the root motion on its position channels).
        nodes = [j for j in range(2, len(bvh.names)) if np.linalg.norm(bvh.offsets[j]) > 0]
        L = np.linalg.norm(P[:, nodes] - P[:, bvh.parents[nodes]], axis=-1)
        worst = max(worst, float(((L.max(0) - L.min(0)) / L.mean(0)).max()))
    assert worst < 1e-6


@needs_bandai
def test_bandai_folder(bandai):
    table, report = bandai
    # 174 clips: the snapshot's 175 labels include dance-long, whose BVH is missing.
    assert table["clip"].nunique() == 174
    assert len(report) == 1 and "dance-long" in report[0] and "missing" in report[0]
    assert len(list((BANDAI / "data").glob("*.json"))) == 175
    main = ["walk", "run", "dash", "walk-back", "walk-left", "walk-right", "bow", "bye", "guide", "byebye"]
    per_motion = table.groupby("motion")["character"].nunique()
    assert all(per_motion[m] == 15 for m in main)
    assert table["character"].nunique() == 15
    assert len(table) == 31914          # 30 fps in, 30 fps out
    assert list(table.columns[-17:]) == list(DEPTH_COLUMNS)
    validate(table, BANDAI)
    P = to_points(features(table))
    head = P[:, JOINT_INDEX["head_top"], 1]
    ankles = P[:, [JOINT_INDEX["l_ankle"], JOINT_INDEX["r_ankle"]], 1].min(axis=1)
    in_main = table["motion"].isin(main).to_numpy()
    assert (head[in_main] < ankles[in_main]).all()          # feet below the head (y down)
    assert np.mean(head < ankles) > 0.999                    # (dance-short kicks high once)
    chars = table["character"].to_numpy()
    X = Unifier().fit(P, chars).transform(P, chars)
    assert X.shape == (len(table), 34) and X.min() >= 0


@needs_bandai
def test_bandai_resampled_to_15_fps():
    files = sorted((BANDAI / "data").glob("dataset-1_walk_old_*.bvh"))[:1]
    c30 = load_clip(files[0], fps=30)
    c15 = load_clip(files[0], fps=15)
    assert abs(len(c15.points) - len(c30.points) / 2) <= 1
    np.testing.assert_allclose(c15.points3d[[0, -1]], c30.points3d[[0, -1]], atol=1e-9)


def _heading_deg(lr_x, lr_z):
    """Heading (degrees, unwrapped) of a body whose summed left-minus-right vector is (x, z)."""
    return np.rad2deg(np.unwrap(np.arctan2(-lr_z, lr_x)))


def test_first_frame_facing_keeps_a_turn_and_faces_the_camera_at_the_start():
    F = 60
    yaw = np.linspace(20, 110, F)                       # a 90° turn, starting 20° off the camera
    P = _figure(yaw, np.stack([np.linspace(0, 2, F), np.zeros(F)], -1))
    pr = project(P, facing="first", across=(1, 2, 3, 4), root=0, center=True, window=1)
    d = pr.xy[:, [1, 3], 0].sum(1) - pr.xy[:, [2, 4], 0].sum(1)
    z = pr.depth[:, [1, 3]].sum(1) - pr.depth[:, [2, 4]].sum(1)
    # camera depth grows away from the camera (-z of the world): heading from (x, -depth)
    h = _heading_deg(d, -z)
    assert abs(h[0]) < 1e-6                              # faces the camera at the start
    assert h[-1] - h[0] == pytest.approx(-(yaw[-1] - yaw[0]), abs=1e-6) or \
        h[-1] - h[0] == pytest.approx(yaw[-1] - yaw[0], abs=1e-6)
    assert np.ptp(pr.yaw) == 0                           # one turn for the whole clip
    # per-frame normalisation removes the turn
    pn = project(P, facing="normalise", across=(1, 2, 3, 4), root=0, center=True, window=1)
    dn = pn.xy[:, [1, 3], 0].sum(1) - pn.xy[:, [2, 4], 0].sum(1)
    np.testing.assert_allclose(dn, dn[0], atol=1e-9)


def _turned_copy(src: Path, dst: Path, degrees: float) -> Path:
    """The clip with a yaw ramp 0 -> ``degrees`` added to its root's Y rotation (a real walk made
    to turn: Bandai-Namco-1 has no turning clip; its root joint carries no rotation)."""
    lines = src.read_text().splitlines()
    m = lines.index("MOTION")
    n = int(lines[m + 1].split()[-1])
    head = lines[:m]
    root_channels = next(ln for ln in head if "CHANNELS" in ln).split()[2:]
    col = root_channels.index("Yrotation")
    out = lines[:m + 3]
    for i, ln in enumerate(lines[m + 3:m + 3 + n]):
        v = ln.split()
        v[col] = repr(float(v[col]) + degrees * i / max(n - 1, 1))
        out.append(" ".join(v))
    dst.write_text("\n".join(out) + "\n")
    return dst


@needs_bandai
@pytest.mark.parametrize("degrees", [90.0, -120.0])
def test_a_turning_clip_keeps_its_turn_through_the_reader(tmp_path, degrees):
    """The root's heading in the projected clip (image x and camera depth of hips and shoulders)
    changes by as much as the motion capture's world heading; per-frame normalisation loses it."""
    src = sorted((BANDAI / "data").glob("dataset-1_walk_normal_*.bvh"))[0]
    path = _turned_copy(src, tmp_path / src.name, degrees)
    pairs = [JOINT_INDEX[n] for n in ("l_hip", "r_hip", "l_shoulder", "r_shoulder")]

    def image_heading(clip):
        x, z = clip.points[..., 0], clip.depth
        return _heading_deg(x[:, pairs[0::2]].sum(1) - x[:, pairs[1::2]].sum(1),
                            -(z[:, pairs[0::2]].sum(1) - z[:, pairs[1::2]].sum(1)))

    clip = load_clip(path, fps=30, facing="first")
    W = clip.points3d
    wl = W[:, pairs[0::2]].sum(1) - W[:, pairs[1::2]].sum(1)
    world = _heading_deg(wl[:, 0], wl[:, 2])
    turn = world[-1] - world[0]
    assert abs(abs(turn) - abs(degrees)) < 15            # the capture turns by about the ramp
    img = image_heading(clip)
    assert abs(img[0]) < 10                              # faces the camera at the start
    assert abs(abs(img[-1] - img[0]) - abs(turn)) < 1.0  # ... and keeps the whole turn
    flat = image_heading(load_clip(path, fps=30, facing="normalise"))
    assert abs(flat[-1] - flat[0]) < 0.2 * abs(turn)


@pytest.mark.parametrize("declared, rows", [(3069, 3070), (5, 4), (5, 7), (4, 2)])
def test_frame_count_off_by_a_row_or_two_is_read_with_a_note(tmp_path, declared, rows):
    body = f"Frames: {declared}\nFrame Time: 0.01\n" + "".join(f"{k} 0 0 0 0 0\n" for k in range(rows))
    b = read_bvh(_write(tmp_path, "off.bvh", GOOD_HEADER + body))
    assert b.n_frames == rows and b.motion[-1, 0] == rows - 1
    assert len(b.notes) == 1 and "off.bvh: line 12: Frames: says" in b.notes[0], b.notes
    assert f"{declared}" in b.notes[0] and f"{rows} motion lines" in b.notes[0]
    exact = read_bvh(_write(tmp_path, "exact.bvh", GOOD_HEADER + f"Frames: {rows}\nFrame Time: 0.01\n"
                            + "".join(f"{k} 0 0 0 0 0\n" for k in range(rows))))
    assert exact.notes == []


@pytest.mark.parametrize("declared, rows", [(3069, 3066), (10, 13), (1000, 4)])
def test_a_large_frame_count_mismatch_is_an_error(tmp_path, declared, rows):
    body = f"Frames: {declared}\nFrame Time: 0.01\n" + "".join(f"{k} 0 0 0 0 0\n" for k in range(rows))
    with pytest.raises(InputError) as err:
        read_bvh(_write(tmp_path, "far.bvh", GOOD_HEADER + body))
    msg = str(err.value)
    assert msg.startswith("far.bvh: line ") or "far.bvh: line " in msg
    assert f"{declared} motion lines" in msg and "\n" not in msg


def test_boxing_toes_header_mismatch_reads_all_rows():
    p = DATA / "bvh-skeletons/3dsmax-style/Boxing_Toes.bvh"
    if not p.is_file():
        pytest.skip(f"{p} not found (../shared/data absent)")
    b = read_bvh(p)
    assert b.n_frames == 3070 and len(b.notes) == 1 and "3069" in b.notes[0]


def test_folder_reports_conflicting_labels_duplicates_and_garbled_json(tmp_path):
    d = _label_folder(tmp_path)
    # two label files give one clip different styles: the clip is left out, both files named
    (d / "ds_kick_x_001.bvh").write_text(_tiny_human(variant=11))
    (d / "kick-a.json").write_text(json.dumps({"content": "kick", "style": "happy", "bvh": "ds_kick_x_001.bvh"}))
    (d / "kick-b.json").write_text(json.dumps({"content": "kick", "style": "sad", "bvh": "ds_kick_x_001.bvh"}))
    # two label files that agree: read once, with a note
    (d / "ds_jump_y_001.bvh").write_text(_tiny_human(variant=12))
    for name in ("jump-a.json", "jump-b.json"):
        (d / name).write_text(json.dumps({"content": "jump", "style": "sad", "bvh": "ds_jump_y_001.bvh"}))
    # a byte-identical copy with the same labels: kept once
    (d / "ds_walk_happy_002.bvh").write_bytes((d / "ds_walk_happy_001.bvh").read_bytes())
    # a byte-identical copy labelled otherwise: both left out
    (d / "ds_run_sad_009.bvh").write_text(_tiny_human(variant=13))
    (d / "ds_run_happy_009.bvh").write_text(_tiny_human(variant=13))
    # a garbled label file
    (d / "broken.json").write_text('{"content": "walk", "style": ')
    table, report = read_folder(d, fps=15)
    text = "\n".join(report)
    clips = set(table["clip"])
    assert "ds_kick_x_001" not in clips and "ds_jump_y_001" in clips
    assert "ds_walk_happy_002" not in clips and "ds_walk_happy_001" in clips
    assert "ds_run_sad_009" not in clips and "ds_run_happy_009" not in clips
    line = next(r for r in report if "ds_kick_x_001.bvh" in r)
    assert "kick-a.json" in line and "kick-b.json" in line and "kick/happy" in line and "kick/sad" in line
    assert any("jump-a.json" in r and "jump-b.json" in r and r.startswith("note:") for r in report), text
    assert any("ds_walk_happy_002.bvh: file: expected a clip of its own, got a byte-identical copy of" in r
               and "ds_walk_happy_001.bvh" in r for r in report), text
    assert any("ds_run_happy_009.bvh" in r and "ds_run_sad_009.bvh" in r and "labelled differently" in r
               for r in report), text
    assert any(r.startswith("skipped label:") and "broken.json: line 1" in r for r in report), text
    assert all("\n" not in r for r in report)


def test_coinciding_key_points_are_the_skeletons_problem_naming_the_joints(tmp_path):
    text = _tiny_human().replace("OFFSET 0 6 0", "OFFSET 0 0 0")      # Head on top of Neck
    p = _write(tmp_path, "flat.bvh", text)
    with pytest.raises(InputError) as err:
        load_clip(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}: skeleton: expected key points at distinct places"), msg
    assert "thorax = Neck and neck = Head" in msg and "--joint-map" in msg and "\n" not in msg


def test_a_motionbuilder_cmu_file_forced_into_rokoko_rules_names_the_coinciding_joints():
    p = DATA / "bvh-skeletons/cmu-motionbuilder/cmu_12_01_walk.bvh"
    if not p.is_file():
        pytest.skip(f"{p} not found (../shared/data absent)")
    with pytest.raises(InputError, match=r"spine = Spine1 and thorax = Neck"):
        load_clip(p, family="rokoko")
    assert load_clip(p).family == "cmu-motionbuilder"


@pytest.mark.parametrize("frame_time", ["100000", "1e300"])
def test_a_huge_frame_time_is_refused_before_resampling(tmp_path, frame_time):
    text = _tiny_human().replace("Frame Time: 0.0333333", f"Frame Time: {frame_time}")
    p = _write(tmp_path, "slow.bvh", text)
    with pytest.raises(InputError) as err:
        load_clip(p, fps=30)
    msg = str(err.value)
    assert msg.startswith(f"{p}: Frame Time: expected a clip of at most 600000 frames"), msg
    assert load_clip(p, fps=None).points.shape == (4, 17, 2)      # at its own rate: 4 frames


def bvh_text(joints, n_frames: int = 6, frame_time: float = 1 / 30, sway: float = 10.0) -> str:
    """A BVH file from ``[(name, parent or None, (x, y, z) offset)]`` (Y-up, cm): the root walks
    towards +z, every joint swings about its x axis by up to ``sway`` degrees; leaves get End Sites."""
    children: dict = {}
    for n, p, _ in joints:
        children.setdefault(p, []).append(n)
    off = {n: o for n, _, o in joints}
    out = ["HIERARCHY"]

    def emit(n, depth):
        pad = "  " * depth
        out.append(f"{pad}{'ROOT' if depth == 0 else 'JOINT'} {n}")
        out.extend([pad + "{", f"{pad}  OFFSET {' '.join(f'{v:g}' for v in off[n])}",
                f"{pad}  CHANNELS {6 if depth == 0 else 3} " + ("Xposition Yposition Zposition " if depth == 0
                                                               else "") + "Zrotation Xrotation Yrotation"])
        for c in children.get(n, []):
            emit(c, depth + 1)
        if n not in children:
            out.extend([pad + "  End Site", pad + "  {", pad + "    OFFSET 0 -2 0", pad + "  }"])
        out.append(pad + "}")

    emit(joints[0][0], 0)
    rows = []
    for f in range(n_frames):
        v = [0.0, off[joints[0][0]][1], 5.0 * f, 0.0, 0.0, 0.0]
        for k in range(1, len(joints)):
            v += [0.0, sway * np.sin(0.7 * f + k), 0.0]
        rows.append(" ".join(f"{x:.4f}" for x in v))
    out += ["MOTION", f"Frames: {n_frames}", f"Frame Time: {frame_time:.7f}", *rows]
    return "\n".join(out) + "\n"


def iclone_joints(prefix: str = "CC_Base_"):
    """A Character Creator rig as iClone exports it: twist and share bones, facial bones, no head End Site."""
    P = prefix
    j = [("RL_BoneRoot", None, (0, 0, 0)), (P + "Hip", "RL_BoneRoot", (0, 98, 0)),
         (P + "Pelvis", P + "Hip", (0, 0, 0)), (P + "Waist", P + "Hip", (0, 5, 0)),
         (P + "Spine01", P + "Waist", (0, 12, 0)), (P + "Spine02", P + "Spine01", (0, 14, 0)),
         (P + "NeckTwist01", P + "Spine02", (0, 18, 0)), (P + "NeckTwist02", P + "NeckTwist01", (0, 5, 0)),
         (P + "Head", P + "NeckTwist02", (0, 5, 1)), (P + "FacialBone", P + "Head", (0, 6, 8)),
         (P + "JawRoot", P + "FacialBone", (0, -4, 1)), (P + "L_Eye", P + "FacialBone", (3, 2, 1)),
         (P + "R_Eye", P + "FacialBone", (-3, 2, 1))]
    for s, x in (("L", 1), ("R", -1)):
        j += [(f"{P}{s}_Thigh", P + "Pelvis", (9 * x, -7, 0)), (f"{P}{s}_ThighTwist01", f"{P}{s}_Thigh", (0, -20, 0)),
              (f"{P}{s}_Calf", f"{P}{s}_Thigh", (0, -42, 0)), (f"{P}{s}_KneeShareBone", f"{P}{s}_Calf", (0, 0, 2)),
              (f"{P}{s}_CalfTwist01", f"{P}{s}_Calf", (0, -20, 0)), (f"{P}{s}_Foot", f"{P}{s}_Calf", (0, -42, 0)),
              (f"{P}{s}_ToeBase", f"{P}{s}_Foot", (0, -6, 12)),
              (f"{P}{s}_Clavicle", P + "Spine02", (3 * x, 14, 0)), (f"{P}{s}_Upperarm", f"{P}{s}_Clavicle", (14 * x, 0, 0)),
              (f"{P}{s}_UpperarmTwist01", f"{P}{s}_Upperarm", (13 * x, 0, 0)),
              (f"{P}{s}_Forearm", f"{P}{s}_Upperarm", (27 * x, 0, 0)), (f"{P}{s}_ElbowShareBone", f"{P}{s}_Forearm", (0, 0, -2)),
              (f"{P}{s}_ForearmTwist01", f"{P}{s}_Forearm", (12 * x, 0, 0)), (f"{P}{s}_Hand", f"{P}{s}_Forearm", (25 * x, 0, 0)),
              (f"{P}{s}_Mid1", f"{P}{s}_Hand", (8 * x, 0, 0))]
    return j


def test_an_iclone_rig_is_read_with_its_twist_and_share_bones_ignored(tmp_path):
    p = _write(tmp_path, "cc.bvh", bvh_text(iclone_joints()))
    clip = load_clip(p, fps=None, facing="none", center=False)
    assert clip.family == "iclone" and clip.up == "y"
    K = clip.points3d[0]
    J = JOINT_INDEX
    np.testing.assert_allclose(K[J["pelvis"]], (K[J["l_hip"]] + K[J["r_hip"]]) / 2)
    # head_top: 1.8 neck lengths (NeckTwist01 -> Head) above the head joint, above everything else
    assert K[J["head_top"], 1] == pytest.approx(K[J["neck"], 1] + 1.8 * (K[J["neck"], 1] - K[J["thorax"], 1]), abs=1.0)
    assert K[J["head_top"], 1] > K[J["neck"], 1] > K[J["thorax"], 1] > K[J["spine"], 1] > K[J["pelvis"], 1]
    assert K[J["pelvis"], 1] > K[J["l_knee"], 1] > K[J["l_ankle"], 1]
    # forearm twist and share bones do not move the elbow: it is the Forearm joint
    assert abs(K[J["l_elbow"], 0] - K[J["l_shoulder"], 0]) > 20


def test_a_shared_name_prefix_is_looked_through(tmp_path):
    mixamo = [("Hips", None, (0, 95, 0)), ("Spine", "Hips", (0, 10, 0)), ("Spine1", "Spine", (0, 12, 0)),
              ("Spine2", "Spine1", (0, 13, 0)), ("Neck", "Spine2", (0, 15, 0)), ("Head", "Neck", (0, 10, 2)),
              ("HeadTop_End", "Head", (0, 18, 2))]
    for s, x in (("Left", 1), ("Right", -1)):
        mixamo += [(f"{s}Shoulder", "Spine2", (6 * x, 9, 0)), (f"{s}Arm", f"{s}Shoulder", (12 * x, 0, 0)),
                   (f"{s}ForeArm", f"{s}Arm", (27 * x, 0, 0)), (f"{s}Hand", f"{s}ForeArm", (25 * x, 0, 0)),
                   (f"{s}UpLeg", "Hips", (9 * x, -7, 0)), (f"{s}Leg", f"{s}UpLeg", (0, -41, 0)),
                   (f"{s}Foot", f"{s}Leg", (0, -40, 0)), (f"{s}ToeBase", f"{s}Foot", (0, -6, 12))]
    renamed = [(f"Character1_{n}", None if p is None else f"Character1_{p}", o) for n, p, o in mixamo]
    p = _write(tmp_path, "hik.bvh", bvh_text(renamed))
    assert load_clip(p, fps=None).family == "mixamo"
    b = read_bvh(p)
    assert detect_family(b.names, p, b.is_end_site).name == "mixamo"


# --------------------------------------------------------------------------- joint maps

ALIEN = {"Spine": "Ruecken1", "Chest": "Ruecken2",
         "UpperArm_L": "OberarmL", "LowerArm_L": "UnterarmL", "Hand_L": "HandL",
         "UpperArm_R": "OberarmR", "LowerArm_R": "UnterarmR", "Hand_R": "HandR",
         "UpperLeg_L": "OberschenkelL", "LowerLeg_L": "UnterschenkelL", "Foot_L": "FussL",
         "UpperLeg_R": "OberschenkelR", "LowerLeg_R": "UnterschenkelR", "Foot_R": "FussR"}

ALIEN_MAP = """\
# joints of a made-up skeleton
format: nnsf.joint_map
version: 1
joints:
  pelvis: [OberschenkelL, OberschenkelR]
  r_hip: OberschenkelR
  r_knee: UnterschenkelR
  r_ankle: FussR
  l_hip: OberschenkelL
  l_knee: UnterschenkelL
  l_ankle: FussL
  spine: mid(Ruecken1, Ruecken2)
  thorax: Neck
  neck: Head
  head_top: local(Head, 3)
  l_shoulder: OberarmL
  l_elbow: UnterarmL
  l_wrist: HandL
  r_shoulder: OberarmR
  r_elbow: UnterarmR
  r_wrist: HandR
"""


def test_made_up_joint_names_are_refused_with_candidates_then_read_with_a_joint_map(tmp_path):
    from nnsf.datasets.joint_map import read_joint_map

    p = _write(tmp_path, "alien.bvh", _tiny_human(ALIEN))
    with pytest.raises(InputError) as err:
        load_clip(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}: joint names: expected joint names of a known family"), msg
    assert "candidates: " in msg and "--joint-map" in msg and "\n" not in msg
    fam = read_joint_map(_write(tmp_path, "alien.yaml", ALIEN_MAP))
    # Hips, Neck and Head are names several families write: they are listed, none maps all 17
    assert re.search(r"candidates: [\w-]+ \(score 0\.\d\d, maps \d+ of 17 key points; lacks ", msg), msg
    clip = load_clip(p, family=fam, fps=None)
    # the same motion as the Bandai-named original, key point for key point
    ref = load_clip(_write(tmp_path, "ref.bvh", _tiny_human()), fps=None)
    assert ref.family == "bandai-namco"
    np.testing.assert_allclose(clip.points, ref.points, atol=1e-9)


def test_a_joint_map_over_a_family_fills_in_the_rest(tmp_path):
    from nnsf.datasets.joint_map import read_joint_map

    renamed = {"UpperLeg_L": "LThigh", "LowerLeg_L": "LShin", "Foot_L": "LFoot"}
    p = _write(tmp_path, "part.bvh", _tiny_human(renamed))
    m = _write(tmp_path, "part.yaml", "family: bandai-namco\njoints:\n  pelvis: [LThigh, UpperLeg_R]\n"
               "  l_hip: LThigh\n  l_knee: LShin\n  l_ankle: LFoot\n")
    clip = load_clip(p, family=read_joint_map(m), fps=None)
    ref = load_clip(_write(tmp_path, "ref.bvh", _tiny_human()), fps=None)
    np.testing.assert_allclose(clip.points, ref.points, atol=1e-9)


@pytest.mark.parametrize("text, field, words", [
    ("joints: [a, b]\n", "joints", "a mapping of key points"),
    ("joints:\n  pelvis: Hips\n", "joints", "all 17 key points"),
    ("family: nope\njoints:\n  pelvis: Hips\n", "family", "one of bandai-namco"),
    ("family: mixamo\njoints:\n  pelvs: Hips\n", "joints.pelvs", "did you mean pelvis"),
    ("family: mixamo\njoints:\n  pelvis: [A, B, C]\n", "joints.pelvis", "two joint names"),
    ("family: mixamo\njoints:\n  pelvis: middle(A)\n", "joints.pelvis", "cannot read key-point rule"),
    ("family: mixamo\nextra: 1\njoints:\n  pelvis: Hips\n", "extra", "only the keys"),
    ("version: 2\nfamily: mixamo\njoints:\n  pelvis: Hips\n", "version", "expected 1"),
    ("joints: {pelvis: [a\n", "line 2", "valid YAML"),
    ("!!python/object/apply:os.system [ls]\n", "line 1", "YAML without tags that build Python objects"),
])
def test_bad_joint_maps_name_the_file_and_field(tmp_path, text, field, words):
    from nnsf.datasets.joint_map import read_joint_map

    p = _write(tmp_path, "bad.yaml", text)
    with pytest.raises(InputError) as err:
        read_joint_map(p)
    msg = str(err.value)
    assert msg.startswith(f"{p}: {field}: ") and words in msg and "\n" not in msg, msg


def test_a_joint_map_naming_a_joint_the_file_lacks_names_the_map_and_the_nearest_joints(tmp_path):
    from nnsf.datasets.joint_map import read_joint_map

    p = _write(tmp_path, "alien.bvh", _tiny_human(ALIEN))
    m = _write(tmp_path, "typo.yaml", ALIEN_MAP.replace("l_knee: UnterschenkelL", "l_knee: UnterschenkeL"))
    with pytest.raises(InputError) as err:
        load_clip(p, family=read_joint_map(m))
    msg = str(err.value)
    assert msg.startswith(f"{m}: joints.l_knee: expected joints of {p}, got 'UnterschenkeL'"), msg
    assert "UnterschenkelL" in msg


def test_an_end_site_at_zero_offset_is_no_point_and_the_next_rule_is_used():
    from nnsf.datasets.bvh_skeletons import mapping_text

    fam = FAMILIES["cmu-motionbuilder"]
    names = ["Hips", "LeftUpLeg", "RightUpLeg", "LeftLeg", "RightLeg", "LeftFoot", "RightFoot", "Spine",
             "Spine1", "Neck", "Neck1", "Head", "Head_end", "LeftArm", "RightArm", "LeftForeArm",
             "RightForeArm", "LeftHand", "RightHand"]
    kinds = [0] * len(names)
    kinds[names.index("Head_end")] = 1
    assert mapping_text(fam, names, kinds)["head_top"] == "end(Head)"
    kinds[names.index("Head_end")] = 2                     # OFFSET 0 0 0: the head joint itself
    assert mapping_text(fam, names, kinds)["head_top"] == "beyond(Neck1, Head, 1)"
    b = parse_bvh(GOOD_HEADER.replace("OFFSET 0 1 0", "OFFSET 0 0 0") + "Frames: 1\nFrame Time: 0.1\n"
                  "0 0 0 0 0 0\n", "zero.bvh")
    assert list(b.site_kinds) == [0, 2]


def _swinging_human(bind: bool, frames: int = 40) -> str:
    """The tiny human walking with its left arm swinging, ``frames`` frames; with ``bind`` a first
    frame of the skeleton's bind pose (every rotation zero, the root at the origin) before them."""
    head = _tiny_human().split("MOTION")[0]
    arm = 6 + 3 * 4                 # UpperArm_L's first rotation channel (Zrotation), fifth joint written
    rows = []
    if bind:
        rows.append(np.zeros(6 + 3 * 16))
    for f in range(frames):
        v = np.zeros(6 + 3 * 16)
        v[1], v[2], v[4] = 90.0, 2.0 * f, 5.0
        v[arm] = -60.0 + 20.0 * np.sin(f / 4.0)
        rows.append(v)
    body = "\n".join(" ".join(f"{x:g}" for x in r) for r in rows)
    return head + f"MOTION\nFrames: {len(rows)}\nFrame Time: 0.0333333\n{body}\n"


def test_a_bind_pose_before_the_motion_is_left_out_with_a_note(tmp_path):
    """Exporters often put the skeleton's bind pose (a T-pose) at frame 0: drawn, it flashed for a
    frame before the motion.  It is left out, and the rest is the clip without it."""
    with_bind = load_clip(_write(tmp_path, "bound.bvh", _swinging_human(True)), fps=None)
    without = load_clip(_write(tmp_path, "plain.bvh", _swinging_human(False)), fps=None)
    assert with_bind.points.shape == without.points.shape == (40, 17, 2)
    np.testing.assert_allclose(with_bind.points, without.points, atol=1e-9)
    assert len(with_bind.notes) == 1 and "bound.bvh: frame 0 is the skeleton's bind pose" in with_bind.notes[0]
    assert without.notes == []


@pytest.mark.parametrize("rel, dropped", [("bvh-skeletons/cmu-motionbuilder/cmu_12_01_walk.bvh", True),
                                          ("bvh-skeletons/cmu-daz/29_01.bvh", True),
                                          ("bvh-skeletons/mixamo/test_freebvh.bvh", False),
                                          ("animated-drawings/bvh/fair1/dab.bvh", False),
                                          ("bandai-namco-1/data/dataset-1_walk_normal_001.bvh", False)])
def test_real_clips_lose_a_bind_pose_first_frame_and_nothing_else(rel, dropped):
    p = DATA / rel
    if not p.is_file():
        pytest.skip(f"{p} not found (../shared/data absent)")
    clip = load_clip(p, fps=None)
    assert len(clip.points) == read_bvh(p).n_frames - int(dropped)
    assert any("bind pose" in n for n in clip.notes) == dropped
