"""Style translation (docs/method.md §8, D5) and its held-out evaluation (docs/method.md §15.5)."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from nnsf.datasets.synthetic import generate
from nnsf.errors import InputError
from nnsf.evaluate.scores import SyntheticTruth, clip_features
from nnsf.evaluate.translation import evaluate_cell, grid_cells, leave_one_cell_out, summarise
from scipy.optimize import linear_sum_assignment

from nnsf.factor.align import atom_cosines, refit_basis
from nnsf.factor.timewarp import dtw_accumulate, dtw_align, dtw_path, joint_distance_matrix
from nnsf.factor.translate import StyleTranslator, to_character_points
from nnsf.stick import write_stick_gif
from nnsf.skeleton import Unifier, to_points

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
BANDAI = DATA / "bandai-namco-1"

SYN_CHARS = ["bruno", "pip", "olga", "gus"]
SYN_MOTIONS = ["walk", "jump", "wave", "bow", "squat"]


@pytest.fixture(scope="module")
def synthetic():
    """A small synthetic set: 4 characters × 5 motions × 2 clips × 24 frames, pixels."""
    return generate(characters=SYN_CHARS, clips_per_cell=2, frames=24, noise_px=0.3, seed=0,
                    motions=SYN_MOTIONS)


@pytest.fixture(scope="module")
def unified(synthetic):
    P = to_points(synthetic.loc[:, "x1":].to_numpy(float))
    ch = synthetic["character"].to_numpy()
    X = Unifier().fit(P, ch).transform(P, ch)
    return X, synthetic["motion"].to_numpy(), ch, synthetic["clip"].to_numpy()


@pytest.fixture(scope="module")
def translator(unified):
    X, mo, ch, cl = unified
    return StyleTranslator(n_components=10, max_iter=80, align_iter=40).fit(X, mo, ch, cl)


# --------------------------------------------------------------------------- DTW
def _dtw_brute(C):
    n, m = C.shape
    D = np.full((n + 1, m + 1), np.inf)
    D[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            D[i, j] = C[i - 1, j - 1] + min(D[i - 1, j - 1], D[i - 1, j], D[i, j - 1])
    return D[1:, 1:]


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (6, 1), (9, 13), (20, 8)])
def test_dtw_accumulate_equals_the_textbook_recursion(shape):
    C = np.random.default_rng(sum(shape)).random(shape)
    np.testing.assert_allclose(dtw_accumulate(C), _dtw_brute(C), rtol=1e-12, atol=1e-12)
    # A batch gives the same as one at a time.
    batch = np.stack([C, 2 * C, C[::-1]])
    for got, want in zip(dtw_accumulate(batch), batch):
        np.testing.assert_allclose(got, _dtw_brute(want), rtol=1e-12, atol=1e-12)


def test_dtw_path_is_monotone_and_sums_to_the_distance():
    C = np.random.default_rng(5).random((15, 11))
    D = dtw_accumulate(C)
    p = dtw_path(D)
    assert tuple(p[0]) == (0, 0) and tuple(p[-1]) == (14, 10)
    steps = np.diff(p, axis=0)
    assert set(map(tuple, steps)) <= {(1, 1), (1, 0), (0, 1)}
    assert C[p[:, 0], p[:, 1]].sum() == pytest.approx(D[-1, -1], rel=1e-12)


def test_time_warped_copy_has_zero_dtw_error():
    rng = np.random.default_rng(0)
    B = rng.random((30, 34)) * 3
    # Repeat some frames (a slower passage), drop none: a pure time warp.
    warp = np.sort(np.concatenate([np.arange(30), rng.integers(0, 30, 12)]))
    err, path = dtw_align(B[warp], B)
    assert err == 0.0
    np.testing.assert_array_equal(warp[path[:, 0]], path[:, 1])
    # And an analytic case: a constant offset of every joint by (3, 4) costs 5.
    err, _ = dtw_align(B + np.tile([3.0, 4.0], 17), B)
    assert err == pytest.approx(5.0, abs=1e-12)


def test_joint_distance_matrix_is_mean_per_joint_euclidean():
    rng = np.random.default_rng(1)
    A, B = rng.random((4, 34)), rng.random((6, 34))
    want = np.linalg.norm(to_points(A)[:, None] - to_points(B)[None], axis=-1).mean(-1)
    np.testing.assert_allclose(joint_distance_matrix(A, B), want, rtol=1e-12)


# ---------------------------------------------------------------- atoms
def test_refit_from_u0_keeps_atom_meaning(unified):
    """Per-character bases refitted from U₀ with V fixed stay close to U₀, atom by atom."""
    X, mo, ch, cl = unified
    t = StyleTranslator(n_components=10, basis="refit", ridge=0.0, max_iter=80).fit(X, mo, ch, cl)
    U0 = t.components_
    for s, U in t.style_bases_.items():
        C = atom_cosines(U0, U)
        assert np.all(np.diag(C) > 0.9), (s, np.diag(C).min())
        # Each refitted atom is still nearest its own U₀ atom: the best matching keeps the order.
        _, perm = linear_sum_assignment(-C)
        np.testing.assert_array_equal(perm, np.arange(U0.shape[0]))
        np.testing.assert_allclose(np.linalg.norm(U, axis=1), 1.0, rtol=1e-10)
        assert U.min() >= 0


def test_refit_basis_lowers_the_fit_and_ridge_pulls_to_u0():
    rng = np.random.default_rng(3)
    U_true = rng.random((5, 34))
    U_true /= np.linalg.norm(U_true, axis=1, keepdims=True)
    V = rng.random((400, 5))
    X = V @ U_true
    U0 = U_true + 0.3 * rng.random((5, 34))
    U0 /= np.linalg.norm(U0, axis=1, keepdims=True)
    U = refit_basis(X, V, U0, max_iter=500, tol=0)
    assert np.linalg.norm(X - V @ U) < 0.05 * np.linalg.norm(X - V @ U0)
    stiff = refit_basis(X, V, U0, max_iter=500, tol=0, ridge=100.0)
    assert np.linalg.norm(stiff - U0) < 0.2 * np.linalg.norm(U - U0)


# ------------------------------------------------------------ translation
def test_same_style_translation_is_the_source_reconstruction(unified, translator):
    X, mo, ch, cl = unified
    clip = cl[0]
    Xc, s = X[cl == clip], ch[cl == clip][0]
    # With the residual kept, translating to one's own style changes nothing.
    np.testing.assert_allclose(translator.translate(Xc, s, s), Xc, atol=1e-10)
    # The style's reconstruction of the clip follows the motion: closer than the clip's mean pose.
    recon = translator.encode(Xc, s) @ translator.style_bases_[s] + translator.style_offsets_[s]
    assert np.linalg.norm(recon - Xc) < np.linalg.norm(Xc - Xc.mean(axis=0))


def test_translation_shapes_readings_and_pixels(unified, translator):
    from nnsf.evaluate.nnsf_variants import style_clip, swapped_translation

    X, mo, ch, cl = unified
    src = X[cl == "pip-wave-00"]
    out = translator.translate(src, "pip", "olga")
    assert out.shape == src.shape and np.isfinite(out).all()
    cons = translator.synthesize("wave", "olga")
    assert cons.shape[1] == 34
    swapped = swapped_translation(translator, src, "olga", "wave")
    # The paper's example read literally: frames and timing come from a clip of the target style.
    assert swapped.shape == style_clip(translator, "olga", "wave", src).shape
    unifier = Unifier().fit(to_points(X), ch)      # any fitted unifier maps features back
    pts = to_character_points(out, "olga", unifier)
    assert pts.shape == (len(src), 17, 2)


def test_translator_rejects_bad_input(unified, translator):
    X, mo, ch, cl = unified
    src = X[cl == "pip-wave-00"]
    with pytest.raises(ValueError, match="unknown target style"):
        translator.translate(src, "pip", "nobody")
    with pytest.raises(ValueError, match="unknown source style"):
        translator.translate(src, "nobody", "pip")
    with pytest.raises(ValueError, match="unknown content"):
        translator.synthesize("moonwalk", "pip")
    with pytest.raises(ValueError, match="features"):
        translator.translate(src[:, :20], "pip", "olga")
    with pytest.raises(ValueError, match="basis"):
        StyleTranslator(basis="separate").fit(X, mo, ch, cl)
    with pytest.raises(ValueError, match="two styles"):
        StyleTranslator().fit(X[ch == "pip"], mo[ch == "pip"], ch[ch == "pip"])


# ------------------------------------------------------------ evaluation
def test_nnsf_beats_no_translation_against_the_exact_truth(synthetic):
    """On the synthetic set the true translated motion is known: NNSF must get closer."""
    rows = []
    for s, c in [("olga", "walk"), ("gus", "squat"), ("pip", "bow")]:
        rows.append(evaluate_cell(synthetic, s, c, methods=("nnsf", "identity"),
                                  translator_params={"n_components": 10, "max_iter": 80,
                                                     "align_iter": 40},
                                  truth=SyntheticTruth(seed=0)))
    table = summarise(pd.concat(rows))
    err = table.set_index("method")["truth_error"]
    assert err["nnsf"] < err["identity"], table


def test_evaluate_cell_rows_and_ranges(synthetic):
    out, ex = evaluate_cell(synthetic, "olga", "wave",
                            methods=("nnsf", "bilinear", "bilinear_template", "identity", "real"),
                            translator_params={"n_components": 8, "max_iter": 50, "align_iter": 20},
                            max_sources=2, return_examples=True)
    assert list(out["method"]) == ["nnsf", "bilinear", "bilinear_template", "identity", "real"]
    assert out["n_sources"].iloc[0] == 2 and out["n_hidden"].iloc[0] == 2
    assert out.loc[out.method == "real", "dtw_error"].item() == 0.0
    assert ((out[["style_acc", "content_acc"]] >= 0) & (out[["style_acc", "content_acc"]] <= 1)).all().all()
    assert (out.loc[out.method != "real", "dtw_error"] > 0).all()
    assert set(ex) == {"nnsf", "bilinear", "bilinear_template", "identity"}
    assert ex["nnsf"]["synth"].shape[1] == 34


def test_evaluate_cell_rejects_bad_cells(synthetic):
    with pytest.raises(InputError, match="styles"):
        evaluate_cell(synthetic, "nobody", "walk")
    with pytest.raises(InputError, match="contents"):
        evaluate_cell(synthetic, "olga", "moonwalk")
    # A content only the hidden style performs has no source clip.
    lonely = synthetic[~((synthetic.motion == "jump") & (synthetic.character != "olga"))]
    with pytest.raises(InputError, match="other than 'olga'"):
        evaluate_cell(lonely, "olga", "jump")
    # A style with one content only cannot be learned.
    single = synthetic[~((synthetic.character == "gus") & (synthetic.motion != "walk"))]
    with pytest.raises(InputError, match="to learn the style from"):
        evaluate_cell(single, "gus", "walk")
    with pytest.raises(ValueError, match="unknown method"):
        evaluate_cell(synthetic, "olga", "walk", methods=("nnsf", "magic"))
    assert ("gus", "walk") not in grid_cells(single)
    with pytest.raises(InputError, match="cells"):
        leave_one_cell_out(synthetic[synthetic.character == "gus"])


def test_clip_features_see_the_direction_of_circling():
    t = np.linspace(0, 2 * np.pi, 40, endpoint=False)
    X = np.full((40, 34), 2.0)
    X[:, 6], X[:, 7] = 2 + np.cos(t), 2 + np.sin(t)          # r_ankle circles
    f, b = clip_features(X), clip_features(X[::-1])
    assert f.shape == (119,)
    np.testing.assert_allclose(f[:102], b[:102], atol=1e-12)   # same poses, same speed
    assert f[102 + 3] > 0 > b[102 + 3]                          # opposite circling


# ---------------------------------------------------------------- GIF
def test_stick_gif_is_written_atomically(tmp_path, unified):
    X, mo, ch, cl = unified
    a, b = X[cl == "pip-wave-00"], X[cl == "olga-wave-00"][:10]
    path = write_stick_gif(tmp_path / "clip.gif", [a, b], titles=["pip", "olga"], fps=12)
    with Image.open(path) as im:
        assert im.n_frames == len(a)
        assert im.size[0] > im.size[1]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.gif"]
    with pytest.raises(ValueError, match="17, 2"):
        write_stick_gif(tmp_path / "bad.gif", [np.zeros((3, 5))])
    assert not (tmp_path / "bad.gif").exists()


# ------------------------------------------------------------- real data
@pytest.mark.skipif(not BANDAI.is_dir(), reason=f"Bandai-Namco data not found at {BANDAI}")
def test_one_bandai_cell_runs_end_to_end():
    from nnsf.datasets.bvh_source import read_folder

    table, _ = read_folder(BANDAI, fps=10)
    out = evaluate_cell(table, "old", "walk-left", methods=("nnsf", "identity", "real"),
                        translator_params={"max_iter": 60, "align_iter": 40}, max_sources=4)
    assert np.isfinite(out.loc[out.method != "real", "dtw_error"]).all()
    assert out["n_hidden"].iloc[0] == 1


# ------------------------------------------------------ consensus synthesis
def test_resample_clip_is_linear_interpolation():
    from nnsf.factor.timewarp import resample_clip

    X = np.outer(np.arange(10.0), np.ones(34)) + np.arange(34.0)
    Y = resample_clip(X, 19)                       # half steps of a linear ramp
    np.testing.assert_allclose(Y[:, 0], np.arange(19) / 2.0, atol=1e-12)
    np.testing.assert_allclose(Y[[0, -1]], X[[0, -1]])
    np.testing.assert_array_equal(resample_clip(X, 10), X)


def test_style_tempo_is_the_median_length_ratio():
    from nnsf.factor.timewarp import _style_tempo

    z = lambda n: np.zeros((n, 34))                # noqa: E731
    clips = {("a", "walk"): [z(10)], ("b", "walk"): [z(30)], ("a", "jump"): [z(20)],
             ("b", "jump"): [z(20)], ("c", "solo"): [z(7)]}
    t = _style_tempo(clips)
    # walk: mean 20 -> a 0.5, b 1.5; jump: mean 20 -> 1.0 each; solo is one style's only.
    assert t == {"a": 0.75, "b": 1.25, "c": 1.0}


def test_restored_amplitude_matches_the_real_clips_on_average(unified, translator):
    """amplitude='restore' makes the mean spread over the content's styles that of the real clips."""
    X, mo, ch, cl = unified
    translator.set_params(tempo=False, amplitude="restore")
    try:
        styles = [s for (s, c) in translator.clips_ if c == "wave"]
        synth = [translator.synthesize("wave", s) for s in styles]
    finally:
        translator.set_params(tempo=True)
    real = [Xq for (s, c), lst in translator.clips_.items() if c == "wave" for Xq in lst]
    assert all(Y.min() > 0 for Y in synth)         # no clipping, so the identity is exact
    np.testing.assert_allclose(np.mean([Y.std(0) for Y in synth], 0),
                               np.mean([Xq.std(0) for Xq in real], 0), rtol=1e-9)
    # Without it the compromise moves less than the real clips.
    translator.set_params(tempo=False, amplitude="none")
    try:
        plain = np.mean([translator.synthesize("wave", s).std(0) for s in styles], 0)
    finally:
        translator.set_params(tempo=True, amplitude="restore")
    assert plain.sum() < np.mean([Xq.std(0) for Xq in real], 0).sum()


