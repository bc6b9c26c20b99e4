"""The ``reshape`` stage end to end, its bad inputs, and the evaluation on one drawing and motion."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nnsf.errors import InputError
from stick_figure import stick_figure
from nnsf.reshape.formats import write_character
from nnsf.reshape.stage import reshape
from nnsf.skeleton import JOINT_INDEX as J, rest_pose
from nnsf.skeleton.layout import FEATURE_COLUMNS

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"


def _rot(p, c, deg):
    a = np.radians(deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    return (p - c) @ R.T + c


def _csv(path: Path, frames: int = 6, nan_at: int | None = None) -> Path:
    """A contract CSV with two clips: the template body waving an arm (template units)."""
    kp = rest_pose() + 2.0
    rows = []
    for clip in ("wave-00", "wave-01"):
        for t in range(frames):
            p = kp.copy()
            p[[J["r_elbow"], J["r_wrist"]]] = _rot(kp[[J["r_elbow"], J["r_wrist"]]], kp[J["r_shoulder"]],
                                                   70 * np.sin(np.pi * t / frames))
            if nan_at is not None and t == nan_at and clip == "wave-00":
                p[J["l_knee"], 0] = np.nan
            rows.append({"clip": clip, "frame": t, "character": "x", "motion": "wave",
                         **dict(zip(FEATURE_COLUMNS, p.ravel()))})
    pd.DataFrame(rows).to_csv(path, index=False)
    return path


def _params(**kw):
    p = {"clip": None, "character": "stick-for-tests", "character_size": 200, "n_vertices": 300,
         "subkeys_per_limb": 3, "method": "ours", "propagation": "limb-frame",
         "fps": 12, "max_frames": 6, "formats": ["png", "gif", "mp4"]}
    p.update(kw)
    return {"reshape": p}


@pytest.fixture(scope="module")
def character_file(tmp_path_factory):
    folder = tmp_path_factory.mktemp("char")
    return write_character(stick_figure(height=200, name="stick"), folder / "stick.json")


def test_stage_writes_frames_gif_mp4_and_metrics_reproducibly(tmp_path, character_file):
    csv = _csv(tmp_path / "motion.csv")
    out = tmp_path / "out"
    res = reshape(_params(), csv, character_file, out)
    names = sorted(p.name for p in out.iterdir())
    assert names == ["frames", "metrics.json", "stick_wave-00.gif", "stick_wave-00.mp4", "stick_wave-00_sheet.png"]
    assert len(list((out / "frames").glob("frame_*.png"))) == 6
    m = json.loads((out / "metrics.json").read_text())
    assert m["clip"] == "wave-00" and m["metrics"]["frames"] == 6
    # an arm waved 70 degrees on one connected mesh: it bends at the shoulder, the limb keeps its width
    assert m["metrics"]["limb_bending_change"] > 0 and res.metrics["reshape_flipped_triangles"] <= 0.02 * 6 * m["metrics"]["triangles"]
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.suffix != ".mp4"}
    reshape(_params(), csv, character_file, out)
    after = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file() and p.suffix != ".mp4"}
    assert before == after


def test_reshape_head_torso_keeps_the_drawn_head_through_a_nod(tmp_path, character_file):
    """``reshape.head``: with ``motion`` a nodding head turns on the drawing; with ``torso`` it keeps
    its drawn angle to the body (the rest of the figure is the same in both)."""
    csv = _csv(tmp_path / "motion.csv")
    table = pd.read_csv(csv)
    cols = list(FEATURE_COLUMNS[2 * J["head_top"]: 2 * J["head_top"] + 2])  # its x and y
    kp = rest_pose() + 2.0
    for i, row in table.iterrows():  # the head nods 40 degrees about the neck and back
        t = int(row["frame"])
        table.loc[i, cols] = _rot(kp[J["head_top"]][None], kp[J["neck"]], 40 * np.sin(np.pi * t / 6))[0]
    table.to_csv(csv, index=False)
    frames = {}
    for head in ("motion", "torso"):
        out = tmp_path / head
        reshape(_params(head=head, formats=["png"]), csv, character_file, out)
        frames[head] = [np.asarray(bytearray(p.read_bytes())) for p in sorted((out / "frames").glob("*.png"))]
    assert len(frames["motion"]) == len(frames["torso"]) == 6
    assert np.array_equal(frames["motion"][0], frames["torso"][0])  # no nod at frame 0
    assert not np.array_equal(frames["motion"][3], frames["torso"][3])  # the nod's peak


def test_bad_head_setting_names_the_field(tmp_path, character_file):
    with pytest.raises(InputError, match=r"reshape\.head"):
        reshape(_params(head="nod"), _csv(tmp_path / "motion.csv"), character_file, tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_default_character_needs_no_shared_data(tmp_path):
    csv = _csv(tmp_path / "motion.csv", frames=3)
    out = tmp_path / "out"
    reshape(_params(character="bruno", character_size=160, max_frames=3, formats=["gif"]), csv, None, out)
    assert (out / "metrics.json").is_file() and len(list(out.glob("*.gif"))) == 1


@pytest.mark.parametrize("case", ["nan", "clip", "method", "formats", "character_path", "escape"])
def test_bad_inputs_raise_and_write_nothing(tmp_path, character_file, case):
    csv = _csv(tmp_path / "motion.csv", nan_at=4 if case == "nan" else None)
    params, char = _params(), character_file
    match = {"nan": r"clip wave-00.*frame 4", "clip": "clip", "method": "reshape.method",
             "formats": "reshape.formats", "character_path": "nope.json", "escape": "inside the project"}[case]
    if case == "clip":
        params["reshape"]["clip"] = "missing"
    elif case == "method":
        params["reshape"]["method"] = "magic"
    elif case == "formats":
        params["reshape"]["formats"] = ["avi"]
    elif case == "character_path":
        char = tmp_path / "nope.json"
    elif case == "escape":
        params["reshape"]["character"] = "../elsewhere/char.json"
        char = None
    out = tmp_path / "out"
    with pytest.raises(InputError, match=match):
        reshape(params, csv, char, out)
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".out")]


def test_joint_outside_mask_and_missing_joints_are_refused(tmp_path, character_file):
    obj = json.loads(character_file.read_text())
    folder = character_file.parent
    bad = dict(obj, keypoints=dict(obj["keypoints"], l_wrist=[0.0, 0.0]))
    (tmp_path / "c.json").write_text(json.dumps(bad))
    for name in ("stick.texture.png", "stick.mask.png"):
        (tmp_path / name).write_bytes((folder / name).read_bytes())
    csv = _csv(tmp_path / "motion.csv")
    with pytest.raises(InputError, match=r"joints.l_wrist: expected a point on the drawing or within"):
        reshape(_params(), csv, tmp_path / "c.json", tmp_path / "out")
    missing = dict(obj, keypoints={k: v for k, v in obj["keypoints"].items() if k != "r_knee"})
    (tmp_path / "c.json").write_text(json.dumps(missing))
    with pytest.raises(InputError, match="r_knee"):
        reshape(_params(), csv, tmp_path / "c.json", tmp_path / "out")
    assert not (tmp_path / "out").exists()


# --------------------------------------------------------------------------- real data

@pytest.mark.skipif(not (SHARED / "animated-drawings" / "characters" / "char6").is_dir(),
                    reason="needs ../shared/data/animated-drawings/characters (char5, char6)")
@pytest.mark.parametrize("name, body", [("char5", "biped"), ("char6", "quadruped")])
def test_the_stage_reads_every_character_nnsf_animate_reads(tmp_path, monkeypatch, name, body):
    """``reshape.character`` names an AnimatedDrawings folder inside the project with six arms
    (char5) or four legs (char6): the stage reads it as ``nnsf animate`` does (the strict biped
    reader refused both) and renders the clip, its metrics naming the character and carrying the
    reader's notes; with ``reshape.arms: motion`` char5 gets a note that ``drawing`` keeps its arms
    spread."""
    import shutil

    from nnsf.reshape.stage import resolve_character

    shutil.copytree(SHARED / "animated-drawings" / "characters" / name, tmp_path / "chars" / name)
    monkeypatch.chdir(tmp_path)
    ch = resolve_character(f"chars/{name}")
    assert ch.body == body and (len(ch.extra_limbs) > 0) == (name == "char5")
    csv = _csv(tmp_path / "motion.csv", frames=4)
    out = tmp_path / "out"
    reshape(_params(character=f"chars/{name}", max_frames=4, formats=["gif"]), csv, None, out)
    m = json.loads((out / "metrics.json").read_text())
    assert m["character"] == name and m["metrics"]["frames"] == 4
    # the reader's notes travel with the output, and the stage adds its own on arms that cross
    notes = " | ".join(m["notes"])
    if name == "char5":
        assert "arm 3 drives the left arm" in notes and "reshape.arms drawing swings them" in notes
    else:
        assert "a quadruped" in notes and "reshape.arms" not in notes
    reshape(_params(character=f"chars/{name}", max_frames=4, formats=["gif"], arms="drawing"), csv, None, out)
    assert "reshape.arms" not in " | ".join(json.loads((out / "metrics.json").read_text())["notes"])


def test_evaluation_on_one_character_and_motion(tmp_path):
    """Both methods on the same mesh, every frame measured against the drawing, a contact sheet; the
    paper's deformation moves the limb-bending measure, subkeys less than key points alone."""
    bvh = SHARED / "bandai-namco-1" / "data" / "dataset-1_punch_normal_001.bvh"
    if not (SHARED / "animated-drawings" / "characters" / "char2").is_dir() or not bvh.is_file():
        pytest.skip(f"AnimatedDrawings characters or Bandai-Namco clips not found under {SHARED}")
    from nnsf.reshape.evaluation import evaluate_item

    out = evaluate_item({"data": str(SHARED), "character": "animated-drawings/characters/char2",
                         "motion": "bandai-namco-1/data/dataset-1_punch_normal_001.bvh", "set": "tuning",
                         "n_vertices": 600, "max_frames": 20, "subkeys_per_limb": 4})
    rows = {r["method"]: r for r in out["rows"]}
    assert set(rows) == {"ours", "keypoints"} and len(out["frames"]) == 20
    ours = rows["ours"]
    assert ours["detached_max"] == 0 and ours["frames_with_detached"] == 0
    for k in ("width_error", "width_change", "width_roughness", "outline_roughness_change", "render_ms"):
        assert np.isfinite(ours[k]), k
    assert 0 < ours["limb_bending_change"] < rows["keypoints"]["limb_bending_change"]
    name, images, labels = out["sheet"]
    assert images.shape[0] == 12 and labels[-1].startswith("worst")


def test_canvas_is_the_clip_extent_plus_margin():
    from nnsf.reshape.animator import canvas

    frames = np.array([[[50.0, 60.0], [80.0, 90.0]], [[40.0, 70.0], [85.0, 121.0]]])
    offset, (h, w) = canvas(frames, margin=5)
    V = frames + offset
    assert V.min() == 5.0                                # every vertex inside, margin 5 px on the low sides
    assert (w, h) == (56, 72)                            # x 35..90 and y 55..126, rounded up to even sides
    assert V[..., 0].max() <= w - 1 - 5 + 1 and V[..., 1].max() <= h - 1 - 5 + 1
