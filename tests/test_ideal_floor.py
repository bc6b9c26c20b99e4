"""experiments/ideal_floor.py: the capsule figure and what the measures make of it, on poses whose
answer is known (a bent elbow stays round; an arm folded onto the body encloses a slit only when
the gap is thin).  Real measure; the figure and poses are built here, so the test reads no data."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from nnsf.reshape.artefacts import FrameMeasures, coverage, cracks
from nnsf.skeleton import BONES, JOINT_INDEX as J

_spec = importlib.util.spec_from_file_location(
    "ideal_floor", Path(__file__).resolve().parents[1] / "experiments" / "ideal_floor.py")
fl = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(fl)

SIZE = (220, 240)
REST = {"pelvis": (120, 150), "r_hip": (108, 150), "r_knee": (106, 180), "r_ankle": (104, 208),
        "l_hip": (132, 150), "l_knee": (134, 180), "l_ankle": (136, 208), "spine": (120, 125),
        "thorax": (120, 100), "neck": (120, 90), "head_top": (120, 58), "l_shoulder": (136, 100),
        "l_elbow": (166, 100), "l_wrist": (196, 100), "r_shoulder": (104, 100), "r_elbow": (74, 100),
        "r_wrist": (44, 100)}


def keypoints(**moved) -> np.ndarray:
    kp = np.zeros((17, 2))
    for name, p in {**REST, **moved}.items():
        kp[J[name]] = p
    return kp


RADII = {**{bone: 5.0 for bone in BONES}, (J["pelvis"], J["spine"]): 14.0, (J["spine"], J["thorax"]): 14.0,
         "head": 16.0}


def measured(kp):
    rest = fl.draw(keypoints(), RADII, SIZE)
    measure = FrameMeasures(rest, rest[..., 3] >= 128, keypoints())
    return measure, measure(fl.draw(kp, RADII, SIZE), kp)


def test_the_capsule_figure_at_rest_is_its_own_reference():
    measure, m = measured(keypoints())
    rest = measure.rest()
    assert m["detached"] == 0 and m["cracks"] == rest["cracks"] == 0
    assert m["notch_beyond_rest"] == 0 and m["spikes"] == rest["spikes"]


def test_a_bent_elbow_stays_round_at_every_angle():
    for deg in range(0, 171, 10):
        a = np.radians(deg)
        wrist = np.array(REST["l_elbow"]) + 30 * np.array([np.cos(a), np.sin(a)])
        _, m = measured(keypoints(l_wrist=tuple(wrist)))
        assert m["notch_beyond_rest"] <= 4, deg


def test_an_arm_folded_onto_the_body_encloses_a_slit_only_when_the_gap_is_thin():
    # The forearm folds back from the elbow to the chest: the wedge between it and the upper arm is
    # closed by the elbow's cap and the torso.  Near the torso it is about 1 px wide, or about 13 px.
    for wrist_y, expect in ((112, True), (125, False)):
        kp = keypoints(r_elbow=(64, 100), r_wrist=(104, wrist_y))
        img = fl.draw(kp, RADII, SIZE)
        labels = np.zeros(SIZE, np.int32)
        n, _ = cracks(coverage(img), labels=labels)
        assert (n > 0) == expect, wrist_y
        if expect:
            ys, xs = np.nonzero(labels)
            assert (xs > 64).all() and (xs < 110).all() and (ys > 100).all() and (ys < 115).all()


def test_radii_come_from_the_drawings_widths_and_the_head_spans_neck_to_top():
    rest = fl.draw(keypoints(), RADII, SIZE)
    mask = rest[..., 3] >= 128
    r = fl.radii(mask, keypoints(), FrameMeasures(rest, mask, keypoints()).rest_widths)
    arm = r[(J["l_shoulder"], J["l_elbow"])]
    assert abs(arm - 5.0) <= 1.0
    assert abs(r["head"] - 16.0) < 1e-9
    assert r[(J["spine"], J["thorax"])] > 2 * arm
