"""The built-in cartoon characters of the synthetic set.

A character is a body (:class:`Proportions`, pixels on the 256 x 256 canvas),
a way of moving (:class:`Style`) and a flat look (:class:`Palette`).  The
body alone is removed by template unification, which rescales every bone to
the template; the style is what must survive it: timing, amplitudes,
posture, bounce, asymmetry.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass


@dataclass(frozen=True)
class Proportions:
    """Bone lengths and drawing widths, in pixels on the 256 x 256 canvas.

    Bones: ``thigh`` (hip-knee), ``shin`` (knee-ankle), ``spine``
    (pelvis-spine), ``chest`` (spine-thorax), ``neck`` (thorax-neck), ``head``
    (neck-head top), ``upper_arm``, ``forearm``, ``hip_width`` (pelvis-hip) and
    ``shoulder_width`` (thorax-shoulder).  Drawing only: ``head_radius``,
    ``arm_width``, ``leg_width``, ``torso_width`` (full widths of the filled
    limbs) and ``outline`` (outline stroke width).
    """

    thigh: float
    shin: float
    spine: float
    chest: float
    neck: float
    head: float
    upper_arm: float
    forearm: float
    hip_width: float
    shoulder_width: float
    head_radius: float
    arm_width: float
    leg_width: float
    torso_width: float
    outline: float = 2.0

    @property
    def leg(self) -> float:
        """Hip to ankle, straight (px): the unit of ``lift``, ``dx`` and ``bounce``."""
        return self.thigh + self.shin

    @property
    def height(self) -> float:
        """Ankle to head top standing straight (px)."""
        return self.leg + self.spine + self.chest + self.neck + self.head


@dataclass(frozen=True)
class Style:
    """How a character moves; angles in degrees, times in fractions of a loop.

    Timing: ``tempo`` multiplies the loop rate; ``tension`` (0 flowing .. 1
    stopping at every key), ``overshoot`` (carry past a key and spring back),
    ``snap`` (1 plain; > 1 holds the keys and snaps between them) and
    ``skew`` (> 0 fast break-away then ease in; < 0 ease out then fast) shape
    the in-betweens (see :func:`nnsf.datasets.synthetic_motions.interpolate`).
    Phase lags: ``lag_torso``, ``lag_head``, ``lag_arms``, ``lag_forearms``
    delay those joint groups behind the legs (drag, follow-through).
    Amplitudes multiply the deviation from the rest pose: ``amp_legs``,
    ``amp_arms`` (upper arms and forearms), ``amp_torso`` (torso and head),
    ``amp_root`` (jump and hop heights, forward shifts).
    Posture offsets added to every frame: ``lean`` (torso forward), ``hunch``
    (chest forward on the spine), ``head_tilt`` (head down), ``knee_bend``,
    ``elbow_bend``, ``arm_carriage`` (upper arms held forward), ``stance``
    (legs split front/back).
    ``bounce``: an extra vertical hop of the pelvis, as a fraction of the leg,
    on every beat of the motion.  ``asymmetry``: the right side's deviations
    are scaled by ``1 + asymmetry`` and the left side's by ``1 - asymmetry``
    (a limp, a favoured side).  ``handedness``: ``"left"`` performs one-sided
    actions (kick, punch, wave, throw, bow) with the other side.
    """

    tempo: float = 1.0
    tension: float = 0.0
    overshoot: float = 0.0
    snap: float = 1.0
    skew: float = 0.0
    lag_torso: float = 0.0
    lag_head: float = 0.0
    lag_arms: float = 0.0
    lag_forearms: float = 0.0
    amp_legs: float = 1.0
    amp_arms: float = 1.0
    amp_torso: float = 1.0
    amp_root: float = 1.0
    lean: float = 0.0
    hunch: float = 0.0
    head_tilt: float = 0.0
    knee_bend: float = 0.0
    elbow_bend: float = 0.0
    arm_carriage: float = 0.0
    stance: float = 0.0
    bounce: float = 0.0
    asymmetry: float = 0.0
    handedness: str = "right"

    def __post_init__(self):
        if self.handedness not in ("right", "left"):
            raise ValueError(f"handedness must be 'right' or 'left', got {self.handedness!r}")
        if not (self.tempo > 0 and self.snap > 0 and abs(self.skew) < 1):
            raise ValueError("tempo and snap must be > 0 and |skew| < 1")


@dataclass(frozen=True)
class Palette:
    """Flat RGB colours (0-255) for rendering: torso, limbs, head and outline."""

    body: tuple[int, int, int]
    limbs: tuple[int, int, int]
    head: tuple[int, int, int]
    outline: tuple[int, int, int]


@dataclass(frozen=True)
class CharacterSpec:
    """A named cartoon character: body, motion style and look."""

    name: str
    description: str
    proportions: Proportions
    style: Style
    palette: Palette

    def to_dict(self) -> dict:
        """JSON-ready description, including the derived height and leg length."""
        d = asdict(self)
        d["proportions"]["height"] = self.proportions.height
        d["proportions"]["leg"] = self.proportions.leg
        d["palette"] = {k: list(v) for k, v in d["palette"].items()}
        return d


def _p(thigh, shin, spine, chest, neck, head, upper_arm, forearm, hip_width, shoulder_width,
       head_radius, arm_width, leg_width, torso_width, outline=2.0) -> Proportions:
    return Proportions(thigh, shin, spine, chest, neck, head, upper_arm, forearm, hip_width,
                       shoulder_width, head_radius, arm_width, leg_width, torso_width, outline)


#: The built-in characters; a pipeline with N characters uses the first N.
CHARACTERS: tuple[CharacterSpec, ...] = (
    CharacterSpec(
        "bruno", "big slow brawler: short legs, long heavy arms carried forward, hunched",
        _p(36, 32, 28, 30, 7, 22, 35, 33, 11, 16, 13, 14, 16, 42, 3),
        Style(tempo=0.8, tension=0.2, snap=1.2, lag_arms=0.06, lag_forearms=0.04,
              amp_legs=0.75, amp_arms=1.1, amp_torso=0.9, amp_root=0.6,
              lean=8, hunch=14, head_tilt=6, knee_bend=12, elbow_bend=22, arm_carriage=12,
              stance=4, bounce=0.01),
        Palette((176, 82, 52), (120, 70, 50), (230, 180, 140), (40, 25, 20)),
    ),
    CharacterSpec(
        "pip", "small quick kid: big head, short limbs, springy and snappy",
        _p(23, 21, 15, 14, 5, 26, 19, 17, 6, 7, 16, 7, 8, 20),
        Style(tempo=1.3, tension=0.1, overshoot=0.2, snap=1.8, skew=0.25,
              amp_legs=1.3, amp_arms=1.3, amp_torso=1.1, amp_root=1.4,
              lean=-4, hunch=-4, head_tilt=-6, elbow_bend=18, bounce=0.07),
        Palette((250, 200, 40), (60, 130, 220), (255, 220, 190), (30, 30, 60)),
    ),
    CharacterSpec(
        "olga", "tall elegant dancer: long legs, small head, proud upright flow",
        _p(46, 44, 23, 23, 12, 18, 32, 30, 7, 10, 10, 6, 8, 22),
        Style(tempo=0.9, tension=0.0, overshoot=0.1, snap=0.85, lag_head=0.05,
              lag_arms=0.05, lag_forearms=0.1, amp_legs=1.1, amp_arms=0.8, amp_torso=0.85,
              amp_root=1.0, lean=-6, hunch=-10, head_tilt=-10, knee_bend=0, elbow_bend=4,
              arm_carriage=-6, stance=-3),
        Palette((150, 60, 160), (200, 120, 210), (245, 215, 200), (50, 20, 60)),
    ),
    CharacterSpec(
        "gus", "old man: bent back, bent knees, slow, small and limping movements",
        _p(32, 30, 22, 22, 7, 23, 28, 26, 8, 10, 13, 8, 9, 28),
        Style(tempo=0.72, tension=0.4, snap=1.0, skew=-0.2, lag_torso=0.04, lag_head=0.06,
              amp_legs=0.6, amp_arms=0.55, amp_torso=0.75, amp_root=0.4,
              lean=14, hunch=24, head_tilt=12, knee_bend=18, elbow_bend=30, arm_carriage=8,
              asymmetry=0.18),
        Palette((110, 120, 110), (90, 80, 70), (235, 200, 175), (35, 35, 35)),
    ),
    CharacterSpec(
        "zed", "robot: stiff pose-to-pose moves that stop dead on every key, no drag",
        _p(36, 36, 22, 26, 10, 20, 30, 30, 10, 13, 12, 9, 11, 30),
        Style(tempo=1.0, tension=1.0, snap=2.6, amp_legs=0.9, amp_arms=1.0, amp_torso=0.7,
              amp_root=0.7, lean=0, hunch=0, head_tilt=0, knee_bend=0, elbow_bend=0,
              arm_carriage=0),
        Palette((150, 160, 175), (100, 110, 125), (190, 200, 210), (20, 25, 35)),
    ),
    CharacterSpec(
        "mimi", "rubber-hose toon: floppy arms that drag, big overshoot and bounce, left-handed",
        _p(26, 25, 18, 18, 6, 28, 26, 24, 7, 8, 17, 7, 8, 24),
        Style(tempo=1.12, tension=0.0, overshoot=0.45, snap=0.9, lag_torso=0.03,
              lag_head=0.06, lag_arms=0.1, lag_forearms=0.08, amp_legs=1.35, amp_arms=1.45,
              amp_torso=1.35, amp_root=1.3, lean=2, hunch=0, head_tilt=-4, knee_bend=6,
              elbow_bend=0, arm_carriage=-4, bounce=0.08, handedness="left"),
        Palette((235, 60, 70), (30, 30, 30), (255, 235, 220), (15, 10, 10)),
    ),
    CharacterSpec(
        "rex", "athlete: forward-leaning, bent arms, powerful and snappy",
        _p(39, 39, 23, 28, 8, 20, 33, 31, 9, 14, 11, 10, 12, 32),
        Style(tempo=1.18, tension=0.1, overshoot=0.15, snap=1.5, skew=0.3, lag_arms=0.02,
              amp_legs=1.2, amp_arms=1.1, amp_torso=1.1, amp_root=1.2,
              lean=9, hunch=4, head_tilt=4, knee_bend=10, elbow_bend=38, arm_carriage=6,
              stance=6, bounce=0.02),
        Palette((30, 140, 90), (240, 240, 240), (200, 150, 110), (10, 40, 25)),
    ),
    CharacterSpec(
        "wendell", "lanky goof: very long loose limbs, droopy posture, lopsided, left-handed",
        _p(46, 46, 20, 20, 13, 19, 39, 39, 6, 9, 11, 5, 6, 18),
        Style(tempo=0.95, tension=0.0, overshoot=0.3, snap=1.0, lag_head=0.08,
              lag_arms=0.06, lag_forearms=0.14, amp_legs=1.15, amp_arms=1.3, amp_torso=1.0,
              amp_root=0.9, lean=4, hunch=12, head_tilt=8, knee_bend=8, elbow_bend=6,
              arm_carriage=-8, stance=-4, bounce=0.04, asymmetry=-0.1, handedness="left"),
        Palette((90, 170, 60), (230, 140, 40), (250, 210, 170), (30, 50, 20)),
    ),
    CharacterSpec(
        "tilly", "shy girl: head down, elbows tucked, small quick hesitant movements",
        _p(29, 28, 19, 19, 7, 25, 25, 23, 7, 8, 14, 7, 8, 24),
        Style(tempo=1.06, tension=0.3, snap=1.3, skew=-0.35, lag_torso=0.02, lag_head=0.03,
              amp_legs=0.7, amp_arms=0.6, amp_torso=0.8, amp_root=0.6,
              lean=3, hunch=14, head_tilt=22, knee_bend=6, elbow_bend=55, arm_carriage=14,
              stance=-2),
        Palette((120, 180, 230), (250, 170, 190), (255, 225, 210), (40, 50, 80)),
    ),
    CharacterSpec(
        "max", "cocky swaggerer: leans back, chest and chin up, big lopsided arm swings",
        _p(36, 35, 24, 28, 9, 21, 32, 30, 9, 14, 12, 10, 11, 34),
        Style(tempo=0.85, tension=0.0, overshoot=0.2, snap=1.1, skew=0.15, lag_torso=0.06,
              lag_arms=0.04, amp_legs=0.9, amp_arms=1.3, amp_torso=1.2, amp_root=0.9,
              lean=-9, hunch=-8, head_tilt=-12, knee_bend=2, elbow_bend=14, arm_carriage=-4,
              stance=5, bounce=0.03, asymmetry=0.12),
        Palette((220, 120, 30), (60, 60, 70), (210, 160, 120), (25, 20, 15)),
    ),
    CharacterSpec(
        "ollie", "chubby kid: short legs, long round body, bouncy waddle",
        _p(24, 21, 25, 21, 5, 24, 23, 21, 11, 10, 14, 10, 13, 44),
        Style(tempo=1.1, tension=0.15, overshoot=0.2, snap=1.2, lag_torso=0.05,
              lag_arms=0.03, amp_legs=0.7, amp_arms=0.9, amp_torso=1.2, amp_root=1.0,
              lean=3, hunch=2, head_tilt=0, knee_bend=12, elbow_bend=28, arm_carriage=18,
              bounce=0.06),
        Palette((90, 200, 200), (250, 230, 90), (255, 215, 180), (20, 60, 60)),
    ),
    CharacterSpec(
        "nova", "graceful gymnast: flowing, wide and smooth, slightly leading with the arms",
        _p(40, 40, 22, 22, 10, 18, 30, 30, 7, 9, 10, 6, 8, 22),
        Style(tempo=0.95, tension=0.0, overshoot=0.05, snap=0.75, lag_torso=0.02,
              lag_head=0.05, lag_arms=-0.04, lag_forearms=0.06, amp_legs=1.25,
              amp_arms=1.25, amp_torso=1.2, amp_root=1.1, lean=-3, hunch=-4, head_tilt=-4,
              elbow_bend=0, arm_carriage=0, stance=0, bounce=0.02),
        Palette((240, 240, 250), (80, 90, 200), (250, 220, 200), (30, 30, 80)),
    ),
)

CHARACTER_NAMES: tuple[str, ...] = tuple(c.name for c in CHARACTERS)
assert len(set(CHARACTER_NAMES)) == len(CHARACTERS) >= 12


def character(name) -> CharacterSpec:
    """The built-in character called ``name`` (a :class:`CharacterSpec` is returned as is).

    Raises ``ValueError`` listing the valid names for an unknown one.
    """
    if isinstance(name, CharacterSpec):
        return name
    for spec in CHARACTERS:
        if spec.name == name:
            return spec
    raise ValueError(f"unknown character {name!r}; valid characters: {', '.join(CHARACTER_NAMES)}")
