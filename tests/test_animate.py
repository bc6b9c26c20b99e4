"""Saved style models, `nnsf translate()`, views, `nnsf styles` and `nnsf animate`.

Self-contained: the model is fitted on a small embedded synthetic set, the
drawn character is the built-in stick figure written out in AnimatedDrawings'
format.  Tests on the real AnimatedDrawings / Bandai-Namco / Kenney files
read ``../shared/data`` and skip when it is absent.
"""
from __future__ import annotations

import json
import os
import shutil
import zipfile
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from conftest import moving_box_frames
from nnsf import cli
from nnsf.animate.animation import encoding_meanwhile
from nnsf.datasets import contract, synthetic
from nnsf.errors import InputError
from nnsf.io import WriteError
from nnsf.factor.translate import StyleTranslator
from nnsf.reshape.video import read_mp4, write_mp4
from nnsf.skeleton import JOINT_INDEX, JOINTS

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
AD = DATA / "animated-drawings"
BN = DATA / "bandai-namco-1" / "data"
needs_shared = pytest.mark.skipif(not DATA.is_dir(), reason=f"shared data absent ({DATA})")

#: AnimatedDrawings joint -> our key point, for writing a char_cfg.yaml.
AD_FROM_OURS = {"root": "pelvis", "hip": "pelvis", "torso": "thorax", "neck": "neck",
                "right_shoulder": "r_shoulder", "right_elbow": "r_elbow", "right_hand": "r_wrist",
                "left_shoulder": "l_shoulder", "left_elbow": "l_elbow", "left_hand": "l_wrist",
                "right_hip": "r_hip", "right_knee": "r_knee", "right_foot": "r_ankle",
                "left_hip": "l_hip", "left_knee": "l_knee", "left_foot": "l_ankle"}


# --------------------------------------------------------------------------- fixtures
@pytest.fixture(scope="module")
def model_file(tmp_path_factory):
    from nnsf.factor.style_model import fit_model, unify_table

    raw = contract.validate(synthetic.generate(characters=3, clips_per_cell=1, frames=16, seed=0), "syn")
    raw = raw[raw["motion"].isin(["walk", "wave", "jump"])].reset_index(drop=True)
    table, unifier = unify_table(raw, 0.5)
    path = tmp_path_factory.mktemp("model") / "styles.npz"
    (view,) = fit_model([(None, table, unifier)], dict(n_components=4, max_iter=40, align_iter=20, random_state=0),
                        path, fps=24.0)
    return path, view.translator, table


def write_ad_folder(folder: Path, height: int = 200, drop=None, move=None) -> Path:
    """The stick figure as an AnimatedDrawings folder (texture.png, mask.png, char_cfg.yaml)."""
    from stick_figure import stick_figure

    ch = stick_figure(height=height)
    folder.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(folder / "texture.png"), cv2.cvtColor(ch.texture, cv2.COLOR_RGBA2BGRA))
    cv2.imwrite(str(folder / "mask.png"), ch.mask.astype(np.uint8) * 255)
    skel = []
    for name, ours in AD_FROM_OURS.items():
        if name == drop:
            continue
        loc = [int(round(v)) for v in ch.keypoints[JOINT_INDEX[ours]]]
        if name == move:
            loc = [ch.mask.shape[1] + 40, loc[1]]
        skel.append({"name": name, "loc": loc, "parent": None})
    (folder / "char_cfg.yaml").write_text(yaml.safe_dump(
        {"width": ch.mask.shape[1], "height": ch.mask.shape[0], "skeleton": skel}))
    return folder


def run_cli(argv, capsys):
    code = cli.main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out, captured.err


# --------------------------------------------------------------------------- the model file
def test_save_load_translates_bit_for_bit(model_file):
    from nnsf.factor.style_model import StyleModel, translate
    from nnsf.factor.translate import StyleTranslator

    path, tr, table = model_file
    # The stage's file keeps 6 significant digits (the same bytes on every machine) ...
    staged = StyleTranslator.load(path)
    X = contract.features(table[table["clip"] == table["clip"].iloc[0]])
    for style in tr.styles_:
        np.testing.assert_allclose(staged.translate_clip(X, style), tr.translate_clip(X, style),
                                   rtol=1e-4, atol=1e-5)
    # ... and save() by default keeps every bit: the loaded model is the fitted one.
    exact = tr.save(path.with_name("exact.npz"))
    loaded = StyleTranslator.load(exact)
    with np.load(exact, allow_pickle=False) as z:      # no pickled object anywhere
        assert "meta" in z.files
    for style in tr.styles_:
        assert np.array_equal(tr.translate_clip(X, style), loaded.translate_clip(X, style))
        assert np.array_equal(tr.translate(X, tr.styles_[0], style), loaded.translate(X, tr.styles_[0], style))
        assert np.array_equal(tr.synthesize("walk", style), loaded.synthesize("walk", style))
    P = synthetic.clip_points("max", "walk", 20)
    m = StyleModel.load(path)
    assert np.array_equal(translate(P, "olga", m), translate(P, "olga", path))
    meta = m.meta
    assert meta["styles"] == ["bruno", "olga", "pip"] and meta["version"] == 2
    (view,) = meta["views"]
    assert view["view"] is None and view["params"]["items"]  # no camera; the params that made it
    assert view["unifier"]["characters"].keys() == {"bruno", "olga", "pip"}


def test_translate_returns_the_callers_coordinates(model_file):
    """Scaling and shifting the input scales and shifts the output: the unification is undone."""
    from nnsf import translate

    path, _, _ = model_file
    P = synthetic.clip_points("max", "walk", 20)
    out = translate(P, "pip", path)
    assert out.shape == P.shape and not np.allclose(out, P)
    big = translate(10.0 * P + [300.0, -50.0], "pip", path)
    np.testing.assert_allclose(big, 10.0 * out + [300.0, -50.0], rtol=1e-9, atol=1e-7)
    assert np.array_equal(translate(P, "none", path), P)