# ------------------------------------------------------ temporal smoothness, public path
def test_second_difference_split_is_the_acceleration_penalty_along_each_chain():
    from nnsf.factor.timewarp import second_difference_split

    rng = np.random.default_rng(0)
    chains, R = [(0, 5), (5, 12), (12, 14)], 14            # the last chain is too short to bend
    W = rng.random((R, 3))
    Lpos, Lneg = second_difference_split(chains, R)
    assert Lpos.min() >= 0 and Lneg.min() >= 0
    by_hand = sum(float(np.sum((W[a:b - 2] - 2 * W[a + 1:b - 1] + W[a + 2:b]) ** 2)) for a, b in chains
                  if b - a >= 3)
    L = (Lpos - Lneg).toarray()
    assert np.trace(W.T @ L @ W) == pytest.approx(by_hand, rel=1e-12)
    # no coupling across chains: rows 4 and 5 (and 3 and 5) are in different chains
    assert L[4, 5] == 0 and L[3, 5] == 0 and L[5, 4] == 0
    # straight lines cost nothing
    line = np.outer(np.arange(R, dtype=float), [1.0, 2.0])
    assert np.allclose(L @ line, 0.0)


def test_smoothed_encoding_removes_jitter_and_zero_is_the_per_frame_encoding(unified, translator):
    from nnsf.factor.updates import weights_for_basis

    X, mo, ch, cl = unified
    Xq = X[cl == cl[0]]
    rng = np.random.default_rng(1)
    noisy = np.maximum(Xq + rng.normal(0, 0.02, Xq.shape), 0.0)
    U = translator.components_
    plain = weights_for_basis(noisy, U, alpha=translator.alpha, max_iter=translator.max_iter, tol=translator.tol)
    acc = lambda V: float(np.abs(np.diff(V, n=2, axis=0)).mean())  # noqa: E731
    t = StyleTranslator(**{**translator.get_params(), "smooth": 20.0})
    assert acc(t.encode_smooth(noisy, U)) < 0.7 * acc(plain)
    t0 = StyleTranslator(**{**translator.get_params(), "smooth": 0.0})
    np.testing.assert_array_equal(t0.encode_smooth(noisy, U), plain)


