"""The embedded synthetic cartoon dataset: characters x motion classes x clips.

A deterministic generator of 2D skeleton motion in pixels.  Each clip is one
character (:mod:`~nnsf.datasets.synthetic_characters`) performing one motion
class (:mod:`~nnsf.datasets.synthetic_motions`): the motion's key poses are
in-betweened with the character's timing, scaled by its amplitudes, offset by
its posture, then posed by 2D forward kinematics on its bones and stood on
the ground of a 256 x 256 canvas (x right, y down).  Motions stay in place (a
walk is a treadmill walk).

``clip_points(s, m, ...)`` is the exact ground truth of "motion m in the
style of character s".  A clip's ``variation`` draws small changes of tempo,
amplitude, start phase and posture from a generator seeded by
``(seed, motion, variation)`` only, so that the same variation of a motion
has the same content for every character; the per-point jitter
(``noise_px``) is seeded per character as well.

The character faces +x in a three-quarter view: hips and shoulders sit side
by side (right side at smaller x, as in the template), limbs swing in the
image plane.
"""
from __future__ import annotations

import zlib
from functools import lru_cache
from typing import Iterable

import numpy as np
import pandas as pd

from nnsf.datasets.contract import COLUMNS, LABEL_COLUMNS
from nnsf.datasets.synthetic_characters import (
    CHARACTER_NAMES, CHARACTERS, CharacterSpec, Palette, Proportions, Style, character,
)
from nnsf.datasets.synthetic_motions import (
    ANGLE_CHANNELS, CHANNEL_GROUP, CHANNEL_INDEX, CHANNELS, LIMITS, MOTION_SPECS, MOTIONS, REST,
    MotionSpec, interpolate, motion,
)
from nnsf.skeleton.layout import FEATURE_COLUMNS, JOINT_INDEX, JOINTS, N_JOINTS, PARENTS

__all__ = [
    "CANVAS", "FPS", "MARGIN", "GROUND_MARGIN", "ROOT_X", "VARIATION",
    "CHARACTERS", "CHARACTER_NAMES", "MOTIONS", "MOTION_SPECS", "CHANNELS",
    "CharacterSpec", "MotionSpec", "Proportions", "Style", "Palette",
    "character", "motion", "clip_variation", "pose_channels", "forward_kinematics",
    "clip_points", "generate", "describe",
]

#: Canvas (width, height) in pixels the built-in characters are sized for.
CANVAS: tuple[int, int] = (256, 256)
#: Frames per second of a clip (a loop of ``duration`` s lasts ``FPS * duration`` frames).
FPS = 24
#: Every key point stays at least this far from the canvas border (px, before jitter).
MARGIN = 10.0
#: Height of the ground line above the canvas bottom (px).
GROUND_MARGIN = 14.0
#: Horizontal place of the pelvis, as a fraction of the canvas width.
ROOT_X = 0.45

#: Spread of the per-clip random changes (standard deviations, each draw
#: clipped to two of them): relative tempo and amplitude, degrees of posture.
VARIATION: dict[str, float] = {
    "tempo": 0.06, "amplitude": 0.07, "lean": 2.0, "arm_carriage": 3.0, "knee_bend": 2.0,
    "head_tilt": 2.0,
}

_ANGLES = np.array([c in ANGLE_CHANNELS for c in CHANNELS])
_LO = np.array([LIMITS.get(c, (-np.inf, np.inf))[0] for c in CHANNELS])
_HI = np.array([LIMITS.get(c, (-np.inf, np.inf))[1] for c in CHANNELS])
_SIDE = np.array([1 if c.endswith("_r") else -1 if c.endswith("_l") else 0 for c in CHANNELS])
_LIFT = CHANNEL_INDEX["lift"]


def _stable_hash(text: str) -> int:
    # Python's hash() is salted per process; CRC32 is the same everywhere.
    return zlib.crc32(text.encode("utf-8"))


