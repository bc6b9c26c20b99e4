"""BVH motion capture: reader and forward kinematics (projection and resampling: :mod:`nnsf.datasets.projection`).

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
  importer and of captures that put a root OFFSET far from the origin, e.g.
  a ``Hips`` OFFSET z = -452 with position channels near 0, and repeat every
  other joint's OFFSET in its position channels).  ``"add"`` gives ``t = OFFSET + channels``, the
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

import codecs
import io
import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nnsf.errors import InputError
from nnsf.io import read_bytes

__all__ = [
    "BVH", "read_bvh", "parse_bvh", "forward_kinematics", "local_rotations", "local_translations",
    "euler_matrices",
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
    notes : list[str]
        What the reader tolerated, one line each (a ``Frames:`` count off by a
        row or two).
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
    notes: list = field(default_factory=list)
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
    def site_kinds(self) -> np.ndarray:
        """Per node, ``(J,)`` int: 0 a joint, 1 an End Site, 2 an End Site whose OFFSET is zero
        (it coincides with its joint, so it marks no point of its own)."""
        void = self.is_end_site & ~np.any(self.offsets != 0, axis=1)
        return self.is_end_site.astype(np.int64) + void

    @property
    def joint_names(self) -> tuple[str, ...]:
        """Names of the real joints (End Sites left out)."""
        return tuple(n for n, e in zip(self.names, self.is_end_site) if not e)

    def index(self, name: str) -> int:
        """Node index of ``name``; ``KeyError`` if absent."""
        return self._index[name]


# --------------------------------------------------------------------------- reading

#: Largest .bvh file read (bytes); an hour of 60 fps capture is about 200 MB.
MAX_BVH_BYTES = 512_000_000
#: Most nodes (joints and End Sites) of a hierarchy: real skeletons, fingers and face bones
#: included, have a few hundred.
MAX_NODES = 10_000
#: Longest HIERARCHY section (characters): :data:`MAX_NODES` nodes of 1 000 characters each.
MAX_HIERARCHY_CHARS = 10_000_000
#: Most motion values (``Frames`` x channels) read, checked on the header before any is parsed:
#: 400 MB of float64, an hour of 60 fps capture of over 200 channels.
MAX_MOTION_VALUES = 50_000_000
#: Shortest ``Frame Time`` (s): 10 000 frames per second, beyond any capture system.
MIN_FRAME_TIME = 1e-4
#: Characters of the motion block handed to the numeric parser at once (bounds its memory).
_CHUNK_CHARS = 8_000_000

#: Byte-order marks and the encodings they announce (UTF-32 first: its LE mark starts with UTF-16's).
_BOMS = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"), (codecs.BOM_UTF8, "utf-8-sig"),
         (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))


def decode_bvh(data: bytes, source="<bytes>") -> str:
    """The text of a BVH file's bytes, with ``\n`` line ends.

    A byte-order mark picks the encoding (UTF-8, UTF-16 or UTF-32, as Windows
    tools write); without one the bytes are UTF-8, else Latin-1 (every byte
    decodes: old exporters write Latin-1 names).  Windows (``\r\n``) and
    old Mac (``\r``) line ends become ``\n``, so line numbers in messages
    are the ones an editor shows.
    """
    for bom, encoding in _BOMS:
        if data.startswith(bom):
            try:
                text = data.decode(encoding)
            except UnicodeDecodeError as exc:
                raise InputError(source, "file", f"a text file in the {encoding.upper()} its byte-order mark "
                                 "announces", reason=f"bytes at offset {exc.start} cannot be decoded") from None
            break
    else:
        try:
            text = data.decode("utf-8", errors="strict")
        except UnicodeDecodeError:
            text = data.decode("latin-1")
    text = text.lstrip("\ufeff")
    if "\r" in text:
        text = text.replace("\r\n", "\n").replace("\r", "\n")
    return text


def read_bvh(path) -> BVH:
    """Read a BVH file; bad content raises :class:`InputError` naming file and line."""
    path = Path(path)
    if not path.is_file():
        raise InputError(path, "file", "an existing .bvh file")

    data = read_bytes(path, MAX_BVH_BYTES, "a readable .bvh file")
    return parse_bvh(decode_bvh(data, path), source=path)


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
    if m.start() > MAX_HIERARCHY_CHARS:
        # Checked before the hierarchy is split into tokens (a Python object each).
        raise InputError(source, "HIERARCHY", f"a hierarchy of at most {MAX_HIERARCHY_CHARS} characters "
                         f"(at most {MAX_NODES} joints and End Sites)", f"{m.start()} characters")
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
    if not (frame_time >= MIN_FRAME_TIME and math.isfinite(frame_time)):
        raise InputError(source, f"line {line_no - 1}", f"Frame Time: a number of seconds >= {MIN_FRAME_TIME:g} "
                         f"(at most {1 / MIN_FRAME_TIME:g} frames per second)", frame_time)
    if n_frames * max(len(ch_node), 1) > MAX_MOTION_VALUES:
        # Checked on the header, before any row is parsed: the rows would be allocated first.
        raise InputError(source, f"line {frames_line}", f"Frames x channels of at most {MAX_MOTION_VALUES} "
                         f"values (with {len(ch_node)} channels, at most "
                         f"{MAX_MOTION_VALUES // max(len(ch_node), 1)} frames)", n_frames)
    motion = _parse_motion(text[pos:], line_no, n_frames, len(ch_node), source)
    notes = []
    if len(motion) != n_frames:
        notes.append(f"{source}: line {frames_line}: Frames: says {n_frames}, the file has {len(motion)} "
                     f"motion lines; all {len(motion)} were read")
    return BVH(
        source=str(source), names=tuple(names), parents=np.array(parents, dtype=np.int64),
        offsets=np.array(offsets, dtype=np.float64).reshape(-1, 3),
        is_end_site=np.array(ends, dtype=bool), channels=tuple(chans),
        channel_node=np.array(ch_node, dtype=np.int64), channel_axis=np.array(ch_axis, dtype=np.int64),
        channel_is_rotation=np.array(ch_rot, dtype=bool), motion=motion, frame_time=frame_time,
        notes=notes,
    )


def _parse_hierarchy(toks, source):
    names, parents, offsets, ends, chans = [], [], [], [], []
    taken: set[str] = set()         # the names, for O(1) look-ups
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
            if not name.isprintable():
                raise InputError(source, f"line {line}", "a joint name of printable characters", name)
            if name in taken:
                raise InputError(source, f"line {line}", "unique joint names", name)
            seen_root = True
            _room(names, source, line)
            taken.add(name)
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
            while name in taken:
                name, c = f"{base}{c}", c + 1
            _room(names, source, line)
            taken.add(name)
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


def _room(names, source, line) -> None:
    if len(names) >= MAX_NODES:
        raise InputError(source, f"line {line}", f"a hierarchy of at most {MAX_NODES} joints and End Sites",
                         "more")


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


#: Motion lines the data may have beyond or short of the ``Frames:`` count and still be read
#: whole (with a note): exporters that count the T-pose or drop the last frame are off by one.
FRAME_COUNT_SLACK = 2


def _parse_motion(block: str, first_line: int, n_frames, n_channels, source) -> np.ndarray:
    """Rows of ``n_channels`` numbers from ``block`` (whose first line is line
    ``first_line`` of the file): ``n_frames`` of them, or up to
    :data:`FRAME_COUNT_SLACK` more or fewer (every complete row is kept).

    The block goes to ``np.loadtxt`` (C parser) in pieces of about
    :data:`_CHUNK_CHARS` characters, written into one array allocated for
    the rows the header announces (the caller bounded it), so memory stays
    that array plus one piece whatever the file's size.  A piece that does
    not parse is passed again line by line, to name the line to blame.
    """
    if n_channels == 0:
        raise InputError(source, "CHANNELS", "at least one channel in the hierarchy", 0)
    lo, hi = max(n_frames - FRAME_COUNT_SLACK, 1), n_frames + FRAME_COUNT_SLACK
    out = np.empty((hi, n_channels))
    rows, pos, line = 0, 0, first_line
    while pos < len(block):
        end = block.find("\n", min(pos + _CHUNK_CHARS, len(block)))
        end = len(block) if end < 0 else end + 1
        piece = block[pos:end]
        part = _piece_rows(piece, n_channels)
        if part is None or rows + len(part) > hi:
            _blame(piece, line, rows, n_frames, hi, n_channels, source)
        out[rows:rows + len(part)] = part
        rows += len(part)
        line += piece.count("\n")
        pos = end
    if rows < lo:
        raise InputError(source, f"line {line}",
                         f"{n_frames} motion lines as Frames: says (file truncated?)", rows)
    return out[:rows]


def _piece_rows(piece: str, n_channels: int) -> np.ndarray | None:
    """``piece`` parsed as rows of ``n_channels`` finite numbers, or None."""
    if not piece.strip():
        return np.empty((0, n_channels))
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            part = np.loadtxt(io.StringIO(piece), dtype=np.float64, ndmin=2, comments=None)
    except ValueError:
        return None
    if part.shape[1] != n_channels or not np.isfinite(part).all():
        return None
    return part


def _blame(piece: str, first_line: int, rows: int, n_frames: int, hi: int, n_channels: int, source):
    """Raise the :class:`InputError` naming the first bad line of ``piece`` (line ``first_line``),
    ``rows`` rows having been read before it."""
    for i, line in enumerate(piece.splitlines()):
        vals = line.split()
        if not vals:
            continue
        lineno = first_line + i
        rows += 1
        if rows > hi:
            raise InputError(source, f"line {lineno}", f"{n_frames} motion lines as Frames: says "
                             f"(give or take {FRAME_COUNT_SLACK})", "more lines")
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
    raise InputError(source, f"line {first_line}", "a readable motion block")  # pragma: no cover


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
