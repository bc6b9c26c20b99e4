"""Artefact measures on hand-made images with known answers, their independence from the renderer,
and user depth overrides."""
from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from nnsf.errors import InputError
from nnsf.reshape import artefacts as A
from nnsf.reshape import depth as D
from nnsf.reshape.parts import PART_INDEX as P


def test_the_measures_import_nothing_from_the_code_they_measure():
    def imports(path):
        tree = ast.parse(Path(path).read_text())
        names = [a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names]
        names += [n.module + "." + a.name for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module
                  for a in n.names]
        return names

    assert not [m for m in imports(A.__file__) if m.startswith("nnsf.reshape")]
    # ... and nothing of the reshaping code but the evaluation imports them.
    for f in Path(A.__file__).parent.glob("*.py"):
        if f.name not in ("artefacts.py", "evaluation.py"):
            assert not [m for m in imports(f) if "artefacts" in m], f


def test_detached_counts_bits_apart_from_the_body():
    cov = np.zeros((40, 40), bool)
    cov[5:30, 5:20] = True
    assert A.detached(cov) == 0
    cov[35:37, 35:37] = True          # 4 px apart from the body
    cov[2, 35] = True                 # 1 px: below the 3 px floor
    assert A.detached(cov) == 1
    cov[20:22, 20:22] = True          # touches the body diagonally: joined (8-connected)
    assert A.detached(cov) == 1


def test_a_crack_is_thin_enclosed_background_only():
    cov = np.zeros((60, 60), bool)
    cov[5:55, 5:55] = True
    assert A.cracks(cov) == (0, 0)
    cov[10:30, 10:12] = False         # a 2 px wide slit inside: a crack of 40 px
    cov[40:46, 40:46] = False         # a 6 px hole: wider than a crack
    cov[20:22, 50:55] = False         # a notch open to the outside: not enclosed
    assert A.cracks(cov) == (1, 40)
    cov[15:18, 30:45] = False         # 3 px wide: still a crack
    assert A.cracks(cov) == (2, 40 + 45)
    cov[[30, 31, 32], [30, 31, 32]] = False   # a diagonal line of single pixels: one crack...
    assert A.cracks(cov)[0] == 3
    assert A.cracks(cov, connectivity=4, isolated=False)[0] == 5   # ... or three specks
    cov[52:55, 52] = False                    # page at the inner corner of the body's edge: touches
    cov[55, 53] = False                       # the outside through a pixel corner, not enclosed
    assert A.cracks(cov)[0] == 3
    cov[42:46, 47:49] = False                 # a thin bit one drawn pixel from the 6 px hole: its
    assert A.cracks(cov)[0] == 3              # pinched end, not a crack ...
    assert A.cracks(cov, isolated=False)[0] == 4   # ... but a speck
    labels = np.zeros(cov.shape, np.int32)   # the pixels counted, numbered by crack
    n, px = A.cracks(cov, labels=labels)
    assert (labels > 0).sum() == px and labels.max() == n and np.unique(labels[labels > 0]).size == n
    assert (labels[10:30, 10:12] > 0).all() and not labels[40:46, 40:46].any()


def test_a_crack_at_a_joint_is_told_from_one_elsewhere():
    cov = np.zeros((60, 60), bool)
    cov[5:55, 5:55] = True
    cov[10:30, 10:12] = False         # a slit near the top left
    cov[40:50, 40:42] = False         # another near the bottom right
    at = np.zeros_like(cov)
    cv2.circle(at.view(np.uint8), (45, 45), 6, 1, -1)   # a joint's disc over the second
    assert A.cracks(cov) == (2, 40 + 20)
    assert A.cracks(cov, near=at) == (1, 20)


def test_joint_notch_counts_the_missing_pixels_of_the_disc():
    kp = np.zeros((17, 2))
    kp[:] = [50, 50]
    mask = np.zeros((100, 100), bool)
    mask[20:80, 20:80] = True
    j = A.JOINTS_CHECKED[0]
    kp[j] = [50, 50]
    kp[A.CHILD_OF[0]] = [50, 75]
    r = A.joint_radii(mask, kp)
    assert r[0] == pytest.approx(0.8 * np.median([25 - 0.0] * 1), abs=6)   # the bone's half-width
    assert A.joint_notches(mask, kp, r)[0] == 0
    cut = mask.copy()
    cut[50:, 50:] = False             # a quarter of the disc missing
    n = A.joint_notches(cut, kp, r)[0]
    assert n == pytest.approx(np.pi * r[0] ** 2 / 4, rel=0.15)


def test_spikes_are_turns_sharper_than_the_drawings_own():
    rest = np.zeros((80, 80), np.uint8)
    cv2.circle(rest, (40, 40), 25, 1, -1)
    thr = A.spike_threshold(A.outline_turning(rest))
    assert thr == 60.0 and A.count_spikes(A.outline_turning(rest), thr) == 0
    star = rest.copy()
    cv2.fillConvexPoly(star, np.array([[36, 20], [44, 20], [40, 2]], np.int32), 1)   # a thin spike
    assert A.count_spikes(A.outline_turning(star), thr) == 1


