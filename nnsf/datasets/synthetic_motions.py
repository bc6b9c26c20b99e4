"""The 15 motion classes of the synthetic cartoon set, as looping key poses.

A motion is pose-to-pose animation, the way a cartoon animator blocks it: a
few key poses at fixed times of a loop, in-betweened by a cubic curve.  Each
key pose sets *pose channels* (see :data:`CHANNELS`):

* joint angles in degrees, flexion-positive for a character facing +x in
  image axes (y down): ``lean`` tilts the torso forward, ``hunch`` bends the
  chest forward on the spine, ``nod`` drops the head, ``hip_*`` swings a thigh
  forward from hanging straight down, ``knee_*`` bends a shin back,
  ``sho_*`` swings an upper arm forward relative to the torso (180 is
  overhead), ``elb_*`` bends a forearm forward;
* ``lift``: the pelvis raised above ground contact, as a fraction of the
  character's leg length (jumps, hops); ``dx``: the pelvis shifted forward,
  same unit.

Every motion loops, one-shot actions included (stand, act, return to stand),
so a clip may start anywhere in the cycle and have any length.  The character
only chooses the timing of the in-betweens (tension, overshoot, snap, skew),
the phase lag between joint groups and amplitudes; see
:mod:`nnsf.datasets.synthetic_characters`.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Pose channels in column order (angles in degrees in the key poses).
CHANNELS: tuple[str, ...] = (
    "lean", "hunch", "nod",
    "hip_r", "knee_r", "hip_l", "knee_l",
    "sho_r", "elb_r", "sho_l", "elb_l",
    "lift", "dx",
)
CHANNEL_INDEX = {c: i for i, c in enumerate(CHANNELS)}
#: Channels holding angles (the rest are lengths in leg units).
ANGLE_CHANNELS: tuple[str, ...] = CHANNELS[:11]

#: Joint group of every channel: amplitude and phase lag act per group.
CHANNEL_GROUP: dict[str, str] = {
    "lean": "torso", "hunch": "torso", "nod": "head",
    "hip_r": "legs", "knee_r": "legs", "hip_l": "legs", "knee_l": "legs",
    "sho_r": "arms", "sho_l": "arms", "elb_r": "forearms", "elb_l": "forearms",
    "lift": "root", "dx": "root",
}

#: The neutral standing pose; amplitudes scale deviations from it.
REST: dict[str, float] = {c: 0.0 for c in CHANNELS} | {
    "knee_r": 4.0, "knee_l": 4.0, "elb_r": 10.0, "elb_l": 10.0,
}

#: Anatomical limits applied after styling, (low, high).  A channel that winds
#: (an arm circling) is not limited.
LIMITS: dict[str, tuple[float, float]] = {
    "lean": (-35.0, 90.0), "hunch": (-30.0, 60.0), "nod": (-45.0, 45.0),
    "hip_r": (-70.0, 120.0), "hip_l": (-70.0, 120.0),
    "knee_r": (0.0, 150.0), "knee_l": (0.0, 150.0),
    "sho_r": (-100.0, 190.0), "sho_l": (-100.0, 190.0),
    "elb_r": (-10.0, 150.0), "elb_l": (-10.0, 150.0),
    "lift": (0.0, 0.5), "dx": (-0.3, 0.3),
}


@dataclass(frozen=True)
class KeyPose:
    """One key pose: a loop time in [0, 1) and the channels it sets.

    Channels it leaves out take the motion's ``base`` value, then :data:`REST`.
    """

    time: float
    pose: tuple[tuple[str, float], ...]


@dataclass(frozen=True)
class MotionSpec:
    """A looping parametric motion class.

    Attributes
    ----------
    name, description : str
        Class label and a one-line account of what the figure does.
    duration : float
        Seconds per loop at tempo 1 (frames are sampled at :data:`FPS`).
    keys : tuple of KeyPose
        Key poses in increasing time order, at least two.
    base : tuple of (channel, value)
        Values shared by every key pose of this motion (e.g. a fighting
        stance) unless a key sets them; also the pivot of amplitude styles.
    wind : tuple of (channel, degrees)
        Channels that gain this many degrees per loop (a windmill arm), so
        the loop is periodic up to a full turn.
    bounces : int
        Bounces of the character's bounce style per loop (0: none).
    """

    name: str
    description: str
    duration: float
    keys: tuple[KeyPose, ...]
    base: tuple[tuple[str, float], ...] = ()
    wind: tuple[tuple[str, float], ...] = ()
    bounces: int = 0

    def __post_init__(self):
        times = [k.time for k in self.keys]
        if len(times) < 2 or times != sorted(times) or times[0] < 0 or times[-1] >= 1:
            raise ValueError(f"motion {self.name}: key times must increase within [0, 1)")
        for ch, _ in self.base + self.wind + tuple(p for k in self.keys for p in k.pose):
            if ch not in CHANNEL_INDEX:
                raise ValueError(f"motion {self.name}: unknown channel {ch!r}")

    def key_table(self) -> tuple[np.ndarray, np.ndarray]:
        """Key times ``(K,)`` and full key poses ``(K, C)`` (degrees / leg units)."""
        base = REST | dict(self.base)
        times = np.array([k.time for k in self.keys])
        values = np.array([[(base | dict(k.pose))[c] for c in CHANNELS] for k in self.keys])
        return times, values

    def base_pose(self) -> np.ndarray:
        """The motion's base pose ``(C,)``: :data:`REST` updated with ``base``.

        Amplitude styles scale every key's deviation from it.
        """
        base = REST | dict(self.base)
        return np.array([base[c] for c in CHANNELS])

    def wind_vector(self) -> np.ndarray:
        """Per-loop gain of every channel, ``(C,)`` degrees (0 for most)."""
        w = np.zeros(len(CHANNELS))
        for ch, deg in self.wind:
            w[CHANNEL_INDEX[ch]] = deg
        return w

    def mirrored(self) -> "MotionSpec":
        """The same motion performed with the other side (``_r`` and ``_l`` swapped)."""
        return MotionSpec(
            name=self.name, description=self.description, duration=self.duration,
            keys=tuple(KeyPose(k.time, _swap(k.pose)) for k in self.keys),
            base=_swap(self.base), wind=_swap(self.wind), bounces=self.bounces,
        )

    def to_dict(self) -> dict:
        """JSON-ready description."""
        return {
            "name": self.name, "description": self.description, "duration_s": self.duration,
            "bounces": self.bounces, "base": dict(self.base), "wind": dict(self.wind),
            "keys": [{"time": k.time, **dict(k.pose)} for k in self.keys],
        }


def _other_side(channel: str) -> str:
    if channel.endswith("_r"):
        return channel[:-2] + "_l"
    if channel.endswith("_l"):
        return channel[:-2] + "_r"
    return channel


def _swap(pairs) -> tuple[tuple[str, float], ...]:
    return tuple((_other_side(c), v) for c, v in pairs)


def _key(time: float, **pose: float) -> KeyPose:
    return KeyPose(time, tuple(pose.items()))


def _mirror(time: float, key: KeyPose) -> KeyPose:
    """``key`` on the other side, at ``time`` (the second half of a gait)."""
    return KeyPose(time, _swap(key.pose))


# --- the 15 motion classes ---------------------------------------------------------------

_walk0 = _key(0.0, lean=3, hip_r=24, knee_r=4, hip_l=-18, knee_l=14,
              sho_r=-22, elb_r=12, sho_l=24, elb_l=30)
_walk1 = _key(0.25, lean=3, hip_r=0, knee_r=8, hip_l=10, knee_l=50,
              sho_r=0, elb_r=15, sho_l=0, elb_l=15)

_run0 = _key(0.0, lean=14, hip_r=32, knee_r=14, hip_l=-24, knee_l=45,
             sho_r=-45, elb_r=80, sho_l=50, elb_l=95, lift=0.0)
_run1 = _key(0.13, lean=14, hip_r=4, knee_r=32, hip_l=20, knee_l=110,
             sho_r=-5, elb_r=85, sho_l=10, elb_l=90, lift=0.0)
_run2 = _key(0.3, lean=14, hip_r=-32, knee_r=40, hip_l=50, knee_l=80,
             sho_r=40, elb_r=90, sho_l=-40, elb_l=80, lift=0.1)

_march0 = _key(0.0, lean=-3, nod=-4, hip_r=75, knee_r=88, hip_l=0, knee_l=0,
               sho_r=-40, elb_r=0, sho_l=55, elb_l=0)
_march1 = _key(0.25, lean=-3, nod=-4, hip_r=0, knee_r=0, hip_l=0, knee_l=0,
               sho_r=0, elb_r=0, sho_l=0, elb_l=0)

_skip0 = _key(0.0, hip_r=16, knee_r=10, hip_l=-16, knee_l=30,
              sho_r=-25, elb_r=30, sho_l=30, elb_l=30, lift=0.0)
_skip1 = _key(0.2, hip_r=-6, knee_r=6, hip_l=65, knee_l=95,
              sho_r=65, elb_r=60, sho_l=-35, elb_l=25, lift=0.18)
_skip2 = _key(0.36, hip_r=2, knee_r=28, hip_l=35, knee_l=60,
              sho_r=30, elb_r=40, sho_l=-10, elb_l=25, lift=0.0)

MOTION_SPECS: tuple[MotionSpec, ...] = (
    MotionSpec(
        "walk", "treadmill walk: legs and opposite arms swing, one step per half loop",
        duration=1.1, bounces=2,
        keys=(_walk0, _walk1, _mirror(0.5, _walk0), _mirror(0.75, _walk1)),
    ),
    MotionSpec(
        "run", "treadmill run: forward lean, pumping bent arms, a flight phase per step",
        duration=0.72, bounces=2,
        keys=(_run0, _run1, _run2, _mirror(0.5, _run0), _mirror(0.63, _run1),
              _mirror(0.8, _run2)),
    ),
    MotionSpec(
        "march", "upright march on the spot: knees raised high, straight arms swinging",
        duration=1.2, bounces=2,
        keys=(_march0, _march1, _mirror(0.5, _march0), _mirror(0.75, _march1)),
    ),
    MotionSpec(
        "skip", "skipping: a step and a hop on each foot, the other knee up",
        duration=0.95, bounces=0,
        keys=(_skip0, _skip1, _skip2, _mirror(0.5, _skip0), _mirror(0.7, _skip1),
              _mirror(0.86, _skip2)),
    ),
    MotionSpec(
        "jump", "crouch, spring up with arms thrown overhead, tuck, land and absorb",
        duration=1.25, bounces=0,
        keys=(
            _key(0.0),
            _key(0.18, lean=32, nod=-10, hip_r=50, knee_r=95, hip_l=50, knee_l=95,
                 sho_r=-45, sho_l=-45),
            _key(0.3, lean=2, hip_r=2, knee_r=4, hip_l=2, knee_l=4,
                 sho_r=165, elb_r=5, sho_l=165, elb_l=5, lift=0.06),
            _key(0.42, lean=6, hip_r=40, knee_r=75, hip_l=40, knee_l=75,
                 sho_r=140, elb_r=20, sho_l=140, elb_l=20, lift=0.3),
            _key(0.55, lean=10, hip_r=12, knee_r=20, hip_l=12, knee_l=20,
                 sho_r=90, sho_l=90, lift=0.0),
            _key(0.66, lean=28, hip_r=45, knee_r=85, hip_l=45, knee_l=85,
                 sho_r=45, sho_l=45),
            _key(0.86),
        ),
    ),
    MotionSpec(
        "kick", "front kick with the right leg from a guard: chamber, snap out, re-chamber",
        duration=1.1, bounces=0,
        base=(("sho_r", 35), ("elb_r", 95), ("sho_l", 35), ("elb_l", 95), ("knee_l", 8)),
        keys=(
            _key(0.0),
            _key(0.2, lean=-8, hip_r=70, knee_r=110),
            _key(0.36, lean=-20, hip_r=95, knee_r=4, sho_r=-30, elb_r=30, sho_l=45, elb_l=100),
            _key(0.52, lean=-8, hip_r=70, knee_r=110),
            _key(0.72),
        ),
    ),
    MotionSpec(
        "punch", "boxing stance: right cross, back to guard, left jab, back to guard",
        duration=0.95, bounces=2,
        base=(("lean", 10), ("hip_r", -12), ("knee_r", 22), ("hip_l", 16), ("knee_l", 22),
              ("sho_r", 45), ("elb_r", 115), ("sho_l", 50), ("elb_l", 110)),
        keys=(
            _key(0.0),
            _key(0.18, lean=24, sho_r=88, elb_r=4, sho_l=35, elb_l=125, dx=0.04),
            _key(0.38),
            _key(0.56, lean=16, sho_l=88, elb_l=4, dx=0.02),
            _key(0.76),
        ),
    ),
    MotionSpec(
        "wave", "right arm raised, forearm waving to and fro, head tilted",
        duration=1.0, bounces=1,
        base=(("sho_r", 135), ("nod", -6), ("sho_l", 0), ("elb_l", 12)),
        keys=(
            _key(0.0, elb_r=0, lean=2),
            _key(0.25, elb_r=65, lean=-2),
            _key(0.5, elb_r=0, lean=2),
            _key(0.75, elb_r=65, lean=-2),
        ),
    ),
    MotionSpec(
        "bow", "formal bow: right hand to the belly, torso folds forward, holds, rises",
        duration=1.5, bounces=0,
        keys=(
            _key(0.0),
            _key(0.3, lean=70, nod=15, hip_r=8, hip_l=8, sho_r=45, elb_r=110,
                 sho_l=68, elb_l=10),
            _key(0.58, lean=72, nod=18, hip_r=8, hip_l=8, sho_r=45, elb_r=110,
                 sho_l=70, elb_l=10),
            _key(0.85),
        ),
    ),
    MotionSpec(
        "sit_down", "sit down on an unseen chair, hands on the thighs, then stand up",
        duration=1.7, bounces=0,
        keys=(
            _key(0.0),
            _key(0.12, lean=25, hip_r=22, knee_r=28, hip_l=22, knee_l=28, sho_r=30, sho_l=30),
            _key(0.3, lean=12, hip_r=88, knee_r=88, hip_l=88, knee_l=88,
                 sho_r=45, elb_r=35, sho_l=45, elb_l=35),
            _key(0.62, lean=4, hip_r=86, knee_r=86, hip_l=86, knee_l=86,
                 sho_r=40, elb_r=40, sho_l=40, elb_l=40),
            _key(0.78, lean=32, hip_r=45, knee_r=55, hip_l=45, knee_l=55, sho_r=30, sho_l=30),
            _key(0.93),
        ),
    ),
    MotionSpec(
        "clap", "clapping in front of the chest, twice per loop, knees bobbing",
        duration=0.8, bounces=2,
        base=(("lean", 3), ("sho_r", 25), ("elb_r", 80), ("sho_l", 30), ("elb_l", 95)),
        keys=(
            _key(0.0, sho_r=-20, elb_r=115, sho_l=38, elb_l=72),
            _key(0.25, sho_r=70, elb_r=40, sho_l=29, elb_l=120),
            _key(0.5, sho_r=-20, elb_r=115, sho_l=38, elb_l=72),
            _key(0.75, sho_r=70, elb_r=40, sho_l=29, elb_l=120),
        ),
    ),
    MotionSpec(
        "squat", "deep squat with both arms held straight out in front",
        duration=1.3, bounces=0,
        keys=(
            _key(0.0),
            _key(0.15, lean=6, hip_r=20, knee_r=30, hip_l=20, knee_l=30,
                 sho_r=85, elb_r=5, sho_l=85, elb_l=5),
            _key(0.35, lean=34, hip_r=100, knee_r=130, hip_l=100, knee_l=130,
                 sho_r=102, elb_r=0, sho_l=102, elb_l=0),
            _key(0.5, lean=34, hip_r=100, knee_r=130, hip_l=100, knee_l=130,
                 sho_r=102, elb_r=0, sho_l=102, elb_l=0),
            _key(0.85),
        ),
    ),
    MotionSpec(
        "throw", "overhand throw: right arm winds back, whips over the top, follows through",
        duration=1.25, bounces=0, wind=(("sho_r", -360.0),),
        keys=(
            _key(0.0),
            _key(0.15, lean=-6, sho_r=-60, elb_r=30, sho_l=30),
            _key(0.32, lean=-16, hip_l=25, knee_l=10, sho_r=-140, elb_r=100, sho_l=80, elb_l=5),
            _key(0.45, lean=28, hip_l=28, knee_l=25, sho_r=-262, elb_r=8, sho_l=10, elb_l=40),
            _key(0.6, lean=34, hip_l=20, knee_l=25, sho_r=-325, elb_r=20, sho_l=-20, elb_l=30),
            _key(0.85, sho_r=-360),
        ),
    ),
    MotionSpec(
        "spin_arms", "windmill: both straight arms circle forward, half a turn apart",
        duration=1.0, bounces=2, wind=(("sho_r", 360.0), ("sho_l", 360.0)),
        base=(("lean", 6), ("knee_r", 10), ("knee_l", 10), ("elb_r", 0), ("elb_l", 0)),
        keys=(
            _key(0.0, sho_r=0, sho_l=180),
            _key(0.25, sho_r=90, sho_l=270),
            _key(0.5, sho_r=180, sho_l=360),
            _key(0.75, sho_r=270, sho_l=450),
        ),
    ),
    MotionSpec(
        "stretch", "reach up high on tiptoe looking up, then fold down to touch the toes",
        duration=2.0, bounces=0,
        keys=(
            _key(0.0),
            _key(0.2, lean=-10, hunch=-8, nod=-22, sho_r=175, elb_r=0, sho_l=175, elb_l=0,
                 knee_r=0, knee_l=0, lift=0.03),
            _key(0.36, lean=-10, hunch=-8, nod=-22, sho_r=175, elb_r=0, sho_l=175, elb_l=0,
                 knee_r=0, knee_l=0, lift=0.03),
            _key(0.46, lean=8, sho_r=40, elb_r=10, sho_l=40, elb_l=10),
            _key(0.6, lean=52, hunch=10, nod=20, hip_r=8, hip_l=8, knee_r=0, knee_l=0,
                 sho_r=62, elb_r=5, sho_l=62, elb_l=5),
            _key(0.72, lean=54, hunch=12, nod=20, hip_r=8, hip_l=8, knee_r=0, knee_l=0,
                 sho_r=64, elb_r=5, sho_l=64, elb_l=5),
            _key(0.92),
        ),
    ),
)

#: The motion class names, in label order.
MOTIONS: tuple[str, ...] = tuple(m.name for m in MOTION_SPECS)
assert len(MOTIONS) == 15 and len(set(MOTIONS)) == 15


def motion(name) -> MotionSpec:
    """The :class:`MotionSpec` called ``name`` (a spec is returned as is).

    Raises ``ValueError`` listing the valid names for an unknown one.
    """
    if isinstance(name, MotionSpec):
        return name
    for spec in MOTION_SPECS:
        if spec.name == name:
            return spec
    raise ValueError(f"unknown motion {name!r}; valid motions: {', '.join(MOTIONS)}")


# --- in-betweening -------------------------------------------------------------------------

def time_warp(s: np.ndarray, snap: float, skew: float) -> np.ndarray:
    """Re-time the local parameter ``s`` in [0, 1] of a key-to-key segment.

    ``skew`` in (-1, 1) moves the motion towards the start of the segment
    (> 0, a fast break-away that eases into the next key) or its end (< 0,
    slow out, fast in).  ``snap`` >= 0.5 is the exponent of a sigmoid: 1
    leaves the timing alone, larger values hold each key and jump between
    them (snappy, pose-to-pose), smaller values rush through the keys.
    Monotone, maps 0 to 0 and 1 to 1.
    """
    u = s + skew * s * (1.0 - s)
    a = u ** snap
    return a / (a + (1.0 - u) ** snap)


def interpolate(times: np.ndarray, values: np.ndarray, wind: np.ndarray, phase: np.ndarray,
                tension: float = 0.0, overshoot: float = 0.0, snap: float = 1.0,
                skew: float = 0.0) -> np.ndarray:
    """Evaluate looping key poses at any phase, one phase per channel.

    times : ``(K,)`` key times in [0, 1); values : ``(K, C)`` key values;
    wind : ``(C,)`` gain per loop; phase : ``(n, C)`` loop phase of every
    frame and channel (unbounded: loop ``i`` adds ``i * wind``).
    Returns ``(n, C)``.

    The in-between is a cubic Hermite curve.  Where a key lies between its
    neighbours its slope is the cardinal-spline slope scaled by
    ``1 - tension`` (tension 1 stops at every key) and limited so the curve
    stays monotone there.  Where a key is a turning point or the start of a
    hold, the slope is ``overshoot`` times the incoming slope, so the curve
    carries on past the key and springs back (cartoon follow-through; 0 stops
    dead).  :func:`time_warp` re-times every segment.
    """
    K = len(times)
    # Extend the loop by two keys on each side so that every segment has the
    # neighbours its slopes need; wrapped keys gain or lose one loop of wind.
    idx = np.r_[K - 2, K - 1, np.arange(K), 0, 1]
    shift = np.r_[-1, -1, np.zeros(K), 1, 1]
    t_ext = times[idx] + shift
    v_ext = values[idx] + shift[:, None] * wind[None, :]

    d = np.diff(v_ext, axis=0) / np.diff(t_ext)[:, None]  # (K+3, C) segment slopes
    d_in, d_out = d[:-1], d[1:]                            # at keys 1 .. K+2
    cardinal = (1.0 - tension) * (v_ext[2:] - v_ext[:-2]) / (t_ext[2:] - t_ext[:-2])[:, None]
    limit = 3.0 * np.minimum(np.abs(d_in), np.abs(d_out))
    through = np.sign(cardinal) * np.minimum(np.abs(cardinal), limit)
    slope = np.where(d_in * d_out > 0, through, overshoot * d_in)
    slope = np.vstack([np.zeros((1, values.shape[1])), slope])  # index = extended key

    loops = np.floor(phase)
    u = phase - loops
    j = np.searchsorted(t_ext, u, side="right") - 1           # segment (j, j+1), 2 <= j <= K+1
    col = np.arange(values.shape[1])[None, :]
    h = t_ext[j + 1] - t_ext[j]
    s = time_warp((u - t_ext[j]) / h, snap, skew)
    s2, s3 = s * s, s * s * s
    h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
    out = (h00 * v_ext[j, col] + h10 * h * slope[j, col]
           + h01 * v_ext[j + 1, col] + h11 * h * slope[j + 1, col])
    return out + loops * wind[None, :]