def _rewrite(path: Path, out: Path, meta_change=None, drop=None):
    with np.load(path, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    meta = json.loads(str(arrays["meta"][()]))
    if meta_change:
        meta.update(meta_change)
    arrays["meta"] = np.array(json.dumps(meta))
    if drop:
        del arrays[drop]
    np.savez(out, **arrays)
    return out


def test_model_file_errors_name_the_file_and_what_is_wrong(model_file, tmp_path):
    from nnsf.factor.style_model import StyleModel

    path, _, _ = model_file
    bad = tmp_path / "corrupt.npz"
    bad.write_bytes(path.read_bytes()[:500])
    with pytest.raises(InputError, match=r"corrupt\.npz: file: expected a readable \.npz style model"):
        StyleModel.load(bad)
    with pytest.raises(InputError, match=r"v1\.npz: meta\.version: expected format version 2.*got 1"):
        StyleModel.load(_rewrite(path, tmp_path / "v1.npz", {"version": 1}))
    with pytest.raises(InputError, match=r"missing\.npz: meta\.views\[0\]\.state\..*: expected the array a3 .*missing"):
        StyleModel.load(_rewrite(path, tmp_path / "missing.npz", drop="a3"))
    text = tmp_path / "text.npz"
    text.write_text("not a zip")
    with pytest.raises(InputError, match="text.npz: file"):
        StyleModel.load(text)
    assert zipfile.is_zipfile(path)


# --------------------------------------------------------------------------- views
def test_auto_view_side_for_a_walk_front_for_a_wave():
    from nnsf.datasets.views import pick_view, view_variances

    t = np.linspace(0, 2 * np.pi, 60)
    rest = np.random.default_rng(0).normal(size=(17, 3))
    walk = np.repeat(rest[None], 60, axis=0)
    walk[:, [3, 6], 2] += np.stack([np.sin(t), -np.sin(t)], axis=1) * 0.5    # ankles forward/back (z)
    wave = np.repeat(rest[None], 60, axis=0)
    wave[:, 16, 0] += 0.5 * np.sin(3 * t)                                    # a wrist across the body (x)

    def front(P):  # the front view's image x, y and depth (elevation 0)
        return np.stack([P[..., 0], -P[..., 1]], -1), -P[..., 2]

    assert pick_view(*front(walk)) == "side"
    assert pick_view(*front(wave)) == "front"
    diag = np.repeat(rest[None], 60, axis=0)
    diag[:, 16, 0] += 0.5 * np.sin(t)
    diag[:, 16, 2] -= 0.5 * np.sin(t)      # along x - z: the 45° image axis
    var = view_variances(*front(diag))
    assert max(var, key=var.get) == "three-quarter"


@needs_shared
def test_auto_view_on_real_clips():
    from nnsf.datasets.views import load_clip_in_view

    _, walk = load_clip_in_view(BN / "dataset-1_walk_normal_001.bvh", "auto")
    _, wave = load_clip_in_view(AD / "bvh" / "fair1" / "wave_hello.bvh", "auto")
    assert (walk, wave) == ("side", "front")


def test_bad_view_is_a_one_line_error(tmp_path, capsys):
    params = Path(__file__).resolve().parents[1] / "params.yaml"
    p = yaml.safe_load(params.read_text())
    p["dataset"]["bvh"]["view"] = "diagonal"
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(p))
    code, _, err = run_cli(["check", "--params", tmp_path / "params.yaml"], capsys)
    assert code == 2 and err.count("\n") == 1 and "dataset.bvh.view" in err and "three-quarter" in err
    code, _, err = run_cli(["animate", "--character", "pip", "--motion", "synthetic:max/walk/8",
                            "--view", "diagonal", "--out", tmp_path / "a.mp4"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--view" in err and not (tmp_path / "a.mp4").exists()
    code, _, err = run_cli(["animate", "--character", "pip", "--motion", "synthetic:max/walk/8",
                            "--arms", "sideways", "--out", tmp_path / "a.mp4"], capsys)
    assert code == 2 and err.count("\n") == 1 and "--arms" in err and "motion, drawing" in err
    assert not (tmp_path / "a.mp4").exists()
    p["dataset"]["bvh"]["view"] = "side"
    p["animate"]["arms"] = "sideways"
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(p))
    code, _, err = run_cli(["check", "--params", tmp_path / "params.yaml"], capsys)
    assert code == 2 and err.count("\n") == 1 and "animate.arms" in err and "drawing" in err


# --------------------------------------------------------------------------- nnsf animate
def _frames(path: Path) -> int:
    cap = cv2.VideoCapture(str(path))
    n = 0
    while cap.read()[0]:
        n += 1
    cap.release()
    return n


def test_animate_an_animated_drawings_folder_end_to_end(model_file, tmp_path, capsys):
    path, _, _ = model_file
    char = write_ad_folder(tmp_path / "stick")
    out = tmp_path / "out" / "stick.mp4"
    code, stdout, err = run_cli(["animate", "--character", char, "--motion", "synthetic:max/jump/16",
                                 "--style", "olga", "--model", path, "--out", out, "--vertices", "300"], capsys)
    assert code == 0, err
    assert _frames(out) == 16
    sheet = cv2.imread(str(out.with_name("stick_sheet.png")))
    assert sheet is not None and sheet.shape[0] > 50
    for part in ("load", "translate", "retarget", "deform", "render", "encode"):
        assert f"{part} " in stdout
    assert str(out) in stdout and "rendered frame 16/16" in err
    gif = tmp_path / "out" / "stick.gif"
    assert run_cli(["animate", "--character", char / "char_cfg.yaml", "--motion", "synthetic:max/wave/8",
                    "--out", gif, "--vertices", "300"], capsys)[0] == 0
    from PIL import Image
    assert Image.open(gif).n_frames == 8
    frames = tmp_path / "out" / "frames"
    assert run_cli(["animate", "--character", char, "--motion", "synthetic:max/wave/6", "--out", frames,
                    "--vertices", "300", "--fps", "12"], capsys)[0] == 0
    # 6 frames of the built-in 24 fps clip last 0.25 s: 3 frames at 12 fps
    assert len(list(frames.glob("*.png"))) == 3


def test_animate_a_png_with_a_joints_yaml(tmp_path, capsys):
    from stick_figure import stick_figure

    ch = stick_figure(height=160)
    cv2.imwrite(str(tmp_path / "hero.png"), cv2.cvtColor(ch.texture, cv2.COLOR_RGBA2BGRA))
    joints = {j: [float(x), float(y)] for j, (x, y) in zip(JOINTS, ch.keypoints) if j != "spine"}
    (tmp_path / "hero.yaml").write_text(yaml.safe_dump({"name": "hero", "joints": joints}))
    out = tmp_path / "hero.mp4"
    code, _, err = run_cli(["animate", "--character", tmp_path / "hero.png", "--motion", "synthetic:max/walk/10",
                            "--out", out, "--vertices", "300"], capsys)
    assert code == 0, err
    assert _frames(out) == 10
    # the YAML alone, naming its image
    (tmp_path / "hero2.yaml").write_text(yaml.safe_dump({"image": "hero.png", "joints": joints}))
    assert run_cli(["animate", "--character", tmp_path / "hero2.yaml", "--motion", "synthetic:max/walk/4",
                    "--out", tmp_path / "h2.gif", "--vertices", "300"], capsys)[0] == 0


def test_animate_a_feature_matrix_csv(tmp_path, capsys):
    """Any 17-point clip in the contract: here one synthetic clip of a multi-clip table."""
    table = contract.validate(synthetic.generate(characters=2, clips_per_cell=1, frames=10, seed=0), "syn")
    csv = tmp_path / "motion.csv"
    contract.write_table(csv, table[table["motion"].isin(["walk", "wave"])])
    clip = sorted(table.loc[table["motion"] == "wave", "clip"])[0]
    out = tmp_path / "csv.mp4"
    code, stdout, err = run_cli(["animate", "--character", "pip", "--motion", csv, "--clip", clip,
                                 "--out", out, "--vertices", "300"], capsys)
    assert code == 0, err
    assert _frames(out) == 10 and f"of {clip} at 24 fps" in err


def _bad(capsys, argv, *needles, out=None):
    code, stdout, err = run_cli(argv, capsys)
    assert code == 2, (code, err)
    assert err.startswith("error: ") and err.count("\n") == 1, err
    for n in needles:
        assert str(n) in err, (n, err)
    if out is not None:
        assert not Path(out).exists() and not Path(out).with_name(Path(out).stem + "_sheet.png").exists()
    return err


def test_bad_input_one_line_exit_2_nothing_written(model_file, tmp_path, capsys):
    path, _, _ = model_file
    out = tmp_path / "o.mp4"
    base = ["animate", "--motion", "synthetic:max/walk/8", "--out", out, "--vertices", "300"]
    # a character folder without a mask
    f = write_ad_folder(tmp_path / "nomask")
    (f / "mask.png").unlink()
    _bad(capsys, base + ["--character", f], "nomask", "mask.png", out=out)
    # an empty mask
    f = write_ad_folder(tmp_path / "empty")
    cv2.imwrite(str(f / "mask.png"), np.zeros(cv2.imread(str(f / "mask.png")).shape[:2], np.uint8))
    _bad(capsys, base + ["--character", f], "empty", "mask", "empty mask", out=out)
    # a texture whose size differs from the mask's
    f = write_ad_folder(tmp_path / "size")
    tex = cv2.imread(str(f / "texture.png"), cv2.IMREAD_UNCHANGED)
    cv2.imwrite(str(f / "texture.png"), cv2.resize(tex, (tex.shape[1] + 10, tex.shape[0])))
    _bad(capsys, base + ["--character", f], "size", "mask", "texture's size", out=out)
    # a joint outside the image, a missing joint
    f = write_ad_folder(tmp_path / "outside", move="left_hand")
    _bad(capsys, base + ["--character", f], "char_cfg.yaml", "skeleton.left_hand.loc", "px outside it", out=out)
    f = write_ad_folder(tmp_path / "missing", drop="left_knee")
    _bad(capsys, base + ["--character", f], "char_cfg.yaml", "skeleton", "missing joints: left_knee", out=out)
    # a YAML with a python tag
    f = write_ad_folder(tmp_path / "tag")
    (f / "char_cfg.yaml").write_text("width: !!python/object/apply:os.system ['echo hi']\nskeleton: []\n")
    _bad(capsys, base + ["--character", f], "char_cfg.yaml", "line 1", "python", out=out)
    png_yaml = tmp_path / "tag.yaml"
    png_yaml.write_text("joints: !!python/name:os.system\n")
    _bad(capsys, base + ["--character", png_yaml], "tag.yaml", out=out)
    # a BVH whose skeleton cannot be mapped
    bvh = tmp_path / "odd.bvh"
    bvh.write_text("HIERARCHY\nROOT Blob\n{\n OFFSET 0 0 0\n CHANNELS 3 Xposition Yposition Zposition\n"
                   " JOINT Tentacle\n {\n  OFFSET 0 10 0\n  CHANNELS 3 Zrotation Xrotation Yrotation\n"
                   "  End Site\n  {\n   OFFSET 0 5 0\n  }\n }\n}\nMOTION\nFrames: 2\nFrame Time: 0.033333\n"
                   "0 0 0 0 0 0\n0 0 0 0 0 0\n")
    char = write_ad_folder(tmp_path / "ok")
    _bad(capsys, ["animate", "--character", char, "--motion", bvh, "--out", out],
         "odd.bvh", "joint names", "--joint-map", "writes any of them", out=out)
    # a style the model does not know (the known ones listed)
    _bad(capsys, base + ["--character", char, "--style", "zorro", "--model", path],
         "styles.npz", "--style", "bruno, olga, pip", "zorro", out=out)
    # a model file of another format version
    v1 = _rewrite(path, tmp_path / "v1.npz", {"version": 1})
    _bad(capsys, base + ["--character", char, "--style", "olga", "--model", v1],
         "v1.npz", "meta.version", out=out)
    # an unknown motion source, a bad output kind
    _bad(capsys, base + ["--character", char, "--motion", "synthetic:max/moonwalk"], "moonwalk", out=out)
    _bad(capsys, ["animate", "--character", char, "--motion", "synthetic:max/walk/4", "--out", tmp_path / "x.avi"],
         "x.avi", "--out")
    # no worker to render with
    _bad(capsys, base + ["--character", char, "--workers", "0"], "--workers", ">= 1", out=out)
    # a head choice that does not exist
    _bad(capsys, base + ["--character", char, "--head", "nod"], "--head", "motion, torso", out=out)


@pytest.mark.slow
def test_frames_rendered_by_two_processes_are_the_frames_of_one(monkeypatch):
    from nnsf.reshape import render_pool
    from nnsf.reshape.animator import BACKGROUND, Animator, canvas
    from stick_figure import stick_figure

    from nnsf.animate.animation import read_motion_spec

    ch = stick_figure(height=160)
    pts = read_motion_spec("synthetic:max/walk/24").points
    a = Animator(ch, n_vertices=200)
    V = a.deformer.run(a.retarget(pts))
    orders, _ = a.orders(V, pts)
    offset, size = canvas(V)
    r = a.renderer(size)
    one = render_pool.render_frames(r, V, orders, offset, BACKGROUND, size, workers=1)
    monkeypatch.setattr(render_pool, "MIN_FRAMES_PER_WORKER", 4)  # a pool for 24 frames
    seen = []
    two = render_pool.render_frames(r, V, orders, offset, BACKGROUND, size, workers=2,
                                    progress=lambda done, total: seen.append((done, total)))
    assert isinstance(two, np.memmap)  # drawn by the pool, not by this process
    assert two.shape == one.shape == (len(V), size[0], size[1], 3)
    assert np.array_equal(two, one)
    assert seen[-1] == (len(V), len(V)) and len(seen) == 8  # 4 chunks per worker
    assert not (one == one[:, :1, :1]).all()  # something was drawn
    # Handed over one by one, in order, as they are drawn (an encoder's feed); not kept if not asked.
    for workers in (1, 2):
        got = []
        assert render_pool.render_frames(r, V, orders, offset, BACKGROUND, size, workers=workers,
                                         each=got.append, keep=False) is None
        assert np.array_equal(np.stack(got), one)


# --------------------------------------------------------------------------- the MP4 encoded as drawn

def test_frames_fed_one_by_one_to_the_encoding_thread_make_the_whole_video(tmp_path):
    imgs = moving_box_frames()
    with encoding_meanwhile(write_mp4, tmp_path / "a.mp4", 12) as feed:
        for img in imgs:
            feed(img)
    back = read_mp4(tmp_path / "a.mp4")   # finished on leaving the block
    assert back.shape == (24, 62, 88, 3) and np.abs(back[:, :61, :87].astype(int) - imgs).mean() < 3.0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4"]


def test_a_write_error_on_the_encoding_thread_is_raised_in_the_drawing_caller(tmp_path, monkeypatch):
    import av

    def refuse(*a, **k):
        raise av.error.OSError(28, "No space left on device")
    monkeypatch.setattr(av.container.OutputContainer, "mux", refuse)
    with pytest.raises(WriteError, match=r"a\.mp4: write: expected free space on its disk"):
        with encoding_meanwhile(write_mp4, tmp_path / "a.mp4", 12) as feed:
            for img in moving_box_frames():
                feed(img)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("after", [0, 5])
def test_a_drawing_that_fails_leaves_no_video(tmp_path, after):
    with pytest.raises(KeyboardInterrupt):
        with encoding_meanwhile(write_mp4, tmp_path / "a.mp4", 12) as feed:
            for img in moving_box_frames(after):
                feed(img)
            raise KeyboardInterrupt
    assert list(tmp_path.iterdir()) == []


@pytest.mark.slow  # a fresh interpreter, as a spawn worker is
def test_a_render_worker_starts_with_numpy_and_opencv_only(tmp_path):
    """A worker imports the pool module and unpickles the renderer; SciPy, pandas or sklearn
    would add a good part of a second to every worker's start (and render nothing)."""
    import pickle
    import subprocess
    import sys

    from nnsf.reshape.animator import Animator
    from stick_figure import stick_figure

    (tmp_path / "r.pkl").write_bytes(pickle.dumps(Animator(stick_figure(height=120), n_vertices=150).renderer((160, 120))))
    code = ("import pickle, sys, nnsf.reshape.render_pool; r = pickle.load(open(sys.argv[1], 'rb')); "
            "print(type(r).__name__, sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'pandas', 'sklearn'}))")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "r.pkl")], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout.split() == ["Renderer", "[]"], out.stderr


