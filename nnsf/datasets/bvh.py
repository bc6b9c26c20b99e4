"""BVH motion capture: reader, forward kinematics, 2D projection and resampling.

The parser is our own (numpy only).  Of the maintained BVH libraries on PyPI,
``pybvh`` (0.9) refuses position channels on non-root joints, which every
Bandai-Namco clip has (six channels on every joint), and ``bvhio`` (1.5)
pulls in PyGLM and builds one Python object per joint per frame, far too slow
for a vectorised pipeline; the older ones (``bvh``, ``bvhtoolbox``) are
unmaintained and do no forward kinematics over frames.  The format is small,
and writing it ourselves lets every error name the file and line.

Conventions
-----------
* A joint's local transform is ``T(t) · R``: translation, then rotation.
  ``R`` is the product of the joint's rotation channels *in the order they
  are listed*: ``CHANNELS 3 Zrotation Xrotation Yrotation`` means
  ``R = Rz(a) @ Rx(b) @ Ry(c)`` (intrinsic Z-X-Y, i.e. scipy's
  ``Rotation.from_euler("ZXY", [a, b, c], degrees=True)``); angles are
  degrees.  Any order and any subset of axes is accepted.
* Position channels, on any joint, *replace* the OFFSET along the axes they
  cover (``position_channels="replace"``, the convention of Blender's
  importer and of the data here: Bandai-Namco's ``Hips`` has OFFSET z = -452
  but position channels near 0, and its other joints repeat their OFFSET in
  their position channels).  ``"add"`` gives ``t = OFFSET + channels``, the
  other convention in the wild.
* Units are the file's own (Bandai-Namco and Rokoko: centimetres; CMU and
  the FAIR clips: arbitrary).  Nothing here rescales; the template unifier
  (:mod:`nnsf.skeleton.unify`) normalises body size later.
* World axes are the file's; most BVH files are Y-up, some (the FAIR clips)
  Z-up.  :func:`project` takes the up axis, and :func:`detect_up_axis`
  guesses it from a head and feet.

Shapes: F frames, J nodes (joints plus End Sites), C channels, K points.
"""
from __future__ import annotations

import io
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.io import read_bytes

__all__ = [
    "BVH", "Projection", "read_bvh", "parse_bvh", "forward_kinematics", "local_rotations",
    "local_translations", "euler_matrices", "detect_up_axis", "up_rotation", "project",
    "resample", "resample_times", "smooth_linear",
]

_CHANNEL = re.compile(r"^([XYZxyz])(position|rotation)$", re.IGNORECASE)
_AXIS = {"x": 0, "y": 1, "z": 2}


@dataclass
class BVH:
    """A parsed BVH file.

    Nodes are listed depth-first as they appear in the file; End Sites are
    nodes too (``is_end_site``), named ``"<parent>_end"`` (with a number if a
    joint has several).

    Attributes
    ----------
    source : str
        The file the data came from (used in error messages).
    names : tuple[str, ...]
        Node names, ``(J,)``.
    parents : ndarray of int, ``(J,)``
        Parent node index, -1 for the root; parents come before children.
    offsets : ndarray, ``(J, 3)``
        OFFSET of each node from its parent, in the file's units.
    is_end_site : ndarray of bool, ``(J,)``
    channels : tuple[tuple[str, ...], ...]
        Channel names per node as written (End Sites have none).
    channel_node, channel_axis : ndarray of int, ``(C,)``
        For each motion column: the node it drives and its axis (0=x, 1=y, 2=z).
    channel_is_rotation : ndarray of bool, ``(C,)``
    motion : ndarray float64, ``(F, C)``
        One row per frame: positions in file units, rotations in degrees.
    frame_time : float
        Seconds per frame.
    """

    source: str
    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    is_end_site: np.ndarray
    channels: tuple[tuple[str, ...], ...]
    channel_node: np.ndarray
    channel_axis: np.ndarray
    channel_is_rotation: np.ndarray
    motion: np.ndarray
    frame_time: float
    _index: dict = field(default_factory=dict, repr=False)

    def __post_init__(self):
        self._index = {n: i for i, n in enumerate(self.names)}

    @property
    def n_frames(self) -> int:
        return int(self.motion.shape[0])

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time`` snapped to a whole number
        within 0.1 % (files write 1/30 s as 0.0333333 or .03333, and the
        rounding would otherwise shift resampled frame counts)."""
        fps = 1.0 / self.frame_time
        whole = round(fps)
        return float(whole) if whole > 0 and abs(fps - whole) <= 1e-3 * fps else fps

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the real joints (End Sites left out)."""
        return tuple(n for n, e in zip(self.names, self.is_end_site) if not e)

    def index(self, name: str) -> int:
        """Node index of ``name``; ``KeyError`` if absent."""
        return self._index[name]

    def end_site_of(self, joint: str) -> int | None:
        """Node index of the (first) End Site below ``joint``, or None."""
        j = self._index[joint]
        for i in np.flatnonzero(self.is_end_site):
            if self.parents[i] == j:
                return int(i)
        return None


