"""Skeletal motion in BVH files: reading, writing and forward kinematics.

A BVH file has a ``HIERARCHY`` section (joints with an ``OFFSET`` from their parent, a list
of ``CHANNELS`` and optional ``End Site`` leaves) and a ``MOTION`` section (``Frames:``,
``Frame Time:``, then one line of channel values per frame, in the order the channels are
declared, joints in file order).

Conventions (what real files from Blender, CMU, motion builders and game studios need):

* **Rotation channels** are intrinsic Euler angles in degrees, composed in the order they
  are written: ``Zrotation Xrotation Yrotation`` means ``R = Rz(z) @ Rx(x) @ Ry(y)``
  applied to column vectors (scipy: ``Rotation.from_euler("ZXY", [z, x, y],
  degrees=True)``). Any order, and any number of rotation channels (0 to 3), per joint
  (``CHANNELS 0``, or no ``CHANNELS`` line: a fixed joint). Refused, naming the joint:
  a position channel twice (which value?), more than 3 rotation channels, or two
  rotations about one axis in a row (``Xrotation Xrotation Yrotation``: no Euler order;
  ``ZXZ`` is one).
* **Position channels** may appear on any joint. When present, they *replace* the matching
  component of the joint's ``OFFSET`` as its translation in the parent frame (the files of
  the Bandai Namco set store every joint's bone vector there, equal to its offset, and
  the root's absolute position); absent components keep the offset. The translation is
  applied before the rotation, whatever the channel order.
* A joint's world transform is ``p_j = p_parent + R_parent @ t_j``, ``R_j = R_parent @
  R_local_j``; a root's parent is the world frame.
* Lines may end in CRLF; tokens may be separated by tabs; keywords are case-insensitive; a
  UTF-8 byte-order mark is skipped; a file that is not UTF-8 is read as Windows-1252 (joint
  names with accents from older exporters). A joint name is everything after ``ROOT``/``JOINT`` on
  its line up to an optional ``{`` (3ds Max writes names with spaces, ``Bip01 L Thigh``;
  runs of whitespace inside a name read as one space).
* Every line after ``Frame Time:`` is a frame, as Blender's importer reads them: when the
  ``Frames:`` count disagrees (exporters write off-by-one counts) a ``UserWarning`` says
  so and all frame lines are kept; a truncated last line still fails (wrong value count).
  Malformed input raises :class:`~shellspline.errors.ShellsplineError` with one line that
  names the file and the line number (a non-finite ``OFFSET`` or channel value too).
* Hierarchies of any depth (a chain of thousands of joints: a rope, a tail) are read and
  written without recursion.

Writing uses ``repr`` of every float (the shortest string that parses back to the same
double), so ``read_bvh(write_bvh(m))`` reproduces channel values, offsets and the frame time
bit for bit.
"""
from __future__ import annotations

import re
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from .atomic import write_text_atomic

__all__ = ["Motion", "read_bvh", "write_bvh", "forward_kinematics", "euler_matrices",
           "CHANNEL_NAMES"]

CHANNEL_NAMES = ("Xposition", "Yposition", "Zposition", "Xrotation", "Yrotation", "Zrotation")
"""Channel names of the BVH format (canonical spelling; files may use any case)."""

_CANONICAL = {c.lower(): c for c in CHANNEL_NAMES}