def test_translate_clip_keeps_the_clips_frames(unified, translator):
    X, mo, ch, cl = unified
    Xq = X[cl == cl[0]]
    for transfer in ("recombine_swing", "offset_swing", "recombine"):
        translator.set_params(transfer=transfer)
        for s in translator.styles_:
            assert translator.translate_clip(Xq, s).shape == Xq.shape
    translator.set_params(transfer="recombine_swing")


def test_constructor_defaults_equal_the_pipelines_params():
    """A bare StyleTranslator() is the translator the pipeline configures (params.yaml)."""
    from nnsf.factor.style_model import translator_params
    from nnsf.params import load

    root = Path(__file__).resolve().parents[1]
    want = translator_params(load(root / "params.yaml"))
    have = StyleTranslator().get_params()
    assert {k: have[k] for k in want} == want


def _doubled_swing(X, clips):
    """``X`` with every coordinate's deviation from its clip mean doubled (clip by clip)."""
    out = np.empty_like(X)
    for q in np.unique(clips):
        r = clips == q
        m = X[r].mean(axis=0)
        out[r] = m + 2.0 * (X[r] - m)
    return out


def test_style_amplitude_carries_a_wider_swinging_style_to_an_unseen_content(unified):
    """Style "wide" is style "base" with every coordinate's deviation from its clip mean doubled.
    With (wide, jump) hidden, amplitude="style" learns from the other contents that "wide" swings
    wider than its restored renderings (h > 1, and h < 1 for "base") and so comes closer to the
    true amplitude of (wide, jump) than the content-only restore."""
    X, mo, ch, cl = unified
    keep = ch == "bruno"
    Xa, moa, cla = X[keep], mo[keep], cl[keep]
    wide = _doubled_swing(Xa, cla) + 1.0                 # + 1 keeps it non-negative
    base = Xa + 1.0
    hide = moa == "jump"
    Xt = np.concatenate([base, wide[~hide]])
    mot = np.concatenate([moa, moa[~hide]])
    cht = np.concatenate([np.full(len(base), "base"), np.full((~hide).sum(), "wide")])
    clt = np.concatenate([np.char.add("b-", cla.astype(str)), np.char.add("w-", cla[~hide].astype(str))])
    t = StyleTranslator(n_components=8, max_iter=80, align_iter=40, tempo=False).fit(Xt, mot, cht, clt)
    assert t._style_gain("wide", "jump").mean() > 1.0 > t._style_gain("base", "jump").mean()
    truth = np.mean([wide[cla == q].std(axis=0) for q in np.unique(cla[hide])], axis=0)
    t.set_params(amplitude="restore")
    plain = t.synthesize("jump", "wide").std(axis=0)
    t.set_params(amplitude="style")
    styled = t.synthesize("jump", "wide").std(axis=0)
    assert np.abs(styled - truth).mean() < 0.7 * np.abs(plain - truth).mean()