# --------------------------------------------------------------------------- reading

#: Largest .bvh file read (bytes); an hour of 60 fps capture is about 200 MB.
MAX_BVH_BYTES = 512_000_000


def read_bvh(path) -> BVH:
    """Read a BVH file; bad content raises :class:`InputError` naming file and line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing .bvh file")

    data = read_bytes(path, MAX_BVH_BYTES, "a readable .bvh file")
    try:
        text = data.decode("utf-8", errors="strict")
    except UnicodeDecodeError:
        text = data.decode("latin-1")  # every byte decodes: old exporters write Latin-1 names
    return parse_bvh(text, source=path)


def _tokens(lines: list[str], start: int, stop: int):
    """(token, 1-based line number) pairs for lines[start:stop]; braces split off."""
    out = []
    for i in range(start, stop):
        line = lines[i]
        if "{" in line or "}" in line:
            line = line.replace("{", " { ").replace("}", " } ")
        out.extend((tok, i + 1) for tok in line.split())
    return out


_MOTION = re.compile(r"^[ \t]*MOTION\b", re.MULTILINE | re.IGNORECASE)


def parse_bvh(text: str, source="<string>") -> BVH:
    """Parse BVH text (see :func:`read_bvh`); ``source`` names it in errors."""
    m = _MOTION.search(text)
    if m is None:
        raise InputError(source, f"line {text.count(chr(10)) + 1}",
                         "a MOTION section after the HIERARCHY", "end of file")
    head = text[:m.start()].splitlines()
    toks = _tokens(head, 0, len(head))
    names, parents, offsets, ends, chans, ch_node, ch_axis, ch_rot = _parse_hierarchy(toks, source)

    # Header of the MOTION section: "Frames: N" and "Frame Time: t".  Only
    # these few lines are split here; the (large) motion block goes to the
    # numeric parser in one piece.
    pos = text.find("\n", m.end())
    pos = len(text) if pos < 0 else pos + 1
    line_no = len(head) + 2                        # 1-based number of the line at pos
    n_frames, pos, line_no = _header_value(text, pos, line_no, "frames", source, int)
    frames_line = line_no - 1
    frame_time, pos, line_no = _header_value(text, pos, line_no, "frame time", source, float)
    if n_frames <= 0:
        raise InputError(source, f"line {frames_line}", "Frames: at least 1", n_frames)
    if not (frame_time > 0 and math.isfinite(frame_time)):
        raise InputError(source, f"line {line_no - 1}", "Frame Time: a positive number of seconds",
                         frame_time)
    motion = _parse_motion(text[pos:], line_no, n_frames, len(ch_node), source)
    return BVH(
        source=str(source), names=tuple(names), parents=np.array(parents, dtype=np.int64),
        offsets=np.array(offsets, dtype=np.float64).reshape(-1, 3),
        is_end_site=np.array(ends, dtype=bool), channels=tuple(chans),
        channel_node=np.array(ch_node, dtype=np.int64), channel_axis=np.array(ch_axis, dtype=np.int64),
        channel_is_rotation=np.array(ch_rot, dtype=bool), motion=motion, frame_time=frame_time,
    )


def _parse_hierarchy(toks, source):
    names, parents, offsets, ends, chans = [], [], [], [], []
    ch_node, ch_axis, ch_rot = [], [], []
    stack: list[int] = []           # open nodes
    pending: int | None = None      # node declared, waiting for its "{"
    k = 0
    n = len(toks)
    last_line = toks[-1][1] if toks else 1

    def need(count, what):
        if k + count > n:
            raise InputError(source, f"line {last_line}", what, "end of hierarchy")

    seen_root = False
    while k < n:
        tok, line = toks[k]
        up = tok.upper()
        if up == "HIERARCHY":
            k += 1
        elif up in ("ROOT", "JOINT"):
            if up == "ROOT" and (seen_root or stack):
                raise InputError(source, f"line {line}", "a single ROOT", "a second ROOT")
            if up == "JOINT" and not stack:
                raise InputError(source, f"line {line}", "JOINT inside a ROOT's braces", tok)
            if pending is not None:
                raise InputError(source, f"line {line}", "'{' after the joint name", tok)
            # The name is the rest of the line (names with spaces exist).
            parts = []
            k += 1
            while k < n and toks[k][1] == line and toks[k][0] not in "{}":
                parts.append(toks[k][0])
                k += 1
            if not parts:
                raise InputError(source, f"line {line}", f"a name after {tok}")
            name = " ".join(parts)
            if name in names:
                raise InputError(source, f"line {line}", "unique joint names", name)
            seen_root = True
            pending = _new_node(names, parents, offsets, ends, chans, name,
                                stack[-1] if stack else -1, False)
        elif up == "END":
            need(2, "'End Site'")
            if toks[k + 1][0].upper() != "SITE":
                raise InputError(source, f"line {line}", "'End Site'", f"End {toks[k + 1][0]}")
            if not stack or pending is not None:
                raise InputError(source, f"line {line}", "End Site inside a joint's braces")
            parent = stack[-1]
            base = f"{names[parent]}_end"
            name = base
            c = 2
            while name in names:
                name, c = f"{base}{c}", c + 1
            pending = _new_node(names, parents, offsets, ends, chans, name, parent, True)
            k += 2
        elif tok == "{":
            if pending is None:
                raise InputError(source, f"line {line}", "'{' only after ROOT, JOINT or End Site")
            stack.append(pending)
            pending = None
            k += 1
        elif tok == "}":
            if not stack:
                raise InputError(source, f"line {line}", "balanced braces", "an extra '}'")
            stack.pop()
            k += 1
        elif up == "OFFSET":
            node = _current(stack, pending, source, line, tok)
            need(4, "OFFSET with 3 numbers")
            vals = []
            for t, ln in toks[k + 1:k + 4]:
                try:
                    v = float(t)
                except ValueError:
                    raise InputError(source, f"line {ln}", "OFFSET with 3 numbers", t) from None
                if not math.isfinite(v):
                    raise InputError(source, f"line {ln}", "finite OFFSET values", t)
                vals.append(v)
            offsets[node] = vals
            k += 4
        elif up == "CHANNELS":
            node = _current(stack, pending, source, line, tok)
            if ends[node]:
                raise InputError(source, f"line {line}", "no CHANNELS in an End Site")
            need(2, "CHANNELS with a count")
            try:
                count = int(toks[k + 1][0])
            except ValueError:
                raise InputError(source, f"line {line}", "CHANNELS followed by a count",
                                 toks[k + 1][0]) from None
            if count < 0:
                raise InputError(source, f"line {line}", "a channel count >= 0", count)
            need(2 + count, f"{count} channel names")
            cnames = []
            for t, ln in toks[k + 2:k + 2 + count]:
                m = _CHANNEL.match(t)
                if m is None:
                    raise InputError(source, f"line {ln}", "a channel name such as Xposition or "
                                     "Zrotation", t)
                cnames.append(t)
                ch_node.append(node)
                ch_axis.append(_AXIS[m.group(1).lower()])
                ch_rot.append(m.group(2).lower() == "rotation")
            if chans[node]:
                raise InputError(source, f"line {line}", "one CHANNELS line per joint", "a second one")
            chans[node] = tuple(cnames)
            k += 2 + count
        else:
            raise InputError(source, f"line {line}", "a HIERARCHY keyword (ROOT, JOINT, End Site, "
                             "OFFSET, CHANNELS, braces)", tok)
    if not names:
        raise InputError(source, "HIERARCHY", "a ROOT joint", "none")
    if stack or pending is not None:
        raise InputError(source, f"line {last_line}", "balanced braces before MOTION",
                         f"{len(stack) + (pending is not None)} unclosed")
    return names, parents, offsets, ends, chans, ch_node, ch_axis, ch_rot


def _new_node(names, parents, offsets, ends, chans, name, parent, end):
    names.append(name)
    parents.append(parent)
    offsets.append([0.0, 0.0, 0.0])
    ends.append(end)
    chans.append(())
    return len(names) - 1


def _current(stack, pending, source, line, tok):
    if pending is not None:
        raise InputError(source, f"line {line}", "'{' before " + tok)
    if not stack:
        raise InputError(source, f"line {line}", f"{tok} inside a joint's braces")
    return stack[-1]


def _header_value(text, pos, line_no, key, source, cast):
    """Read ``key: value`` from the line at char ``pos`` (blank lines skipped).

    Returns ``(value, next pos, next line number)``.
    """
    while True:
        if pos >= len(text):
            raise InputError(source, f"line {line_no}", f"'{key.title()}:' in the MOTION section",
                             "end of file")
        nl = text.find("\n", pos)
        nl = len(text) if nl < 0 else nl
        line = text[pos:nl]
        pos, line_no = nl + 1, line_no + 1
        if line.strip():
            break
    head, sep, value = line.partition(":")
    if not sep or " ".join(head.split()).lower() != key:
        raise InputError(source, f"line {line_no - 1}", f"'{key.title()}: <value>'", line.strip())
    try:
        v = cast(value.strip())
    except ValueError:
        raise InputError(source, f"line {line_no - 1}", f"{key.title()}: a number", value.strip()) from None
    return v, pos, line_no


def _parse_motion(block: str, first_line: int, n_frames, n_channels, source) -> np.ndarray:
    """Rows of ``n_channels`` numbers from ``block`` (whose first line is line
    ``first_line`` of the file), exactly ``n_frames`` of them.

    The fast path hands the whole block to ``np.loadtxt`` (C parser); any
    problem falls back to a line-by-line pass that finds the line to blame.
    """
    if n_channels == 0:
        raise InputError(source, "CHANNELS", "at least one channel in the hierarchy", 0)
    try:
        data = np.loadtxt(io.StringIO(block), dtype=np.float64, ndmin=2, comments=None)
        ok = data.shape == (n_frames, n_channels) and bool(np.isfinite(data).all())
    except ValueError:
        ok = False
    if ok:
        return data
    # Slow pass: find the first offending line.
    rows = 0
    last = first_line - 1
    for i, line in enumerate(block.splitlines()):
        vals = line.split()
        if not vals:
            continue
        lineno = first_line + i
        last = lineno
        rows += 1
        if rows > n_frames:
            raise InputError(source, f"line {lineno}", f"exactly {n_frames} motion lines (Frames:)",
                             "more lines")
        if len(vals) != n_channels:
            raise InputError(source, f"line {lineno}",
                             f"{n_channels} values per motion line (one per channel)", len(vals))
        for v in vals:
            try:
                x = float(v)
            except ValueError:
                raise InputError(source, f"line {lineno}", "numeric motion values", v) from None
            if not math.isfinite(x):
                raise InputError(source, f"line {lineno}", "finite motion values", v)
    if rows < n_frames:
        raise InputError(source, f"line {last + 1}",
                         f"{n_frames} motion lines as Frames: says (file truncated?)", rows)
    raise InputError(source, "MOTION", "a readable motion block")  # pragma: no cover


# --------------------------------------------------------------------------- kinematics

_EYE = np.eye(3)
# Cross-product matrices [e_k]_x of the unit axes, (3, 3, 3).
_CROSS = np.array([[[0, 0, 0], [0, 0, -1], [0, 1, 0]],
                   [[0, 0, 1], [0, 0, 0], [-1, 0, 0]],
                   [[0, -1, 0], [1, 0, 0], [0, 0, 0]]], dtype=np.float64)
_OUTER = np.einsum("ka,kb->kab", _EYE, _EYE)   # e_k e_k^T, (3, 3, 3)


def euler_matrices(angles_deg: np.ndarray, axes) -> np.ndarray:
    """Elementary rotation matrices, vectorised.

    angles_deg : ``(...)`` degrees; axes : ints broadcastable to it (0=x,
    1=y, 2=z).  Returns ``(..., 3, 3)``, the right-handed rotation by each
    angle about its axis: Rodrigues' formula with a unit axis e,
    ``R = cos a I + (1 - cos a) e e^T + sin a [e]_x`` (plain broadcasting;
    no per-element indexing).
    """
    a = np.deg2rad(np.asarray(angles_deg, dtype=np.float64))
    axes = np.broadcast_to(np.asarray(axes), a.shape)
    c = np.cos(a)[..., None, None]
    s = np.sin(a)[..., None, None]
    return c * _EYE + (1.0 - c) * _OUTER[axes] + s * _CROSS[axes]


def local_rotations(bvh: BVH, motion: np.ndarray | None = None) -> np.ndarray:
    """Each node's local rotation for every frame, ``(F, J, 3, 3)``.

    Built for all joints and frames at once: slot s (the s-th rotation
    channel of every node) gives one ``(F, J)`` batch of elementary matrices,
    and the slots multiply in channel order, ``R = M_0 @ M_1 @ M_2``.  Nodes
    with fewer rotation channels get zero angles (identity) in the spare slots.
    """
    motion = bvh.motion if motion is None else motion
    F, J = motion.shape[0], len(bvh.names)
    rot_cols = np.flatnonzero(bvh.channel_is_rotation)
    if rot_cols.size == 0:
        return np.broadcast_to(_EYE, (F, J, 3, 3)).copy()
    nodes = bvh.channel_node[rot_cols]
    # slot of each rotation channel within its node (channels of a node are contiguous
    # in file order, but counting keeps this independent of that)
    slot = np.zeros(len(rot_cols), dtype=np.int64)
    counts = np.zeros(J, dtype=np.int64)
    for k, nd in enumerate(nodes.tolist()):
        slot[k] = counts[nd]
        counts[nd] += 1
    n_slots = int(counts.max())
    angles = np.zeros((F, J, n_slots))
    axes = np.zeros((J, n_slots), dtype=np.int64)
    angles[:, nodes, slot] = motion[:, rot_cols]
    axes[nodes, slot] = bvh.channel_axis[rot_cols]
    R = euler_matrices(angles[:, :, 0], axes[:, 0])
    for s in range(1, n_slots):
        R = R @ euler_matrices(angles[:, :, s], axes[:, s])
    return R


def local_translations(bvh: BVH, motion: np.ndarray | None = None,
                       position_channels: str = "replace") -> np.ndarray:
    """Each node's translation from its parent, ``(F, J, 3)``, file units."""
    motion = bvh.motion if motion is None else motion
    if position_channels not in ("replace", "add"):
        raise ValueError(f"position_channels must be 'replace' or 'add', got {position_channels!r}")
    F = motion.shape[0]
    T = np.broadcast_to(bvh.offsets, (F,) + bvh.offsets.shape).copy()
    pos = np.flatnonzero(~bvh.channel_is_rotation)
    if pos.size:
        nd, ax = bvh.channel_node[pos], bvh.channel_axis[pos]
        if position_channels == "replace":
            T[:, nd, ax] = motion[:, pos]
        else:
            T[:, nd, ax] += motion[:, pos]
    return T


