"""Elbow and knee caps: the upper segment's end rounded past its cut, hidden under the lower one."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nnsf.reshape import artefacts as A
from nnsf.reshape import depth as D
from nnsf.reshape.cuts import Cut, SEGMENT_NAMES
from nnsf.reshape.tab_regions import cap_region, tab_region
from nnsf.skeleton import JOINT_INDEX as J

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
KENNEY_ANN = Path(__file__).resolve().parent / "data" / "kenney"


def _arm():
    """A straight horizontal arm 11 px thick (rows 15-25), upper arm x 10-39, forearm x 40-69,
    cut across at x = 40, pivot 3 px inside the upper arm."""
    label = np.full((40, 80), -1)
    up, fore = SEGMENT_NAMES.index("l_upper_arm"), SEGMENT_NAMES.index("l_forearm")
    label[15:26, 10:40] = up
    label[15:26, 40:70] = fore
    cut = Cut(joint=J["l_elbow"], parent=up, child=fore, p=np.array([40.0, 15.0]), q=np.array([40.0, 25.0]),
              pivot=np.array([37.0, 20.0]), normal=np.array([1.0, 0.0]), half_width=5.0)
    return label, cut


def test_a_cap_lies_past_the_cut_inside_the_forearm_and_rounds_the_joint_with_the_tab():
    label, cut = _arm()
    cap = cap_region(label, cut)
    tab = tab_region(label, cut, 0.0)
    ys, xs = np.nonzero(cap)
    assert len(xs)
    # Past the cut, on the forearm's pixels, within half the cut's length of its middle or the
    # disc about the pivot that reaches both ends of the cut.
    assert xs.min() >= 40 and np.all(label[ys, xs] == cut.child)
    reach = float(np.hypot(3.0, 5.0))
    assert np.all((np.hypot(xs - 40.0, ys - 20.0) <= 5.0) | (np.hypot(xs - 37.0, ys - 20.0) <= reach))
    # Like a tab, it keeps off the outermost rows (at rest it must hide under the forearm's edge).
    assert not cap[15].any() and not cap[25].any()
    # Tab and cap together: a solid round joint about the pivot, on both sides of the cut.
    yy, xx = np.mgrid[:40, :80]
    disc = np.hypot(xx - 37.0, yy - 20.0) <= 3.5
    assert np.all((tab | cap)[disc & (label >= 0)])
    # Each on its own side of the cut (both hold its column, x = 40): the tab under the upper arm,
    # the cap under the forearm, half the cut's length deep.
    assert not tab[:, 41:].any() and not cap[:, :40].any() and cap[17:24, 40:45].all()


@pytest.mark.skipif(not (SHARED / "kenney-toon" / "male_adventurer").is_dir(),
                    reason="../shared/data (Kenney toon male_adventurer) not present")
def test_caps_narrow_the_gap_at_folded_elbows_and_knees_of_a_kenney_character():
    """male_adventurer's hands and feet are blobs on short segments: a forearm or shin folded far
    leaves the outer side of the joint open.  Each elbow and knee folded 120° either way (8
    poses), background pixels in the joint's disc beyond the rest pose's, summed: 80 without the
    caps, 44 with them (benchmarks/joint_caps.py); the largest single joint 14 → 7."""
    from nnsf.reshape.kenney import kenney_character
    from nnsf.reshape.render import MeshRenderer
    from nnsf.reshape.stage import build_rig

    ch, _ = kenney_character("male_adventurer", SHARED / "kenney-toon", KENNEY_ANN)
    rig = build_rig(ch, "ours", "layered", 300, 4)
    assert sum(t.cut is None and t.pivot is None for t in rig.mesh.tabs) == 4  # the four caps
    r = MeshRenderer.for_mesh(rig.mesh, ch)
    joints = list(A.JOINTS_CHECKED)
    radii = A.joint_radii(ch.mask, ch.keypoints)
    rest = r.render(rig.mesh.vertices, D.default_order())[..., 3] >= 128
    _, e0 = A.joint_gaps(rest, ch.keypoints[joints], radii, per_joint=True)
    a = np.radians(120.0)
    gaps = []
    for sgn in (1.0, -1.0):
        R = np.array([[np.cos(sgn * a), -np.sin(sgn * a)], [np.sin(sgn * a), np.cos(sgn * a)]])
        for joint, end in (("l_elbow", "l_wrist"), ("r_elbow", "r_wrist"), ("l_knee", "l_ankle"),
                           ("r_knee", "r_ankle")):
            kp = ch.keypoints.copy()
            kp[J[end]] = (kp[J[end]] - kp[J[joint]]) @ R.T + kp[J[joint]]
            solid = r.render(rig.animate(kp[None])[0], D.default_order())[..., 3] >= 128
            _, each = A.joint_gaps(solid, kp[joints], radii, per_joint=True)
            k = joints.index(J[joint])
            gaps.append(max(int(each[k]) - int(e0[k]), 0))
    assert sum(gaps) <= 50 and max(gaps) <= 8, gaps