@dataclass(frozen=True, eq=False)
class Motion:
    """A skeleton and its channel values over time, as stored in a BVH file.

    Attributes
    ----------
    names : tuple of str, length J
        Joint names in file order (parents before children).
    parents : (J,) int64 numpy array
        Index of every joint's parent, ``-1`` for a root.
    offsets : (J,3) float64 numpy array
        ``OFFSET`` of every joint in its parent's frame.
    channels : tuple of tuple of str, length J
        Channel names of every joint, in file order (canonical spelling, e.g.
        ``("Xposition", "Yposition", "Zposition", "Zrotation", "Xrotation", "Yrotation")``).
    frame_time : float
        Seconds per frame.
    values : (T,C) float64 numpy array
        Channel values of every frame, ``C = sum(len(c) for c in channels)`` columns in
        file order; rotations in degrees.
    end_sites : tuple of (int, (3,) float64 numpy array)
        ``(parent joint, OFFSET)`` of every ``End Site``, in file order.
    """

    names: tuple
    parents: np.ndarray
    offsets: np.ndarray
    channels: tuple
    frame_time: float
    values: np.ndarray
    end_sites: tuple = ()

    def __post_init__(self):
        J = len(self.names)
        parents = np.asarray(self.parents, dtype=np.int64).reshape(-1)
        offsets = np.asarray(self.offsets, dtype=np.float64)
        if parents.shape != (J,) or offsets.shape != (J, 3) or len(self.channels) != J:
            raise ShellsplineError(
                f"Motion: names, parents, offsets and channels must describe the same "
                f"{J} joints, got parents {parents.shape}, offsets {offsets.shape}, "
                f"{len(self.channels)} channel lists")
        if np.any(parents >= np.arange(J)) or np.any(parents < -1):
            raise ShellsplineError("Motion: every parent must come before its child (index "
                                   f"-1 for a root), got parents {parents.tolist()}")
        channels = tuple(tuple(_canonical_channel(c, "Motion") for c in cs)
                         for cs in self.channels)
        for j, cs in enumerate(channels):
            why = _channel_problem(cs)
            if why is not None:
                raise ShellsplineError(f"Motion: joint {self.names[j]!r}: {why}")
        if not np.all(np.isfinite(offsets)):
            j = int(np.argwhere(~np.isfinite(offsets))[0, 0])
            raise ShellsplineError(f"Motion: the OFFSET of joint {self.names[j]!r} is not "
                                   f"finite: {offsets[j].tolist()}")
        C = sum(len(c) for c in channels)
        values = np.asarray(self.values, dtype=np.float64)
        if values.ndim != 2 or values.shape[1] != C:
            raise ShellsplineError(f"Motion: values must be a (frames, {C}) array, got shape "
                                   f"{values.shape}")
        if not (np.isfinite(self.frame_time) and self.frame_time > 0):
            raise ShellsplineError(f"Motion: frame_time must be positive, got "
                                   f"{self.frame_time!r}")
        ends = tuple((int(p), np.asarray(o, dtype=np.float64).reshape(3))
                     for p, o in self.end_sites)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))
        object.__setattr__(self, "parents", parents)
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "channels", channels)
        object.__setattr__(self, "frame_time", float(self.frame_time))
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "end_sites", ends)

    @property
    def n_frames(self) -> int:
        """Number of frames ``T``."""
        return self.values.shape[0]

    @property
    def n_joints(self) -> int:
        """Number of joints ``J`` (End Sites not counted)."""
        return len(self.names)

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time``."""
        return 1.0 / self.frame_time

    def joint_index(self, name: str) -> int:
        """Index of the joint called ``name`` (raises ``ShellsplineError`` if absent)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise ShellsplineError(f"Motion: no joint named {name!r} (joints: "
                                   f"{', '.join(self.names)})") from None

    def channel_columns(self, joint: int) -> np.ndarray:
        """Columns of :attr:`values` that belong to ``joint``: (c,) int64."""
        start = sum(len(c) for c in self.channels[:joint])
        return np.arange(start, start + len(self.channels[joint]), dtype=np.int64)

    def frames(self, start: int = 0, stop: int | None = None, step: int = 1) -> "Motion":
        """The same skeleton with the frames ``values[start:stop:step]`` (frame time scaled
        by ``step``)."""
        return Motion(self.names, self.parents, self.offsets, self.channels,
                      self.frame_time * step, self.values[start:stop:step], self.end_sites)

    def local_transforms(self) -> tuple[np.ndarray, np.ndarray]:
        """Every joint's rotation and translation in its parent's frame, at every frame.

        Returns
        -------
        R : (T,J,3,3) float64 numpy array
            Local rotations (identity for joints without rotation channels).
        t : (T,J,3) float64 numpy array
            Local translations: the offset, with components given by position channels
            replaced by their values.
        """
        T, J = self.n_frames, self.n_joints
        R = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
        t = np.broadcast_to(self.offsets, (T, J, 3)).copy()
        col = 0
        for j, chans in enumerate(self.channels):
            rot_axes, rot_cols = [], []
            for c in chans:
                if c.endswith("position"):
                    t[:, j, "XYZ".index(c[0])] = self.values[:, col]
                else:
                    rot_axes.append(c[0])
                    rot_cols.append(col)
                col += 1
            if rot_axes:
                R[:, j] = euler_matrices(self.values[:, rot_cols], "".join(rot_axes))
        return R, t