def forward_kinematics(bvh: BVH, end_sites: bool = True, position_channels: str = "replace",
                       return_rotations: bool = False, motion: np.ndarray | None = None):
    """World positions of every node for every frame.

    Vectorised over frames; the only Python loop is over nodes (parents come
    first, so one top-down pass composes the chain).

    Parameters
    ----------
    end_sites : bool
        Keep End Sites in the output (as extra points, in node order).  If
        False only the real joints are returned, in ``bvh.joint_names`` order.
    position_channels : ``"replace"`` or ``"add"``
        How position channels combine with OFFSET (see the module docstring).
    return_rotations : bool
        Also return the world rotation of every node, ``(F, J', 3, 3)``.
    motion : ``(F, C)``, optional
        Channel values to use instead of ``bvh.motion``.

    Returns
    -------
    positions : ndarray ``(F, J', 3)`` in the file's units and world axes.
    rotations : ndarray ``(F, J', 3, 3)`` (only if ``return_rotations``).
    """
    motion = bvh.motion if motion is None else np.asarray(motion, dtype=np.float64)
    R_loc = local_rotations(bvh, motion)
    T_loc = local_translations(bvh, motion, position_channels)
    F, J = motion.shape[0], len(bvh.names)
    P = np.empty((F, J, 3))
    G = np.empty((F, J, 3, 3))
    for j, p in enumerate(bvh.parents):
        if p < 0:
            P[:, j] = T_loc[:, j]
            G[:, j] = R_loc[:, j]
        else:
            # p_j = p_parent + G_parent t_j ; G_j = G_parent R_j
            P[:, j] = P[:, p] + (G[:, p] @ T_loc[:, j, :, None])[..., 0]
            G[:, j] = G[:, p] @ R_loc[:, j]
    if not end_sites:
        keep = ~bvh.is_end_site
        P, G = P[:, keep], G[:, keep]
    return (P, G) if return_rotations else P