def clip_variation(motion_name: str, variation: int = 0, seed: int = 0) -> dict[str, float]:
    """The random changes of one clip: factors ``tempo`` and ``amplitude``,
    ``phase`` (start, fraction of a loop) and posture offsets in degrees
    (``lean``, ``arm_carriage``, ``knee_bend``, ``head_tilt``).

    Depends only on ``(seed, motion, variation)``, not on the character, so
    one variation of a motion has the same content for every character.
    """
    rng = np.random.default_rng([int(seed), _stable_hash(str(motion_name)), int(variation)])
    z = np.clip(rng.standard_normal(6), -2.0, 2.0)
    return {
        "tempo": float(1.0 + VARIATION["tempo"] * z[0]),
        "amplitude": float(1.0 + VARIATION["amplitude"] * z[1]),
        "phase": float(rng.uniform()),
        "lean": float(VARIATION["lean"] * z[2]),
        "arm_carriage": float(VARIATION["arm_carriage"] * z[3]),
        "knee_bend": float(abs(VARIATION["knee_bend"] * z[4])),
        "head_tilt": float(VARIATION["head_tilt"] * z[5]),
    }


@lru_cache(maxsize=4096)
def _variation_arrays(motion_name: str, variations: tuple[int, ...], seed: int):
    draws = [clip_variation(motion_name, v, seed) for v in variations]
    return {k: np.array([d[k] for d in draws]) for k in draws[0]}


@lru_cache(maxsize=256)
def _motion_tables(spec: MotionSpec):
    times, values = spec.key_table()
    return times, values, spec.wind_vector(), spec.base_pose()


def _group_vector(values: dict[str, float]) -> np.ndarray:
    return np.array([values[CHANNEL_GROUP[c]] for c in CHANNELS])


def pose_channels(character, motion_name, n_frames: int, variation=0,
                  seed: int = 0) -> np.ndarray:
    """Styled pose channels of a clip, ``(n_frames, len(CHANNELS))``.

    ``variation`` may also be a sequence of V variations, giving
    ``(V, n_frames, len(CHANNELS))``.  Angles come out in radians
    (flexion-positive, see :mod:`~nnsf.datasets.synthetic_motions`),
    ``lift`` and ``dx`` in leg lengths.  ``character`` and ``motion_name``
    may be names or specs.
    """
    st: Style = _character(character).style
    spec = motion_name if isinstance(motion_name, MotionSpec) else motion(motion_name)
    single = np.ndim(variation) == 0
    variations = (int(variation),) if single else tuple(int(v) for v in variation)
    var = _variation_arrays(spec.name, variations, int(seed))
    if st.handedness == "left":
        spec = spec.mirrored()
    times, values, wind, pivot = _motion_tables(spec)
    n = int(n_frames)

    # Loop phase of every frame, (V, n); each joint group runs behind the
    # legs by its lag.
    period = FPS * spec.duration / (st.tempo * var["tempo"])
    t = var["phase"][:, None] + np.arange(n)[None, :] / period[:, None]
    lags = _group_vector({"torso": st.lag_torso, "head": st.lag_head, "arms": st.lag_arms,
                          "forearms": st.lag_forearms, "legs": 0.0, "root": 0.0})
    phase = t.reshape(-1, 1) - lags[None, :]
    ch = interpolate(times, values, wind, phase, tension=st.tension, overshoot=st.overshoot,
                     snap=st.snap, skew=st.skew).reshape(len(variations), n, len(CHANNELS))

    # Exaggeration: scale deviations from the motion's base pose per joint
    # group and side (a bigger punch from the same guard).  A winding channel
    # keeps its full turn per loop, or the loop would not close.
    amp = _group_vector({"torso": st.amp_torso, "head": st.amp_torso, "arms": st.amp_arms,
                         "forearms": st.amp_arms, "legs": st.amp_legs, "root": st.amp_root})
    amp = amp * (1.0 + st.asymmetry * _SIDE)
    amp = np.where(wind != 0, 1.0, amp[None, :] * var["amplitude"][:, None])   # (V, C)
    ch = pivot + amp[:, None, :] * (ch - pivot)

    # Posture: constant offsets of the character plus the clip's small ones.
    offset = np.zeros((len(variations), len(CHANNELS)))
    offset[:, CHANNEL_INDEX["lean"]] = st.lean + var["lean"]
    offset[:, CHANNEL_INDEX["hunch"]] = st.hunch
    offset[:, CHANNEL_INDEX["nod"]] = st.head_tilt + var["head_tilt"]
    for side, sign in (("r", 1.0), ("l", -1.0)):
        offset[:, CHANNEL_INDEX[f"knee_{side}"]] = st.knee_bend + var["knee_bend"]
        offset[:, CHANNEL_INDEX[f"elb_{side}"]] = st.elbow_bend
        offset[:, CHANNEL_INDEX[f"sho_{side}"]] = st.arm_carriage + var["arm_carriage"]
        offset[:, CHANNEL_INDEX[f"hip_{side}"]] = sign * st.stance / 2
    ch = ch + offset[:, None, :]

    if spec.bounces and st.bounce:
        beat = 2 * np.pi * spec.bounces * t
        ch[..., _LIFT] += st.bounce * st.amp_root * 0.5 * (1.0 - np.cos(beat))
    ch = np.where(wind != 0, ch, np.clip(ch, _LO, _HI))
    ch[..., _ANGLES] = np.deg2rad(ch[..., _ANGLES])
    return ch[0] if single else ch