def euler_matrices(angles, axes: str) -> np.ndarray:
    """Rotation matrices of intrinsic Euler angles in degrees.

    Parameters
    ----------
    angles : (...,k) array_like
        Angles in degrees, one per axis.
    axes : str of length k (1 to 3)
        Axes among ``"X", "Y", "Z"`` (case-insensitive), in composition order.

    Returns
    -------
    (...,3,3) float64 numpy array
        ``R = R_axes[0](angles[...,0]) @ R_axes[1](angles[...,1]) @ ...``, acting on column
        vectors; equal to ``scipy.spatial.transform.Rotation.from_euler(axes.upper(),
        angles, degrees=True).as_matrix()``.

    Examples
    --------
    >>> R = euler_matrices([90.0, 0.0], "ZX")
    >>> np.round(R @ [1.0, 0.0, 0.0], 12) + 0.0
    array([0., 1., 0.])
    """
    a = np.radians(np.asarray(angles, dtype=np.float64))
    axes = axes.upper()
    if a.shape[-1:] != (len(axes),) or not axes or set(axes) - set("XYZ"):
        raise ShellsplineError(f"euler_matrices: need one angle per axis among X, Y, Z, got "
                               f"axes {axes!r} and angles of shape {a.shape}")
    R = None
    for i, ax in enumerate(axes):
        c, s = np.cos(a[..., i]), np.sin(a[..., i])
        E = np.zeros(a.shape[:-1] + (3, 3))
        p, q = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[ax]
        r = 3 - p - q
        E[..., r, r] = 1.0
        E[..., p, p] = c
        E[..., q, q] = c
        E[..., p, q] = -s
        E[..., q, p] = s
        R = E if R is None else R @ E
    return R


def forward_kinematics(motion: Motion) -> tuple[np.ndarray, np.ndarray]:
    """World positions and rotations of every joint at every frame.

    Parameters
    ----------
    motion : Motion

    Returns
    -------
    positions : (T,J,3) float64 numpy array
        Joint origins in world coordinates.
    rotations : (T,J,3,3) float64 numpy array
        Joint frames in world coordinates (``rotations[f, j] @ x`` maps a vector given in
        joint ``j``'s frame to world coordinates).

    Notes
    -----
    Vectorised over frames; one pass over the joints in file (topological) order:
    ``p_j = p_parent + R_parent t_j``, ``R_j = R_parent R_local_j``.
    """
    R_loc, t_loc = motion.local_transforms()
    P = np.empty_like(t_loc)  # every joint is written below, parents first
    R = np.empty_like(R_loc)
    for j, p in enumerate(motion.parents):
        if p < 0:
            P[:, j] = t_loc[:, j]
            R[:, j] = R_loc[:, j]
        else:
            P[:, j] = P[:, p] + np.einsum("fab,fb->fa", R[:, p], t_loc[:, j])
            R[:, j] = R[:, p] @ R_loc[:, j]
    return P, R


# ----------------------------------------------------------------------------------------
# Reading
# ----------------------------------------------------------------------------------------
class _Tokens:
    """Whitespace tokens of the HIERARCHY section with their line numbers."""

    def __init__(self, lines: list[str], start: int, stop: int, name: str):
        self.items = [(tok, i + 1) for i in range(start, stop) for tok in lines[i].split()]
        self.pos = 0
        self.name = name
        self.last_line = stop

    def error(self, msg: str, line: int | None = None) -> ShellsplineError:
        line = self.last_line if line is None else line
        return ShellsplineError(f"{self.name}:{line}: {msg}")

    def next(self, what: str) -> tuple[str, int]:
        if self.pos >= len(self.items):
            raise self.error(f"unexpected end of HIERARCHY, expected {what}")
        self.pos += 1
        return self.items[self.pos - 1]

    def peek(self) -> str | None:
        return self.items[self.pos][0] if self.pos < len(self.items) else None

    def peek_line(self) -> int | None:
        return self.items[self.pos][1] if self.pos < len(self.items) else None

    def expect(self, word: str) -> int:
        tok, line = self.next(repr(word))
        if tok.lower() != word.lower():
            raise self.error(f"expected {word!r}, got {tok!r}", line)
        return line

    def floats(self, k: int, what: str) -> np.ndarray:
        out = []
        for _ in range(k):
            tok, line = self.next(what)
            try:
                out.append(float(tok))
            except ValueError:
                raise self.error(f"{what}: expected a number, got {tok!r}", line) from None
            if not np.isfinite(out[-1]):
                raise self.error(f"{what}: expected a finite number, got {tok!r}", line)
        return np.array(out)


