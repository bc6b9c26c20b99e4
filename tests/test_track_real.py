"""Tracking on real cartoon frames scored against their alpha silhouettes (nnsf.roto.real), on the
Kenney toon walk cycles and their hand-made keyframe annotations."""
from pathlib import Path

import numpy as np
import pytest

from nnsf.roto.real import annotated_names, score_silhouette, silhouette_boundary, track_frames

PROJECT = Path(__file__).resolve().parents[1]
KENNEY = PROJECT.parent / "shared" / "data" / "kenney-toon"
ANNOTATIONS = PROJECT / "tests" / "data" / "kenney"


def _disc(r=30.0, size=128):
    yy, xx = np.mgrid[:size, :size]
    d = np.hypot(xx - 64.0, yy - 64.0)
    return (np.clip(r + 0.5 - d, 0, 1) * 255).astype(np.uint8)      # anti-aliased edge at r


def test_silhouette_boundary_of_a_disc():
    pts = silhouette_boundary(_disc())
    r = np.hypot(pts[:, 0] - 64, pts[:, 1] - 64)
    assert abs(np.median(r) - 30.0) < 0.3 and r.std() < 0.3


def test_score_of_curves_on_and_off_the_boundary():
    alpha = _disc()
    ang = np.linspace(0.2, 1.4, 5)
    on = np.stack([64 + 30 * np.cos(ang), 64 + 30 * np.sin(ang)], -1)[None]   # (1, 5, 2)
    assert score_silhouette(on, alpha) == 1.0
    assert score_silhouette((on - 64) * (33.0 / 30.0) + 64, alpha) == 0.0   # 3 px out
    half = np.concatenate([on, (on - 64) * (26.0 / 30.0) + 64])                     # 4 px in
    assert score_silhouette(half, alpha) == pytest.approx(0.5)


def test_kenney_walk_cycles():
    if not KENNEY.is_dir():
        pytest.skip(f"shared Kenney frames not found at {KENNEY}")
    if not (ANNOTATIONS / "robot.annotation.json").is_file():
        pytest.skip(f"hand annotation {ANNOTATIONS / 'robot.annotation.json'} not present")
    table, tracked = track_frames(KENNEY, ANNOTATIONS, names=("robot",))
    s = table.set_index("tracker")["score"]
    assert set(s.index) == {"ours", "agarwala", "lk"}
    # the space-time tracker stays on the outline far more often than per-frame LK
    assert s["ours"] > s["lk"] + 0.1
    assert s["ours"] > 0.5
    # ... without buying that score by shrinking: it keeps the keyframes' curve length and
    # covers most of the outline the keyframes cover
    t = table.set_index("tracker")
    assert t.loc["ours", "length_ratio"] == pytest.approx(1.0, abs=0.1)
    assert t.loc["ours", "coverage"] > 0.75
    assert tracked[("robot", "ours")].shape[:2] == (8, 16)


def test_kenney_target_with_the_project_options():
    """With params.yaml's tracker at least 0.70 of the outline samples lie within 1.5 px of the
    silhouette: on these flat-colour sprites ``snap_to: auto`` snaps to the colour edge, and
    the snap adds to the score of the same solve without it."""
    if not KENNEY.is_dir():
        pytest.skip(f"shared Kenney frames not found at {KENNEY}")
    from nnsf import params
    from nnsf.roto.options import track_options
    from nnsf.roto.real import silhouette_summary

    opts = track_options(params.load(PROJECT / "params.yaml"))
    assert opts["snap"] > 0 and opts["snap_to"] == "auto"
    table, _ = track_frames(KENNEY, ANNOTATIONS, methods=("ours",), **opts)
    assert len(table) == len(annotated_names(ANNOTATIONS)) == 6
    assert set(table["snap"]) == {"edge"} and (table["stroke_share"] < 0.1).all()   # flat colour
    s = silhouette_summary(table, 1.5)
    assert s["trackers"]["ours"] >= 0.70
    assert s["length_ratio"]["ours"] == pytest.approx(1.0, abs=0.1)
    off, _ = track_frames(KENNEY, ANNOTATIONS, methods=("ours",), names=("robot",),
                          **{**opts, "snap": 0.0})
    assert table.set_index("character").loc["robot", "score"] > off["score"].iloc[0] + 0.05