# --------------------------------------------------------------------------- projection

_AXIS_VEC = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _axis_vector(up) -> np.ndarray:
    if isinstance(up, str):
        s = up.strip().lower()
        sign = -1.0 if s.startswith("-") else 1.0
        s = s.lstrip("+-")
        if s not in _AXIS_VEC:
            raise ValueError(f"up must be one of x, y, z with an optional sign, got {up!r}")
        return sign * np.array(_AXIS_VEC[s])
    v = np.asarray(up, dtype=float).reshape(3)
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError("up vector must be non-zero")
    return v / n


def up_rotation(up) -> np.ndarray:
    """Rotation ``(3, 3)`` taking the ``up`` axis onto +y (the smallest such turn).

    ``up`` is ``"y"``, ``"z"``, ``"-y"``, … or a 3-vector.  For ``"z"`` this
    maps (x, y, z) to (x, z, -y), so a Z-up file's +y (usually its forward)
    becomes -z.
    """
    u = _axis_vector(up)
    y = np.array([0.0, 1.0, 0.0])
    v = np.cross(u, y)
    c = float(u @ y)
    if np.linalg.norm(v) < 1e-12:
        return np.eye(3) if c > 0 else np.diag([1.0, -1.0, -1.0])  # 180° about x
    K = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    return np.eye(3) + K + K @ K / (1.0 + c)  # Rodrigues


