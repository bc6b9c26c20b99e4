"""The independent judges, the mean-pose-offset baseline and the smoothness of syntheses:
judges never see the hidden cell, ``offset`` matches a hand computation, and a
consensus synthesis is no jerkier than the real clips of its target style."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from nnsf.datasets import contract
from nnsf.datasets.synthetic import generate
from nnsf.evaluate.judges import FAMILIES, Judges, angle_statistics, pose_statistics
from nnsf.evaluate.cell_baselines import BASELINES, CellData, style_offset
from nnsf.evaluate.scores import jerk
from nnsf.evaluate.translation import JUDGE_COLUMNS, evaluate_cell
from nnsf.factor.translate import StyleTranslator
from nnsf.skeleton import Unifier, to_points

CHARS = ["bruno", "pip", "olga", "gus"]
MOTIONS = ["walk", "jump", "wave", "bow"]


@pytest.fixture(scope="module")
def pixels():
    return generate(characters=CHARS, clips_per_cell=2, frames=16, noise_px=0.3, seed=0, motions=MOTIONS)


# --------------------------------------------------------------------- judges
def test_statistics_shapes_and_what_they_ignore():
    rng = np.random.default_rng(0)
    P = rng.normal(size=(12, 17, 2))
    f = pose_statistics(P)
    assert f.shape == (96,)
    # root-relative: moving the whole figure changes nothing
    np.testing.assert_allclose(pose_statistics(P + np.array([3.0, -2.0])), f, atol=1e-12)
    a = angle_statistics(P)
    assert a.shape == (64,)
    # bone directions: a uniform scale changes nothing
    np.testing.assert_allclose(angle_statistics(2.5 * P), a, atol=1e-12)
    with pytest.raises(ValueError, match="key points"):
        pose_statistics(np.zeros((5, 16, 2)))


def test_judges_recognise_real_clips_of_a_clear_grid(pixels):
    P = to_points(contract.features(pixels))
    clips = pixels["clip"].to_numpy()
    names = sorted(set(clips))
    seqs = [P[clips == q] for q in names]
    st = [pixels.loc[clips == q, "character"].iloc[0] for q in names]
    co = [pixels.loc[clips == q, "motion"].iloc[0] for q in names]
    j = Judges().fit(seqs[::2], st[::2], co[::2])
    score = j.score(seqs[1::2], st[1::2], co[1::2])
    assert set(score) == set(FAMILIES) | {"all"}
    for fam in FAMILIES:
        assert score[fam][1].mean() >= 0.75, fam       # synthetic contents are easy to tell apart
    np.testing.assert_array_equal(score["all"][0], np.min([score[f][0] for f in FAMILIES], axis=0))


def test_the_judges_never_see_the_hidden_cell(pixels):
    """Replacing the hidden cell's clips by anything leaves every judge's verdict on every
    synthesis unchanged (only the errors against the hidden clips move)."""
    methods = ("nnsf", "offset", "identity")
    kw = dict(methods=methods, translator_params={"n_components": 6, "max_iter": 30, "align_iter": 10},
              max_sources=2)
    a = evaluate_cell(pixels, "olga", "wave", **kw)
    other = pixels.copy()
    hidden = (other["character"] == "olga") & (other["motion"] == "wave")
    cols = list(contract.COLUMNS[4:])
    rng = np.random.default_rng(3)
    # a wildly different "performance": another content's frames, shifted and shaken
    walk = pixels[(pixels["character"] == "olga") & (pixels["motion"] == "walk")][cols].to_numpy()
    other.loc[hidden, cols] = walk[: hidden.sum()] + rng.normal(0, 4.0, (hidden.sum(), 34)) + 7
    b = evaluate_cell(other, "olga", "wave", **kw)
    same = [*JUDGE_COLUMNS, "jerk_ratio", "style_acc", "content_acc"]
    pd.testing.assert_frame_equal(a[same], b[same])
    assert not np.allclose(a["dtw_error"], b["dtw_error"])
    # No training clip is of the hidden cell, so one nearest neighbour can name its style or its
    # content, never both: a leak of the cell into the judges would break this bound.
    assert ((a["style_nn1"] + a["content_nn1"]) <= 1 + 1e-12).all()


# --------------------------------------------------------------- the offset baseline
def test_offset_matches_a_hand_computation_on_a_tiny_grid():
    """Styles normal/a, contents c1..c3; every clip a constant pose.  Offset a<-normal is the mean
    over the shared contents other than the cell's of mean(a, c) − mean(normal, c)."""
    d = 34
    pose = {("normal", "c1"): 1.0, ("normal", "c2"): 2.0, ("normal", "c3"): 3.0,
            ("a", "c2"): 2.5, ("a", "c3"): 5.0}
    # (a, c1) is the hidden cell: absent.  Two clips of (a, c3) with different lengths.
    clips = [(s, c, np.full((4, d), v)) for (s, c), v in pose.items()]
    clips.append(("a", "c3", np.full((7, d), 6.0)))
    X = np.concatenate([x for *_, x in clips])
    starts = np.cumsum([0] + [len(x) for *_, x in clips])
    rows = [np.arange(starts[i], starts[i + 1]) for i in range(len(clips))]
    cell = CellData(X=X, clip_rows=rows, clip_style=np.array([s for s, *_ in clips]),
                    clip_content=np.array([c for _, c, _ in clips]), style="a", content="c1")
    # by hand: c2: 2.5 − 2 = 0.5; c3: mean(5, 6) − 3 = 2.5; mean = 1.5
    np.testing.assert_allclose(style_offset(cell, "normal", "a"), np.full(d, 1.5))
    np.testing.assert_allclose(style_offset(cell, "a", "normal"), np.full(d, -1.5))
    src = np.arange(3 * d, dtype=float).reshape(3, d)
    np.testing.assert_allclose(BASELINES["offset"](cell)(src, "normal"), src + 1.5)
    # the cell's own content never enters: a content-c1 clip of style a would be the hidden one
    cell2 = CellData(X=X, clip_rows=rows, clip_style=cell.clip_style, clip_content=cell.clip_content,
                     style="a", content="c2")
    np.testing.assert_allclose(style_offset(cell2, "normal", "a"), np.full(d, 2.5))