def test_limb_width_across_a_drawn_bar_and_its_stats():
    cov = np.zeros((100, 100), bool)
    cov[20:80, 40:52] = True          # a vertical bar 12 px wide
    kp = np.zeros((17, 2))
    a, b = next(iter(A.LIMBS.values()))
    kp[a], kp[b] = [45.5, 20], [45.5, 79]
    w = A.limb_widths(cov, kp, np.full(8, 20.0))
    assert np.allclose(w[0], 12, atol=1)
    assert np.isnan(w[1:]).all()      # the other limbs have zero length here
    thin = A.width_stats(w[None] * 0.5, w)
    assert thin["width_change"] == pytest.approx(-0.5) and thin["width_error"] == pytest.approx(0.5)
    same = A.width_stats(np.stack([w, w]), w)
    assert same["width_error"] == 0 and same["width_jitter"] == 0


def test_frame_measures_of_the_drawing_itself_are_its_rest_numbers():
    from stick_figure import stick_figure

    ch = stick_figure(height=200)
    m = A.FrameMeasures(ch.texture, ch.mask, ch.keypoints)
    got = m(ch.texture, ch.keypoints)
    rest = m.rest()
    assert got["detached"] == rest["detached"] == 0
    assert got["cracks"] == rest["cracks"] and got["spikes"] == rest["spikes"]
    assert got["notch_beyond_rest"] == 0


# --------------------------------------------------------------------------- depth overrides

def test_depth_override_changes_exactly_its_frames():
    T = 40
    orders = np.tile(D.default_order(), (T, 1))  # torso drawn first, behind everything
    ov = D.parse_overrides(["torso over left_arm from 12 to 30"], T)
    new = D.apply_overrides(orders, ov)
    changed = np.flatnonzero((new != orders).any(axis=1))
    np.testing.assert_array_equal(changed, np.arange(12, 31))
    rank = D.order_ranks(new)
    assert (rank[12:31, P["torso"]] > rank[12:31, P["l_upper_arm"]]).all()
    assert (rank[12:31, P["torso"]] > rank[12:31, P["l_forearm"]]).all()
    for t in range(12, 31):  # every other pair keeps its order
        others = [p for p in new[t] if p != P["torso"]]
        assert others == [p for p in orders[t] if p != P["torso"]]
    # The same in mapping form; an override already true changes nothing.
    same = D.apply_overrides(orders, D.parse_overrides([{"over": "left_arm", "under": "torso", "from": 0,
                                                         "to": 39}], T))
    np.testing.assert_array_equal(same, orders)


def test_depth_override_on_depth_driven_orders():
    rng = np.random.default_rng(0)
    z = np.cumsum(rng.normal(0, 0.05, (60, 10)), axis=0)
    orders = D.depth_orders(z, 0.02)
    new = D.apply_overrides(orders, D.parse_overrides(["right_leg over head from 5 to 20"], 60))
    rank = D.order_ranks(new)
    assert (rank[5:21, P["r_thigh"]] > rank[5:21, P["head"]]).all()
    np.testing.assert_array_equal(new[:5], orders[:5])
    np.testing.assert_array_equal(new[21:], orders[21:])


@pytest.mark.parametrize("spec, field", [
    (["left_arm over tail from 1 to 3"], r"reshape\.depth_overrides\[0\]\.under"),
    ([{"over": "wing", "under": "torso", "from": 1, "to": 3}], r"reshape\.depth_overrides\[0\]\.over"),
    (["left_arm over torso from 12 to 99"], r"reshape\.depth_overrides\[0\]\.to.*0\.\.39"),
    (["left_arm over torso from -1 to 3"], r"reshape\.depth_overrides\[0\]\.from"),
    (["left_arm under torso"], r"reshape\.depth_overrides\[0\]"),
])
def test_depth_override_bad_input(spec, field):
    with pytest.raises(InputError, match=field):
        D.parse_overrides(spec, 40)


@pytest.mark.slow  # starts `nnsf reshape` as a process
def test_depth_override_bad_input_from_the_command_line(tmp_path):
    """``nnsf reshape`` with an unknown part / a frame outside the clip: one line naming the field, exit 2."""
    import yaml

    from tests.test_reshape_stage import _csv, _params
    from stick_figure import stick_figure
    from nnsf.reshape.formats import write_character

    csv = _csv(tmp_path / "motion.csv")
    char = write_character(stick_figure(height=200, name="stick"), tmp_path / "stick.json")
    repo = Path(__file__).resolve().parents[1]
    for spec, field in ((["left_arm over tail from 1 to 3"], "reshape.depth_overrides[0].under"),
                        (["left_arm over torso from 2 to 50"], "reshape.depth_overrides[0].to")):
        params = _params(depth_overrides=spec, formats=["gif"])
        pf = tmp_path / "params.yaml"
        pf.write_text(yaml.safe_dump(params))
        out = tmp_path / "out"
        r = subprocess.run([sys.executable, "-m", "nnsf.cli", "reshape", "--params", str(pf), "--motion", str(csv),
                            "--character", str(char), "--out", str(out)], capture_output=True, text=True,
                           cwd=repo)
        assert r.returncode == 2, r.stderr
        lines = [ln for ln in (r.stderr + r.stdout).splitlines() if ln.strip()]
        assert len(lines) == 1 and field in lines[0], lines
        assert not out.exists()