def detect_up_axis(points: np.ndarray, head: int, feet) -> str:
    """Guess the world up axis from key points ``(F, K, 3)``.

    The signed axis closest to the mean of head minus feet over all frames,
    e.g. ``"y"`` or ``"z"`` (or ``"-y"``).
    """
    pts = np.asarray(points, dtype=float)
    v = (pts[:, head] - pts[:, list(np.atleast_1d(feet))].mean(axis=1)).mean(axis=0)
    k = int(np.argmax(np.abs(v)))
    return ("" if v[k] >= 0 else "-") + "xyz"[k]


def smooth_linear(x: np.ndarray, window: int) -> np.ndarray:
    """Smooth along axis 0, reproducing straight lines exactly.

    The clip's least-squares line (per column) is kept; the residual about
    it is replaced by its centred moving average over ``window`` samples, and
    within half a window of either end by the average of the first / last
    full window.  So constant-velocity travel and constant-rate turning pass
    through unchanged, and a periodic swing (a pelvis turning with each
    stride, a sway about the path) averages out everywhere, ends included (a
    plain moving average with edge padding, or a Savitzky-Golay line fit at
    the ends, would turn half a stride of swing into a bias or a slope there).
    ``window`` is clipped to the largest odd number <= len(x); below 3 the
    input is returned unchanged.  Shapes: ``(n, ...)`` -> ``(n, ...)``.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[0]
    w = min(int(window), n)
    if w % 2 == 0:
        w -= 1
    if w < 3:
        return x.copy()
    flat = x.reshape(n, -1)
    t = np.arange(n, dtype=float)
    A = np.stack([np.ones(n), t - t.mean()], axis=1)
    coef, *_ = np.linalg.lstsq(A, flat, rcond=None)
    trend = A @ coef
    r = flat - trend
    c = np.concatenate([np.zeros((1, r.shape[1])), np.cumsum(r, axis=0)])
    full = (c[w:] - c[:-w]) / w                   # mean of r[i:i+w], centred at i + h
    h = w // 2
    sm = np.concatenate([np.repeat(full[:1], h, axis=0), full, np.repeat(full[-1:], h, axis=0)])
    return (trend + sm).reshape(x.shape)


@dataclass
class Projection:
    """Result of :func:`project`.

    xy : ``(F, K, 2)`` image coordinates, x to the right, y down, in the
        BVH's units (orthographic, no scaling).
    depth : ``(F, K)`` camera-space z: distance along the viewing direction,
        larger is farther from the camera (same units).
    yaw : ``(F,)`` degrees each frame was turned about the vertical axis by
        facing normalisation (zeros without it).
    travel : ``(F, 2)`` horizontal root position (world x, z after up
        alignment) that was subtracted (zeros without centring).
    """

    xy: np.ndarray
    depth: np.ndarray
    yaw: np.ndarray
    travel: np.ndarray


def project(points: np.ndarray, azimuth: float = 0.0, elevation: float = 0.0, up="y",
            facing: str = "none", across: tuple[int, ...] | None = None, root: int | None = None,
            center: bool = False, window: int = 31) -> Projection:
    """Orthographic projection of 3D points to image coordinates.

    Parameters
    ----------
    points : ``(F, K, 3)`` world positions (file units).
    azimuth, elevation : degrees.  The camera looks at the origin from
        direction ``(sin az cos el, sin el, cos az cos el)`` in the Y-up
        frame.  ``0, 0`` is the front view: looking along -z, so a
        character facing +z (the BVH convention, and what facing
        normalisation produces) faces the camera and its left side appears
        on the image's right.  ``azimuth=90`` views its left side.
    up : the world up axis, ``"y"`` (BVH default), ``"z"``, ``"-y"``, … or a
        3-vector; points are first turned so that it becomes +y.
    facing : ``"none"``, ``"first"`` or ``"normalise"``.  ``"first"`` turns
        the whole clip once, about the vertical axis through the root's first
        position, so that the body faces +z at the start (its heading over
        the first ``window`` frames): turning within the clip is kept, only
        the clip's initial orientation is removed.  ``"normalise"`` turns every frame
        about the vertical axis through the root so that the body faces +z.
        The facing direction is ``(left - right) x up`` of the ``across``
        pairs (e.g. hips and shoulders), smoothed over ``window`` frames
        (unwrapped angle, :func:`smooth_linear`) so that turning and walking
        in circles are removed but the pelvis' swing within a stride is kept.
        ``window=1`` normalises every frame exactly.
    across : indices ``(left_1, right_1, left_2, right_2, ...)`` into K of
        left/right pairs; required for facing normalisation.
    root : index of the root point (pelvis); required for ``center`` and used
        as the pivot of facing normalisation (else the origin).
    center : subtract the root's horizontal travel, smoothed over ``window``
        frames, from every point (vertical motion such as a jump is kept, and
        so is the sway about the path).  ``window=1`` pins the root exactly.

    Returns
    -------
    :class:`Projection`
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 3 or P.shape[-1] != 3:
        raise ValueError(f"points must be (frames, points, 3), got {P.shape}")
    F = P.shape[0]
    P = P @ up_rotation(up).T
    travel = np.zeros((F, 2))
    if root is not None:
        pivot = smooth_linear(P[:, root][:, [0, 2]], window)
    else:
        pivot = np.zeros((F, 2))
    yaw = np.zeros(F)
    if facing not in ("none", "first", "normalise", "normalize"):
        raise ValueError(f"facing must be 'none', 'first' or 'normalise', got {facing!r}")
    if facing != "none":
        if not across or len(across) % 2:
            raise ValueError("facing normalisation needs left/right index pairs in `across`")
        lr = np.asarray(across).reshape(-1, 2)
        d = (P[:, lr[:, 0]] - P[:, lr[:, 1]]).sum(axis=1)   # (F, 3) summed left-minus-right
        # forward = d x (0,1,0) = (-d_z, 0, d_x); heading angle from +z toward +x
        theta = np.unwrap(np.arctan2(-d[:, 2], d[:, 0]))
        if facing == "first":
            # One turn for the whole clip (the heading of its first frames, the
            # pelvis' swing averaged out) about the root's first position:
            # a turn within the clip stays a turn.
            theta = np.full(F, theta[:max(min(int(window), F), 1)].mean())
            pivot = np.broadcast_to(pivot[0], pivot.shape)
        else:
            theta = smooth_linear(theta, window)
        yaw = -np.rad2deg(theta)  # per frame; constant with "first"
        c, s = np.cos(-theta), np.sin(-theta)
        hx = P[..., 0] - pivot[:, None, 0]
        hz = P[..., 2] - pivot[:, None, 1]
        P = P.copy()
        # rotation about y by phi = -theta: x' = x c + z s, z' = -x s + z c
        P[..., 0] = hx * c[:, None] + hz * s[:, None] + pivot[:, None, 0]
        P[..., 2] = -hx * s[:, None] + hz * c[:, None] + pivot[:, None, 1]
        if facing == "first" and root is not None:
            # The root's path turned with the clip: centre on the turned path.
            pivot = smooth_linear(P[:, root][:, [0, 2]], window)
    if center:
        if root is None:
            raise ValueError("center=True needs the root index")
        travel = pivot
        P = P.copy()
        P[..., 0] -= travel[:, None, 0]
        P[..., 2] -= travel[:, None, 1]
    az, el = np.deg2rad(azimuth), np.deg2rad(elevation)
    d = np.array([np.sin(az) * np.cos(el), np.sin(el), np.cos(az) * np.cos(el)])  # towards camera
    r = np.array([np.cos(az), 0.0, -np.sin(az)])                                  # image right
    u = np.cross(d, r)                                                           # image up
    xy = np.stack([P @ r, -(P @ u)], axis=-1)
    depth = -(P @ d)
    return Projection(xy=xy, depth=depth, yaw=yaw, travel=travel)


