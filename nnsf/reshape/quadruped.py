"""Four-legged drawings: their skeleton read as our 17 points, and driven by a biped's motion.

AnimatedDrawings' skeleton of a quadruped (an animal drawn from the side) has ``root``, ``hip``,
``torso``, ``neck`` and three joints per leg: ``{right,left}_{hip,knee,foot}_{b,f}`` (``b`` the hind
legs, ``f`` the front).  Our 17-point body has two legs and two arms, so a quadruped is read as
(:func:`quadruped_keypoints`):

* the hind legs are the legs (``r_hip``, ``r_knee``, ``r_ankle`` …);
* the front legs are the arms (``r_shoulder``, ``r_elbow``, ``r_wrist`` …);
* ``pelvis`` and ``thorax`` are the middles of the hind and front hips,
  ``spine`` halfway between; ``neck`` is AnimatedDrawings' ``neck`` (the head's centre) and
  ``head_top`` continues its torso→neck direction to just inside the mask, as for a biped.

A biped's motion cannot give a horizontal body its bone directions (it would stand the animal up on
its hind legs), so a quadruped is driven about its drawn pose (:func:`retarget_quadruped`): every
leg bone keeps its drawn direction, turned by the swing of a motion leg bone about its mean
direction; the hind legs follow the motion's legs of their own side and the front legs the legs of
the other side, so the diagonal pairs step together (a trot, as a walking biped's left arm swings
with its right leg).  The body and the head move as one rigid piece: the root follows the motion's
pelvis, the body turns by the swing of the motion's spine.  A motion seen walking the other way from
the drawing's facing is mirrored first, so the animal does not walk backwards.  Drawn from the side,
its near legs are in front of the body and the head, its far legs behind them
(:func:`quadruped_orders`).
"""
from __future__ import annotations

import numpy as np

from nnsf.errors import InputError
from nnsf.reshape.character import head_top_along, points_in_mask
from nnsf.reshape.parts import PART_INDEX, PARTS
from nnsf.skeleton import BONES, JOINT_INDEX as J

#: The AnimatedDrawings joint names of a quadruped ``char_cfg.yaml``.
QUADRUPED_JOINTS: tuple[str, ...] = ("root", "hip", "torso", "neck") + tuple(
    f"{side}_{j}_{end}" for end in ("b", "f") for side in ("right", "left") for j in ("hip", "knee", "foot"))

#: Our leg chains and the quadruped joints they copy: hind legs → legs, front legs → arms.
_CHAINS = {
    ("r_hip", "r_knee", "r_ankle"): ("right_hip_b", "right_knee_b", "right_foot_b"),
    ("l_hip", "l_knee", "l_ankle"): ("left_hip_b", "left_knee_b", "left_foot_b"),
    ("r_shoulder", "r_elbow", "r_wrist"): ("right_hip_f", "right_knee_f", "right_foot_f"),
    ("l_shoulder", "l_elbow", "l_wrist"): ("left_hip_f", "left_knee_f", "left_foot_f"),
}

#: Each leg bone of the drawing and the motion bone whose swing turns it (indices into BONES):
#: hind legs from the same side's leg, front legs from the other side's leg (diagonal pairs).
_DRIVERS = tuple((BONES.index((J[a], J[b])), BONES.index((J[c], J[d]))) for (a, b), (c, d) in (
    (("r_hip", "r_knee"), ("r_hip", "r_knee")), (("r_knee", "r_ankle"), ("r_knee", "r_ankle")),
    (("l_hip", "l_knee"), ("l_hip", "l_knee")), (("l_knee", "l_ankle"), ("l_knee", "l_ankle")),
    (("r_shoulder", "r_elbow"), ("l_hip", "l_knee")), (("r_elbow", "r_wrist"), ("l_knee", "l_ankle")),
    (("l_shoulder", "l_elbow"), ("r_hip", "r_knee")), (("l_elbow", "l_wrist"), ("r_knee", "r_ankle"))))

#: The points that move with the body (everything but the knees, ankles, elbows and wrists).
BODY = tuple(J[j] for j in ("pelvis", "r_hip", "l_hip", "spine", "thorax", "neck", "head_top",
                            "l_shoulder", "r_shoulder"))


def is_quadruped(names) -> bool:
    """Whether a skeleton names any of AnimatedDrawings' quadruped leg joints (``right_hip_b`` …):
    read as a quadruped, so that one missing joint is named as such (:func:`quadruped_keypoints`)."""
    return bool(set(QUADRUPED_JOINTS[4:]) & set(names))


def quadruped_keypoints(loc: dict, mask: np.ndarray, source) -> np.ndarray:
    """Our 17 key points ``(17, 2)`` of a quadruped's joints ``loc`` (name → ``[x, y]`` px)."""
    missing = [n for n in QUADRUPED_JOINTS if n not in loc]
    if missing:
        raise InputError(source, "skeleton", "the quadruped joints " + ", ".join(QUADRUPED_JOINTS),
                         "missing " + ", ".join(missing))
    kp = np.full((len(J), 2), np.nan)
    for ours, theirs in _CHAINS.items():
        for a, b in zip(ours, theirs):
            kp[J[a]] = loc[b]
    kp[J["pelvis"]] = 0.5 * (kp[J["r_hip"]] + kp[J["l_hip"]])
    kp[J["thorax"]] = 0.5 * (kp[J["r_shoulder"]] + kp[J["l_shoulder"]])
    kp[J["spine"]] = 0.5 * (kp[J["pelvis"]] + kp[J["thorax"]])
    neck, base = np.asarray(loc["neck"], float), np.asarray(loc["torso"], float)
    if not np.linalg.norm(neck - base) > 0:
        raise InputError(source, "skeleton.neck", "a point distinct from torso", neck.tolist())
    if not points_in_mask(mask, neck):
        raise InputError(source, "skeleton.neck", "a point inside the mask", neck.tolist())
    kp[J["neck"]] = neck
    kp[J["head_top"]] = head_top_along(mask, neck, (neck - base) / np.linalg.norm(neck - base))
    return kp