def test_frame_files_of_dead_processes_are_removed_and_no_other(tmp_path):
    from nnsf.reshape import render_pool

    try:
        dead = int(Path("/proc/sys/kernel/pid_max").read_text()) + 1  # no process has this pid
    except OSError:
        dead = 2 ** 22 + 1
    names = [f"nnsf-frames-{dead}-x1.u8", f"nnsf-frames-{os.getpid()}-x2.u8", "nnsf-frames-1-x3.u8",
             f"other-{dead}.u8", f"nnsf-frames-{dead}-x4.txt"]
    for n in names:
        (tmp_path / n).write_bytes(b"\0" * 16)
    gone = render_pool.remove_stale(str(tmp_path))
    assert gone == [str(tmp_path / names[0])]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(names[1:])


def _children(pid: int) -> list[int]:
    """Process ids whose parent is ``pid`` (from /proc)."""
    kids = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            kids.append(int(stat.parent.name))
    return kids


def _pooled_render(out: Path, **popen):
    """A `nnsf animate` process drawing 1,800 frames on 2 workers, once its pool runs (seconds of
    drawing, so a signal lands while the workers draw): (the process, its frame files, its worker pids)."""
    import subprocess
    import sys
    import tempfile
    import time

    proc = subprocess.Popen([sys.executable, "-m", "nnsf.cli", "animate", "--character", "pip", "--motion",
                             "synthetic:max/walk/1800", "--out", str(out), "--vertices", "300",
                             "--workers", "2"], **popen)
    folders = (Path("/dev/shm"), Path(tempfile.gettempdir()))
    seen, kids = [], []
    deadline = time.monotonic() + 120
    while (not seen or len(kids) < 2) and proc.poll() is None and time.monotonic() < deadline:
        seen = [f for d in folders for f in d.glob(f"nnsf-frames-{proc.pid}-*.u8")]
        kids = _children(proc.pid) if seen else []
        time.sleep(0.05)
    assert seen and len(kids) >= 2, "the render never started its pool"
    return proc, seen, kids