def _canonical_channel(c: str, where: str) -> str:
    try:
        return _CANONICAL[c.lower()]
    except (KeyError, AttributeError):
        raise ShellsplineError(f"{where}: unknown channel {c!r} (expected one of "
                               f"{', '.join(CHANNEL_NAMES)})") from None


def _channel_problem(chans) -> str | None:
    """Why a joint's channel list (canonical names) gives no well-defined transform, or None:
    a position channel twice (which value?), more than 3 rotation channels, or two rotations
    about one axis in a row (``Xrotation Xrotation Yrotation``: no Euler order; ``ZXZ`` is
    one)."""
    pos = [c for c in chans if c.endswith("position")]
    dup = next((c for c in pos if pos.count(c) > 1), None)
    if dup is not None:
        return f"{dup} appears twice in {' '.join(chans)}"
    rot = "".join(c[0] for c in chans if c.endswith("rotation"))
    if len(rot) > 3:
        return f"{len(rot)} rotation channels (at most 3, one Euler order) in {' '.join(chans)}"
    if any(x == y for x, y in zip(rot, rot[1:])):
        return f"two rotations about one axis in a row in {' '.join(chans)} (no Euler order)"
    return None


def read_bvh(path) -> Motion:
    """Read a BVH file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    Motion

    Raises
    ------
    ShellsplineError
        One line naming the file and line: missing ``HIERARCHY``/``MOTION``, unbalanced
        braces, unknown channels, a bad ``Frames:``/``Frame Time:`` header, a frame line
        with the wrong number of values or a non-number. ``OSError`` if the file cannot be
        read.

    Warns
    -----
    UserWarning
        When the number of frame lines differs from the ``Frames:`` count (all are read).
    """
    p = Path(path)
    name = str(p)
    data = p.read_bytes()
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError:  # joint names in a Windows code page (older exporters)
        text = data.decode("cp1252", errors="replace")
    text = text.removeprefix("\ufeff")  # byte-order mark
    lines = text.splitlines()
    motion_at = next((i for i, s in enumerate(lines) if s.strip().upper() == "MOTION"), None)
    first = next((i for i, s in enumerate(lines) if s.strip()), None)
    if first is None or lines[first].strip().upper() != "HIERARCHY":
        raise ShellsplineError(f"{name}:{(first or 0) + 1}: not a BVH file: expected "
                               "'HIERARCHY' as the first line")
    if motion_at is None:
        raise ShellsplineError(f"{name}: no MOTION section (the file ends after "
                               f"{len(lines)} lines of HIERARCHY)")
    toks = _Tokens(lines, first + 1, motion_at, name)
    names, parents, offsets, channels, ends = [], [], [], [], []
    while toks.peek() is not None:
        tok, line = toks.next("ROOT")
        if tok.upper() != "ROOT":
            raise toks.error(f"expected 'ROOT', got {tok!r}", line)
        _read_tree(toks, names, parents, offsets, channels, ends)
    if not names:
        raise ShellsplineError(f"{name}:{first + 1}: HIERARCHY declares no joint")
    frame_time, values = _read_motion(lines, motion_at, sum(len(c) for c in channels), name)
    return Motion(tuple(names), np.array(parents, dtype=np.int64), np.array(offsets),
                  tuple(channels), frame_time, values, tuple(ends))


