"""Driving a drawn character from a motion (docs/method.md §12; inverse unification §4).

A motion is any 17-point clip ``(T, 17, 2)``: unified template features
(``data/features/features.csv``), pixel key points, a translated clip, or a
projected BVH clip.  :func:`retarget` puts it on a character:

* bone directions come from the motion, frame by frame (with
  ``arms="drawing"`` the arms keep their drawn directions, turned by the motion's swing);
* bone lengths come from the drawing;
* the root is anchored at the drawing's pelvis: it moves by
  ``s · (root(t) − median root)``, with ``s`` the ratio of the drawing's to
  the motion's leg-plus-torso length (the body scale).

For limbs and head this is the composition ``W_char⁻¹ ∘ W_motion`` of two
template-unification maps (``W = D⁻¹ R D``, :mod:`nnsf.skeleton.unify`),
each fitted with :func:`nnsf.skeleton.character_scale`: the motion's on its
own frames, the character's on its rest pose, less the motion's
foreshortening; the drawn torso moves rigidly (:func:`retarget`).
Coordinates are pixels, x right, y down.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from nnsf.datasets import contract
from nnsf.errors import InputError
from nnsf.params import ARM_CHOICES, HEAD_CHOICES, LEG_CHOICES
from nnsf.reshape.quadruped import facing as motion_facing, knees_ahead, retarget_quadruped, swing
from nnsf.reshape.rig import distance_transform, sample
from nnsf.skeleton import BONES, JOINT_INDEX, JOINTS, N_JOINTS, character_scale, to_points
from nnsf.skeleton.layout import FEATURE_COLUMNS


def check_finite(points: np.ndarray, source="motion", frames=None) -> np.ndarray:
    """Return ``points`` ``(T, 17, 2)`` as float64 or raise :class:`InputError` naming the first bad frame.

    ``frames`` ``(T,)`` are the frame numbers to report (default 0..T−1).
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 3 or P.shape[1:] != (N_JOINTS, 2):
        raise InputError(source, "points", f"a clip of shape (frames, {N_JOINTS}, 2)", f"shape {P.shape}")
    if len(P) == 0:
        raise InputError(source, "frames", "at least one frame", "none")
    bad = ~np.isfinite(P).all(axis=2)
    if bad.any():
        t, j = np.argwhere(bad)[0]
        n_bad = int(bad.any(axis=1).sum())
        frame = int(frames[t]) if frames is not None else int(t)
        raise InputError(source, f"frame {frame}", "finite coordinates for all 17 key points",
                         f"NaN/Inf at {JOINTS[j]} ({n_bad} bad frame{'s' if n_bad > 1 else ''} in all)")
    return P


#: Key points moved as one rigid body by :func:`retarget` (turned with the spine), so the drawn torso keeps its shape;
#: the neck is the base of the head in the drawings, so it moves with the torso
#: and only head_top follows the motion (the head turns about the neck).
TORSO = tuple(JOINT_INDEX[j] for j in (
    "pelvis", "r_hip", "l_hip", "spine", "thorax", "neck", "l_shoulder", "r_shoulder"))

#: Key points ``legs="torso"`` moves with the torso: the knees and ankles (the hips are the torso's).
LEGS = tuple(JOINT_INDEX[j] for j in ("r_knee", "r_ankle", "l_knee", "l_ankle"))

#: The arm bones (parent, child) that ``arms="drawing"`` turns about their drawn direction.
ARM_BONES = tuple((JOINT_INDEX[p], JOINT_INDEX[c]) for p, c in (
    ("l_shoulder", "l_elbow"), ("l_elbow", "l_wrist"), ("r_shoulder", "r_elbow"), ("r_elbow", "r_wrist")))


def drawn_from_side(mask: np.ndarray, keypoints: np.ndarray, share: float = 0.25) -> bool:
    """Whether a biped is drawn from the side: its torso drawn at least ``share`` of its length wide
    (the silhouette's depth at the spine; a stick figure's is not) and its two shoulders and two hips
    each less than ``share`` of that width apart (docs/method.md §12)."""
    kp = np.asarray(keypoints, dtype=np.float64)
    J = JOINT_INDEX
    length = float(np.linalg.norm(kp[J["thorax"]] - kp[J["pelvis"]]))
    width = 2.0 * float(sample(distance_transform(mask), kp[J["spine"]]))
    gap = max(np.linalg.norm(kp[J["l_" + j]] - kp[J["r_" + j]]) for j in ("shoulder", "hip"))
    return width >= share * length and gap < share * width


