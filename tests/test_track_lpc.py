"""Tracking on the LPC sprite sheets' walk rows (nnsf.roto.lpc) from the hand-made annotations."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.frames.annotation import read_annotation
from nnsf.roto.lpc import read_tiles, track_lpc
from nnsf.roto.real import annotated_names, score_silhouette

ANNOTATIONS = Path(__file__).resolve().parent / "data" / "lpc"
LPC = Path(__file__).resolve().parents[2] / "shared" / "data" / "lpc-bodies"
needs_lpc = pytest.mark.skipif(not (LPC / "male.png").is_file(),
                               reason=f"the LPC sprite sheets are not at {LPC}")


BODIES = annotated_names(ANNOTATIONS)


def test_every_body_has_a_valid_walk_row_annotation():
    assert len(BODIES) == 5
    for body in BODIES:
        ann = read_annotation(ANNOTATIONS / f"{body}.annotation.json")
        assert ann.image_size == (64, 64) and len(ann.frames) == 9
        assert ann.keyframe_indices == [0, 8] and len(ann.curve_names) == 12


@needs_lpc
def test_the_annotated_keyframes_lie_on_the_silhouettes():
    for body in BODIES:
        ann = read_annotation(ANNOTATIONS / f"{body}.annotation.json")
        _, alpha = read_tiles(LPC / f"{body}.png", ann.frames)
        for k in ann.keyframes:
            control = np.stack([k.curves[n] for n in ann.curve_names])
            # control points on outline pixel centres: within 1 px of the alpha boundary
            assert score_silhouette(control, alpha[k.frame], tol=1.0) >= 0.95, (body, k.frame)


@needs_lpc
def test_tiles_and_a_tracked_walk_row(tmp_path):
    ann = read_annotation(ANNOTATIONS / "male.annotation.json")
    rgb, alpha = read_tiles(LPC / "male.png", ann.frames)
    assert rgb.shape == (9, 64, 64, 3) and alpha.shape == (9, 64, 64)
    assert (rgb[alpha == 0] == 255).all()                       # composited over white
    table, tracked = track_lpc(LPC, ANNOTATIONS, methods=("ours",), names=("male",))
    row = table.iloc[0]
    assert row["frames"] == 7 and row["keyframe_score"] >= 0.95
    assert row["score"] >= 0.8 and np.isfinite(tracked[("male", "ours")]).all()
    with pytest.raises(InputError, match=r"frame 'walk0.png': expected a tile name"):
        read_tiles(LPC / "male.png", ["walk0.png"])
    with pytest.raises(InputError, match=r"expected a tile inside"):
        read_tiles(LPC / "male.png", ["r30c0.png"])