def _read_tree(toks: _Tokens, names, parents, offsets, channels, ends) -> None:
    """The joints of one ``ROOT`` (its keyword read), depth first. A stack of the joints
    whose ``}`` is pending, not recursion: a chain of thousands of joints (a rope, a tail)
    reads like any other."""
    stack = [_read_joint(toks, -1, names, parents, offsets, channels)]
    while stack:
        j = stack[-1]
        jname = names[j]
        tok, line = toks.next(f"'}}' closing {jname}")
        key = tok.upper()
        if key == "}":
            stack.pop()
        elif key == "JOINT":
            stack.append(_read_joint(toks, j, names, parents, offsets, channels))
        elif key == "END":
            toks.expect("Site")
            toks.expect("{")
            toks.expect("OFFSET")
            ends.append((j, toks.floats(3, f"End Site OFFSET of {jname}")))
            toks.expect("}")
        else:
            raise toks.error(f"in joint {jname}: expected 'JOINT', 'End Site' or '}}', "
                             f"got {tok!r}", line)


def _read_joint(toks: _Tokens, parent, names, parents, offsets, channels) -> int:
    """A joint's name, ``{``, ``OFFSET`` and ``CHANNELS`` (the ``ROOT``/``JOINT`` keyword
    read); returns its index."""
    jname, line = toks.next("a joint name")
    if jname == "{":
        raise toks.error("joint without a name", line)
    while toks.peek() not in (None, "{") and toks.peek_line() == line:
        jname += " " + toks.next("a joint name")[0]  # "Bip01 L Thigh" (3ds Max Biped)
    j = len(names)
    names.append(jname)
    parents.append(parent)
    toks.expect("{")
    toks.expect("OFFSET")
    offsets.append(toks.floats(3, f"OFFSET of {jname}"))
    chans = []
    if (toks.peek() or "").upper() == "CHANNELS":
        _, cline = toks.next("CHANNELS")
        tok, line = toks.next("the channel count")
        if not tok.isdigit():
            raise toks.error(f"CHANNELS of {jname}: expected a count, got {tok!r}", line)
        for _ in range(int(tok)):
            c, line = toks.next(f"channel names of {jname}")
            if c.lower() not in _CANONICAL:
                raise toks.error(f"CHANNELS of {jname}: unknown channel {c!r} (expected "
                                 f"{tok} of {', '.join(CHANNEL_NAMES)})", line)
            chans.append(_CANONICAL[c.lower()])
        why = _channel_problem(chans)
        if why is not None:
            raise toks.error(f"CHANNELS of {jname}: {why}", cline)
    channels.append(tuple(chans))
    return j


_HEADER = re.compile(r"^\s*(frames|frame\s+time)\s*:\s*(\S+)\s*$", re.IGNORECASE)


def _read_motion(lines: list[str], at: int, C: int, name: str) -> tuple[float, np.ndarray]:
    header = {}
    i = at + 1
    for key in ("frames", "frame time"):
        while i < len(lines) and not lines[i].strip():
            i += 1
        m = _HEADER.match(lines[i]) if i < len(lines) else None
        if m is None or " ".join(m.group(1).lower().split()) != key:
            got = repr(lines[i].strip()) if i < len(lines) else "the end of the file"
            raise ShellsplineError(f"{name}:{i + 1}: expected '{key.title()}: <value>' after "
                                   f"MOTION, got {got}")
        try:
            header[key] = int(m.group(2)) if key == "frames" else float(m.group(2))
        except ValueError:
            raise ShellsplineError(f"{name}:{i + 1}: {key.title()}: expected "
                                   f"{'an integer' if key == 'frames' else 'a number'}, got "
                                   f"{m.group(2)!r}") from None
        i += 1
    n, ft = header["frames"], header["frame time"]
    if n < 0:
        raise ShellsplineError(f"{name}:{i - 1}: Frames: must be non-negative, got {n}")
    if not (np.isfinite(ft) and ft > 0):
        raise ShellsplineError(f"{name}:{i}: Frame Time: must be positive, got {ft!r}")
    rows = [(k + 1, s) for k, s in enumerate(lines[i:], start=i) if s.strip()]
    if len(rows) != n:  # as Blender's importer: every frame line is read, the count warned
        warnings.warn(f"{name}: Frames: declares {n} frames, the file has {len(rows)} frame "
                      f"lines; all {len(rows)} are read", UserWarning, stacklevel=3)
        n = len(rows)
    values = np.zeros((n, C))
    for f, (line, s) in enumerate(rows):
        tok = s.split()
        if len(tok) != C:
            raise ShellsplineError(f"{name}:{line}: frame {f} has {len(tok)} values, the "
                                   f"HIERARCHY declares {C} channels")
        try:
            values[f] = [float(x) for x in tok]
        except ValueError:
            bad = next(x for x in tok if not _is_float(x))
            raise ShellsplineError(f"{name}:{line}: frame {f}: expected numbers, got "
                                   f"{bad!r}") from None
    if not np.all(np.isfinite(values)):
        f = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise ShellsplineError(f"{name}:{rows[f][0]}: frame {f} has a non-finite value")
    return ft, values