def _dir(alpha: np.ndarray) -> np.ndarray:
    """Unit vectors ``(n, 2)`` at image angles ``alpha`` (0: +x, pi/2: +y = down)."""
    return np.stack([np.cos(alpha), np.sin(alpha)], axis=-1)


# Hips and shoulders droop a little below horizontal, as in the template.
_HIP_DROOP = np.deg2rad(4.0)
_SHOULDER_DROOP = np.deg2rad(3.0)


def forward_kinematics(proportions: Proportions, channels: np.ndarray,
                       canvas: tuple[int, int] = CANVAS) -> np.ndarray:
    """Pose ``(n, C)`` channels (radians, leg units) -> key points ``(n, 17, 2)`` px.

    Bone lengths are ``proportions`` scaled by ``min(canvas) / 256``.  The
    pelvis sits at ``ROOT_X`` of the canvas width (plus ``dx``) and at the
    height where the lower ankle touches the ground line (minus ``lift``).
    """
    channels = np.asarray(channels, dtype=float)
    scale = min(canvas) / 256.0
    P = proportions
    c = {name: channels[:, i] for i, name in enumerate(CHANNELS)}
    half_pi = np.pi / 2

    # Absolute image angles of every bone, down the tree.
    a_spine = -half_pi + c["lean"]
    a_thorax = a_spine + c["hunch"]
    a_neck = a_thorax + 0.5 * c["nod"]
    a_head = a_thorax + c["nod"]
    # Hips and shoulders are side by side in the three-quarter view: a
    # forward bend turns the body about the axis through them, so the
    # lateral bones keep their image direction.
    a_pelvis = np.zeros_like(a_spine)
    a_thigh = {s: half_pi - c[f"hip_{s}"] for s in "rl"}
    a_shin = {s: a_thigh[s] + c[f"knee_{s}"] for s in "rl"}
    a_upper = {s: a_thorax + np.pi - c[f"sho_{s}"] for s in "rl"}
    a_fore = {s: a_upper[s] - c[f"elb_{s}"] for s in "rl"}

    length = {
        "r_hip": P.hip_width, "l_hip": P.hip_width, "r_knee": P.thigh, "l_knee": P.thigh,
        "r_ankle": P.shin, "l_ankle": P.shin, "spine": P.spine, "thorax": P.chest,
        "neck": P.neck, "head_top": P.head, "l_shoulder": P.shoulder_width,
        "r_shoulder": P.shoulder_width, "l_elbow": P.upper_arm, "r_elbow": P.upper_arm,
        "l_wrist": P.forearm, "r_wrist": P.forearm,
    }
    angle = {
        "r_hip": a_pelvis + np.pi - _HIP_DROOP, "l_hip": a_pelvis + _HIP_DROOP,
        "r_knee": a_thigh["r"], "l_knee": a_thigh["l"],
        "r_ankle": a_shin["r"], "l_ankle": a_shin["l"],
        "spine": a_spine, "thorax": a_thorax, "neck": a_neck, "head_top": a_head,
        "r_shoulder": a_pelvis + np.pi - _SHOULDER_DROOP,
        "l_shoulder": a_pelvis + _SHOULDER_DROOP,
        "r_elbow": a_upper["r"], "l_elbow": a_upper["l"],
        "r_wrist": a_fore["r"], "l_wrist": a_fore["l"],
    }
    n = channels.shape[0]
    pts = np.zeros((n, N_JOINTS, 2))
    for j in range(1, N_JOINTS):
        name = JOINTS[j]
        pts[:, j] = pts[:, PARENTS[j]] + scale * length[name] * _dir(angle[name])

    # Stand on the ground: the lower ankle touches it, unless lifted.
    ground = canvas[1] - GROUND_MARGIN * scale
    feet = pts[:, [JOINT_INDEX["r_ankle"], JOINT_INDEX["l_ankle"]], 1].max(axis=1)
    leg = scale * P.leg
    root_y = ground - feet - c["lift"] * leg
    # Most actions reach forward (+x), so the body stands a little left of centre.
    root_x = ROOT_X * canvas[0] + c["dx"] * leg
    pts += np.stack([root_x, root_y], axis=-1)[:, None, :]
    return pts


