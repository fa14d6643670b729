"""Skeletal animations as curves on SO(3)^d x R^m: conversion, features, metrics, operations.

A :class:`~shellspline.io.bvh.Motion` becomes a :class:`MotionCurve`: the local rotation of
every joint that has rotation channels (``d`` joints, ``R (N,d,3,3)``) and the values of every
position channel (``m`` channels, ``X (N,m)``, file units), sampled at ``N`` frames. The curve
goes back to a ``Motion`` with the same channel layout: rotations are written in each joint's
own Euler order, on the branch nearest a reference (the source values), position channels
stay position channels. Nothing here assumes a skeleton, joint names, an up axis, a frame
rate or a channel layout.

On top of it:

* resampling to another frame rate or length (:func:`resample`, geodesic between frames);
* the up axis (:func:`up_axis`), the feet (:func:`find_feet`) and foot contacts from joint
  heights and speeds (:func:`foot_contacts`), all detected from the data;
* metrics: foot skate (:func:`foot_skate`) and the seam gap of a loop (:func:`seam_gap`);
* operations (:func:`distance`, :func:`align`, :func:`blend`, :func:`close`) built on the
  square-root-velocity machinery of :mod:`shellspline.curves` (seed 000), with foot contacts
  as feature points (seed 003), and a root-translation correction that keeps planted feet
  from sliding (:func:`plant_feet`);
* the same operations on mesh animations (LΘA descriptor curves, ``mesh_*``) and on rigid
  pose tracks (camera / rigid-body trajectories as curves in SO(3) x R^3, ``track_*``).

Layer: above :mod:`shellspline.io` (imports ``io.bvh``, ``curves``, ``groups``, ``errors``).
"""
from __future__ import annotations

import numbers
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .errors import ShellsplineError
from .groups import so3
from .io.bvh import Motion, euler_matrices, forward_kinematics

__all__ = ["MotionCurve", "motion_curve", "euler_angles", "resample", "skeleton_mismatch",
           "with_channel_layout", "common_grid", "MOTION_DP_FRAMES", "heading_aligned",
           "warp_motion", "stage_joint", "stage_kinematics", "STATIC_TOL", "up_axis",
           "body_height", "body_joints", "translation_root", "find_feet", "CLOSE_MAX_STEP", "FLIP_TOL",
           "FootContacts", "foot_contacts", "foot_skate", "seam_gap", "plant_feet",
           "contact_features", "AlignReport", "align", "distance", "blend", "CloseReport",
           "loop_range", "close", "MeshCurve", "mesh_curve", "reconstruct_frames", "MeshReport",
           "mesh_close", "close_euclidean", "MESH_C1_MAX_DIMS", "mesh_align", "mesh_distance",
           "mesh_blend", "reparametrize_vertices", "mesh_on_source", "CLOSE_TOL",
           "track_length", "track_curve", "TRACK_DP_SAMPLES", "TrackReport", "track_close",
           "track_align", "track_distance", "track_blend"]

# Contact thresholds, relative to the leg length L (hip branch point to the foot leaf):
# a foot joint is planted when it is within CONTACT_HEIGHT * L of its own lowest level and
# moves horizontally slower than CONTACT_SPEED * L per second. On the real walks (L ~ 90 cm)
# planted toes move < 10 cm/s and swinging ones 100-400 cm/s; heights 4.2 cm planted, up to
# 14 cm in swing (tests/test_animation.py checks the gait periodicity).
CONTACT_HEIGHT = 0.05
CONTACT_SPEED = 0.5
# Weight of the feature term lam * sum (phi(a_i) - b_i)^2 (normalised times) when feature
# points are given without a weight. walk_normal against walk_happy with their touch-downs
# as features (tests/test_animation.py): lam = 0, 1, 10 leave the touch-downs 13.7 frames
# apart on average (the DP matches a step with the next one), lam = 100 brings them to 1.1
# frames for 1 % more SRV distance (6.14 -> 6.21); lam = 1000: 0.75 frames, 6.25.
FEATURE_WEIGHT = 100.0
# Contacts and gaps shorter than this (seconds) are noise: a foot that brushes the ground
# for one frame after lift-off, or a planted foot that jitters for one frame (on the
# synthetic 120 Hz walk a 1-frame brush after every lift-off doubled the touch-downs).
CONTACT_MIN_TIME = 0.06


# ----------------------------------------------------------------------------------------
# Motion <-> curve
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MotionCurve:
    """A motion as a sampled curve in SO(3)^d x R^m.

    Attributes
    ----------
    R : (N,d,3,3) float64 numpy array
        Local rotations of the joints that have rotation channels.
    X : (N,m) float64 numpy array
        Values of every position channel (file units), in column order.
    frame_time : float
        Seconds per frame.
    template : Motion
        The motion that gives the skeleton and channel layout.
    rot_joints : (d,) int64 numpy array
        Joint index of every rotation block.
    pos_cols : (m,) int64 numpy array
        Column of :attr:`Motion.values` of every position channel.
    reference : (N,C) float64 numpy array
        Channel values whose Euler branches :meth:`to_motion` follows (the source values,
        resampled to the curve's frames).
    """

    R: np.ndarray
    X: np.ndarray
    frame_time: float
    template: Motion
    rot_joints: np.ndarray
    pos_cols: np.ndarray
    reference: np.ndarray

    @property
    def n_frames(self) -> int:
        """Number of samples ``N``."""
        return self.R.shape[0]

    @property
    def t(self) -> np.ndarray:
        """Normalised parameter ``(N,)``: ``linspace(0, 1, N)``."""
        return np.linspace(0.0, 1.0, self.n_frames)

    @property
    def duration(self) -> float:
        """``(N - 1) * frame_time`` seconds."""
        return (self.n_frames - 1) * self.frame_time

    def with_samples(self, R, X, frame_time=None, reference=None) -> "MotionCurve":
        """The same layout with other samples (``reference`` resampled from this curve's by
        frame position when not given)."""
        R = np.asarray(R, dtype=np.float64)
        X = np.asarray(X, dtype=np.float64)
        if reference is None:
            reference = _resample_linear(self.reference, R.shape[0])
        return replace(self, R=R, X=X, reference=np.asarray(reference, dtype=np.float64),
                       frame_time=self.frame_time if frame_time is None else float(frame_time))

    def to_motion(self) -> Motion:
        """The curve as a :class:`Motion` with the template's channel layout.

        Rotations are converted to each joint's own Euler order (1 to 3 rotation channels),
        choosing per frame the Euler solution and the multiples of 360 degrees nearest the
        reference values (a frame whose rotation equals the reference's, to 4e-16, keeps the
        reference angles exactly: unchanged frames round-trip bit for bit, gimbal lock
        included); position channels take the values of ``X``; channels of joints without
        rotation keep their reference values.
        """
        tpl = self.template
        values = self.reference.copy()
        values[:, self.pos_cols] = self.X
        for b, j in enumerate(self.rot_joints):
            cols = tpl.channel_columns(int(j))
            rcols = [c for c, name in zip(cols, tpl.channels[j]) if name.endswith("rotation")]
            axes = "".join(name[0] for name in tpl.channels[j] if name.endswith("rotation"))
            ref = values[:, rcols]
            ang = euler_angles(self.R[:, b], axes, ref)
            # frames whose rotation is the reference's keep its angles bit for bit (also at
            # gimbal lock, where other angles give the same rotation)
            same = np.abs(euler_matrices(ref, axes) - self.R[:, b]).max(axis=(1, 2)) <= 4e-16
            values[:, rcols] = np.where(same[:, None], ref, ang)
        return Motion(tpl.names, tpl.parents, tpl.offsets, tpl.channels, self.frame_time,
                      values, tpl.end_sites)


def _rotation_layout(motion: Motion):
    rot_joints, pos_cols = [], []
    col = 0
    for j, chans in enumerate(motion.channels):
        if any(c.endswith("rotation") for c in chans):
            rot_joints.append(j)
        for c in chans:
            if c.endswith("position"):
                pos_cols.append(col)
            col += 1
    return np.array(rot_joints, dtype=np.int64), np.array(pos_cols, dtype=np.int64)


def motion_curve(motion: Motion) -> MotionCurve:
    """A motion as a curve in SO(3)^d x R^m.

    Parameters
    ----------
    motion : Motion
        Any skeleton and channel layout; at least one frame.

    Returns
    -------
    MotionCurve
        ``R (T,d,3,3)``: local rotations (``bvh.euler_matrices`` of each joint's rotation
        channels) of the ``d`` joints with rotation channels; ``X (T,m)``: the ``m`` position
        channels; ``reference``: the channel values.

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.io.bvh import Motion
    >>> m = Motion(("root",), [-1], np.zeros((1, 3)), (("Xposition", "Zrotation"),), 0.1,
    ...            [[1.0, 30.0], [2.0, 40.0]])
    >>> c = motion_curve(m)
    >>> c.R.shape, c.X.ravel().tolist()
    ((2, 1, 3, 3), [1.0, 2.0])
    >>> bool(np.allclose(c.to_motion().values, m.values))
    True
    """
    if not isinstance(motion, Motion):
        raise ShellsplineError(f"motion_curve: expected a Motion, got {type(motion).__name__}")
    if motion.n_frames < 1:
        raise ShellsplineError("motion_curve: the motion has no frame")
    rot_joints, pos_cols = _rotation_layout(motion)
    T = motion.n_frames
    R = np.zeros((T, rot_joints.size, 3, 3))
    for b, j in enumerate(rot_joints):
        cols = motion.channel_columns(int(j))
        rcols = [c for c, name in zip(cols, motion.channels[j]) if name.endswith("rotation")]
        axes = "".join(name[0] for name in motion.channels[j] if name.endswith("rotation"))
        R[:, b] = euler_matrices(motion.values[:, rcols], axes)
    return MotionCurve(R, motion.values[:, pos_cols].copy(), motion.frame_time, motion,
                       rot_joints, pos_cols, motion.values.copy())


def euler_angles(R, axes: str, reference=None) -> np.ndarray:
    """Intrinsic Euler angles in degrees of rotation matrices: the inverse of
    :func:`~shellspline.io.bvh.euler_matrices`.

    Parameters
    ----------
    R : (...,3,3) array_like
    axes : str of length k (1 to 3)
        Composition order, e.g. ``"ZXY"``.
    reference : (...,k) array_like, optional
        Angles to stay near: of the two Euler solutions (3 axes) the nearer one is taken and
        every angle is shifted by the multiple of 360 nearest the reference.

    Returns
    -------
    (...,k) float64 numpy array
        Exact for 3 axes; for 1 or 2 axes the rotation is projected on the axes (exact when
        ``R`` is a product of rotations about them).
    """
    from scipy.spatial.transform import Rotation

    R = np.asarray(R, dtype=np.float64)
    axes = axes.upper()
    lead = R.shape[:-2]
    flat = R.reshape(-1, 3, 3)
    k = len(axes)
    if k == 1:
        p, q = {"X": (1, 2), "Y": (2, 0), "Z": (0, 1)}[axes]
        cands = [np.degrees(np.arctan2(flat[:, q, p], flat[:, p, p]))[:, None]]
    else:
        full = axes if k == 3 else axes + ({"X", "Y", "Z"} - set(axes)).pop()
        with warnings.catch_warnings():  # gimbal lock: scipy warns and sets the last angle 0
            warnings.simplefilter("ignore")
            a = Rotation.from_matrix(flat).as_euler(full, degrees=True)
        if k == 3:
            alt = a + [180.0, 0.0, 180.0]
            alt[:, 1] = -a[:, 1] if full[0] == full[2] else 180.0 - a[:, 1]
            cands = [a, alt]
        else:
            cands = [a[:, :2]]
    if reference is None:
        out = cands[0]
    else:
        ref = np.broadcast_to(np.asarray(reference, dtype=np.float64), lead + (k,)).reshape(-1, k)
        shifted = [c + 360.0 * np.round((ref - c) / 360.0) for c in cands]
        cost = np.stack([np.abs(s - ref).sum(axis=1) for s in shifted])
        out = np.take_along_axis(np.stack(shifted), np.argmin(cost, axis=0)[None, :, None],
                                 axis=0)[0]
    return out.reshape(lead + (k,))


def _resample_linear(A, n: int) -> np.ndarray:
    """Rows of ``A (N,...)`` linearly interpolated at ``n`` evenly spaced positions."""
    N = A.shape[0]
    if n == N:
        return A.copy()
    s = np.linspace(0.0, N - 1.0, n)
    i = np.minimum(np.floor(s).astype(np.int64), max(N - 2, 0))
    w = (s - i).reshape((-1,) + (1,) * (A.ndim - 1))
    return A[i] * (1 - w) + A[np.minimum(i + 1, N - 1)] * w


def _slerp_rows(R, s) -> np.ndarray:
    """Rotations ``R (N,d,3,3)`` at fractional frame positions ``s (n,)`` (geodesic between
    neighbouring frames)."""
    N = R.shape[0]
    i = np.minimum(np.floor(s).astype(np.int64), max(N - 2, 0))
    w = s - i
    j = np.minimum(i + 1, N - 1)
    D = so3.log(np.swapaxes(R[i], -1, -2) @ R[j])  # (n,d,3), body-frame step
    return R[i] @ so3.exp(D * w[:, None, None])