@pytest.mark.slow  # a `nnsf animate` process and its render pool
@pytest.mark.parametrize("how, wait", [("SIGTERM", 0.0), ("SIGTERM", 2.0), ("SIGINT", 2.0)],
                         ids=["sigterm-as-workers-start", "sigterm-while-drawing", "ctrl-c-while-drawing"])
def test_an_interrupted_pooled_render_exits_in_one_line_and_leaves_no_frame_file(tmp_path, how, wait):
    """SIGTERM to the process (a scheduler), or SIGINT to its whole process group (Ctrl-C in a
    terminal, which the workers receive too), as the workers start or while they draw."""
    import signal
    import subprocess
    import time

    out = tmp_path / "walk.mp4"
    proc, seen, _ = _pooled_render(out, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   start_new_session=True)
    time.sleep(wait)
    assert proc.poll() is None, "the render ended before it could be interrupted"
    t0 = time.monotonic()
    if how == "SIGINT":
        os.killpg(proc.pid, signal.SIGINT)
    else:
        proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=60)
    stopped = time.monotonic() - t0
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "error: interrupted"
    assert "Traceback" not in err and "Error" not in err, err
    assert not any(f.exists() for f in seen)
    assert not out.exists()
    assert stopped < 15, f"{stopped:.1f} s to stop: the chunks not started were drawn"