def seen_from_side(ch) -> bool:
    """Whether a character's motion is seen from the side, the view it is drawn in: a quadruped, a biped
    :func:`drawn_from_side`, or one whose YAML says which way it faces (a three-quarter body with its head
    and feet in profile: seen from the front, a punch forwards would go out sideways, often behind it)."""
    return ch.body == "quadruped" or ch.facing is not None or drawn_from_side(ch.mask, ch.keypoints)


def biped_facing(mask: np.ndarray, keypoints: np.ndarray, share: float = 0.1) -> float:
    """Which way a biped drawn from the side (:func:`drawn_from_side`) faces: +1 towards +x, −1, 0 for
    any other drawing or if it cannot tell.  Feet point forwards (the mean offset of the drawn pixels
    below each ankle, within half a shin), failing that bent knees do; either counts beyond
    ``share`` of the mean shin length."""
    if not drawn_from_side(mask, keypoints):
        return 0.0
    m = np.asarray(mask, dtype=bool)
    kp = np.asarray(keypoints, dtype=np.float64)
    J = JOINT_INDEX
    legs = (("r_hip", "r_knee", "r_ankle"), ("l_hip", "l_knee", "l_ankle"))
    shin = float(np.mean([np.linalg.norm(kp[J[a]] - kp[J[k]]) for _, k, a in legs]))
    ys, xs = np.nonzero(m)
    ahead = 0.0
    for _, _, a in legs:
        x, y = kp[J[a]]
        near = (ys > y) & ((xs - x) ** 2 + (ys - y) ** 2 <= (0.5 * shin) ** 2)
        ahead += float(xs[near].mean() - x) if near.any() else 0.0
    if abs(ahead) < share * shin:
        ahead = knees_ahead(kp[None])
    return float(np.sign(ahead)) if abs(ahead) >= share * shin else 0.0


def retarget(points: np.ndarray, rest_keypoints: np.ndarray, source="motion", frames=None,
             arms: str = "motion", body: str = "biped", head: str = "motion",
             facing: float = 0.0, legs: str = "motion") -> np.ndarray:
    """Map a motion ``(T, 17, 2)`` (any units) onto a character: ``(T, 17, 2)`` pixels (docs/method.md §12).

    ``rest_keypoints`` ``(17, 2)``: the drawing's key points.  The root is the drawing's pelvis plus
    the motion's root displacement scaled by the body-scale ratio (:func:`nnsf.skeleton.character_scale`);
    the torso (:data:`TORSO`) is the drawn one, rigid, turned by the motion's spine angle (ARAP cannot
    meet handles that are not a similarity of the drawing); every other bone takes the motion's
    direction at the drawing's length, chained from its parent, without the motion's foreshortening.

    * ``arms="drawing"``: each arm bone (:data:`ARM_BONES`) keeps its drawn direction turned by the
      motion's swing about the clip's mean direction (an unchanged motion arm gives the drawn pose).
    * ``head="torso"``: head_top moves with the drawn torso (a head drawn as the top of one shape).
    * ``legs="torso"``: the knees and ankles move with the drawn torso, in their drawn pose (a figure
      drawn without legs, or cut off at the waist: the motion's legs would swing what is not there).
    * ``body="quadruped"``: :func:`nnsf.reshape.quadruped.retarget_quadruped` (``arms``, ``head`` and
      ``legs`` do not apply).
    * ``facing``: the drawing's (:func:`biped_facing`; +1 towards +x, −1, 0 unknown); a biped motion
      facing the other way is mirrored, so a figure drawn from the side does not walk backwards.

    A NaN/Inf frame or a bone of zero median length raises :class:`InputError` naming ``source``
    and the frame / bone.
    """
    P = check_finite(points, source, frames)
    if arms not in ARM_CHOICES:
        raise InputError(source, "arms", f"one of {', '.join(ARM_CHOICES)}", repr(arms))
    if head not in HEAD_CHOICES:
        raise InputError(source, "head", f"one of {', '.join(HEAD_CHOICES)}", repr(head))
    if legs not in LEG_CHOICES:
        raise InputError(source, "legs", f"one of {', '.join(LEG_CHOICES)}", repr(legs))
    rest = np.asarray(rest_keypoints, dtype=np.float64)
    if body == "quadruped":
        return retarget_quadruped(P, rest)
    if facing * motion_facing(P) < 0:
        P = P.copy()
        P[..., 0] *= -1.0
    J = JOINT_INDEX
    mid = 0.5 * (P[:, J["pelvis"]] + P[:, J["thorax"]])
    if min(np.median(np.linalg.norm(P[:, J["spine"]] - P[:, k], axis=1)) for k in (J["pelvis"], J["thorax"])) <= 0:
        # A skeleton with no joint between pelvis and chest puts the spine on one of them: its middle
        # then (the torso moves as one piece, so the spine point only anchors the body's scale).
        P = P.copy()
        P[:, J["spine"]] = mid
    try:
        mot = character_scale(P)
        drawn = character_scale(rest[None])
    except ValueError as exc:
        raise InputError(source, "bones", "bones of non-zero length", reason=str(exc)) from None
    out = np.empty_like(P)
    out[:, 0] = rest[0] + (mot.root_scale / drawn.root_scale) * (P[:, 0] - mot.root_ref)
    vec = P[:, [c for _, c in BONES]] - P[:, [p for p, _ in BONES]]  # (T, 16, 2)
    unit = vec / np.maximum(np.linalg.norm(vec, axis=2), 1e-12)[..., None]
    if arms == "drawing":
        unit = _swing_about_drawing(unit, rest)
    drawn_len = np.linalg.norm(rest[[c for _, c in BONES]] - rest[[p for p, _ in BONES]], axis=1)
    placed = np.zeros(N_JOINTS, dtype=bool)
    up_m = P[:, J["thorax"]] - P[:, J["pelvis"]]
    up_d = rest[J["thorax"]] - rest[J["pelvis"]]
    ang = np.arctan2(up_m[:, 1], up_m[:, 0]) - np.arctan2(up_d[1], up_d[0])
    u = up_d / np.linalg.norm(up_d)
    n = np.array([-u[1], u[0]])
    rigid = TORSO + ((JOINT_INDEX["head_top"],) if head == "torso" else ()) + (LEGS if legs == "torso" else ())
    rel = rest[list(rigid)] - rest[0]  # (k, 2)
    local = (rel @ u)[:, None] * u + (rel @ n)[:, None] * n
    c, s_ = np.cos(ang)[:, None], np.sin(ang)[:, None]
    rot = np.stack([c * local[..., 0] - s_ * local[..., 1], s_ * local[..., 0] + c * local[..., 1]], -1)
    out[:, list(rigid)] = out[:, :1] + rot
    placed[list(rigid)] = True
    for b, (p, c) in enumerate(BONES):
        if not placed[c]:
            out[:, c] = out[:, p] + unit[:, b] * drawn_len[b]
    return out