# --------------------------------------------------------------------------- resampling

def resample_times(n_frames: int, src_fps: float, dst_fps: float) -> np.ndarray:
    """Sample times (in source frames) for resampling ``n_frames`` to ``dst_fps``.

    The clip's duration ``(n-1)/src_fps`` is covered by ``m = round(duration
    * dst_fps) + 1`` evenly spaced samples that include both end frames, so
    the output rate is ``dst_fps`` to within half a frame over the clip
    (30 -> 15 fps on 129 frames gives exactly every other frame, 65 frames).
    """
    if not (src_fps > 0 and dst_fps > 0):
        raise ValueError("frame rates must be positive")
    if n_frames < 2:
        return np.zeros(max(n_frames, 0))
    duration = (n_frames - 1) / src_fps
    m = max(int(np.floor(duration * dst_fps + 0.5)) + 1, 2)
    return np.linspace(0.0, n_frames - 1, m)


def resample(x: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Resample per-frame data ``(F, ...)`` from ``src_fps`` to ``dst_fps``.

    Linear interpolation of positions between neighbouring frames (of
    positions, not joint angles: it needs no care with Euler angle wrap, and
    at 30 fps source rates the chord shortening of a rotating bone between
    two samples is negligible).  Both end frames are kept; see
    :func:`resample_times` for the frame count.  Returns ``(M, ...)``.
    """
    x = np.asarray(x, dtype=np.float64)
    if abs(src_fps - dst_fps) < 1e-9 * src_fps:
        return x.copy()
    t = resample_times(x.shape[0], src_fps, dst_fps)
    i0 = np.clip(np.floor(t).astype(np.int64), 0, max(x.shape[0] - 2, 0))
    w = (t - i0).reshape((-1,) + (1,) * (x.ndim - 1))
    i1 = np.minimum(i0 + 1, x.shape[0] - 1)
    return (1.0 - w) * x[i0] + w * x[i1]