def _character(c) -> CharacterSpec:
    return c if isinstance(c, CharacterSpec) else character(c)


def clip_points(character, motion, n_frames: int, variation: int = 0, seed: int = 0,
                noise_px: float = 0.0, canvas: tuple[int, int] = CANVAS) -> np.ndarray:
    """Key points of one clip, ``(n_frames, 17, 2)`` in pixels (x right, y down).

    ``character``: a name or a :class:`CharacterSpec`; ``motion``: a name in
    :data:`MOTIONS` or a :class:`MotionSpec`.  ``noise_px`` adds Gaussian
    jitter of that standard deviation (px) to every coordinate.  Deterministic
    in its arguments.  Raises ``ValueError`` for unknown names.
    """
    char = _character(character)
    spec = motion if isinstance(motion, MotionSpec) else _motion(motion)
    _check_sizes(n_frames, 1, noise_px)
    pts = forward_kinematics(char.proportions, pose_channels(char, spec, n_frames, variation, seed),
                             canvas)
    return _jitter(pts, char, spec, variation, seed, noise_px)


def _check_sizes(frames, clips, noise_px) -> None:
    if int(frames) < 1 or int(clips) < 1:
        raise ValueError(f"frames and clips must be >= 1, got {frames} and {clips}")
    if not noise_px >= 0:
        raise ValueError(f"noise_px must be >= 0, got {noise_px}")


def _jitter(pts, char: CharacterSpec, spec: MotionSpec, variation: int, seed: int,
            noise_px: float) -> np.ndarray:
    # Own stream per (character, motion, variation): the same clip gets the
    # same jitter whether it is made alone or inside generate().
    if noise_px <= 0:
        return pts
    rng = np.random.default_rng([int(seed), _stable_hash(char.name), _stable_hash(spec.name),
                                 int(variation), 1])
    return pts + rng.normal(0.0, noise_px, size=pts.shape)


def _motion(name) -> MotionSpec:
    # clip_points's argument ``motion`` hides the module-level function.
    return motion(name)


def _select_characters(characters) -> tuple[CharacterSpec, ...]:
    if isinstance(characters, (int, np.integer)):
        if not 1 <= characters <= len(CHARACTERS):
            raise ValueError(f"characters must be between 1 and {len(CHARACTERS)}, got {characters}")
        return CHARACTERS[: int(characters)]
    chars = tuple(_character(c) for c in characters)
    names = [c.name for c in chars]
    if len(set(names)) != len(names) or not names:
        raise ValueError(f"characters must be distinct and at least one, got {names}")
    return chars


def _select_motions(motions) -> tuple[MotionSpec, ...]:
    if motions is None:
        return MOTION_SPECS
    return tuple(m if isinstance(m, MotionSpec) else motion(m) for m in motions)