def test_offset_in_evaluate_cell_is_the_source_plus_the_hand_offset(pixels):
    out, ex = evaluate_cell(pixels, "pip", "jump", methods=("offset",), max_sources=1, return_examples=True)
    hidden = (pixels["character"] == "pip") & (pixels["motion"] == "jump")
    train = pixels[~hidden].reset_index(drop=True)
    P = to_points(contract.features(train))
    u = Unifier(margin=0.5).fit(P, train["character"].to_numpy())
    X = pd.DataFrame(u.transform(P, train["character"].to_numpy()))
    X["clip"], X["s"], X["c"] = train["clip"], train["character"], train["motion"]
    src = ex["offset"]["source"]
    s_src = X.loc[X["clip"] == src, "s"].iloc[0]
    shared = sorted((set(X.loc[X["s"] == "pip", "c"]) & set(X.loc[X["s"] == s_src, "c"])) - {"jump"})
    means = X.groupby(["clip", "s", "c"]).mean(numeric_only=True).reset_index()
    m = lambda s, c: means[(means["s"] == s) & (means["c"] == c)].iloc[:, 3:].to_numpy().mean(0)  # noqa: E731
    off = np.mean([m("pip", c) - m(s_src, c) for c in shared], axis=0)
    want = X.loc[X["clip"] == src].iloc[:, :34].to_numpy() + off
    np.testing.assert_allclose(ex["offset"]["synth"], want, atol=1e-10)


