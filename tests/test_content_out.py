"""Leave one content out: the user's situation, scored through nnsf.translate (docs/method.md §15.5)."""
from __future__ import annotations

import numpy as np
import pytest

from nnsf.datasets.synthetic import generate
from nnsf.evaluate.content_out import content_folds, evaluate_content, summary_tables, target_check
from nnsf.factor.style_model import StyleModel

CHARS = ["bruno", "pip", "olga"]
MOTIONS = ["walk", "jump", "wave", "bow"]
TP = {"n_components": 6, "max_iter": 30, "align_iter": 10, "random_state": 0}


@pytest.fixture(scope="module")
def pixels():
    return generate(characters=CHARS, clips_per_cell=2, frames=16, noise_px=0.3, seed=0, motions=MOTIONS)


def test_the_fold_never_fits_on_the_hidden_content(pixels, tmp_path):
    """The fold's model file -- written and read back as ``nnsf styles`` would -- holds no clip, cell or
    content of the hidden action; every other style's take of it is translated into each style."""
    rows, info = evaluate_content(pixels, "wave", translator_params=TP, source_style="pip",
                                  methods=("api", "api_source", "offset", "spectral", "identity", "real"),
                                  model_dir=tmp_path, fps=24.0)
    model = StyleModel.load(tmp_path / "styles.npz")
    assert "wave" not in model.meta["contents"] and info["model_contents"] == ["bow", "jump", "walk"]
    tr = model.translator
    assert all(c != "wave" for _, c in tr.clips_) and "wave" not in set(tr.cells_[:, 1])
    assert "wave" not in tr.content_rows_ and tr.neutral == "pip"          # the source is the neutral style
    stored = [Xq for lst in tr.clips_.values() for Xq in lst]
    others = pixels[pixels["motion"] != "wave"]
    assert len(stored) == others["clip"].nunique()                          # every other clip, no more
    assert sum(len(Xq) for Xq in stored) == len(others)
    # cells: the content in every style but the source's; every method scored in each
    assert sorted(set(rows["style"])) == ["bruno", "olga"] and set(rows["content"]) == {"wave"}
    assert len(rows) == 2 * 6 and info["cells"] == 2
    real = rows[rows["method"] == "real"]
    assert (real["n_hidden"] == 2).all() and (real["n_sources"] == 0).all()
    api = rows[rows["method"] == "api"]
    assert (api["lean_change_first"] < 3.0).all() and (api["n_sources"] == 2).all()
    assert np.isfinite(rows[["style_lr", "content_angles", "dtw_error", "jerk_ratio"]].to_numpy()).all()


def test_folds_tables_and_targets(pixels):
    assert content_folds(pixels) == sorted(MOTIONS)
    assert content_folds(pixels[~((pixels["motion"] == "bow") & (pixels["character"] == "pip"))], "pip") == \
        ["jump", "walk", "wave"]
    rows, _ = evaluate_content(pixels, "jump", translator_params=TP, methods=("api", "offset", "spectral"))
    # no source style: every other style's clips are sources (2 styles × 2 clips)
    assert set(rows["n_sources"]) == {4}
    tables = summary_tables(rows)
    assert set(tables["methods"]) == {"api", "offset", "spectral"} and "bruno/api" in tables["per_style"]
    check = target_check(rows)
    assert check["method"] == "api" and check["of"] == 9 and isinstance(check["met"], bool)
    assert "style_lr > spectral" in check["checks"] and "style_angles > offset" in check["checks"]
    with pytest.raises(ValueError, match="unknown method"):
        evaluate_content(pixels, "jump", translator_params=TP, methods=("magic",))