def knees_ahead(points: np.ndarray) -> float:
    """How far (x, the points' units) a biped's knees lie ahead of their hip–ankle lines, summed over
    both legs: the median over the frames of ``points`` ``(T, 17, 2)``."""
    P = np.asarray(points, dtype=np.float64)
    ahead = 0.0
    for hip, knee, ankle in (("r_hip", "r_knee", "r_ankle"), ("l_hip", "l_knee", "l_ankle")):
        ahead += float(np.median(P[:, J[knee], 0] - 0.5 * (P[:, J[hip], 0] + P[:, J[ankle], 0])))
    return ahead


def facing(points: np.ndarray) -> float:
    """+1 when a biped motion ``(T, 17, 2)`` (image coordinates) faces +x, −1 when it faces −x, 0 if
    unknown: the side its knees bend to (:func:`knees_ahead`)."""
    return float(np.sign(knees_ahead(points)))


def drawn_facing(rest: np.ndarray) -> float:
    """+1 when a quadruped drawing's head is on its +x side, −1 otherwise."""
    return 1.0 if rest[J["neck"], 0] >= rest[J["pelvis"], 0] else -1.0


def _angles(vec: np.ndarray) -> np.ndarray:
    return np.arctan2(vec[..., 1], vec[..., 0])


def swing(theta: np.ndarray) -> np.ndarray:
    """Each frame's angle ``(T, ...)`` from the circular mean over the frames of ``theta``
    ``(T, ...)`` (radians; the angle of the mean unit vector), wrapped to ±π."""
    mean = np.arctan2(np.sin(theta).mean(axis=0), np.cos(theta).mean(axis=0))
    return np.angle(np.exp(1j * (theta - mean)))


def retarget_quadruped(points: np.ndarray, rest_keypoints: np.ndarray) -> np.ndarray:
    """A biped motion ``(T, 17, 2)`` (checked, finite) as a quadruped drawing's key points ``(T, 17, 2)`` px.

    Module docstring.  Units: the motion's are free (only angles and the ratio of the drawing's
    hind-leg length to the motion's leg length are used); lengths are the drawing's exactly.
    """
    P = np.array(points, dtype=np.float64)
    rest = np.asarray(rest_keypoints, dtype=np.float64)
    if facing(P) * drawn_facing(rest) < 0:
        P[..., 0] *= -1.0   # the motion walks the other way: its mirror image
    vec = P[:, [c for _, c in BONES]] - P[:, [p for p, _ in BONES]]          # (T, 16, 2)
    theta = _angles(vec)
    T = len(P)
    out = np.empty((T, len(J), 2))
    # The body: rigid, turned by the spine's swing about the pelvis, carried by the root.
    legs = [BONES.index((J[a], J[b])) for a, b in (("r_hip", "r_knee"), ("r_knee", "r_ankle"),
                                                   ("l_hip", "l_knee"), ("l_knee", "l_ankle"))]
    motion_leg = float(np.median(np.linalg.norm(vec[:, legs], axis=2).sum(axis=1))) / 2
    drawn_leg = float(np.mean([np.linalg.norm(rest[J[k]] - rest[J[h]]) + np.linalg.norm(rest[J[a]] - rest[J[k]])
                               for h, k, a in (("r_hip", "r_knee", "r_ankle"), ("l_hip", "l_knee", "l_ankle"))]))
    scale = drawn_leg / max(motion_leg, 1e-12)
    root = rest[J["pelvis"]] + scale * (P[:, J["pelvis"]] - np.median(P[:, J["pelvis"]], axis=0))
    spine = swing(_angles(P[:, J["thorax"]] - P[:, J["pelvis"]]))
    c, s = np.cos(spine)[:, None], np.sin(spine)[:, None]
    rel = rest[list(BODY)] - rest[J["pelvis"]]                                # (k, 2)
    out[:, list(BODY)] = root[:, None] + np.stack([c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1]], -1)
    # Each leg bone: its drawn direction turned by the body's turn and its driver's swing, chained.
    for bone, driver in _DRIVERS:
        p, q = BONES[bone]
        d = rest[q] - rest[p]
        a = _angles(d) + spine + swing(theta[:, driver])
        out[:, q] = out[:, p] + np.linalg.norm(d) * np.stack([np.cos(a), np.sin(a)], -1)
    return out


def quadruped_orders(orders: np.ndarray, rest_keypoints: np.ndarray) -> np.ndarray:
    """Depth orders ``(T, P)`` (back to front) of a quadruped drawn from the side: the far legs,
    the body, the head, the near legs.

    An animal facing +x shows its right side (its right is towards the viewer), so its right legs
    are near; facing −x, its left.  Within the far and the near legs the motion's order is kept.
    """
    near = "r_" if drawn_facing(rest_keypoints) > 0 else "l_"
    front = [PART_INDEX["torso"], PART_INDEX["head"]]
    out = np.asarray(orders)
    is_near = np.array([PARTS[p].startswith(near) for p in range(len(PARTS))])[out]
    body = np.isin(out, front)
    far_legs = out[~is_near & ~body].reshape(len(out), -1)
    near_legs = out[is_near].reshape(len(out), -1)
    return np.concatenate([far_legs, np.tile(front, (len(out), 1)), near_legs], axis=1)