@pytest.mark.slow  # a `nnsf animate` process and its render pool
def test_the_workers_of_a_killed_render_end_and_its_frame_file_goes_with_the_next(tmp_path):
    import signal
    import subprocess
    import time

    from nnsf.reshape import render_pool

    proc, seen, kids = _pooled_render(tmp_path / "walk.mp4", stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    time.sleep(1.0)
    assert proc.poll() is None, "the render ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    deadline = time.monotonic() + 20
    while any(Path(f"/proc/{k}").exists() for k in kids) and time.monotonic() < deadline:
        time.sleep(0.1)
    alive = [k for k in kids if Path(f"/proc/{k}").exists()]
    for k in alive:
        os.kill(k, signal.SIGKILL)
    assert not alive, "workers outlived the render they drew for"
    assert all(f.exists() for f in seen)  # killed outright: nothing could remove it ...
    removed = [p for f in seen for p in render_pool.remove_stale(str(f.parent))]
    assert sorted(removed) == sorted(str(f) for f in seen)  # ... until the next render looks
    assert not any(f.exists() for f in seen)
    for sem in Path("/dev/shm").glob(f"sem.loky-{proc.pid}-*"):  # joblib's, which SIGKILL also leaves
        sem.unlink(missing_ok=True)


def test_reshape_eval_and_tracking_real_need_data(capsys):
    for command in ("reshape-eval", "roto-real"):
        try:
            code = cli.main([command])
        except SystemExit as exc:  # argparse's own refusal of a missing required option
            code = exc.code
        assert code == 2
        err = capsys.readouterr().err
        assert "--data" in err and "Traceback" not in err


# --------------------------------------------------------------------------- real characters
@needs_shared
@pytest.mark.parametrize("name", ["char1", "char2", "char3", "char4", "char5"])
def test_every_animated_drawings_character_loads(name):
    from nnsf.animate.animation import read_character

    ch = read_character(AD / "characters" / name)
    assert ch.keypoints.shape == (17, 2) and ch.mask.any()


@needs_shared
def test_char6_is_read_as_a_quadruped():
    """char6 has four legs and no arms: read as a quadruped (nnsf.reshape.quadruped), its hind legs
    our legs and its front legs our arms, and said in a note."""
    from nnsf.animate.animation import read_character
    from nnsf.skeleton import JOINT_INDEX as J

    ch = read_character(AD / "characters" / "char6")
    assert ch.body == "quadruped" and any("quadruped" in n for n in ch.notes)
    assert np.allclose(ch.keypoints[J["r_hip"]], (139, 266)) and np.allclose(ch.keypoints[J["l_wrist"]], (360, 336))


@needs_shared
def test_char5_maps_the_arm_nearest_the_chest_and_says_so():
    """char5 has three arms a side: arm 3 (shoulders nearest the chest) drives each arm."""
    from nnsf.animate.animation import read_character
    from nnsf.reshape.character import points_in_mask

    ch = read_character(AD / "characters" / "char5")
    cfg = yaml.safe_load((AD / "characters" / "char5" / "char_cfg.yaml").read_text())
    loc = {j["name"]: j["loc"] for j in cfg["skeleton"]}
    assert ch.keypoints[JOINT_INDEX["r_wrist"]].tolist() == loc["right_hand3"]
    assert ch.keypoints[JOINT_INDEX["l_shoulder"]].tolist() == loc["left_shoulder3"]
    assert any("right arm 3 drives the right arm; arms 1, 2 turn as it turns" in n for n in ch.notes)
    assert points_in_mask(ch.mask, ch.keypoints).all()


@needs_shared
@pytest.mark.parametrize("arms", ["motion", "drawing"])
def test_char5_with_arms_from_the_motion_gets_a_note_on_its_spread_arms(tmp_path, capsys, arms):
    """With ``--arms motion`` char5's six arms point as the performer's and cross its body: a note
    says that ``--arms drawing`` keeps them spread.  With ``--arms drawing`` there is no such note."""
    out = tmp_path / "bug.gif"
    code, _, err = run_cli(["animate", "--character", AD / "characters" / "char5", "--motion",
                            "synthetic:max/walk/4", "--out", out, "--vertices", "200", "--arms", arms], capsys)
    assert code == 0, err
    assert ("swings them about their drawn pose" in err) == (arms == "motion")


@needs_shared
def test_the_animate_stage_keeps_the_notes_in_animate_json(tmp_path, monkeypatch):
    """The DVC stage on char5 (a folder inside the project) with ``animate.arms: motion``: the
    reader's note on the arms and the note on arms from the motion are in ``animate.json``."""
    from nnsf.animate.stage import animate

    shutil.copytree(AD / "characters" / "char5", tmp_path / "chars" / "char5")
    monkeypatch.chdir(tmp_path)
    params = {"animate": {"character": "chars/char5", "motion": "synthetic:max/walk/4", "style": "none",
                          "view": "auto", "fps": 12, "n_vertices": 200, "max_frames": 4, "output": ["gif"],
                          "arms": "motion"}}
    animate(params, model=tmp_path / "none.npz", out_dir=tmp_path / "out")
    notes = " | ".join(json.loads((tmp_path / "out" / "animate.json").read_text())["notes"])
    assert "arm 3 drives the left arm" in notes and "--arms (animate.arms) drawing swings them" in notes


@needs_shared
def test_kenney_frame_with_the_hand_made_joints(tmp_path, capsys):
    png = DATA / "kenney-toon" / "robot" / "robot_idle.png"
    joints = Path(__file__).resolve().parent / "data" / "kenney" / "robot.keypoints.json"
    out = tmp_path / "robot.mp4"
    code, _, err = run_cli(["animate", "--character", png, "--joints", joints, "--motion", "synthetic:max/walk/8",
                            "--out", out, "--vertices", "200"], capsys)
    assert code == 0, err
    assert _frames(out) == 8


@needs_shared
def test_nnsf_reshape_takes_a_png_with_its_joints_like_nnsf_animate(tmp_path, capsys):
    """``nnsf reshape --character robot_idle.png --joints robot.keypoints.json`` renders the clip;
    ``--joints`` without a PNG character is one line naming both options, exit 2."""
    from tests.test_reshape_stage import _csv

    png = DATA / "kenney-toon" / "robot" / "robot_idle.png"
    joints = Path(__file__).resolve().parent / "data" / "kenney" / "robot.keypoints.json"
    csv = _csv(tmp_path / "motion.csv", frames=3)
    out = tmp_path / "out"
    code, _, err = run_cli(["reshape", "--motion", csv, "--character", png, "--joints", joints, "--out", out], capsys)
    assert code == 0, err
    assert json.loads((out / "metrics.json").read_text())["metrics"]["frames"] == 3
    code, _, err = run_cli(["reshape", "--motion", csv, "--joints", joints, "--out", tmp_path / "no"], capsys)
    assert code == 2 and "--joints: --character: expected an existing PNG" in err
    assert "Traceback" not in err and not (tmp_path / "no").exists()


@needs_shared
def test_dataset_bvh_view_names_an_azimuth_and_auto_picks_one_for_the_folder(tmp_path):
    from nnsf import stages

    folder = tmp_path / "bvh"
    folder.mkdir()
    for style in ("normal", "old"):
        name = f"dataset-1_walk_{style}_001.bvh"
        shutil.copyfile(BN / name, folder / name)  # a copy: links leaving the folder are refused
    base = {"seed": 0, "dataset": {"name": "bvh", "path": str(folder), "bvh": {
        "fps": 15, "azimuth": 90.0, "elevation": 0.0, "facing": "normalise", "center": True,
        "complete_grid": True}}}
    by_azimuth = stages.data(base, out_dir=tmp_path / "a")
    side = {**base, "dataset": {**base["dataset"], "bvh": {**base["dataset"]["bvh"], "azimuth": 0.0,
                                                              "view": "side"}}}
    stages.data(side, out_dir=tmp_path / "b")
    auto = {**base, "dataset": {**base["dataset"], "bvh": {**base["dataset"]["bvh"], "view": "auto"}}}
    result = stages.data(auto, out_dir=tmp_path / "c")
    a, b, c = (contract.read_table(tmp_path / d / "keypoints.csv") for d in "abc")
    assert a.equals(b) and a.equals(c)            # a walk: auto takes the side view
    assert result.params["bvh_view"] == "side" and by_azimuth.params["bvh_azimuth"] == 90.0


def test_the_model_records_the_view_its_styles_were_learned_in():
    from nnsf.factor.style_model import dataset_view

    bvh = {"name": "bvh", "bvh": {"azimuth": 0.0}}
    assert dataset_view({"dataset": {"name": "synthetic"}}) is None
    assert dataset_view({"dataset": bvh}) == "front"
    assert dataset_view({"dataset": {**bvh, "bvh": {"azimuth": 90.0, "view": None}}}) == "side"
    assert dataset_view({"dataset": {**bvh, "bvh": {"azimuth": 30.0}}}) == "azimuth 30"
    assert dataset_view({"dataset": {**bvh, "bvh": {"azimuth": 0.0, "view": "auto"}}}) == "auto"


def test_a_model_keeps_one_translator_per_view_and_picks_the_motions(model_file, tmp_path):
    """A file with a front and a side view: a motion seen from the side gets the side view's
    translator, one seen three-quarter the nearest (a note says so), one with no camera the first."""
    from nnsf.factor.model_file import ModelView, save_model
    from nnsf.factor.style_model import StyleModel, translate

    path, tr, table = model_file
    m = StyleModel.load(path)
    side = StyleTranslator(**{**tr.get_params(), "n_components": 3}).fit(
        contract.features(table), table["motion"].to_numpy(), table["character"].to_numpy(),
        table["clip"].to_numpy(), fps=24.0)
    two = save_model([ModelView("front", tr, m.unifier), ModelView("side", side, m.unifier)],
                     tmp_path / "two.npz")
    m2 = StyleModel.load(two)
    assert m2.view_names == ["front", "side"] and m2.meta["views"][1]["view"] == "side"
    picked, note = m2.pick_view("side")
    assert picked.translator.n_components == 3 and note is None
    picked, note = m2.pick_view("three-quarter")
    assert picked.view == "front" and "no style model for the three-quarter view" in note
    assert m2.pick_view(None) == (m2.views[0], None)
    P = synthetic.clip_points("max", "walk", 20)
    assert not np.allclose(translate(P, "olga", m2, view="side"), translate(P, "olga", m2, view="front"))
    with pytest.raises(ValueError, match="each view once"):
        save_model([ModelView("side", tr), ModelView("side", side)], tmp_path / "dup.npz")
    _, note = m.pick_view("side")                     # a model from 2D key points
    assert "2D key points with no camera view" in note


@needs_shared
def test_styles_on_a_bvh_folder_learns_every_view_without_a_params_edit(tmp_path, capsys):
    """``nnsf styles --data FOLDER`` on motion capture: one translator per view in one file, the
    neutral style recorded; ``--neutral`` names a style of the folder or is refused in one line."""
    from nnsf.factor.style_model import StyleModel

    folder = tmp_path / "bandai"
    shutil.copytree(BN.parent / "cfg", folder / "cfg")
    (folder / "data").mkdir()
    for stem in BN_CLIPS:
        for suffix in (".bvh", ".json"):
            shutil.copy2(BN / (stem + suffix), folder / "data" / (stem + suffix))
    p = yaml.safe_load((Path(__file__).resolve().parents[1] / "params.yaml").read_text())
    p["dataset"]["bvh"]["fps"] = 10
    p["translation"].update(rank=4, max_iter=30, align_iter=10)
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(p))
    out = tmp_path / "styles.npz"
    code, stdout, err = run_cli(["styles", "--params", tmp_path / "params.yaml", "--data", folder, "--out", out,
                                 "--neutral", "angry"], capsys)
    assert code == 0, err
    assert "3 view(s)" in stdout
    model = StyleModel.load(out)
    assert model.view_names == ["front", "side", "three-quarter"]
    assert all(v.translator.neutral == "angry" and v.translator.fps_ == 10.0 for v in model.views)
    assert model.pick_view("side")[0].view == "side"
    code, _, err = run_cli(["styles", "--params", tmp_path / "params.yaml", "--data", folder, "--out",
                            tmp_path / "x.npz", "--neutral", "calm", "--views", "side"], capsys)
    assert code == 2 and err.count("\n") == 1 and "translation.neutral" in err and "calm" in err
    assert not (tmp_path / "x.npz").exists()