def _swing_about_drawing(unit: np.ndarray, rest: np.ndarray) -> np.ndarray:
    """Bone unit vectors ``(T, 16, 2)`` with the arm bones' replaced by the drawn direction turned by the swing.

    For each bone of :data:`ARM_BONES`: the motion's angle in each frame minus the angle of its mean
    unit vector (a circular mean: it is defined for any clip whose arm does not point every way
    equally), added to the drawn bone's angle in ``rest`` ``(17, 2)``.
    """
    out = unit.copy()
    bones = [BONES.index(b) for b in ARM_BONES]
    u = unit[:, bones]                                           # (T, 4, 2)
    d = rest[[c for _, c in ARM_BONES]] - rest[[p for p, _ in ARM_BONES]]
    ang = np.arctan2(d[:, 1], d[:, 0]) + swing(np.arctan2(u[..., 1], u[..., 0]))   # (T, 4)
    out[:, bones] = np.stack([np.cos(ang), np.sin(ang)], -1)
    return out


def read_motion(path, clip: str | None = None) -> tuple[str, np.ndarray, np.ndarray]:
    """One clip of a feature-matrix CSV (contract layout): ``(name, frames (T,), points (T, 17, 2))``.

    ``clip`` None takes the first clip (sorted by name).  NaN or missing
    coordinates raise :class:`InputError` naming the file, the clip and the
    frame (before the contract's own checks, which name only the row).
    """
    path = Path(path)
    table = contract.read_csv(path)
    missing = [c for c in contract.COLUMNS if c not in table.columns]
    if missing:
        raise InputError(path, missing[0], "a column of the feature-matrix contract (clip, frame, "
                         "character, motion, x1..y17)")
    clips = sorted(table["clip"].astype(str).unique())
    if not clips:
        raise InputError(path, "rows", "at least one frame")
    name = clips[0] if clip is None else str(clip)
    if name not in clips:
        raise InputError(path, "clip", f"one of the file's clips ({', '.join(clips[:8])}"
                         f"{', ...' if len(clips) > 8 else ''})", name)
    rows = table[table["clip"].astype(str) == name]
    vals = rows.loc[:, list(FEATURE_COLUMNS)].apply(pd.to_numeric, errors="coerce").to_numpy(float)
    frames = pd.to_numeric(rows["frame"], errors="coerce").to_numpy()
    order = np.argsort(frames, kind="stable")
    check_finite(vals[order].reshape(-1, N_JOINTS, 2), f"{path} (clip {name})", frames[order])
    table = contract.validate(rows, path)
    return name, table["frame"].to_numpy(), to_points(contract.features(table))