def _sample_curve(c: MotionCurve, s) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(R, X, reference)`` of a curve at fractional frame positions ``s (n,)``."""
    s = np.asarray(s, dtype=np.float64)
    N = c.n_frames
    i = np.minimum(np.floor(s).astype(np.int64), max(N - 2, 0))
    w = (s - i)[:, None]
    j = np.minimum(i + 1, N - 1)
    return (_slerp_rows(c.R, s), c.X[i] * (1 - w) + c.X[j] * w,
            c.reference[i] * (1 - w) + c.reference[j] * w)


def resample(motion: Motion, *, frame_time: float | None = None,
             n_frames: int | None = None) -> Motion:
    """The motion at another frame rate, or stretched to another number of frames.

    Parameters
    ----------
    motion : Motion
    frame_time : float, optional
        New seconds per frame; the duration is kept (to the nearest frame).
    n_frames : int, optional
        New number of frames (>= 2); with ``frame_time`` too, the clip is stretched to
        ``(n_frames - 1) * frame_time`` seconds, otherwise the duration is kept.

    Returns
    -------
    Motion
        Rotations interpolated along SO(3) geodesics between neighbouring frames, position
        channels linearly; the same channel layout.
    """
    if motion.n_frames < 2:
        raise ShellsplineError(f"resample: need at least 2 frames, got {motion.n_frames}")
    dur = (motion.n_frames - 1) * motion.frame_time
    if frame_time is not None and not (np.isfinite(frame_time) and frame_time > 0):
        raise ShellsplineError(f"resample: frame_time must be positive, got {frame_time!r}")
    if n_frames is None:
        if frame_time is None:
            return motion
        n_frames = int(round(dur / frame_time)) + 1
    n_frames = int(n_frames)
    if n_frames < 2:
        raise ShellsplineError(f"resample: n_frames must be >= 2, got {n_frames}")
    if frame_time is None:
        frame_time = dur / (n_frames - 1)
    c = motion_curve(motion)
    R, X, ref = _sample_curve(c, np.linspace(0.0, motion.n_frames - 1.0, n_frames))
    return c.with_samples(R, X, frame_time, ref).to_motion()


def _rotation_axes(chans) -> str:
    return "".join(c[0] for c in chans if c.endswith("rotation"))


def _position_axes(chans) -> str:
    return "".join(c[0] for c in chans if c.endswith("position"))


def _joint_key(name: str) -> str:
    """A joint name as compared between clips: without a namespace (``mixamorig:Hips``,
    ``mixamorig1:Hips`` and ``Hips`` are one joint) and case-insensitive."""
    return name.rsplit(":", 1)[-1].strip().lower()


def _joints_by_name(a: Motion, b: Motion) -> np.ndarray | None:
    """The index in ``b`` of every joint of ``a``, matched by name (:func:`_joint_key`), or
    None when names do not identify the joints: a name twice in one clip, or not the same
    names in both."""
    ka, kb = [_joint_key(n) for n in a.names], [_joint_key(n) for n in b.names]
    if len(set(ka)) != len(ka) or len(set(kb)) != len(kb) or set(ka) != set(kb):
        return None
    at = {k: i for i, k in enumerate(kb)}
    return np.array([at[k] for k in ka], dtype=np.int64)


def _joints_reordered(motion: Motion, order) -> Motion:
    """``motion`` with its joints in ``order`` (old indices; parents first): names, parents,
    offsets, channels, value columns and End Sites carried along."""
    order = [int(j) for j in order]
    if order == list(range(motion.n_joints)):
        return motion
    new = {j: i for i, j in enumerate(order)}
    parents = [-1 if motion.parents[j] < 0 else new[int(motion.parents[j])] for j in order]
    cols = np.concatenate([motion.channel_columns(j) for j in order])
    ends = sorted(((new[p], o) for p, o in motion.end_sites), key=lambda e: e[0])
    return Motion(tuple(motion.names[j] for j in order), parents, motion.offsets[order],
                  tuple(motion.channels[j] for j in order), motion.frame_time,
                  motion.values[:, cols], tuple(ends))


def _parent_name(m: Motion, p) -> str:
    return "none (a root)" if p < 0 else m.names[int(p)]


def _name_list(names, k: int = 3) -> str:
    return ", ".join(names[:k]) + (f" and {len(names) - k} more" if len(names) > k else "")


def skeleton_mismatch(a: Motion, b: Motion) -> str | None:
    """Why two motions are not clips of one skeleton, or None when they are.

    One skeleton: the same joints with the same parents, and on every joint the same
    position channels (in any order) and rotation channels that give the same rotations:
    the same axes in the same order, or three distinct axes in each (any Euler order: ZXY
    and XYZ files of one rig are one skeleton, see :func:`with_channel_layout`). When the
    joint names match one to one (ignoring case and a namespace such as ``mixamorig:``),
    joints are matched by name, in any file order (exporters list the legs or the arms
    first; the left leg listed before the right one in one file and after it in the other
    is not the same joint); otherwise by position in the file, and names may differ
    (another naming convention). Offsets may differ (another performer).
    """
    why = None
    order = _joints_by_name(a, b)
    if order is not None:  # b's joints in a's order, their parents matched by name too
        where = np.empty(b.n_joints, dtype=np.int64)
        where[order] = np.arange(b.n_joints)
        pb = np.array([-1 if b.parents[j] < 0 else where[b.parents[j]] for j in order])
        if not np.array_equal(pb, a.parents):
            j = int(np.flatnonzero(pb != a.parents)[0])
            why = (f"; joint {a.names[j]}: parent {_parent_name(a, a.parents[j])} against "
                   f"{_parent_name(a, pb[j])}")
        else:
            b = _joints_reordered(b, order)
    if why is None:
        why = _layout_difference(a, b)
    if why is None:
        return None
    return (f"the two motions have different skeletons: {a.n_joints} joints "
            f"({sum(map(len, a.channels))} channels) against {b.n_joints} joints "
            f"({sum(map(len, b.channels))} channels){why}")


def _joint_order_like(motion: Motion, template: Motion) -> Motion:
    """``motion`` with its joints in ``template``'s file order when they are matched by name
    (:func:`skeleton_mismatch`), so that joint ``j`` is the same joint in both; raises when
    the skeletons differ."""
    why = skeleton_mismatch(template, motion)
    if why is not None:
        raise ShellsplineError(why)
    order = _joints_by_name(template, motion)
    return motion if order is None else _joints_reordered(motion, order)


def _layout_difference(a: Motion, b: Motion) -> str | None:
    """The first difference of two skeletons with joints matched by position in the file
    (``"; ..."``, to append to a message), or None."""
    if a.n_joints != b.n_joints:
        ka, kb = {_joint_key(n) for n in a.names}, {_joint_key(n) for n in b.names}
        only = [(which, [n for n in m.names if _joint_key(n) not in other])
                for which, m, other in (("first", a, kb), ("second", b, ka))]
        if ka & kb and any(names for _, names in only):  # one naming: the joints one lacks
            return "; " + "; ".join(f"only in the {which}: {_name_list(names)}"
                                    for which, names in only if names)
    n = min(a.n_joints, b.n_joints)
    diff = np.flatnonzero(a.parents[:n] != b.parents[:n])
    if diff.size or a.n_joints != b.n_joints:
        j = int(diff[0]) if diff.size else n

        def joint(m):
            return "no joint" if j >= m.n_joints else \
                f"{m.names[j]} (parent {_parent_name(m, m.parents[j])})"
        return f"; joint {j}: {joint(a)} against {joint(b)}"
    for j in range(a.n_joints):
        ra, rb = _rotation_axes(a.channels[j]), _rotation_axes(b.channels[j])
        pa, pb = _position_axes(a.channels[j]), _position_axes(b.channels[j])
        rot_ok = ra == rb or (len(set(ra)) == len(ra) == 3 and len(set(rb)) == len(rb) == 3)
        if not rot_ok or sorted(pa) != sorted(pb) or len(a.channels[j]) != len(b.channels[j]):
            return (f"; joint {j} ({a.names[j]}): channels "
                    f"{' '.join(a.channels[j]) or 'none'} against "
                    f"{' '.join(b.channels[j]) or 'none'}")
    return None


def with_channel_layout(motion: Motion, template: Motion) -> Motion:
    """``motion`` with the channel layout of ``template`` (another clip of its skeleton).

    Parameters
    ----------
    motion, template : Motion
        One skeleton (:func:`skeleton_mismatch` is None); the Euler orders and the order of
        the position channels may differ per joint.

    Returns
    -------
    Motion
        ``motion``'s names, offsets, frames and poses, written in ``template``'s channels:
        its joints in the template's file order when they are matched by name
        (:func:`skeleton_mismatch`), every joint's rotation converted to the template's
        Euler order (angles continuous along the clip), position channels reordered.
        Unchanged when the layouts agree.

    Raises
    ------
    ShellsplineError
        When the skeletons differ.

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.io.bvh import Motion, euler_matrices
    >>> zxy = Motion(("root",), [-1], np.zeros((1, 3)), (("Zrotation", "Xrotation",
    ...              "Yrotation"),), 0.1, [[10.0, 20.0, 30.0], [15.0, 25.0, 35.0]])
    >>> xyz = Motion(("root",), [-1], np.zeros((1, 3)), (("Xrotation", "Yrotation",
    ...              "Zrotation"),), 0.1, [[0.0, 0.0, 0.0]])
    >>> m = with_channel_layout(zxy, xyz)
    >>> m.channels[0]
    ('Xrotation', 'Yrotation', 'Zrotation')
    >>> bool(np.allclose(euler_matrices(m.values, "XYZ"), euler_matrices(zxy.values, "ZXY")))
    True
    """
    motion = _joint_order_like(motion, template)
    if tuple(motion.channels) == tuple(template.channels):
        return motion
    values = np.zeros((motion.n_frames, template.values.shape[1]))
    for j in range(motion.n_joints):
        src, dst = motion.channel_columns(j), template.channel_columns(j)
        names = list(motion.channels[j])
        for c, name in zip(dst, template.channels[j]):
            if name.endswith("position"):
                values[:, c] = motion.values[:, src[names.index(name)]]
        ra, rt = _rotation_axes(motion.channels[j]), _rotation_axes(template.channels[j])
        if not rt:
            continue
        rsrc = [c for c, n in zip(src, names) if n.endswith("rotation")]
        rdst = [c for c, n in zip(dst, template.channels[j]) if n.endswith("rotation")]
        if ra == rt:
            values[:, rdst] = motion.values[:, rsrc]
        else:
            ang = euler_angles(euler_matrices(motion.values[:, rsrc], ra), rt)
            values[:, rdst] = np.unwrap(ang, period=360.0, axis=0)
    return Motion(motion.names, motion.parents, motion.offsets, template.channels,
                  motion.frame_time, values, motion.end_sites)


def _grid_frames(a: Motion, b: Motion) -> int:
    """Frames of the common grid: the longer clip at the finer frame time."""
    ft = min(a.frame_time, b.frame_time)
    dur = max((a.n_frames - 1) * a.frame_time, (b.n_frames - 1) * b.frame_time)
    return int(round(dur / ft)) + 1


# Most frames of the grid the DP alignment runs on (align, distance, blend). The DP costs
# O(N^2) (a band of 1/4 of the duration): two 40 s clips at 120 Hz (4,801 frames) take
# 14.4 s (README, benchmarks/bench_motion.py --long-only); two 5-minute clips at 120 Hz
# (36,001 frames) would take ~56x that per warp (distance: two). Longer clips are aligned
# on this many frames (the warp is then interpolated: blend still runs on the full grid):
# distance 17 s / 300 MB, blend 22 s / 1.1 GB for two 5-minute clips.
MOTION_DP_FRAMES = 4801


def common_grid(a: Motion, b: Motion, n_frames: int | None = None) -> tuple[Motion, Motion]:
    """Two motions of one skeleton brought to the same number of frames.

    Each clip is stretched over ``[0, 1]`` to ``n_frames`` samples (default: enough for the
    longer clip at the finer frame time), so their curves share one parameter grid; ``b``
    is written in ``a``'s channel layout (:func:`with_channel_layout`) when its Euler orders
    differ.

    Raises
    ------
    ShellsplineError
        When the two skeletons differ (:func:`skeleton_mismatch`).
    """
    b = with_channel_layout(b, a)
    if n_frames is None:
        n_frames = _grid_frames(a, b)
    out = []
    for m in (a, b):
        if m.n_frames == n_frames:
            out.append(m)
        else:
            dur = (m.n_frames - 1) * m.frame_time
            out.append(resample(m, n_frames=n_frames, frame_time=dur / (n_frames - 1)))
    return out[0], out[1]


# ----------------------------------------------------------------------------------------
# Up axis, feet, contacts
# ----------------------------------------------------------------------------------------
# A joint is static when its channel values change by less than this over the clip (relative
# to the largest of them, at least 1; values read from text are usually equal to the last
# digit).
STATIC_TOL = 1e-9


def stage_joint(motion: Motion) -> int:
    """The static joint above the body whose frame the clip is analysed in, or ``-1``.

    A chain of joints from a root, each static (constant channel values over the clip,
    ``STATIC_TOL``; a joint without channels is static) and each with exactly one child
    joint, stopped before the first joint that moves: a ground marker or an armature above the hips (``joint_Root`` in the Bandai
    Namco files). Its world frame is the clip's *stage*: a file turned to Z-up (or moved,
    or yawed) by a constant transform of such a root is the same motion on the same stage.
    ``-1`` when the first root moves or branches (CMU: the hips are the root).
    """
    roots = np.flatnonzero(motion.parents < 0)
    if roots.size != 1:
        return -1
    ch = _children(motion)
    out, j = -1, int(roots[0])
    while len(ch[j]) == 1:
        v = motion.values[:, motion.channel_columns(j)]  # static: constant channel values
        if v.size and np.ptp(v, axis=0).max() > STATIC_TOL * max(float(np.abs(v).max()), 1.0):
            break
        out, j = j, ch[j][0]
    return out


def stage_kinematics(motion: Motion) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Joint positions and rotations in the clip's stage frame (see :func:`stage_joint`).

    Returns
    -------
    positions : (T,J,3) float64 numpy array
        ``S^T (p - s)`` for world positions ``p`` and the stage's world pose ``(S, s)``
        (the world positions when there is no static stage joint).
    rotations : (T,J,3,3) float64 numpy array
        ``S^T R`` for world rotations ``R``.
    S : (3,3) float64 numpy array
        The stage's world rotation (identity without a stage).
    s : (3,) float64 numpy array
        The stage's world position (zero without a stage).

    Notes
    -----
    Everything :mod:`shellspline.animation` measures (up axis, feet, contacts, skate, seam
    gaps, the horizontal travel) is measured here, so results do not change when a static
    root is turned or moved: the same motion converted to Z-up by a 90 degree root rotation
    closes, aligns and blends to the same channel values.
    """
    P, Rw = forward_kinematics(motion)
    k = stage_joint(motion)
    if k < 0:
        return P, Rw, np.eye(3), np.zeros(3)
    S, s = Rw[0, k].copy(), P[0, k].copy()
    return (P - s) @ S, np.swapaxes(S, -1, -2) @ Rw, S, s


def _positions(motion: Motion, positions=None) -> np.ndarray:
    return stage_kinematics(motion)[0] if positions is None else np.asarray(positions)


def _parse_up(up, motion: Motion | None = None) -> tuple[int, float]:
    """``(axis, sign)`` in the stage frame. A tuple is taken as already in it; a string
    (``"y"``, ``"-z"``) names a world axis, turned into the stage frame of ``motion``."""
    if isinstance(up, tuple) and len(up) == 2:
        return int(up[0]), float(up[1])
    s = str(up).strip().lower()
    sign = -1.0 if s.startswith("-") else 1.0
    s = s.lstrip("+-")
    if s not in ("x", "y", "z"):
        raise ShellsplineError(f"up axis must be one of x, y, z, +y, -z, ..., got {up!r}")
    axis = "xyz".index(s)
    k = -1 if motion is None else stage_joint(motion)
    if k < 0:
        return axis, sign
    u = forward_kinematics(motion.frames(0, 1))[1][0, k][axis] * sign  # world axis in stage
    a = int(np.argmax(np.abs(u)))
    if abs(u[a]) < 1 - 1e-6:
        raise ShellsplineError(
            f"up axis {up!r}: the static root {motion.names[k]!r} turns it off the axes of "
            f"its own frame ({np.round(u, 3).tolist()}); leave --up out to detect it")
    return a, float(np.sign(u[a]))


def body_joints(motion: Motion) -> np.ndarray:
    """The joints of the body ``(J,)`` bool: all but the static stage (:func:`stage_joint`)
    and the root below it (the root itself without a stage), unless that leaves fewer than
    2. That root may be a ground marker far from the body (the Bandai Namco run's
    ``joint_Root`` carries the travel while the hips move in place), and a static joint
    added above a skeleton changes nothing."""
    body = np.ones(motion.n_joints, dtype=bool)
    k = stage_joint(motion)
    if k >= 0:
        top = _children(motion)[k][0]
        while k >= 0:
            body[k] = False
            k = int(motion.parents[k])
        body[top] = False
    else:
        body[motion.parents < 0] = False
    return body if body.sum() >= 2 else np.ones(motion.n_joints, dtype=bool)