@needs_shared
def test_animate_says_the_view_mismatch_before_rendering(model_file, tmp_path, capsys):
    """A model learned from 2D key points and a BVH motion seen from the side: the note is on
    stderr before the first rendered frame."""
    path, _, _ = model_file
    code, _, err = run_cli(["animate", "--character", "pip", "--motion", BN / "dataset-1_bow_normal_001.bvh",
                            "--view", "side", "--style", "olga", "--model", path, "--fps", "6",
                            "--out", tmp_path / "a.gif", "--vertices", "200"], capsys)
    assert code == 0, err
    note = err.index("2D key points with no camera view")
    assert note < err.index("animate: rendered frame")
    assert err.count("no camera view") == 1


@pytest.mark.slow
def test_the_stage_model_file_has_the_same_bytes_whatever_the_hash_seed(tmp_path):
    """Two processes with different string-hash seeds write byte-identical style models.

    A dict built from a set of style names once took the set's per-process order,
    so ``models/styles.npz`` (and its hash in dvc.lock) changed from run to run.
    """
    import os
    import subprocess
    import sys

    script = (
        "import sys\n"
        "from nnsf.datasets import contract, synthetic\n"
        "from nnsf.factor.style_model import fit_model, unify_table\n"
        "raw = contract.validate(synthetic.generate(characters=4, clips_per_cell=1, frames=12, seed=0), 'syn')\n"
        "raw = raw[raw['motion'].isin(['walk', 'wave', 'jump'])].reset_index(drop=True)\n"
        "table, unifier = unify_table(raw, 0.5)\n"
        "fit_model([(None, table, unifier)], dict(n_components=4, max_iter=20, align_iter=10, random_state=0),\n"
        "          sys.argv[1])\n"
    )
    outs = []
    for seed in ("1", "2"):
        out = tmp_path / f"styles-{seed}.npz"
        env = dict(os.environ, PYTHONHASHSEED=seed)
        done = subprocess.run([sys.executable, "-c", script, str(out)], env=env, capture_output=True,
                              text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        outs.append(out.read_bytes())
    assert outs[0] == outs[1]


# --------------------------------------------------------------------------- styles -> animate on BVH, by DVC

#: Two styles x two contents of Bandai-Namco-1, the shortest clips (70-123 frames at 30 fps).
BN_CLIPS = [f"dataset-1_{content}_{style}_001" for content in ("bow", "bye") for style in ("angry", "childish")]


@pytest.mark.slow  # runs `dvc exp run`, its stages as processes, against the session's Prefect server
@needs_shared
def test_styles_then_animate_on_a_bvh_folder_through_dvc_exp_run(tmp_path, make_project):
    """``dvc exp run -S dataset.name=bvh -S dataset.path=motions/bandai … styles animate`` in a
    tiny copy of the project: the style model learns the folder's two styles, and animate
    re-performs one of its clips in the other style."""
    import re
    import subprocess
    import sys

    from conftest import git, run
    from test_pipeline import SMALL_PARAMS

    from nnsf.factor.style_model import StyleModel

    root, env = make_project()
    folder = root / "motions" / "bandai"
    shutil.copytree(BN.parent / "cfg", folder / "cfg")
    (folder / "data").mkdir()
    for stem in BN_CLIPS:
        for suffix in (".bvh", ".json"):
            shutil.copy2(BN / (stem + suffix), folder / "data" / (stem + suffix))
    params = yaml.safe_load(SMALL_PARAMS)
    params["dataset"]["bvh"]["fps"] = 15                   # half the frames: seconds, not minutes
    params["animate"].update(max_frames=6, fps=15)
    (root / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    git(root, "add", "-A")
    git(root, "commit", "-q", "-m", "tiny params, four Bandai-Namco clips")

    motion = "motions/bandai/data/dataset-1_bye_angry_001.bvh"
    done = run([sys.executable, "-m", "dvc", "exp", "run", "-S", "dataset.name=bvh",
                "-S", "dataset.path=motions/bandai", "-S", f"animate.motion={motion}",
                "-S", "animate.style=childish", "styles", "animate"], root, env, timeout=1200)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    ran = set(re.findall(r"Running stage '([^']+)'", done.stdout))
    assert ran == {"data", "features", "styles", "animate"}, ran   # nothing else of the pipeline

    model = StyleModel.load(root / "models" / "styles.npz")
    assert sorted(model.translator.styles_) == ["angry", "childish"]
    assert sorted(model.translator.contents_) == ["bow", "bye"]
    out = root / "reports" / "animate"
    made = json.loads((out / "animate.json").read_text())
    assert made["style"] == "childish" and made["frames"] == 6 and made["view"] in ("front", "side",
                                                                                     "three-quarter")
    assert made["motion"].startswith("dataset-1_bye_angry_001")
    assert sorted(made["files"]) == ["animation.gif", "animation.mp4", "animation_sheet.png"]
    video = cv2.VideoCapture(str(out / "animation.mp4"))
    frames = 0
    while video.read()[0]:
        frames += 1
    assert frames == 6
    sheet = cv2.imread(str(out / "animation_sheet.png"), cv2.IMREAD_UNCHANGED)
    assert sheet is not None and sheet.shape[0] > 64 and sheet.std() > 5   # a drawing, not a blank
    # The experiment is recorded with its parameters.
    shown = subprocess.run([sys.executable, "-m", "dvc", "exp", "show", "--json"], cwd=root, env=env,
                           capture_output=True, text=True, timeout=300)
    assert shown.returncode == 0 and '"bvh"' in shown.stdout and "motions/bandai" in shown.stdout


def test_a_figure_with_both_knees_bent_one_way_gets_a_hint_to_say_its_facing():
    """Both knees drawn bent one way, each by a tenth of its shin or more: the figure may be turned that
    way (``animate`` then suggests ``facing``).  One bent knee, knees bent apart or straight legs: no hint."""
    from nnsf.animate.animation import turned_way
    from nnsf.reshape.character import Character
    from nnsf.skeleton import rest_pose

    kp = (rest_pose() - rest_pose().min(axis=0)) * 100 + 20
    H, W = int(kp[:, 1].max()) + 20, int(kp[:, 0].max()) + 20
    tex = np.full((H, W, 4), 255, np.uint8)

    def bent(left: float, right: float) -> Character:
        k = kp.copy()
        for side, by in (("l", left), ("r", right)):
            shin = np.linalg.norm(k[JOINT_INDEX[f"{side}_ankle"]] - k[JOINT_INDEX[f"{side}_knee"]])
            k[JOINT_INDEX[f"{side}_knee"], 0] += by * shin
        return Character("bent", tex, np.ones((H, W), bool), k)

    assert turned_way(bent(-0.3, -0.15)) == "left" and turned_way(bent(0.2, 0.12)) == "right"
    for left, right in ((-0.3, 0.0), (-0.3, 0.05), (-0.2, 0.2), (0.0, 0.0)):
        assert turned_way(bent(left, right)) is None, (left, right)
    ch = bent(-0.3, -0.3)
    ch.body = "quadruped"
    assert turned_way(ch) is None