# --------------------------------------------------------------- smoothness
def test_a_consensus_synthesis_is_no_jerkier_than_real_clips_of_its_style(pixels):
    """Mean |second difference| of the key points of X̂ = V_c U_s + b_s within 1.5× of the real
    clips of the target style, for every cell, with the pipeline's defaults."""
    P = to_points(contract.features(pixels))
    ch = pixels["character"].to_numpy()
    mo = pixels["motion"].to_numpy()
    cl = pixels["clip"].to_numpy()
    X = Unifier(margin=0.5).fit(P, ch).transform(P, ch)
    tr = StyleTranslator(n_components=8, max_iter=60, align_iter=40).fit(X, mo, ch, cl)
    for s in CHARS:
        real = np.mean([jerk(X[cl == q]) for q in np.unique(cl[ch == s])])
        for c in MOTIONS:
            assert jerk(tr.synthesize(c, s)) <= 1.5 * real, (s, c)


# ------------------------------------------------------- independence of the judges
@pytest.mark.slow
def test_judges_module_imports_nothing_of_the_project():
    """judges.py imports numpy and scikit-learn only: not the skeleton unifier, not the
    translation or its evaluation (checked in its source and in a fresh interpreter)."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    import nnsf.evaluate.judges as jm

    tree = ast.parse(Path(jm.__file__).read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom):
            imported.add(node.module)
    assert {m.split(".")[0] for m in imported} <= {"__future__", "numpy", "sklearn"}, imported
    code = ("import sys, nnsf.evaluate.judges; "
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] == 'nnsf')))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert loaded == ["nnsf", "nnsf.evaluate", "nnsf.evaluate.judges"], loaded


def test_the_judges_skeleton_is_the_data_contracts():
    from nnsf.evaluate.judges import PARENTS as judged
    from nnsf.skeleton.layout import PARENTS

    assert judged == PARENTS


def test_judges_normalise_position_and_size_themselves(pixels):
    """A clip shifted and scaled (another camera, another unit) gets the same verdicts."""
    P = to_points(contract.features(pixels))
    clips = pixels["clip"].to_numpy()
    names = sorted(set(clips))
    seqs = [P[clips == q] for q in names]
    st = [pixels.loc[clips == q, "character"].iloc[0] for q in names]
    co = [pixels.loc[clips == q, "motion"].iloc[0] for q in names]
    j = Judges().fit(seqs[::2], st[::2], co[::2])
    moved = [3.7 * Q + np.array([120.0, -45.0]) for Q in seqs[1::2]]
    a, b = j.predict(seqs[1::2]), j.predict(moved)
    for fam in FAMILIES:
        np.testing.assert_array_equal(a[fam][0], b[fam][0])
        np.testing.assert_array_equal(a[fam][1], b[fam][1])
    np.testing.assert_allclose(pose_statistics(moved[0]), pose_statistics(seqs[1]), atol=1e-12)


def test_judges_get_the_raw_clips_and_the_target_characters_pixels(pixels, monkeypatch):
    """In evaluate_cell the judges are fitted on the remaining clips exactly as read (pixels, no
    clip of the hidden cell), and judge each synthesis mapped to the target character's pixels
    (the inverse of the cell's unification) and the hidden clip as read."""
    import nnsf.evaluate.translation as ev

    seen = {}

    class Spy(Judges):
        def fit(self, clips, style, content):
            seen["fit"] = (list(clips), list(style), list(content))
            return super().fit(clips, style, content)

        def score(self, clips, style, content):
            seen["score"] = list(clips)
            return super().score(clips, style, content)

    monkeypatch.setattr(ev, "Judges", Spy)
    out, ex = evaluate_cell(pixels, "olga", "wave", methods=("offset", "identity", "real"), max_sources=1,
                            return_examples=True)
    cols = list(contract.COLUMNS[4:])
    hidden = (pixels["character"] == "olga") & (pixels["motion"] == "wave")
    raw = {q: pixels.loc[pixels["clip"] == q, cols].to_numpy().reshape(-1, 17, 2)
           for q in pixels["clip"].unique()}
    fit_clips, fit_style, fit_content = seen["fit"]
    train_names = sorted(pixels.loc[~hidden, "clip"].unique())
    assert len(fit_clips) == len(train_names)
    for P, q in zip(fit_clips, train_names):
        np.testing.assert_array_equal(P, raw[q])                 # as read, bit for bit
    assert not any(s == "olga" and c == "wave" for s, c in zip(fit_style, fit_content))
    # scored: offset, identity (one source) then the hidden clip as read
    train = pixels[~hidden].reset_index(drop=True)
    u = Unifier(margin=0.5).fit(to_points(contract.features(train)), train["character"].to_numpy())
    np.testing.assert_allclose(seen["score"][0], u.inverse_transform(ex["offset"]["synth"], "olga"), atol=1e-9)
    np.testing.assert_allclose(seen["score"][1], u.inverse_transform(ex["identity"]["synth"], "olga"), atol=1e-9)
    hidden_names = sorted(pixels.loc[hidden, "clip"].unique())
    for P, q in zip(seen["score"][2:], hidden_names):
        np.testing.assert_array_equal(P, raw[q])


def test_the_api_method_is_exactly_nnsf_translate(pixels, monkeypatch):
    """``api`` judges what nnsf.translate() returns for the source clip as read, with a model
    fitted on the cell's remaining clips (the cell's unifier, the default translator);
    ``api_source`` the same call told the source clip's style."""
    import nnsf.evaluate.translation as ev
    from nnsf import translate
    from nnsf.factor.style_model import StyleModel

    seen = {}

    class Spy(Judges):
        def score(self, clips, style, content):
            seen["score"] = list(clips)
            return super().score(clips, style, content)

    monkeypatch.setattr(ev, "Judges", Spy)
    tp = {"n_components": 6, "max_iter": 30, "align_iter": 10}
    out, ex = evaluate_cell(pixels, "olga", "wave", methods=("api", "api_source"), translator_params=tp,
                            max_sources=1, return_examples=True)
    hidden = (pixels["character"] == "olga") & (pixels["motion"] == "wave")
    train = pixels[~hidden].reset_index(drop=True)
    P = to_points(contract.features(train))
    ch, mo, cl = (train[k].astype(str).to_numpy() for k in ("character", "motion", "clip"))
    u = Unifier(margin=0.5).fit(P, ch)
    tr = StyleTranslator(**tp, random_state=0).fit(u.transform(P, ch), mo, ch, cl)
    src = ex["api"]["source"]
    want = translate(P[cl == src], "olga", StyleModel(tr, u))
    np.testing.assert_array_equal(seen["score"][0], want)
    s_src = ch[cl == src][0]
    told = translate(P[cl == src], "olga", StyleModel(tr, u), source_style=s_src)
    np.testing.assert_array_equal(seen["score"][1], told)
    assert not np.allclose(told, want)
    assert np.isfinite(out["dtw_error"]).all()


BANDAI = Path(__file__).resolve().parents[2] / "shared" / "data" / "bandai-namco-1"


@pytest.mark.skipif(not BANDAI.is_dir(), reason=f"Bandai-Namco-1 data not found at {BANDAI}")
def test_held_out_syntheses_on_real_motion_are_no_jerkier_than_the_styles_real_clips():
    """On a small Bandai-Namco-1 subset (6 styles x 5 contents, read with params.yaml's BVH
    settings), the default translation of four held-out cells, spread over the grid, has a mean
    jerk ratio (mean |second difference| over that of the target style's real training clips)
    of at most 1.5."""
    from nnsf.datasets.bvh_source import read_folder
    from nnsf.evaluate.translation import _pick, grid_cells
    from nnsf.params import load

    bvh = load(Path(__file__).resolve().parents[1] / "params.yaml")["dataset"]["bvh"]
    table, _ = read_folder(BANDAI, fps=bvh["fps"], azimuth=bvh["azimuth"], elevation=bvh["elevation"],
                           facing=bvh["facing"], center=bvh["center"])
    styles = ["normal", "active", "tired", "old", "proud", "sad"]
    contents = ["walk", "run", "bow", "byebye", "dash"]
    table = table[table["character"].isin(styles) & table["motion"].isin(contents)].reset_index(drop=True)
    ratios = [evaluate_cell(table, s, c, methods=("nnsf",))["jerk_ratio"].iloc[0]
              for s, c in _pick(grid_cells(table), 4)]
    assert np.mean(ratios) <= 1.5, ratios