def up_axis(motion: Motion, positions=None) -> tuple[int, float]:
    """The up axis of a motion, detected from the data.

    Parameters
    ----------
    motion : Motion
    positions : (T,J,3) array_like, optional
        Joint positions in the stage frame (``stage_kinematics(motion)[0]``), when already
        computed.

    Returns
    -------
    axis : int
        0, 1 or 2: the axis along which the body (every joint but the roots, which may be a
        ground marker far from the body) has its largest extent, median over frames.
    sign : float
        ``+1`` or ``-1``: the sign that puts the centroid of the joints above the middle of
        their extent (more joints sit in the upper body: spine, arms, head).

    Notes
    -----
    A heuristic for humanoids standing or walking; pass ``up="y"``, ``"-z"``, ... to the
    functions that take it when it fails (lying, crawling, quadrupeds).
    """
    P = _positions(motion, positions)
    B = P[:, body_joints(motion)]
    ext = np.median(B.max(axis=1) - B.min(axis=1), axis=0)
    axis = int(np.argmax(ext))
    h = B[..., axis]
    mid = 0.5 * (h.max(axis=1) + h.min(axis=1))
    sign = 1.0 if np.median(h.mean(axis=1) - mid) >= 0 else -1.0
    return axis, sign


def _children(motion: Motion) -> list[list[int]]:
    ch = [[] for _ in range(motion.n_joints)]
    for j, p in enumerate(motion.parents):
        if p >= 0:
            ch[p].append(j)
    return ch


def find_feet(motion: Motion, up=None, positions=None, count: int = 2) -> tuple[int, ...]:
    """The feet: the ``count`` leaf joints lowest on average along the up axis.

    Parameters
    ----------
    motion : Motion
    up : str or (int, float), optional
        Up axis override (``"y"``, ``"-z"``, ...); detected by :func:`up_axis` otherwise.
    positions : (T,J,3) array_like, optional
        Joint positions in the stage frame, when already computed.
    count : int
        Number of feet (2 for bipeds; fewer when the skeleton has fewer leaves).

    Returns
    -------
    tuple of int
        Leaf joint indices in file order (the same feet in the same order for every clip of
        one skeleton). Joint names are not used.
    """
    P = _positions(motion, positions)
    ax, sign = up_axis(motion, P) if up is None else _parse_up(up, motion)
    ch = _children(motion)
    leaves = [j for j in range(motion.n_joints) if not ch[j] and motion.parents[j] >= 0]
    if not leaves:
        leaves = [j for j in range(motion.n_joints) if not ch[j]]
    height = sign * P[:, leaves, ax].mean(axis=0)
    return tuple(sorted(int(leaves[i]) for i in np.argsort(height, kind="stable")[:count]))


def _chain(motion: Motion, foot: int, ch) -> list[int]:
    """The foot leaf and its ancestors up to (not including) the nearest branch point."""
    out = [foot]
    p = int(motion.parents[foot])
    while p >= 0 and len(ch[p]) == 1:
        out.append(p)
        p = int(motion.parents[p])
    return out


@dataclass(frozen=True, eq=False)
class FootContacts:
    """Foot contacts of a motion.

    Attributes
    ----------
    feet : tuple of int
        Foot leaf joints.
    joints : tuple of (int, int)
        The joints tested for contact per foot: the leaf (toe) and its parent (ankle) when
        the parent is on the foot's chain, else the leaf twice.
    contact : (T,k) bool numpy array
        Foot ``i`` planted at frame ``f`` (either of its joints planted).
    joint_contact : (T,k,2) bool numpy array
        Contact of each tested joint.
    heights : (T,k,2) float64 numpy array
        Heights of the tested joints above their own lowest level (file units).
    up : (int, float)
        Up axis and sign used.
    leg_length : float
        Rest length of the leg chain (file units): the mean over feet of the summed bone
        lengths from the leaf to the branch point (the hips).
    positions : (T,J,3) float64 numpy array
        Joint positions in the stage frame (:func:`stage_kinematics`).
    """

    feet: tuple
    joints: tuple
    contact: np.ndarray
    joint_contact: np.ndarray
    heights: np.ndarray
    up: tuple
    leg_length: float
    positions: np.ndarray = field(repr=False)

    def onsets(self, foot: int) -> np.ndarray:
        """Frames where foot ``foot`` (its index in :attr:`feet`) touches down."""
        c = self.contact[:, foot]
        return np.flatnonzero(c[1:] & ~c[:-1]) + 1


def foot_contacts(motion: Motion, *, feet=None, up=None, height: float = CONTACT_HEIGHT,
                  speed: float = CONTACT_SPEED) -> FootContacts:
    """Foot contacts from joint heights and horizontal speeds.

    Parameters
    ----------
    motion : Motion
    feet : sequence of int or str, optional
        Foot joints (indices or names); :func:`find_feet` otherwise.
    up : str or (int, float), optional
        Up axis override; :func:`up_axis` otherwise.
    height : float
        A joint is low when within ``height * leg_length`` of its own lowest level (the 2nd
        percentile of its height over the clip: robust to a single spike).
    speed : float
        ... and slow when its horizontal speed is below ``speed * leg_length`` per second
        (central differences).

    Returns
    -------
    FootContacts
    """
    P = _positions(motion)
    ax, sign = up_axis(motion, P) if up is None else _parse_up(up, motion)
    if feet is None:
        feet = find_feet(motion, (ax, sign), P)
    else:
        feet = tuple(motion.joint_index(f) if isinstance(f, str) else int(f) for f in feet)
        bad = [f for f in feet if not 0 <= f < motion.n_joints]
        if bad:
            raise ShellsplineError(f"feet: joint indices out of range 0..{motion.n_joints - 1}:"
                                   f" {bad}")
    ch = _children(motion)
    chains = [_chain(motion, f, ch) for f in feet]
    _, t_loc = motion.local_transforms()
    rest = np.linalg.norm(t_loc[0], axis=1)
    leg = float(np.mean([rest[c[1:]].sum() if len(c) > 1 else rest[c[0]] for c in chains]))
    if not leg > 0:
        leg = float(np.ptp(P[..., ax])) or 1.0
    joints = tuple((c[0], c[1] if len(c) > 1 else c[0]) for c in chains)
    idx = np.array(joints, dtype=np.int64)  # (k,2)
    H = sign * P[:, idx, ax]  # (T,k,2)
    H = H - np.percentile(H, 2, axis=0)
    hor = [a for a in range(3) if a != ax]
    Q = P[:, idx][..., hor]  # (T,k,2,2)
    if motion.n_frames > 1:
        V = np.gradient(Q, motion.frame_time, axis=0)
        v = np.linalg.norm(V, axis=-1)
    else:
        v = np.zeros(H.shape)
    jc = _debounce((H <= height * leg) & (v <= speed * leg),
                   int(np.ceil(CONTACT_MIN_TIME / motion.frame_time - 1e-9)))
    return FootContacts(tuple(feet), joints, jc.any(axis=2), jc, H, (ax, sign), leg, P)


def _debounce(c, n: int) -> np.ndarray:
    """``c (T,...)`` bool with runs, then gaps, shorter than ``n`` frames removed along axis
    0 (a morphological opening, then a closing: a brush of the ground is dropped before it
    could bridge a gap; the clip's ends are extended, so a run cut by the clip's start or
    end is kept)."""
    if n <= 1 or c.shape[0] < 2:
        return c
    from scipy.ndimage import binary_closing, binary_opening

    st = np.ones((n,) + (1,) * (c.ndim - 1), dtype=bool)
    pad = [(n, n)] + [(0, 0)] * (c.ndim - 1)
    x = np.pad(c, pad, mode="edge")
    x = binary_closing(binary_opening(x, st), st)
    return x[n:-n]


def foot_skate(motion: Motion, contacts: FootContacts | None = None, **kw) -> dict:
    """Horizontal drift of planted feet.

    Parameters
    ----------
    motion : Motion
    contacts : FootContacts, optional
        Contacts to measure with (e.g. those of the source clip, for a modified clip of the
        same timing); detected on ``motion`` (``**kw`` to :func:`foot_contacts`) otherwise.

    Returns
    -------
    dict
        ``drift``: the summed horizontal displacement of the planted point of every foot
        between consecutive frames where it is planted (file units; of the foot's planted
        joints the one that moves least, so that a foot rolling over its toe pivots);
        ``drift_per_leg``: the same over the leg length; ``speed``: the mean horizontal
        speed while planted (units/s); ``speed_per_leg``: the same in leg lengths per
        second; ``contact_frames``: planted foot-steps counted.
    """
    if contacts is None:
        contacts = foot_contacts(motion, **kw)
    step, planted = _planted_steps(motion, contacts)
    drift = float(np.linalg.norm(step, axis=-1)[planted].sum())
    n = int(planted.sum())
    leg = contacts.leg_length
    spd = drift / (n * motion.frame_time) if n else 0.0
    return {"drift": drift, "drift_per_leg": drift / leg, "speed": spd,
            "speed_per_leg": spd / leg, "contact_frames": n}


def _planted_steps(motion: Motion, contacts: FootContacts):
    """Per frame step and foot: the horizontal step ``(T-1,k,2)`` of the planted point (of
    the foot's tested joints planted at both ends of the step, the one that moves least: a
    foot rolling over its toe pivots about the toe) and whether the foot is planted
    ``(T-1,k)``."""
    P = _positions(motion)
    ax = contacts.up[0]
    hor = [a for a in range(3) if a != ax]
    idx = np.array(contacts.joints, dtype=np.int64)
    D = np.diff(P[:, idx][..., hor], axis=0)  # (T-1,k,2,2)
    jc = contacts.joint_contact[: motion.n_frames]
    both = jc[1:] & jc[:-1]  # (T-1,k,2)
    size = np.where(both, np.linalg.norm(D, axis=-1), np.inf)
    pick = np.argmin(size, axis=2)  # (T-1,k)
    planted = both.any(axis=2)
    steps = np.take_along_axis(D, pick[..., None, None], axis=2)[:, :, 0]
    return steps, planted


def seam_gap(motion: Motion, *, up=None, root_motion: str = "keep") -> dict:
    """How far the last frame is from the first: the jump when the clip loops.

    Parameters
    ----------
    motion : Motion
    up : str, optional
        Up axis override.
    root_motion : {"keep", "close"}
        ``"keep"``: the horizontal travel of the root between the first and last frame is
        the loop's root motion, not a gap (a walk loops forward); ``"close"``: it is a gap.

    Returns
    -------
    dict
        ``rotation_rms`` and ``rotation_max``: angles of ``R_last R_first^T`` over the joints
        (degrees); ``position_max``: the largest jump of a body joint's world position (roots
        excluded, see :func:`up_axis`; file units;
        for ``"keep"`` the horizontal travel of the body, the median jump over the joints,
        removed); ``position_per_height``: the
        same over the body height; ``energy``: ``1/2 |log c(1) c(0)^-1|^2`` on the analysis
        curve (radians; position channels over the body height), the seed's closing energy.
    """
    c = motion_curve(motion)
    P = _positions(motion)
    ax, sign = up_axis(motion, P) if up is None else _parse_up(up, motion)
    H = body_height(motion, P, ax)
    ang = so3.angle(c.R[-1] @ np.swapaxes(c.R[0], -1, -2))
    body = body_joints(motion)  # a root may be a ground marker, not part of the body
    jump = (P[-1] - P[0])[body]
    if root_motion == "keep":  # poses compared up to the horizontal travel of the body
        travel = np.median(jump, axis=0)
        travel[ax] = 0.0
        jump = jump - travel
    Xd = _detrend(c, ax) if root_motion == "keep" else c.X
    dx = (Xd[-1] - Xd[0]) / H
    energy = 0.5 * (float(np.sum(so3.log(c.R[-1] @ np.swapaxes(c.R[0], -1, -2)) ** 2))
                    + float(dx @ dx))
    pm = float(np.linalg.norm(jump, axis=1).max())
    return {"rotation_rms": float(np.degrees(np.sqrt(np.mean(ang ** 2)))),
            "rotation_max": float(np.degrees(ang.max())) if ang.size else 0.0,
            "position_max": pm, "position_per_height": pm / H, "energy": energy}


def body_height(motion: Motion, positions=None, axis: int | None = None) -> float:
    """Median over frames of the body's extent along the up axis (roots excluded), the
    length scale that makes position channels comparable with angles."""
    P = _positions(motion, positions)
    if axis is None:
        axis = up_axis(motion, P)[0]
    h = P[:, body_joints(motion), axis]
    H = float(np.median(h.max(axis=1) - h.min(axis=1)))
    return H if H > 0 else 1.0


def translation_root(motion: Motion) -> int:
    """The joint whose world position carries the horizontal travel: the first joint with
    varying position channels, else the first root."""
    col = 0
    for j, chans in enumerate(motion.channels):
        for c in chans:
            if c.endswith("position") and np.ptp(motion.values[:, col]) > 0:
                return j
            col += 1
    return int(np.flatnonzero(motion.parents < 0)[0])


def _horizontal_cols(c: MotionCurve, ax: int) -> np.ndarray:
    """Positions in ``X`` of the travel channels: the position channels along the stage's
    horizontal axes (``ax`` the stage's up axis) of the joints whose channels are given in
    the stage frame (the children of the static stage joint, or the roots without one).
    Position channels of other joints live in moving frames: they are not travel."""
    tpl = c.template
    k = stage_joint(tpl)
    names, owner = [], []
    for j in range(tpl.n_joints):
        names += list(tpl.channels[j])
        owner += [j] * len(tpl.channels[j])
    return np.array([i for i, col in enumerate(c.pos_cols)
                     if tpl.parents[owner[col]] == k and names[col][0] != "XYZ"[ax]],
                    dtype=np.int64)


def _detrend(c: MotionCurve, ax: int, trend_out: list | None = None) -> np.ndarray:
    """``X`` with the straight line from the first to the last frame removed from the
    horizontal position channels (the loop's root motion)."""
    X = c.X.copy()
    hc = _horizontal_cols(c, ax)
    if hc.size:
        s = np.linspace(0.0, 1.0, c.n_frames)[:, None]
        trend = s * (X[-1, hc] - X[0, hc])
        X[:, hc] -= trend
        if trend_out is not None:
            trend_out.append((hc, trend))
    return X