def _is_float(x: str) -> bool:
    try:
        float(x)
    except ValueError:
        return False
    return True


# ----------------------------------------------------------------------------------------
# Writing
# ----------------------------------------------------------------------------------------
def write_bvh(motion: Motion, path) -> Path:
    """Write a BVH file (LF line endings, tab indentation, ``repr`` of every float).

    Parameters
    ----------
    motion : Motion
    path : str or path-like
        Destination; written atomically (a temporary sibling renamed into place).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    ShellsplineError
        Before anything is written, for what would not read back: a joint name that is
        empty or holds a line break or a ``{`` word, a non-finite channel value.

    Notes
    -----
    ``repr`` gives the shortest decimal string that parses back to the same double, so
    reading the file back reproduces ``values``, ``offsets`` and ``frame_time`` exactly.
    """
    for n in motion.names:
        if not n.split() or "{" in n.split() or "\n" in n or "\r" in n:
            raise ShellsplineError(f"write_bvh: {path}: joint name {n!r} cannot be written "
                                   "(empty, a line break or a '{' word)")
    if not np.all(np.isfinite(motion.values)):
        f, c = map(int, np.argwhere(~np.isfinite(motion.values))[0])
        j = int(np.searchsorted(np.cumsum([len(ch) for ch in motion.channels]), c, "right"))
        raise ShellsplineError(f"write_bvh: {path}: frame {f} has a non-finite value "
                               f"({float(motion.values[f, c])!r}) in a channel of joint "
                               f"{motion.names[j]!r}")
    out = ["HIERARCHY"]
    children = [[] for _ in motion.names]
    for j, p in enumerate(motion.parents):
        if p >= 0:
            children[p].append(j)
    ends = [[] for _ in motion.names]
    for p, o in motion.end_sites:
        ends[p].append(o)

    def fmt(xs):
        return " ".join(repr(float(x)) for x in xs)

    order = []
    stack = [int(j) for j in np.flatnonzero(motion.parents < 0)][::-1]
    while stack:
        j = stack.pop()
        order.append(j)
        stack += children[j][::-1]
    if order != list(range(motion.n_joints)):
        raise ShellsplineError(f"write_bvh: {path}: joints must be in depth-first order (every "
                               f"joint's subtree right after it), got order {order}")
    # a stack, not recursion (chains of thousands of joints): a joint's header, its
    # children, then its End Sites and its closing brace
    todo = [(False, int(j), 0) for j in np.flatnonzero(motion.parents < 0)][::-1]
    while todo:
        closing, j, depth = todo.pop()
        ind = "\t" * depth
        if closing:
            for o in ends[j]:
                out.extend([f"{ind}\tEnd Site", ind + "\t{", f"{ind}\t\tOFFSET {fmt(o)}",
                            ind + "\t}"])
            out.append(ind + "}")
            continue
        out.append(f"{ind}{'ROOT' if motion.parents[j] < 0 else 'JOINT'} {motion.names[j]}")
        out.append(ind + "{")
        out.append(f"{ind}\tOFFSET {fmt(motion.offsets[j])}")
        if motion.channels[j]:
            out.append(f"{ind}\tCHANNELS {len(motion.channels[j])} "
                       + " ".join(motion.channels[j]))
        todo.append((True, j, depth))
        todo += [(False, c, depth + 1) for c in children[j][::-1]]
    out += ["MOTION", f"Frames: {motion.n_frames}", f"Frame Time: {motion.frame_time!r}"]
    out += [" ".join(map(repr, row)) for row in motion.values.tolist()]
    return write_text_atomic(path, "\n".join(out) + "\n")