def generate(characters: int | Iterable = 9, clips_per_cell: int = 4, frames: int = 32,
             noise_px: float = 0.4, seed: int = 0, motions: Iterable | None = None,
             canvas: tuple[int, int] = CANVAS) -> pd.DataFrame:
    """The synthetic dataset as a contract table (``nnsf.datasets.contract.COLUMNS``).

    ``characters``: the first N built-in characters, or names/specs;
    ``motions``: all 15 by default.  One clip per (character, motion,
    variation) with ``frames`` rows, clip id ``"{character}-{motion}-{variation:02d}"``,
    coordinates in pixels.  Rows are ordered by character, motion, variation, frame.
    """
    chars = _select_characters(characters)
    specs = _select_motions(motions)
    _check_sizes(frames, clips_per_cell, noise_px)
    frames, variations = int(frames), tuple(range(int(clips_per_cell)))
    blocks, clip_ids, char_names, motion_names = [], [], [], []
    for ch in chars:
        # One forward-kinematics pass per character over all its clips.
        channels = np.stack([pose_channels(ch, spec, frames, variations, seed) for spec in specs])
        pts = forward_kinematics(ch.proportions, channels.reshape(-1, len(CHANNELS)), canvas)
        pts = pts.reshape(len(specs), len(variations), frames, N_JOINTS, 2)
        for m, spec in enumerate(specs):
            for v in variations:
                blocks.append(_jitter(pts[m, v], ch, spec, v, seed, noise_px))
                clip_ids.append(f"{ch.name}-{spec.name}-{v:02d}")
                char_names.append(ch.name)
                motion_names.append(spec.name)
    coords = np.concatenate(blocks).reshape(-1, len(FEATURE_COLUMNS))
    table = pd.DataFrame(coords, columns=list(FEATURE_COLUMNS))
    labels = pd.DataFrame({
        "clip": np.repeat(clip_ids, frames),
        "frame": np.tile(np.arange(frames, dtype=np.int64), len(clip_ids)),
        "character": np.repeat(char_names, frames),
        "motion": np.repeat(motion_names, frames),
    })
    return pd.concat([labels, table], axis=1).loc[:, list(COLUMNS)]


def describe(characters: int | Iterable = 9, clips_per_cell: int = 4, frames: int = 32,
             noise_px: float = 0.4, seed: int = 0, motions: Iterable | None = None,
             canvas: tuple[int, int] = CANVAS) -> dict:
    """JSON-ready ground truth of a :func:`generate` call with the same arguments.

    Holds the generation parameters, the canvas and timing constants, the
    pose channels and their limits, every motion's key poses and every
    character's proportions, style and palette.
    """
    chars = _select_characters(characters)
    specs = _select_motions(motions)
    return {
        "generator": "nnsf.datasets.synthetic",
        "parameters": {
            "characters": len(chars), "clips_per_cell": int(clips_per_cell),
            "frames": int(frames), "noise_px": float(noise_px), "seed": int(seed),
        },
        "canvas": [int(canvas[0]), int(canvas[1])],
        "fps": FPS,
        "margin_px": MARGIN,
        "ground_y": float(canvas[1] - GROUND_MARGIN * min(canvas) / 256.0),
        "root_x": float(ROOT_X * canvas[0]),
        "units": {
            "points": "pixels, image axes (x right, y down)",
            "proportions": "pixels at a 256 x 256 canvas (scaled by min(canvas) / 256)",
            "angles": "degrees, flexion-positive, character facing +x",
            "lift, dx, bounce": "fractions of the character's leg length",
            "lags, key times": "fractions of a motion loop",
            "duration_s": "seconds per loop at tempo 1",
        },
        "joints": list(JOINTS),
        "label_columns": list(LABEL_COLUMNS),
        "clip_id": "{character}-{motion}-{variation:02d}",
        "channels": list(CHANNELS),
        "rest_pose": {c: REST[c] for c in CHANNELS},
        "limits": {c: list(v) for c, v in LIMITS.items()},
        "variation": dict(VARIATION),
        "motions": [m.to_dict() for m in specs],
        "characters": [c.to_dict() for c in chars],
    }