def plant_feet(motion: Motion, contacts: FootContacts, *, smooth: int = 0) -> Motion:
    """Keep planted feet from sliding by moving the root horizontally (no IK).

    While a foot is planted (``contacts.joint_contact`` at two consecutive frames), the
    horizontal step of its planted point (see :func:`foot_skate`) is subtracted from the
    root's translation (averaged over the feet planted at that step); the corrections
    accumulate over the clip.

    Parameters
    ----------
    motion : Motion
    contacts : FootContacts
        Contacts (usually those of the source clip).
    smooth : int
        Half-width in frames of a moving average of the per-step correction (0: none), to
        soften the velocity change at touch-down and lift-off.

    Returns
    -------
    Motion
        The position channels of the body's carrier changed (per root, the first joint with
        all three position channels below the static stage: the root itself in CMU files,
        the hips under a static ``joint_Root``; the shift is turned into the carrier's
        parent frame); exact for one planted foot (world
        positions are linear in that translation), a compromise in double support. The
        motion unchanged when no joint has three position channels.
    """
    hor = [a for a in range(3) if a != contacts.up[0]]
    steps, planted = _planted_steps(motion, contacts)
    w = planted.sum(axis=1).astype(np.float64)
    corr = -(steps * planted[..., None]).sum(axis=1) / np.maximum(w, 1.0)[:, None]
    if smooth > 0:
        ker = np.ones(2 * smooth + 1) / (2 * smooth + 1)
        corr = np.stack([np.convolve(corr[:, i], ker, mode="same") for i in range(2)], 1)
    offset = np.vstack([np.zeros((1, 2)), np.cumsum(corr, axis=0)])
    delta = np.zeros((motion.n_frames, 3))
    delta[:, hor] = offset
    _, Rw, S, _ = stage_kinematics(motion)  # delta is in the stage frame, like Rw
    values = motion.values.copy()
    for j in _carriers(motion):
        # p_j = p_parent + R_parent t_j: a shift d is R_parent^T d in j's channels
        p = int(motion.parents[j])
        local = delta @ S.T if p < 0 else np.einsum("tba,tb->ta", Rw[:, p], delta)
        names = motion.channels[j]
        cols = motion.channel_columns(j)
        for k, name in enumerate(names):
            if name.endswith("position"):
                values[:, cols[k]] += local[:, "XYZ".index(name[0])]
    return Motion(motion.names, motion.parents, motion.offsets, motion.channels,
                  motion.frame_time, values, motion.end_sites)


def _carriers(motion: Motion) -> list[int]:
    """Per root, the first joint of its subtree (file order) with all three position
    channels below the static stage (:func:`stage_joint`, which stays static): the joint
    whose translation moves the whole body."""
    out = []
    tree = -np.ones(motion.n_joints, dtype=np.int64)
    for j, p in enumerate(motion.parents):
        tree[j] = j if p < 0 else tree[p]
    stage = set()
    k = stage_joint(motion)
    while k >= 0:
        stage.add(k)
        k = int(motion.parents[k])
    for r in np.flatnonzero(motion.parents < 0):
        for j in np.flatnonzero(tree == r):
            if int(j) in stage:
                continue
            if sum(c.endswith("position") for c in motion.channels[j]) == 3:
                out.append(int(j))
                break
    return out


# ----------------------------------------------------------------------------------------
# Operations: distance, alignment, blending, closing (seed 000 on SO(3)^d x R^m)
# ----------------------------------------------------------------------------------------
def _product_curve(c: MotionCurve, scale: float, X=None, cols=None, rots=None):
    """The analysis curve of seed 000: rotations, position channels over ``scale`` (the
    body height: lengths in body heights weigh like radians), on ``t = linspace(0, 1, N)``.
    ``cols``: the position channels kept (constant channels have a zero SRV: leaving them
    out changes no distance, warp, blend or closing, and makes each cheaper)."""
    from .curves.srv import ProductCurve

    X = c.X if X is None else X
    if cols is not None:
        X = X[:, cols]
    R = c.R if rots is None else c.R[:, rots]
    return ProductCurve(R, X / scale, c.t)


def _varying(*Xs) -> np.ndarray:
    """Columns that change over time in any of the ``(N,m)`` arrays."""
    return np.flatnonzero(np.any([np.ptp(X, axis=0) > 0 for X in Xs], axis=0))


def _turning(*Rs) -> np.ndarray:
    """Joints whose rotation changes over time in any of the ``(N,d,3,3)`` arrays. The
    others have a zero SRV in exact arithmetic, but the rounding of ``log(R R^T)`` of a
    constant turned joint (a static root at 90 degrees: ~1e-16) becomes ~1e-8 in
    ``eta / sqrt(|eta|)``: left out, a turned static root changes no distance or warp."""
    return np.flatnonzero(np.any([np.any(R != R[:1], axis=(0, 2, 3)) for R in Rs], axis=0))


def _top_joints(motion: Motion) -> list[int]:
    """The joints whose channels are given in the stage frame: the child of the static stage
    joint, or the roots without one."""
    k = stage_joint(motion)
    return [int(j) for j in np.flatnonzero(motion.parents == k)] if k >= 0 else \
        [int(j) for j in np.flatnonzero(motion.parents < 0)]


def _heading_fit(b: Motion, a: Motion, up=None):
    """``(ax, th, pa, pb)``: the up axis, the turn ``th`` (radians, about +up) that takes
    ``b`` to face like ``a`` and the start positions ``pa``, ``pb`` (stage frame) of their
    travel joints; None when ``b``'s top joints cannot be turned and moved (see
    :func:`heading_aligned`)."""
    ax = _parse_up(up, a)[0] if up is not None else up_axis(a)[0]
    h0, h1 = (ax + 1) % 3, (ax + 2) % 3       # the ground plane; h0 -> h1 turns about +up
    hz = {"XYZ"[h0], "XYZ"[h1]}
    ok = all(len(set(_rotation_axes(m.channels[j]))) == 3 and
             hz <= set(_position_axes(m.channels[j])) for m in (a, b) for j in _top_joints(m))
    if not ok or a.n_frames != b.n_frames:
        return None
    Pa, Pb = stage_kinematics(a)[0], stage_kinematics(b)[0]
    body = body_joints(a)
    ra, rb = translation_root(a), translation_root(b)
    da = Pa[-1, ra, [h0, h1]] - Pa[0, ra, [h0, h1]]
    db = Pb[-1, rb, [h0, h1]] - Pb[0, rb, [h0, h1]]
    H = body_height(a, Pa, ax)
    if min(np.linalg.norm(da), np.linalg.norm(db)) > H:   # both travel: their directions
        Qa, Qb = da[None, None], db[None, None]
    else:  # the bodies' horizontal layout about the travel joint, over all frames
        Qa = Pa[:, body][..., [h0, h1]] - Pa[:, ra, None][..., [h0, h1]]
        Qb = Pb[:, body][..., [h0, h1]] - Pb[:, rb, None][..., [h0, h1]]
    th = float(np.arctan2(np.sum(Qa[..., 1] * Qb[..., 0] - Qa[..., 0] * Qb[..., 1]),
                          np.sum(Qa * Qb)))
    return ax, th, Pa[0, ra].copy(), Pb[0, rb].copy()


def _ground_moved(m: Motion, ax: int, th: float, shift) -> Motion:
    """``m`` with its top joints (:func:`_top_joints`) moved by ``x -> G x + shift`` in the
    stage frame, ``G`` the turn by ``th`` about the axis ``ax``."""
    shift = np.asarray(shift, dtype=np.float64)
    if th == 0.0 and not shift.any():
        return m
    G = _turn(ax, th)
    values = m.values.copy()
    R, t = m.local_transforms()
    for j in _top_joints(m):
        cols, chans = m.channel_columns(j), m.channels[j]
        rcols = [c for c, n in zip(cols, chans) if n.endswith("rotation")]
        axes = _rotation_axes(chans)
        values[:, rcols] = euler_angles(G @ R[:, j], axes, reference=values[:, rcols])
        tj = t[:, j] @ G.T + shift
        for c, n in zip(cols, chans):
            if n.endswith("position"):
                values[:, c] = tj[:, "XYZ".index(n[0])]
    return Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, values, m.end_sites)


def _turn(ax: int, th: float) -> np.ndarray:
    h0, h1 = (ax + 1) % 3, (ax + 2) % 3
    G = np.eye(3)
    G[[h0, h0, h1, h1], [h0, h1, h0, h1]] = [np.cos(th), -np.sin(th), np.sin(th), np.cos(th)]
    return G


def heading_aligned(b: Motion, a: Motion, *, up=None) -> tuple[Motion, float]:
    """``b`` turned about the up axis and moved on the ground to face and start like ``a``.

    Clips of one skeleton recorded in different directions of the capture volume (CMU
    takes start anywhere, facing anywhere) are the same motion: compared or blended as
    they are, a walk to the north and one to the east differ by their heading alone, and
    their blend walks diagonally; facing opposite ways, the blend's travel cancels (a
    moonwalk on the spot).

    Parameters
    ----------
    b, a : Motion
        One skeleton on one frame grid (:func:`common_grid`).
    up : str, optional
        Up axis override (default: :func:`up_axis` of ``a``).

    Returns
    -------
    Motion
        ``b`` with the joints whose channels are given in the stage frame (the child of the
        static stage joint, or the root) turned about the up axis and moved on the ground so
        that the travel joint (:func:`translation_root`) starts where ``a``'s does. The turn
        takes ``b``'s horizontal travel (first to last frame) to ``a``'s direction when both
        travel more than a body height; otherwise it best maps ``b``'s body onto ``a``'s
        (2-D Kabsch of the horizontal joint positions relative to the travel joint, over
        all frames: in-place motions). Unchanged when those joints do not have
        three rotation channels and the two horizontal position channels.
    float
        The turn in degrees (0 when unchanged).
    """
    fit = _heading_fit(b, a, up)
    if fit is None:
        return b, 0.0
    ax, th, pa, pb = fit
    shift = pa - _turn(ax, th) @ pb
    shift[ax] = 0.0
    return _ground_moved(b, ax, th, shift), float(np.degrees(th))


def _faced(b: Motion, place) -> Motion:
    """``b`` turned and moved by the heading fit ``place`` (:func:`_heading_fit`) to face and
    start like ``a`` (see :func:`heading_aligned`); unchanged when ``place`` is None."""
    if place is None:
        return b
    ax, th, pa, pb = place
    shift = pa - _turn(ax, th) @ pb
    shift[ax] = 0.0
    return _ground_moved(b, ax, th, shift)


def _pair(a: Motion, b: Motion, n_frames=None, heading="align", up=None):
    if min(a.n_frames, b.n_frames) < 2:
        raise ShellsplineError(f"the clips have {a.n_frames} and {b.n_frames} frames: "
                               "distance, align and blend need at least 2 per clip")
    if heading not in ("align", "keep"):
        raise ShellsplineError(f"heading must be 'align' or 'keep', got {heading!r}")
    a2, b2 = common_grid(a, b, n_frames)
    place = _heading_fit(b2, a2, up) if heading == "align" else None
    b2 = _faced(b2, place)
    ca, cb = motion_curve(a2), motion_curve(b2)
    for which, m, c in (("a", a, ca), ("b", b, cb)):  # on the clip's own frames
        _check_steps(c if c.template is m else motion_curve(m), f"clip {which}")
    H = 0.5 * (body_height(a) + body_height(b))  # symmetric in a and b
    return a2, b2, ca, cb, H, place


def contact_features(a: Motion, b: Motion, *, up=None) -> np.ndarray:
    """Feature points for aligning two clips: their foot touch-downs, paired.

    For every foot (the same joints in both clips: one skeleton), each touch-down of ``a``
    is paired with the touch-down of ``b`` nearest in normalised time; pairs that would
    not keep both sequences increasing are dropped.

    Returns
    -------
    (k,2) float64 numpy array
        ``(t_a, t_b)`` in normalised time ``[0, 1]`` of each clip, sorted by ``t_a``.
    """
    b = _joint_order_like(b, a)  # a's feet are the same joints of b
    fa, fb = foot_contacts(a, up=up), foot_contacts(b, up=up)
    fb = foot_contacts(b, up=up, feet=fa.feet) if fb.feet != fa.feet else fb  # own stage
    pairs = []
    for i in range(len(fa.feet)):
        ta = fa.onsets(i) / max(a.n_frames - 1, 1)
        tb = fb.onsets(i) / max(b.n_frames - 1, 1)
        if not ta.size or not tb.size:
            continue
        last = -1.0
        for x in ta:
            y = tb[np.argmin(np.abs(tb - x))]
            if y > last:
                pairs.append((x, y))
                last = y
    P = np.array(sorted(pairs), dtype=np.float64).reshape(-1, 2)
    if P.shape[0]:  # keep the pairs monotone across feet too
        keep = np.concatenate([[True], np.diff(P[:, 1]) > 0])
        P = P[keep]
    return P


