"""A stick figure drawn from the template body: a character with no data files, for the tests and the benchmarks (which fall back on it without the data folder)."""
from __future__ import annotations

import cv2
import numpy as np

from nnsf.reshape.character import Character
from nnsf.skeleton import JOINT_INDEX, rest_pose


def stick_figure(height: int = 400, arm_angle: float = 55.0, leg_angle: float = 8.0,
                 limb_width: float = 0.09, name: str = "stick") -> Character:
    """A simple drawn character built from the template body (tests and benchmarks; no data files).

    The template rest pose (:func:`nnsf.skeleton.rest_pose`) scaled to ``height`` pixels, its arms
    raised ``arm_angle`` degrees from hanging and its legs spread ``leg_angle`` degrees, drawn with
    thick limbs (``limb_width`` × height), a torso quad and a round head, flat colours, dark outlines.
    """
    kp = rest_pose()
    J = JOINT_INDEX

    def swing(chain, pivot, deg):
        a = np.radians(deg)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        kp[chain] = (kp[chain] - kp[pivot]) @ R.T + kp[pivot]

    swing([J["l_elbow"], J["l_wrist"]], J["l_shoulder"], -arm_angle)
    swing([J["r_elbow"], J["r_wrist"]], J["r_shoulder"], arm_angle)
    swing([J["l_knee"], J["l_ankle"]], J["l_hip"], -leg_angle)
    swing([J["r_knee"], J["r_ankle"]], J["r_hip"], leg_angle)
    span = kp.max(0) - kp.min(0)
    scale = 0.8 * height / span[1]
    head_r = 0.22 * scale
    w = int(np.ceil(span[0] * scale + 2 * head_r + 0.2 * height))
    kp = (kp - kp.min(0)) * scale + [(w - span[0] * scale) / 2, 0.1 * height + head_r * 0.3]
    thick = max(3, int(round(limb_width * height)))
    mask = np.zeros((height, w), np.uint8)
    tex = np.zeros((height, w, 3), np.uint8)
    tex[:] = (235, 230, 220)
    colours = {"torso": (70, 120, 200), "arm": (230, 170, 60), "leg": (60, 160, 90), "head": (240, 200, 170)}
    torso = np.rint([kp[J["l_hip"]], kp[J["r_hip"]], kp[J["r_shoulder"]], kp[J["l_shoulder"]]]).astype(np.int32)
    head_c = 0.5 * (kp[J["neck"]] + kp[J["head_top"]])

    def pt(p):
        return tuple(int(v) for v in np.rint(p))

    def draw(img, colour=None, grow=0):
        def c(part):
            return colour if colour is not None else colours[part]

        for a, b, part in ((11, 12, "arm"), (12, 13, "arm"), (14, 15, "arm"), (15, 16, "arm"),
                           (1, 2, "leg"), (2, 3, "leg"), (4, 5, "leg"), (5, 6, "leg")):
            cv2.line(img, pt(kp[a]), pt(kp[b]), c(part), thick + grow)
        cv2.fillConvexPoly(img, torso, c("torso"))
        cv2.polylines(img, [torso], True, c("torso"), thick // 2 + grow)
        cv2.line(img, pt(kp[J["thorax"]]), pt(head_c), c("head"), thick + grow)
        cv2.circle(img, pt(head_c), int(head_r) + grow, c("head"), -1)

    draw(mask, 255, grow=2)
    draw(tex, (40, 40, 40), grow=2)   # a dark outline, then the fills on top
    draw(tex)
    mask = mask > 0
    rgba = np.dstack([tex, np.where(mask, 255, 0).astype(np.uint8)])
    return Character(name=name, texture=rgba, mask=mask, keypoints=kp, source=f"<stick_figure {name}>")