def _features(features, a: Motion, b: Motion, up=None):
    """Canonical feature pairs in normalised time, or None."""
    if features is None or (isinstance(features, str) and features == "none"):
        return None
    if isinstance(features, str):
        if features != "contacts":
            raise ShellsplineError(f"features must be 'contacts', 'none' or (k,2) pairs of "
                                   f"times in seconds, got {features!r}")
        P = contact_features(a, b, up=up)
        return P if P.shape[0] else None
    P = np.asarray(features, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 2 or not np.all(np.isfinite(P)):
        raise ShellsplineError(f"features: expected (k,2) pairs of times in seconds, got "
                               f"shape {P.shape}")
    da = (a.n_frames - 1) * a.frame_time
    db = (b.n_frames - 1) * b.frame_time
    P = P / [da, db]
    if P.min() < 0 or P.max() > 1:
        raise ShellsplineError(f"features: times must lie within the clips (0..{da:g} s and "
                               f"0..{db:g} s)")
    return P


@dataclass(frozen=True, eq=False)
class AlignReport:
    """A time alignment of two motions.

    Attributes
    ----------
    t : (N,) float64 numpy array
        Normalised time of the first clip, ``linspace(0, 1, N)``.
    phi : (N,) float64 numpy array
        The warp: ``b(phi(t))`` matches ``a(t)`` (normalised times).
    seconds : (N,2) float64 numpy array
        ``(t * duration_a, phi * duration_b)``.
    distance_before, distance_after : float
        SRV distance with the identity warp and with ``phi``.
    features : (k,2) float64 numpy array or None
        Feature pairs used (normalised times).
    result : object
        The result of :func:`shellspline.curves.align` (status, iterations, energies).
    """

    t: np.ndarray
    phi: np.ndarray
    seconds: np.ndarray
    distance_before: float
    distance_after: float
    features: np.ndarray | None
    result: object = None


def _align_curves(pa, pb, features, kw):
    """``phi`` aligning ``pb`` to ``pa`` (normalised time) and the solver's result."""
    from .curves.align import align as align_curves

    kw = dict(kw)
    if features is not None:
        kw.setdefault("lam", FEATURE_WEIGHT)
        features = (features[:, 0], features[:, 1])
    res = align_curves(pa, pb, features=features, **kw)
    return np.clip(np.asarray(res.phi, dtype=np.float64), 0.0, 1.0), res


def align(a: Motion, b: Motion, *, features=None, n_frames=None, up=None,
          heading: str = "align", **kw) -> AlignReport:
    """The time warp that aligns ``b`` to ``a`` (elastic SRV metric on SO(3)^d x R^m).

    Parameters
    ----------
    a, b : Motion
        One skeleton (the same joints and channel layout); any frame rates and lengths
        (both are brought to one grid by :func:`common_grid`).
    features : None, "contacts" or (k,2) array_like
        Feature points pulling the alignment (seed 003): ``"contacts"`` pairs the foot
        touch-downs (:func:`contact_features`); an array gives ``(t_a, t_b)`` pairs in
        seconds.
    n_frames : int, optional
        Grid size (default: :func:`common_grid`'s, at most ``MOTION_DP_FRAMES``).
    up : str, optional
        Up axis override (for contacts and the heading).
    heading : {"align", "keep"}
        ``"align"``: ``b`` is first turned about the up axis and moved on the ground to face
        and start like ``a`` (:func:`heading_aligned`: clips recorded in other directions
        are the same motion); ``"keep"``: compared where they are.
    **kw
        Passed to :func:`shellspline.curves.align.align` (``lam``, ``window``, ...).

    Returns
    -------
    AlignReport
    """
    from .curves.srv import reparametrize, srv_distance

    if n_frames is None:
        n_frames = min(_grid_frames(a, b), MOTION_DP_FRAMES)
    a2, b2, ca, cb, H, _ = _pair(a, b, n_frames, heading, up)
    cols, rots = _varying(ca.X, cb.X), _turning(ca.R, cb.R)
    pa, pb = (_product_curve(ca, H, cols=cols, rots=rots),
              _product_curve(cb, H, cols=cols, rots=rots))
    F = _features(features, a, b, up)
    phi, res = _align_curves(pa, pb, F, kw)
    before = srv_distance(pa, pb)
    after = srv_distance(pa, reparametrize(pb, phi, pa.t))
    da = (a.n_frames - 1) * a.frame_time
    db = (b.n_frames - 1) * b.frame_time
    return AlignReport(pa.t, phi, np.stack([pa.t * da, phi * db], axis=1), before, after, F,
                       res)


_align_motions = align  # the parameters called ``align`` below shadow the function


def distance(a: Motion, b: Motion, *, align: str = "dp", features=None, n_frames=None,
             up=None, heading: str = "align", results=None, **kw) -> float:
    """SRV distance of two motions of one skeleton (seed 000 eq. 7).

    Parameters
    ----------
    a, b : Motion
    align : {"dp", "none"}
        ``"none"``: the clips are compared on one normalised time grid; ``"dp"``: the
        symmetric shape distance ``(d(a, b o phi) + d(b, a o psi)) / 2`` with each warp
        found by dynamic programming.
    features : None, "contacts" or (k,2) array_like
        As in :func:`align`.
    heading : {"align", "keep"}
        As in :func:`align` (default: independent of where and which way each clip was
        recorded).
    results : list, optional
        With ``align="dp"``, the two alignments' :class:`~shellspline.curves.align.
        AlignResult` (``b`` onto ``a``, then ``a`` onto ``b``) are appended to it: their
        ``status`` and ``success`` tell whether each refinement converged.

    Returns
    -------
    float
        ``0`` for a motion and itself; symmetric in ``a`` and ``b``.
    """
    from .curves.srv import srv_distance

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    if align == "none":
        _, _, ca, cb, H, _ = _pair(a, b, n_frames, heading, up)
        cols, rots = _varying(ca.X, cb.X), _turning(ca.R, cb.R)
        return srv_distance(_product_curve(ca, H, cols=cols, rots=rots),
                            _product_curve(cb, H, cols=cols, rots=rots))
    r1 = _align_motions(a, b, features=features, n_frames=n_frames, up=up, heading=heading,
                        **kw)
    F = _features(features, a, b, up)
    F2 = None if F is None else F[:, ::-1] * [(b.n_frames - 1) * b.frame_time,
                                              (a.n_frames - 1) * a.frame_time]
    r2 = _align_motions(b, a, features=F2, n_frames=n_frames, up=up, heading=heading, **kw)
    if results is not None:
        results.extend([r1.result, r2.result])
    return 0.5 * (r1.distance_after + r2.distance_after)


def _blend_weight(s) -> float:
    """The weight ``s`` of :func:`blend`, :func:`mesh_blend` and :func:`track_blend` as a
    float: a finite real number; a bool or a string (even ``"0.5"``) is refused, as by the
    other numeric arguments of the API (``eta``, ``K``, ...)."""
    if isinstance(s, (bool, np.bool_)) or not isinstance(s, numbers.Real) or \
            not np.isfinite(float(s)):
        raise ShellsplineError(f"s must be a finite number (the weight of the second "
                               f"animation), got {s!r}")
    return float(s)


def blend(a: Motion, b: Motion, s: float = 0.5, *, align: str = "dp", features=None,
          n_frames=None, up=None, plant: bool = False, heading: str = "align",
          **kw) -> tuple[Motion, AlignReport | None]:
    """A new motion between two takes: the SRV geodesic ``R^-1((1-s) q_a + s q_b o phi)``.

    Parameters
    ----------
    a, b : Motion
        One skeleton; any frame rates and lengths.
    s : float
        Weight of ``b`` (0: ``a``, 1: ``b``).
    align : {"dp", "none"}
        Align ``b`` to ``a`` in time first (seed 000 Fig. 4: needed when the takes are out of
        phase) or blend on one normalised grid.
    features : None, "contacts" or (k,2) array_like
        Feature points of the alignment.
    plant : bool
        Detect the blend's foot contacts and correct its root where planted feet slide
        (:func:`plant_feet`).
    heading : {"align", "keep"}
        ``"align"`` (default): the motions are blended with ``b`` turned about the up axis
        and moved on the ground to face and start like ``a`` (:func:`heading_aligned`), and
        the blend is then placed between them: turned by ``s`` times ``b``'s turn and moved
        by ``s`` times the step between their starts (``s = 0`` is ``a``, ``s = 1`` is
        ``b``, where they were recorded). Takes recorded facing other ways blend into one
        walk; blended as recorded, two walks facing opposite ways cancelled their travel
        (a walk on the spot). ``"keep"``: blended as recorded.

    Returns
    -------
    motion : Motion
        ``a``'s channel layout, the finer of the two frame times, duration
        ``(1-s) T_a + s T_b``; its timing is blended too: the result is the blend composed
        with the inverse of ``(1-s) id + s phi``, so that ``s = 1`` plays ``b``'s timing.
        The blend of the clips themselves (piecewise geodesics through their own frames,
        :func:`~shellspline.curves.srv.warp_grid`), read once at the output frames: ``s =
        0`` gives ``a`` and ``s = 1`` gives ``b`` (where recorded) to rounding, at their
        frames when the frame times agree (else the clip's geodesics at the finer rate).
    report : AlignReport or None
    """
    from .curves.srv import reparametrize, warp_grid
    from .curves.srv import blend as blend_curves

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    s = _blend_weight(s)
    a2, _, _, _, H, place = _pair(a, b, n_frames, heading, up)
    # the blend runs on the clips' own frames (b faced like a on the common grid's fit):
    # a clip resampled to the common grid's frame count and back is not the clip (s = 0
    # was 5 degrees off walk_normal blended with the longer walk_happy)
    ca, cb = motion_curve(a), motion_curve(_faced(with_channel_layout(b, a), place))
    cols = _varying(ca.X, cb.X)
    pa, pb = _product_curve(ca, H, cols=cols), _product_curve(cb, H, cols=cols)
    rep = None
    warp_t = warp = np.array([0.0, 1.0])
    if align == "dp":
        rep = _align_motions(a, b, features=features, up=up, heading=heading, **kw,
                             n_frames=min(a2.n_frames, MOTION_DP_FRAMES))
        warp_t, warp = rep.t, rep.phi
    # on a's frames, the warp's breakpoints and the times where it passes a frame of b, a
    # and b o phi are single geodesics between samples: the blend of these samples is the
    # SRV geodesic of the clips themselves, for every s (exactly a at s = 0, b at s = 1;
    # on a's grid alone, b o phi cut off frames of b where phi is steep)
    t, phi = warp_grid(pa.t, warp_t, warp, pb.t)
    c = blend_curves(reparametrize(pa, t, t), pb, s, warp=phi)
    # its timing blended too: the output at u plays the blend at psi^-1(u), psi the blended
    # clock (1-s) id + s phi (piecewise linear on t), evaluated once at the output frames
    da = (a.n_frames - 1) * a.frame_time
    db = (b.n_frames - 1) * b.frame_time
    dur = max((1 - s) * da + s * db, 0.0)
    ft = min(a.frame_time, b.frame_time)
    n_out = max(int(round(dur / ft)) + 1, 2)
    u = np.linspace(0.0, 1.0, n_out)
    psi = (1 - s) * t + s * phi
    if np.any(np.diff(psi) < 0):  # s outside [0, 1] with a warp that stalls
        psi = np.maximum.accumulate(psi)
    tu = _inverse_clock(u, psi, t)
    cu = reparametrize(c, tu, u)
    fa = np.interp(tu, pa.t, np.arange(ca.n_frames, dtype=np.float64))
    fb = np.interp(np.interp(tu, t, phi), pb.t, np.arange(cb.n_frames, dtype=np.float64))
    ref = (1 - s) * _rows_at(ca.reference, fa) + s * _rows_at(cb.reference, fb)
    X = np.broadcast_to((1 - s) * ca.X[0] + s * cb.X[0], (n_out, ca.X.shape[1])).copy()
    X[:, cols] = cu.X * H  # the constant channels keep their blended value
    m = ca.with_samples(cu.R, X, ft, ref).to_motion()
    if place is not None:  # placed between a and b: turned by s of b's turn, moved by s
        ax, th, pa, pb = place
        d = pb - pa
        d[ax] = 0.0
        m = _ground_moved(m, ax, -s * th, pa + s * d - _turn(ax, -s * th) @ pa)
    if plant:
        m = plant_feet(m, foot_contacts(m, up=up))
    return m, rep


def _inverse_clock(u, psi, t) -> np.ndarray:
    """``t`` where the non-decreasing piecewise-linear ``psi (on t)`` reaches ``u``: exactly
    ``t[j]`` where ``u`` is ``psi[j]`` (a flat piece: its last time), clamped to the ends."""
    j = np.clip(np.searchsorted(psi, u, side="right") - 1, 0, psi.size - 2)
    den = psi[j + 1] - psi[j]
    w = np.clip(np.divide(u - psi[j], den, out=np.zeros_like(u), where=den > 0), 0.0, 1.0)
    out = np.where(w == 0.0, t[j], t[j] + w * (t[j + 1] - t[j]))
    out[u >= psi[-1]] = t[-1]
    out[u <= psi[0]] = t[0]
    return out


def _rows_at(A, pos) -> np.ndarray:
    """Rows of ``A (N,C)`` linearly interpolated at fractional frame positions ``pos``."""
    i = np.clip(np.floor(pos).astype(np.int64), 0, max(A.shape[0] - 2, 0))
    w = (pos - i)[:, None]
    return A[i] * (1 - w) + A[np.minimum(i + 1, A.shape[0] - 1)] * w


def warp_motion(motion: Motion, phi, frame_time: float | None = None) -> Motion:
    """``motion o phi``: the clip sampled at the normalised times ``phi (N,)`` (non-decreasing,
    in ``[0, 1]``), geodesically between frames; ``N`` frames of ``frame_time`` seconds
    (default: the duration kept)."""
    phi = np.asarray(phi, dtype=np.float64).reshape(-1)
    if phi.size < 2 or not np.all(np.isfinite(phi)) or phi.min() < 0 or phi.max() > 1:
        raise ShellsplineError(f"warp_motion: phi must be >= 2 finite times in [0, 1], got "
                               f"{phi.size} values")
    c = motion_curve(motion)
    R, X, ref = _sample_curve(c, phi * (c.n_frames - 1))
    if frame_time is None:
        frame_time = c.duration / (phi.size - 1)
    return c.with_samples(R, X, frame_time, ref).to_motion()


def loop_range(motion: Motion, *, min_fraction: float = 0.5, up=None) -> tuple[int, int]:
    """The frames ``start..stop`` of a clip that loop best: frame ``stop`` (and the one after
    it) closest to frame ``start`` (and the one after it), keeping at least
    ``min_fraction`` of the clip.

    Parameters
    ----------
    motion : Motion
    min_fraction : float
        Shortest loop kept, as a fraction of the clip (0 < min_fraction <= 1).
    up : str, optional
        Up axis override (the horizontal position channels, the travel, are not compared).

    Returns
    -------
    (int, int)
        ``start < stop``; ``motion.frames(start, stop + 1)`` is the clip to close.

    Notes
    -----
    Pose distance ``sum_j |R_j(a) - R_j(b)|_F^2`` (chordal, all joints at once as one
    matrix product) plus the squared difference of the non-horizontal position channels in
    body heights; the pair ``(a, b)`` and ``(a + 1, b + 1)`` are compared, so that the
    velocities match too. Candidates on a stride above 1,500 frames.
    """
    if not 0 < min_fraction <= 1:
        raise ShellsplineError(f"min_fraction must be in (0, 1], got {min_fraction!r}")
    T = motion.n_frames
    if T < 3:
        raise ShellsplineError(f"loop_range: need at least 3 frames, got {T}")
    c = motion_curve(motion)
    P = _positions(motion)
    ax = (up_axis(motion, P) if up is None else _parse_up(up, motion))[0]
    H = body_height(motion, P, ax)
    keep = np.setdiff1d(np.arange(c.X.shape[1]), _horizontal_cols(c, ax))
    Y = np.concatenate([c.R.reshape(T, -1), c.X[:, keep] / H], axis=1)
    stride = max(1, int(np.ceil(T / 1500)))
    idx = np.arange(0, T - 1, stride)
    G = Y[idx] @ Y[idx].T
    sq = np.diag(G)
    D = sq[:, None] + sq[None, :] - 2 * G  # squared distances between candidate frames
    Y1 = Y[idx + 1]
    G1 = Y1 @ Y1.T
    sq1 = np.diag(G1)
    D = D + sq1[:, None] + sq1[None, :] - 2 * G1
    span = idx[None, :] - idx[:, None]
    D[span < max(int(np.ceil(min_fraction * (T - 1))), 2)] = np.inf  # >= 3 frames kept
    if not np.isfinite(D).any():  # too short to choose: the whole clip
        return 0, T - 1
    a, b = np.unravel_index(np.argmin(D), D.shape)
    return int(idx[a]), int(idx[b])


@dataclass(frozen=True, eq=False)
class CloseReport:
    """What closing a clip did.

    Attributes
    ----------
    history : (k+1,) float64 numpy array
        Seam gap ``|log c(1) c(0)^-1|`` of the analysis curve (radians; position channels
        in body heights) before each iteration and after the last.
    velocity_jump : (k+1,) float64 numpy array
        Jump of the velocity across the seam at the same moments.
    gap_before, gap_after : dict
        :func:`seam_gap` of the input and of the result.
    skate_before, skate_closed, skate_after : dict
        :func:`foot_skate` (with the input's contacts) of the input, of the closed clip
        before planting the feet, and of the result.
    iterations : int
    status : str
        The closing solver's: ``"converged"``, ``"limit"`` or ``"stalled"``.
    message : str
    frames : (int, int)
        The input frames ``start..stop`` that were closed (all of them unless ``trim``).
    """

    history: np.ndarray
    velocity_jump: np.ndarray
    gap_before: dict
    gap_after: dict
    skate_before: dict
    skate_closed: dict
    skate_after: dict
    iterations: int
    status: str
    message: str
    frames: tuple = (0, 0)

    @property
    def success(self) -> bool:
        """The seam closed to the solver's tolerance."""
        return self.status == "converged"


def close(motion: Motion, *, iterations: int = 10, c1: bool = False,
          root_motion: str = "keep", plant: bool = True, up=None, trim: bool = False,
          min_fraction: float = 0.5, **kw) -> tuple[Motion, CloseReport]:
    """Make a clip loop: close its curve on SO(3)^d x R^m, then keep planted feet planted.

    Parameters
    ----------
    motion : Motion
        At least 3 frames; any skeleton and layout.
    iterations : int
        Closing iterations (:func:`shellspline.curves.closing.close`).
    c1 : bool
        Also remove the velocity jump at the seam.
    root_motion : {"keep", "close"}
        ``"keep"``: the straight line from the first to the last horizontal position of
        every position channel is taken out before closing and put back after, so that a
        walk loops forward (its root motion); ``"close"``: the root returns to its start.
    plant : bool
        After closing, correct the root's horizontal translation where the input's feet were
        planted (:func:`plant_feet`); with ``root_motion="close"`` the correction's drift is
        spread linearly so that the loop stays closed.
    up : str, optional
        Up axis override.
    trim : bool
        First cut the clip to the frames that loop best (:func:`loop_range`, keeping at
        least ``min_fraction`` of it): whole gait cycles close with a far smaller change.
    **kw
        Passed to the curve closing (``method``, ``kappa``, ``tol``).

    Returns
    -------
    motion : Motion
        The same layout and frame count (of the trimmed range with ``trim``); the last frame
        matches the first (drop it when playing the clip in a loop).
    report : CloseReport
    """
    from .curves.closing import close as close_curve

    if root_motion not in ("keep", "close"):
        raise ShellsplineError(f"root_motion must be 'keep' or 'close', got {root_motion!r}")
    if motion.n_frames < 3:
        raise ShellsplineError(f"close: need at least 3 frames, got {motion.n_frames}")
    frames = (0, motion.n_frames - 1)
    if trim:
        frames = loop_range(motion, min_fraction=min_fraction, up=up)
        motion = motion.frames(frames[0], frames[1] + 1)
    contacts = foot_contacts(motion, up=up)
    ax = contacts.up[0]
    c = motion_curve(motion)
    H = body_height(motion, contacts.positions, ax)
    trend = []
    X = _detrend(c, ax, trend) if root_motion == "keep" else c.X
    cols = _varying(X)
    _check_steps(c, "close")
    pc, keep = _subdivided(_product_curve(c, H, X, cols))
    res = close_curve(pc, iterations=iterations, c1=c1, **kw)
    Xc = X.copy()
    Xc[:, cols] = res.curve.X[keep] * H
    for cols, tr in trend:
        Xc[:, cols] += tr
    closed = c.with_samples(res.curve.R[keep], Xc).to_motion()
    out = closed
    if plant:
        out = plant_feet(closed, contacts)
        if root_motion == "close":
            out = _spread_drift(out, closed)
    report = CloseReport(np.asarray(res.seam_gap), np.asarray(res.velocity_jump),
                         seam_gap(motion, up=contacts.up, root_motion=root_motion),
                         seam_gap(out, up=contacts.up, root_motion=root_motion),
                         foot_skate(motion, contacts), foot_skate(closed, contacts),
                         foot_skate(out, contacts), int(res.iterations), res.status,
                         res.message, frames)
    return out, report


# Largest joint step (rad) between two samples of a curve that is closed as it is. Closing
# changes the SRV most where it is largest, so a joint that turns fast between two frames
# (a flip of the data, a spin at 30 Hz) would be pushed past pi, where the piecewise
# geodesic turns the other way round (srv_inverse refuses it); such intervals are split
# along their own geodesic first, which leaves the curve and its SRV as they are and
# spreads the change. A walk with an arm turned 178 degrees in one frame: seam gap 157 ->
# 143 degrees in 10 iterations without the split, closed to 1e-13 with it
# (tests/test_animation.py::test_closing_a_clip_with_a_joint_flip).
CLOSE_MAX_STEP = np.pi / 4
# A joint step this close to pi has no direction: refused.
FLIP_TOL = 1e-6


def _check_steps(c: MotionCurve, where: str) -> None:
    """One-line refusal of a joint that turns by pi (to ``FLIP_TOL``) between two frames."""
    if not c.R.shape[1] or c.n_frames < 2:
        return
    ang = so3.angle(c.R[1:] @ np.swapaxes(c.R[:-1], -1, -2))
    if ang.max() > np.pi - FLIP_TOL:
        n, b = map(int, np.argwhere(ang > np.pi - FLIP_TOL)[0])
        name = c.template.names[int(c.rot_joints[b])]
        raise ShellsplineError(
            f"{where}: joint {name!r} turns by {np.degrees(ang[n, b]):.4f} degrees between "
            f"frames {n} and {n + 1} ({n * c.frame_time:.3f} s), a half turn that has no "
            "direction (a flipped or swapped joint in the data): fix or cut out that frame")


def _subdivided(pc):
    """``(curve, keep)``: ``pc`` with every interval where a joint turns by more than
    ``CLOSE_MAX_STEP`` split evenly along its own geodesic; ``keep (N,)`` the indices of the
    original samples in it."""
    from .curves.srv import ProductCurve, reparametrize

    if not pc.d:
        return pc, np.arange(pc.n_frames)
    ang = so3.angle(pc.R[1:] @ np.swapaxes(pc.R[:-1], -1, -2)).max(axis=1)
    k = np.maximum(np.ceil(ang / CLOSE_MAX_STEP - 1e-12), 1).astype(np.int64)
    if k.max() == 1:
        return pc, np.arange(pc.n_frames)
    i = np.repeat(np.arange(k.size), k)
    frac = np.arange(i.size) - np.repeat(np.cumsum(k) - k, k)
    t = np.append(pc.t[i] + frac / k[i] * np.diff(pc.t)[i], pc.t[-1])
    keep = np.append(np.cumsum(k) - k, i.size)
    fine = reparametrize(pc, t, t)
    R, X = fine.R.copy(), fine.X.copy()
    R[keep], X[keep] = pc.R, pc.X  # the original samples bit for bit
    return ProductCurve(R, X, t), keep


def _spread_drift(planted: Motion, closed: Motion) -> Motion:
    """``planted`` with the change from ``closed`` made periodic: its end value spread
    linearly over the clip (a closed loop stays closed)."""
    dv = planted.values - closed.values
    s = np.linspace(0.0, 1.0, planted.n_frames)[:, None]
    values = closed.values + dv - s * dv[-1]
    return Motion(planted.names, planted.parents, planted.offsets, planted.channels,
                  planted.frame_time, values, planted.end_sites)


# ----------------------------------------------------------------------------------------
# Mesh animations: curves in LΘA descriptor space (d = 0, m = #descriptors)
# ----------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class MeshCurve:
    """A mesh animation as a curve in LΘA descriptor space.

    Attributes
    ----------
    Z : (N,D) float64 numpy array
        Edge lengths, dihedral angles (unwrapped along time) and face areas per frame.
    sqrt_w : (D,) float64 numpy array
        Square roots of the LΘA weights at the first frame: the curve given to the SRV
        machinery is ``Z * sqrt_w``, so its Euclidean norm is the LΘA energy's metric
        (paper 001 eq. 10).
    T : Topology
    """

    Z: np.ndarray
    sqrt_w: np.ndarray
    T: object

    def product_curve(self):
        from .curves.srv import ProductCurve

        return ProductCurve(X=self.Z * self.sqrt_w)


def _mesh_frames(Vs, name="Vs") -> np.ndarray:
    Vs = np.asarray(Vs, dtype=np.float64)
    if Vs.ndim != 3 or Vs.shape[2] != 3 or Vs.shape[0] < 2:
        raise ShellsplineError(f"{name} must be (N,n,3) frames with N >= 2, got shape "
                               f"{Vs.shape}")
    if not np.all(np.isfinite(Vs)):
        raise ShellsplineError(f"{name} has non-finite coordinates")
    return Vs


def mesh_curve(Vs, F, *, T=None, reference=None, **weights) -> MeshCurve:
    """The LΘA descriptor curve of a mesh animation.

    Parameters
    ----------
    Vs : (N,n,3) array_like
        Frames of one mesh.
    F : (m,3) array_like
        Faces.
    T : Topology, optional
        Connectivity, when already built.
    reference : (n,3) array_like, optional
        Pose of the weights (default: the first frame).
    **weights
        ``mu``, ``lam``, ``eta`` of :func:`shellspline.shells.descriptors.lta_weights`.

    Returns
    -------
    MeshCurve
    """
    from .mesh.topology import topology
    from .shells.descriptors import lta_descriptors, lta_weights, unwrap_angles

    Vs = _mesh_frames(Vs)
    T = topology(F, Vs.shape[1]) if T is None else T
    Z = lta_descriptors(Vs, T)
    sT = T.descriptor_slices()[1]
    Z[:, sT] = unwrap_angles(Z[:, sT])  # dense frames: every step is the short way
    ref = Vs[0] if reference is None else np.asarray(reference, dtype=np.float64)
    w = lta_weights(ref, T, **weights)
    return MeshCurve(Z, np.sqrt(w), T)


def reconstruct_frames(Z, curve: MeshCurve, V_init, place_on=None, **options):
    """Meshes with the descriptors ``Z``: one Gauss–Newton solve per frame (one solver,
    its symbolic factorization reused), each frame placed rigidly on a target.

    Parameters
    ----------
    Z : (N,D) array_like
        Target descriptors.
    curve : MeshCurve
        Gives the topology and the weights.
    V_init : (N,n,3) array_like
        Initial guesses.
    place_on : (N,n,3) array_like, optional
        Rigid placement targets (default ``V_init``): shell energies leave rigid motions free.
    **options
        Options of :class:`shellspline.shells.reconstruct.GaussNewton`.

    Returns
    -------
    Vs : (N,n,3) float64 numpy array
    results : list of ReconstructionResult
    """
    from .shells.reconstruct import GaussNewton, rigid_placement

    Z = np.asarray(Z, dtype=np.float64)
    V_init = np.asarray(V_init, dtype=np.float64)
    place_on = V_init if place_on is None else np.asarray(place_on, dtype=np.float64)
    gn = GaussNewton(curve.T, **options)
    w = curve.sqrt_w ** 2
    out, results = np.zeros_like(V_init), []
    for k in range(Z.shape[0]):  # one nonlinear solve per frame
        res = gn.solve(Z[k], w, V_init[k])
        out[k] = rigid_placement(res.V, place_on[k])
        results.append(res)
    return out, results


@dataclass(frozen=True, eq=False)
class MeshReport:
    """What an operation on mesh animations did.

    Attributes
    ----------
    converged : int
        Frames whose Gauss–Newton reconstruction converged (of ``frames``).
    frames : int
    descriptor_error : float
        Largest weighted descriptor residual ``|sqrt_w (z(V_k) - z_k)|`` over the frames,
        relative to the largest ``|sqrt_w z_k|``.
    history : (k,) float64 numpy array or None
        Seam gap per closing iteration (closing only).
    align : object or None
        The alignment result (blending with ``align="dp"``).
    status : str or None
        Closing only: ``"converged"`` (the seam gap fell below the closing's tolerance),
        ``"limit"`` (``iterations`` reached first) or ``"stalled"`` (no step lowered it).
    times : (K,) float64 numpy array or None
        The normalised time of the (first) input that each output frame was read at: its own
        frame ``k / (N-1)`` when closing, the aligned time when blending
        (:func:`mesh_on_source` uses them).
    """

    converged: int
    frames: int
    descriptor_error: float
    history: np.ndarray | None = None
    align: object = None
    status: str | None = None
    times: np.ndarray | None = None

    @property
    def success(self) -> bool:
        """Every frame's reconstruction converged and, when closing, the seam closed."""
        return self.converged == self.frames and self.status in (None, "converged")


def _mesh_report(Vs, Z, curve, results, **extra) -> MeshReport:
    from .shells.descriptors import lta_descriptors, wrap_angle

    Zr = lta_descriptors(Vs, curve.T)
    sT = curve.T.descriptor_slices()[1]

    D = Zr - Z
    D[:, sT] = wrap_angle(D[:, sT])
    err = np.linalg.norm(D * curve.sqrt_w, axis=1).max() / \
        max(np.linalg.norm(Z * curve.sqrt_w, axis=1).max(), 1e-300)
    return MeshReport(sum(r.success for r in results), len(results), float(err), **extra)


def mesh_close(Vs, F, *, iterations: int = 10, c1: bool = False, method=None,
               root_motion: str = "keep", **options) -> tuple[np.ndarray, MeshReport]:
    """Make a mesh animation loop: close its LΘA descriptor curve, then reconstruct.

    Parameters
    ----------
    Vs : (N,n,3) array_like
        Frames (N >= 3).
    F : (m,3) array_like
    iterations, c1 :
        As in :func:`shellspline.curves.closing.close`. Without ``c1`` the closing is
        :func:`close_euclidean`; ``c1`` needs the generic closing, at most
        ``MESH_C1_MAX_DIMS`` descriptors (about 125 vertices).
    method : {None, "gauss-newton", "gradient"}
        The closing method (``"gradient"``: seed 000's flow, by the generic closing).
    root_motion : {"keep", "close"}
        ``"keep"``: every frame placed rigidly on its input frame, so the last frame is the
        first frame's shape where the input's last frame is (a walk loops forward, as BVH
        clips do with ``root_motion="keep"``); ``"close"``: the rigid motion from the last
        frame to the first is then taken out along the sequence (frame ``k`` moved by the
        screw motion's fraction ``k / (N-1)``), so the last frame equals the first and the
        loop plays in place.
    **options
        Gauss–Newton options.

    Returns
    -------
    Vs : (N,n,3) float64 numpy array
        Every frame reconstructed from the closed descriptors (started at, and placed
        rigidly on, the input frame); the last frame has the first frame's shape.
    report : MeshReport
    """
    from .curves.closing import close as close_curve

    if root_motion not in ("keep", "close"):
        raise ShellsplineError(f"root_motion must be 'keep' or 'close', got {root_motion!r}")
    Vs = _mesh_frames(Vs)
    if Vs.shape[0] < 3:
        raise ShellsplineError(f"mesh_close: need at least 3 frames, got {Vs.shape[0]}")
    mc = mesh_curve(Vs, F)
    X = mc.Z * mc.sqrt_w
    D = X.shape[1]
    gauss_newton = method in (None, "gauss-newton")
    if gauss_newton and not c1:  # the same Gauss-Newton closing, O(frames x D)
        Xc, history = close_euclidean(X, iterations=iterations)
        # close_euclidean's own test: it stops there, or at the limit, or when stalled
        status = ("converged" if history[-1] <= CLOSE_TOL * max(1.0, np.abs(X).max()) else
                  "limit" if history.size > iterations else "stalled")
    else:
        if gauss_newton and D > MESH_C1_MAX_DIMS:
            raise ShellsplineError(
                f"mesh_close: c1 closing of {D} descriptors (about {D // 8} vertices) is too "
                f"slow (its constraint system is {2 * D} x {2 * D}); at most "
                f"{MESH_C1_MAX_DIMS} descriptors: decimate the mesh or close without c1")
        kw = {} if method is None else {"method": method}
        res = close_curve(mc.product_curve(), iterations=iterations, c1=c1, **kw)
        Xc, history, status = res.curve.X, np.asarray(res.seam_gap), res.status
    Z = Xc / mc.sqrt_w
    out, results = reconstruct_frames(Z, mc, Vs, **options)
    if root_motion == "close":
        out = _rigid_drift_removed(out)
    return out, _mesh_report(out, Z, mc, results, history=history, status=status,
                             times=np.linspace(0.0, 1.0, Vs.shape[0]))


def _rigid_drift_removed(Vs) -> np.ndarray:
    """Frames ``Vs`` moved by ``exp(k/(N-1) log G)``, ``G`` the rigid motion (Kabsch) that
    takes the last frame onto the first: the last frame lands on the first."""
    from .groups import se3
    from .mesh.rigid import best_rotations

    c_end, c_0 = Vs[-1].mean(axis=0), Vs[0].mean(axis=0)
    R = best_rotations(Vs[-1] - c_end, Vs[0] - c_0)
    xi = se3.log(se3.from_rt(R, c_0 - R @ c_end))
    G = se3.exp(np.linspace(0.0, 1.0, Vs.shape[0])[:, None] * xi)  # (N,4,4)
    return np.einsum("kij,knj->kni", G[:, :3, :3], Vs) + G[:, None, :3, 3]


# curves.closing.close solves its Gauss-Newton step in the constraint space: a (D,D) Schur
# complement (2D with c1) assembled column by column, O(frames D^2 + D^3) per iteration.
# On a body skinned to the real walk (34 frames): D = 984 / 1,984 / 3,984 / 7,984 took
# 1.7 / 8.6 / 39 / 494 s (c1: 14 / 60 / 233 s; 1.5 GB at D = 7,984) against 0.005 / 0.2 /
# 0.26 / 0.07 s for close_euclidean (the same steps in the frame space, equal to 1e-15).
# So mesh curves are closed by close_euclidean; c1 (which it does not do) only up to:
MESH_C1_MAX_DIMS = 1000
# close_euclidean's default tolerance: the seam gap relative to max(1, |X|_max)
CLOSE_TOL = 1e-12


def close_euclidean(X, *, iterations: int = 10, tol: float = CLOSE_TOL):
    """Close a curve in R^m (``X (N,m)`` on ``linspace(0, 1, N)``) with the least change of
    its SRV: Gauss–Newton steps on the seam gap ``X(1) - X(0) = sum_i h_i |q_i| q_i``.

    Each step minimises ``sum_i h_i |dq_i|^2`` subject to the linearised closure
    ``g + sum_i h_i J_i dq_i = 0``, ``J_i = |q_i| I + q_i q_i^T / |q_i|``: ``dq_i = -J_i y``
    with ``(a I + 3 B B^T) y = g``, ``a = sum h_i |q_i|^2``, ``B = Q^T diag(sqrt h)``,
    solved by the Woodbury identity in the frame space: ``O(N m)`` memory and ``O(N^2 m +
    N^3)`` time per step. :func:`shellspline.curves.closing.close` takes the same steps (to
    1e-15) through an ``(m, m)`` system in the constraint space, ``O(N m^2 + m^3)``: right
    for skeletons (m ~ 100), 7,000x slower for a 1,000-vertex mesh (m ~ 8,000; see
    ``MESH_C1_MAX_DIMS``). Start point kept; backtracking on ``|g|``.

    Returns
    -------
    X : (N,m) float64 numpy array
        The closed curve.
    history : (k+1,) float64 numpy array
        ``|g|`` before each step and after the last.
    """
    X = np.asarray(X, dtype=np.float64)
    N = X.shape[0]
    h = np.full(N - 1, 1.0 / (N - 1))
    eta = np.diff(X, axis=0) / h[:, None]
    nrm = np.linalg.norm(eta, axis=1)
    q = eta / np.sqrt(np.where(nrm > 0, nrm, 1.0))[:, None]

    def gap(qq):
        return (h * np.linalg.norm(qq, axis=1)) @ qq

    g = gap(q)
    hist = [float(np.linalg.norm(g))]
    for _ in range(int(iterations)):
        if hist[-1] <= tol * max(1.0, np.abs(X).max()):
            break
        nq = np.linalg.norm(q, axis=1)
        a = float(h @ nq ** 2)
        B = q.T * np.sqrt(h)  # (m, N-1)
        small = (a / 3.0) * np.eye(N - 1) + B.T @ B
        y = (g - B @ np.linalg.solve(small, B.T @ g)) / a
        safe = np.where(nq > 0, nq, 1.0)
        dq = -(nq[:, None] * y + ((q @ y) / safe)[:, None] * q)
        step = 1.0
        for _ in range(30):
            gn = gap(q + step * dq)
            if np.linalg.norm(gn) < hist[-1]:
                break
            step *= 0.5
        else:
            break
        q, g = q + step * dq, gn
        hist.append(float(np.linalg.norm(g)))
    inc = h[:, None] * np.linalg.norm(q, axis=1)[:, None] * q
    return X[0] + np.vstack([np.zeros((1, X.shape[1])), np.cumsum(inc, axis=0)]), np.array(hist)


def _mesh_curve_pair(Vs0, Vs1, F):
    """Two animations of one mesh, validated, and their LΘA curves weighted alike (at the
    first frame of ``Vs0``): ``(Vs0, Vs1, c0, c1)``."""
    Vs0, Vs1 = _mesh_frames(Vs0, "Vs0"), _mesh_frames(Vs1, "Vs1")
    if Vs0.shape[1] != Vs1.shape[1]:
        raise ShellsplineError(f"Vs0 and Vs1 must be frames of one mesh, got {Vs0.shape[1]} "
                               f"and {Vs1.shape[1]} vertices")
    c0 = mesh_curve(Vs0, F)
    return Vs0, Vs1, c0, mesh_curve(Vs1, F, T=c0.T, reference=Vs0[0])


def mesh_align(Vs0, Vs1, F, *, features=None, **kw):
    """The warp ``phi`` (normalised times) with ``Vs1(phi(t))`` matching ``Vs0(t)`` in LΘA
    space: :func:`shellspline.curves.align.align` on the weighted descriptor curves
    (weights at the first frame of ``Vs0``). ``features``: ``(k,2)`` pairs of normalised
    times. Returns the :class:`~shellspline.curves.align.AlignResult`."""
    from .curves.align import align as align_curves

    _, _, c0, c1 = _mesh_curve_pair(Vs0, Vs1, F)
    if features is not None:
        P = np.asarray(features, dtype=np.float64).reshape(-1, 2)
        kw.setdefault("lam", FEATURE_WEIGHT)
        features = (P[:, 0], P[:, 1])
    return align_curves(c0.product_curve(), c1.product_curve(), features=features, **kw)


def mesh_blend(Vs0, Vs1, F, s: float = 0.5, *, align: str = "dp", features=None,
               **options) -> tuple[np.ndarray, MeshReport]:
    """Blend two animations of one mesh along the SRV geodesic of their LΘA curves.

    Parameters
    ----------
    Vs0 : (N,n,3) array_like
    Vs1 : (M,n,3) array_like
        The same mesh (vertex order and faces); any frame count.
    F : (m,3) array_like
    s : float
        Weight of ``Vs1`` (0: ``Vs0``, 1: ``Vs1``).
    align : {"dp", "none"}
        Align ``Vs1`` to ``Vs0`` in time first, or map their frames affinely.
    **options
        Gauss–Newton options.

    Returns
    -------
    Vs : (K,n,3) float64 numpy array
        ``K = round((1-s)(N-1) + s(M-1)) + 1`` frames, evenly spaced: the blend of the clips
        themselves (the SRV geodesic of their piecewise-linear descriptor curves, on
        :func:`~shellspline.curves.srv.warp_grid`) with its timing blended too, as
        :func:`blend` does for BVH clips (the blend composed with the inverse of ``(1-s) id +
        s phi``), read at the output frames and reconstructed (started at the vertex blend of
        the two aligned frames and placed rigidly on it). ``s = 0`` gives ``Vs0`` and ``s =
        1`` gives ``Vs1``, frame for frame, to the reconstruction's tolerance.
    report : MeshReport
    """
    from .curves.srv import blend as blend_curves
    from .curves.srv import reparametrize, warp_grid

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    s = _blend_weight(s)
    Vs0, Vs1, c0, c1 = _mesh_curve_pair(Vs0, Vs1, F)
    p0, p1 = c0.product_curve(), c1.product_curve()
    rep = None
    warp_t = warp = np.array([0.0, 1.0])
    if align == "dp":
        rep = mesh_align(Vs0, Vs1, F, features=features)
        warp_t, warp = rep.t, np.clip(rep.phi, 0.0, 1.0)
    # on the clips' own frames (as blend for BVH): on Vs0's frames alone, s = 1 was Vs1
    # resampled onto them, not Vs1
    t, phi = warp_grid(p0.t, warp_t, warp, p1.t)
    c = blend_curves(reparametrize(p0, t, t), p1, s, warp=phi)
    u, tu = _blend_clock(p0.t, p1.t, t, phi, s)
    Z = reparametrize(c, tu, u).X / c0.sqrt_w
    # vertex positions of both at the aligned times: the initial guesses and placement track
    guess = (1 - s) * reparametrize_vertices(Vs0, tu) + \
        s * reparametrize_vertices(Vs1, np.interp(tu, t, phi))
    out, results = reconstruct_frames(Z, c0, guess, **options)
    return out, _mesh_report(out, Z, c0, results, align=rep, times=tu)


def _lerp(x, y, s: float):
    """``(1-s) x + s y``: exactly ``x`` at ``s = 0`` (and where ``y == x``) and exactly ``y``
    at ``s = 1``, so that blended times and counts are a clip's own at the ends."""
    x, y = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
    return x + s * (y - x) if s <= 0.5 else y - (1 - s) * (y - x)


def _blend_times(ta, tb, s: float) -> np.ndarray:
    """Sample times of a blend of clips sampled at ``ta (N_a,)`` and ``tb (N_b,)``:
    ``round((1-s)(N_a-1) + s(N_b-1)) + 1`` samples (at least 2), the k-th the blend of the
    clips' times at the same fraction of their samples (interpolated between samples): ``ta``
    at ``s = 0``, ``tb`` at ``s = 1``, exactly."""
    n = max(int(round(float(_lerp(ta.size - 1, tb.size - 1, s)))) + 1, 2)
    x = np.linspace(0.0, 1.0, n)

    def own(tt):
        return tt if tt.size == n else np.interp(x, np.linspace(0.0, 1.0, tt.size), tt)
    return _lerp(own(ta), own(tb), s)


def _blend_clock(ta, tb, t, phi, s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(u, tu)``: the output times ``u`` of a blend (:func:`_blend_times`, in the blended
    clock ``psi = (1-s) t + s phi``) and the times ``tu = psi^-1(u)`` of the blend's grid
    ``t`` to read it at (``ta`` itself at ``s = 0``; at ``s = 1`` where ``phi`` meets
    ``tb``)."""
    u = _blend_times(ta, tb, s)
    psi = _lerp(t, phi, s)
    if np.any(np.diff(psi) < 0):  # s outside [0, 1] with a warp that stalls
        psi = np.maximum.accumulate(psi)
    if np.any(np.diff(u) <= 0):
        raise ShellsplineError(f"s = {s:g} extrapolates the two clips' times to times that do "
                               "not increase; give s between 0 and 1")
    return u, _inverse_clock(u, psi, t)


def reparametrize_vertices(Vs, phi) -> np.ndarray:
    """Frames ``Vs (N,n,3)`` at normalised times ``phi (K,)``, linearly between frames."""
    Vs = np.asarray(Vs, dtype=np.float64)
    s = np.clip(np.asarray(phi, dtype=np.float64), 0.0, 1.0) * (Vs.shape[0] - 1)
    i = np.minimum(np.floor(s).astype(np.int64), Vs.shape[0] - 2)
    w = (s - i)[:, None, None]
    return Vs[i] * (1 - w) + Vs[i + 1] * w


def mesh_on_source(Vs, kf, times) -> np.ndarray:
    """Frames made on the solve mesh of a keyframe set, on the vertices of its files.

    Parameters
    ----------
    Vs : (K,n,3) array_like
        Frames of ``kf``'s solve mesh (:func:`mesh_close`, :func:`mesh_blend` of ``kf.V``).
    kf : Keyframes
        The input, read from files (:func:`shellspline.io.read_keyframes`): its ``source``
        maps the solve mesh back to the files' vertices.
    times : (K,) array_like
        The normalised time of ``kf`` that each frame was made from (``MeshReport.times``).

    Returns
    -------
    (K,n_source,3) float64 numpy array
        ``Vs`` itself when ``kf.source`` is None. Else a vertex welded at a seam (UV splits)
        takes its solve vertex's position, a fin's tip keeps its coordinates in its anchor
        face's frame (those of the input at ``times``, linearly between its frames) and an
        isolated vertex the input's position at ``times``. (:meth:`SourceMesh.expand` is for
        in-betweens of the keyframes themselves: it gives every seam vertex the keyframe's
        coordinates back at the keyframes, which tore the seams of a closed or blended
        frame.)
    """
    from .mesh.source_mesh import face_frames

    Vs = np.asarray(Vs, dtype=np.float64)
    src = kf.source
    if src is None:
        return Vs
    out = np.zeros((Vs.shape[0], src.n_source, 3))
    kept = src.to_solve >= 0
    out[:, kept] = Vs[:, src.to_solve[kept]]
    if src.set_aside.size:
        X = src.exact_V[:, np.searchsorted(src.exact, src.set_aside)]  # (J,s,3) as read
        fin = src.anchors[:, 0] >= 0
        local = X.copy()
        if fin.any():
            origin, R = face_frames(np.asarray(kf.V, dtype=np.float64), src.anchors[fin])
            local[:, fin] = np.einsum("jsba,jsb->jsa", R, X[:, fin] - origin)
        loc = reparametrize_vertices(local, times)
        if fin.any():
            origin, R = face_frames(Vs, src.anchors[fin])
            loc[:, fin] = origin + np.einsum("ksab,ksb->ksa", R, loc[:, fin])
        out[:, src.set_aside] = loc
    return out


def mesh_distance(Vs0, Vs1, F, *, align: str = "dp", results=None, **kw) -> float:
    """SRV distance of two animations of one mesh in LΘA space (weights at the first frame of
    ``Vs0``, the same for both directions): ``"none"`` on one normalised grid (``Vs1``'s
    descriptor curve resampled linearly to ``Vs0``'s frames), ``"dp"`` the mean of the
    aligned distances both ways (symmetric; the two ``AlignResult`` are appended to the list
    ``results`` when one is given, as by :func:`distance`)."""
    from .curves.align import align as align_curves
    from .curves.srv import reparametrize, srv_distance

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    Vs0, Vs1, c0, c1 = _mesh_curve_pair(Vs0, Vs1, F)
    p0, p1 = c0.product_curve(), c1.product_curve()
    if align == "none":
        return srv_distance(p0, reparametrize(p1, p0.t, p0.t))

    def aligned(x, y):
        r = align_curves(x, y, **kw)
        if results is not None:
            results.append(r)
        return srv_distance(x, reparametrize(y, np.clip(r.phi, 0.0, 1.0), x.t))
    return 0.5 * (aligned(p0, p1) + aligned(p1, p0))


# ----------------------------------------------------------------------------------------
# Rigid pose tracks: curves in SO(3) x R^3 (d = 1, m = 3)
# ----------------------------------------------------------------------------------------
def _as_track(track, name, at_least=2):
    from .io.posefiles import PoseTrack

    if not isinstance(track, PoseTrack):
        raise ShellsplineError(f"{name}: expected a PoseTrack (io.posefiles.read_poses), got "
                               f"{type(track).__name__}")
    n = track.t.shape[0]
    if n < at_least:
        raise ShellsplineError(f"{name}: a pose track needs at least {at_least} poses, got {n}")
    return track


def track_length(*tracks) -> float:
    """The default position scale of pose tracks: their RMS distance from their mean position.

    Parameters
    ----------
    *tracks : PoseTrack
        One or more tracks; with several, the root mean square over them of each track's
        RMS (symmetric in the tracks, so distances are too).

    Returns
    -------
    float
        File units of position that weigh like one radian of rotation in the SRV metric
        (1.0 for tracks that do not move).

    Notes
    -----
    The metric of ``SO(3) x R^3`` adds rotations in radians to positions in file units:
    dividing the positions by this length makes results independent of the unit (metres or
    millimetres) and of the origin, and makes a sweep across the track's typical extent
    weigh like a turn of about one radian.
    """
    ms = []
    for k, tr in enumerate(tracks):
        p = _as_track(tr, f"track {k}", 1).T[:, :3, 3]
        ms.append(float(np.mean(np.sum((p - p.mean(axis=0)) ** 2, axis=1))))
    L = float(np.sqrt(np.mean(ms)))
    scale = max(1.0, max(float(np.abs(tr.T[:, :3, 3]).max()) for tr in tracks))
    return L if L > 1e-12 * scale else 1.0


def _length(length, *tracks) -> float:
    if length is None:
        return track_length(*tracks)
    if not (np.isfinite(length) and length > 0):
        raise ShellsplineError(f"length must be a positive number (file units per radian), "
                               f"got {length!r}")
    return float(length)


def track_curve(track, length: float = 1.0):
    """A pose track as a :class:`~shellspline.curves.srv.ProductCurve` in ``SO(3) x R^3``.

    Parameters
    ----------
    track : PoseTrack
    length : float
        Position scale: ``X = position / length``.

    Returns
    -------
    ProductCurve
        ``R (N,1,3,3)`` the rotations body -> world, ``X (N,3)`` the scaled positions,
        ``t`` the file's times (KITTI: the pose index).
    """
    from .curves.srv import ProductCurve

    track = _as_track(track, "track")
    return ProductCurve(R=track.T[:, None, :3, :3], X=track.T[:, :3, 3] / float(length),
                        t=track.t)


# Most evenly spaced samples of a pose track on the DP lattice of track_align /
# track_distance. The DP costs O(N^2) (a band of 1/4 of the duration): 1.3 / 4.2 / 20 s
# for 2,000 / 4,000 / 8,000 poses (track_align on windows of a 100 Hz random-walk track,
# 2-core VM at load ~4), so a 50,000-pose EuRoC or TUM track against a 3,000-pose one ran
# for more than 10 minutes at 2.3 GB (now 10 s, 170 MB); a longer track is resampled to
# this many times over its span for the alignment (the warp is smooth at that scale).
TRACK_DP_SAMPLES = 4000


def _track_like(curve, length, like):
    from .groups import se3
    from .io.posefiles import PoseTrack

    T = se3.from_rt(curve.R[:, 0], curve.X * length)
    return PoseTrack(np.asarray(curve.t, dtype=np.float64).copy(), T, like.format,
                     like.origin_ns, like.time_unit)


def _uniform(curve, n=None):
    """The curve on ``n`` (default ``N``) evenly spaced times over its own span, counted
    from its start (``0 .. t[-1] - t[0]``: evenly spaced to rounding also for Unix-epoch
    timestamps, whose spacing ``linspace`` cannot keep uniform to 1e-6)."""
    from .curves.srv import reparametrize

    n = curve.n_frames if n is None else int(n)
    u = np.linspace(0.0, curve.t[-1] - curve.t[0], n)
    return reparametrize(curve, np.clip(curve.t[0] + u, curve.t[0], curve.t[-1]), u)


@dataclass(frozen=True, eq=False)
class TrackReport:
    """What an operation on pose tracks did.

    Attributes
    ----------
    length : float
        The position scale used (file units per radian).
    result : object
        The :class:`~shellspline.curves.closing.CloseResult` (closing) or
        :class:`~shellspline.curves.align.AlignResult` (blending with ``align="dp"``), or
        None.
    rotation_gap : (2,) float64 numpy array or None
        Closing: the seam's rotation (radians) before and after.
    position_gap : (2,) float64 numpy array or None
        Closing: the seam's position jump (file units) before and after.
    """

    length: float
    result: object = None
    rotation_gap: np.ndarray | None = None
    position_gap: np.ndarray | None = None


def _track_gaps(track):
    R, p = track.T[:, :3, :3], track.T[:, :3, 3]
    return (float(so3.angle(R[-1] @ R[0].T)), float(np.linalg.norm(p[-1] - p[0])))


def track_close(track, *, iterations: int = 10, c1: bool = False, length=None,
                method: str = "gauss-newton"):
    """Make a pose track loop: close its curve in ``SO(3) x R^3`` with the least SRV change.

    Parameters
    ----------
    track : PoseTrack
        At least 3 poses.
    iterations, c1, method :
        As in :func:`shellspline.curves.closing.close`.
    length : float, optional
        Position scale (default :func:`track_length`).

    Returns
    -------
    PoseTrack
        The same times, format and first pose; the last pose equals the first (to the
        closing tolerance).
    TrackReport
        With the ``CloseResult`` (``seam_gap`` per iteration, in the scaled metric) and the
        rotation / position gaps before and after.
    """
    from .curves.closing import close as close_curve

    track = _as_track(track, "track", 3)
    L = _length(length, track)
    res = close_curve(track_curve(track, L), iterations=iterations, c1=c1, method=method)
    out = _track_like(res.curve, L, track)
    g0, g1 = _track_gaps(track), _track_gaps(out)
    return out, TrackReport(L, res, np.array([g0[0], g1[0]]), np.array([g0[1], g1[1]]))


def _track_pair(a, b, length):
    a, b = _as_track(a, "a"), _as_track(b, "b")
    L = _length(length, a, b)
    return a, b, L, track_curve(a, L), track_curve(b, L)


def _features_pairs(features, kw):
    if features is None:
        return None
    P = np.asarray(features, dtype=np.float64).reshape(-1, 2)
    kw.setdefault("lam", FEATURE_WEIGHT)
    return (P[:, 0], P[:, 1])


def track_align(a, b, *, length=None, features=None, **kw):
    """The warp ``phi`` with ``b(phi(t))`` matching ``a(t)``: :func:`shellspline.curves.align.
    align` on the tracks' curves, each resampled to evenly spaced times over its own span
    (the DP lattice needs them; camera clocks jitter).

    Parameters
    ----------
    a, b : PoseTrack
        At least 2 poses each; any counts and formats.
    length : float, optional
        Position scale (default :func:`track_length` of both).
    features : (k,2) array_like, optional
        Pairs ``(time in a, time in b)`` in the files' times (weight ``lam``, default
        ``FEATURE_WEIGHT``).
    **kw
        Options of :func:`shellspline.curves.align.align`.

    Returns
    -------
    AlignResult
        ``t``: ``min(N_a, TRACK_DP_SAMPLES)`` evenly spaced times over ``a``'s span;
        ``phi``: times of ``b``.
    """
    a, b, L, ca, cb = _track_pair(a, b, length)
    r = _track_warp(ca, cb, features, kw)
    r.t = r.t + ca.t[0]
    r.phi = r.phi + cb.t[0]
    r.shift = r.shift + float(cb.t[0])
    return r


def _track_warp(ca, cb, features, kw):
    """:func:`track_align`'s ``AlignResult`` with the times counted from each track's start
    (``t`` from 0 to ``a``'s span, ``phi`` from 0 to ``b``'s, exactly at the ends)."""
    from .curves.align import align as align_curves

    feats = _features_pairs(features, kw)
    if feats is not None:
        feats = (feats[0] - ca.t[0], feats[1] - cb.t[0])
    return align_curves(_uniform(ca, min(ca.n_frames, TRACK_DP_SAMPLES)),
                        _uniform(cb, min(cb.n_frames, TRACK_DP_SAMPLES)), features=feats, **kw)


def track_distance(a, b, *, align: str = "dp", length=None, results=None, **kw) -> float:
    """SRV distance of two pose tracks (normalised time; positions divided by ``length``,
    default :func:`track_length` of both).

    Both tracks are resampled to ``max(N_a, N_b)`` evenly spaced times over their own spans
    (at most ``TRACK_DP_SAMPLES``);
    ``align="none"`` compares them on that grid, ``"dp"`` is the mean of the aligned
    distances both ways (the two ``AlignResult`` are appended to the list ``results`` when
    one is given, as by :func:`distance`). Both are symmetric in ``a`` and ``b``.
    """
    from .curves.align import align as align_curves
    from .curves.srv import reparametrize, srv_distance

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    a, b, L, ca, cb = _track_pair(a, b, length)
    n = min(max(ca.n_frames, cb.n_frames), TRACK_DP_SAMPLES)
    ua, ub = _uniform(ca, n), _uniform(cb, n)
    if align == "none":
        return srv_distance(ua, ub.with_times(ua.t))

    def aligned(x, y):
        r = align_curves(x, y, **kw)
        if results is not None:
            results.append(r)
        return srv_distance(x, reparametrize(y, np.clip(r.phi, y.t[0], y.t[-1]), x.t))
    return 0.5 * (aligned(ua, ub) + aligned(ub, ua))


def track_blend(a, b, s: float = 0.5, *, align: str = "dp", length=None, features=None,
                **kw):
    """Blend two pose tracks along the SRV geodesic in ``SO(3) x R^3``.

    Parameters
    ----------
    a, b : PoseTrack
    s : float
        Weight of ``b`` (0: ``a``, 1: ``b``).
    align : {"dp", "none"}
        Align ``b`` to ``a`` in time first (:func:`track_align`), or map their spans
        affinely.
    length : float, optional
        Position scale (default :func:`track_length` of both).
    features : (k,2) array_like, optional
        Feature time pairs for the alignment.
    **kw
        Options of :func:`shellspline.curves.align.align`.

    Returns
    -------
    PoseTrack
        In ``a``'s format, ``round((1-s)(N_a-1) + s(N_b-1)) + 1`` poses; the blend of the
        tracks themselves (the SRV geodesic of their piecewise geodesics, on
        :func:`~shellspline.curves.srv.warp_grid`) with its timing blended too, as
        :func:`blend` does for BVH clips: the k-th time is the blend of the tracks' times at
        the same fraction of their poses (``b``'s times taken in ``a``'s ``origin_ns``), the
        pose there the blend read through the blended clock ``(1-s) id + s phi``. ``s = 0``
        gives ``a`` (its times and poses), ``s = 1`` gives ``b``, to rounding; starts at the
        geodesic blend of the start poses. A KITTI track (no times: its ``t`` is the pose
        index) blended with a timed one takes that one's span, its poses evenly spaced (``s
        = 1`` then has ``b``'s poses over ``a``'s span); a KITTI result's ``t`` is its pose
        index.
    TrackReport
        With the ``AlignResult`` (``align="dp"``, in the files' times) or None.
    """
    from .curves.srv import blend as blend_curves
    from .curves.srv import reparametrize, warp_grid
    from .groups import se3
    from .io.posefiles import PoseTrack

    if align not in ("dp", "none"):
        raise ShellsplineError(f"align must be 'dp' or 'none', got {align!r}")
    s = _blend_weight(s)
    a, b, L, ca, cb = _track_pair(a, b, length)
    # each track on its own clock counted from its start: at Unix-epoch magnitudes the grid's
    # arithmetic rounds to 2e-7 s, enough to move s = 1 off b's poses
    pa, pb = ca.with_times(ca.t - ca.t[0]), cb.with_times(cb.t - cb.t[0])
    # a KITTI file has no times (t is the pose index): such a track takes the other one's
    # clock, its poses evenly spread over that span, so that neither the blended timing nor
    # the file times blend pose indices with seconds (a TUM track blended with a KITTI one
    # wrote stamps at half the Unix epoch)
    spans = pa.t[-1], pb.t[-1]
    if b.format == "kitti" and a.format != "kitti":
        pb = pb.with_times(np.linspace(0.0, pa.t[-1], pb.n_frames))
    elif a.format == "kitti" and b.format != "kitti":
        pa = pa.with_times(np.linspace(0.0, pb.t[-1], pa.n_frames))
    warp_t, warp, rep = pa.t[[0, -1]], pb.t[[0, -1]], None
    if align == "dp":
        rep = _track_warp(ca, cb, features, dict(kw))
        warp_t, warp = rep.t, np.clip(rep.phi, 0.0, spans[1])
        if (pa.t[-1], pb.t[-1]) != spans:  # the warp on the clocks taken
            warp_t = np.interp(warp_t, [0.0, spans[0]], [0.0, pa.t[-1]])
            warp = np.interp(warp, [0.0, spans[1]], [0.0, pb.t[-1]])
        rep.t, rep.phi = rep.t + ca.t[0], rep.phi + cb.t[0]
        rep.shift = rep.shift + float(cb.t[0])
    elif features is not None:
        raise ShellsplineError("features need align='dp'")
    # on the tracks' own poses (as blend for BVH): on a's times alone, s = 1 was b resampled
    # onto them, not b
    t, phi = warp_grid(pa.t, warp_t, warp, pb.t)
    c = blend_curves(reparametrize(pa, t, t), pb, s, warp=phi)
    u, tu = _blend_clock(pa.t, pb.t, t, phi, s)
    cu = reparametrize(c, tu, u)
    # the file times: the same blend of a's and b's own (b's in a's origin_ns); KITTI: the
    # pose index
    shift = (int(b.origin_ns) - int(a.origin_ns)) / 1e9
    if a.format == "kitti":
        times = np.arange(u.size, dtype=np.float64)
    else:
        tb = a.t[0] + pb.t if b.format == "kitti" else b.t + shift if shift else b.t
        times = _blend_times(a.t, tb, s)
    out = PoseTrack(times, se3.from_rt(cu.R[:, 0], cu.X * L), a.format, a.origin_ns,
                    a.time_unit)
    return out, TrackReport(L, rep)
