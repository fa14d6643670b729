"""Synthetic skeletal motions (BVH) with the layouts real files come in.

A procedural biped walk (hip, knee, ankle swing; arm swing; torso sway; root travel and
bob) written with any frame rate, 3 or 6 channels per joint, any Euler order (one for all
joints or a different order per joint), Y-up or Z-up, any unit scale and plain numbered or
human joint names. The motion is defined by rotation matrices and then encoded in the
requested channels, so the same walk in two layouts is the same motion.

``python -m data_synth motion OUT.bvh [--fps 120] [--channels 3] [--order ZYX|mixed]
[--up y|z] [--seconds 2] [--scale 1] [--names human|numbered|mixamo]
[--skeleton simple|cmu|fingers] [--frames N] [--lift H] [--tpose-first] [--root-only]``

Skeletons: ``simple`` (19 joints), ``cmu`` (the 31-joint CMU layout: ``Hips, LHipJoint,
LeftUpLeg, ..., LeftToeBase, ..., LThumb``, zero-length hip and shoulder joints, finger and
thumb leaves) and ``fingers`` (a game rig: ``simple`` plus three-joint fingers on both hands,
49 joints, 15 end sites). ``names="mixamo"`` prefixes every name with ``mixamorig:``; with
``channels=6`` every joint has 6 channels, as Mixamo exports write them.
"""
from __future__ import annotations

import argparse

import numpy as np

ORDERS = ("ZXY", "XYZ", "ZYX", "YXZ", "YZX", "XZY")

# name, parent, offset (Y-up, forward +Z, centimetres)
_SKELETON = (
    ("pelvis", -1, (0.0, 0.0, 0.0)),
    ("spine", 0, (0.0, 10.0, 0.0)),
    ("chest", 1, (0.0, 15.0, 0.0)),
    ("neck", 2, (0.0, 15.0, 0.0)),
    ("head", 3, (0.0, 8.0, 0.0)),
    ("upperarm_l", 2, (17.0, 12.0, 0.0)),
    ("forearm_l", 5, (0.0, -28.0, 0.0)),
    ("hand_l", 6, (0.0, -25.0, 0.0)),
    ("upperarm_r", 2, (-17.0, 12.0, 0.0)),
    ("forearm_r", 8, (0.0, -28.0, 0.0)),
    ("hand_r", 9, (0.0, -25.0, 0.0)),
    ("thigh_l", 0, (9.0, -5.0, 0.0)),
    ("shin_l", 11, (0.0, -42.0, 0.0)),
    ("foot_l", 12, (0.0, -40.0, 0.0)),
    ("toe_l", 13, (0.0, -6.0, 12.0)),
    ("thigh_r", 0, (-9.0, -5.0, 0.0)),
    ("shin_r", 15, (0.0, -42.0, 0.0)),
    ("foot_r", 16, (0.0, -40.0, 0.0)),
    ("toe_r", 17, (0.0, -6.0, 12.0)),
)
_END_SITES = ((4, (0.0, 10.0, 0.0)), (7, (0.0, -8.0, 0.0)), (10, (0.0, -8.0, 0.0)),
              (14, (0.0, 0.0, 5.0)), (18, (0.0, 0.0, 5.0)))
PELVIS_HEIGHT = 95.0
_FINE_RATE = 2400.0  # Hz, the grid the planted root path is integrated on

# The CMU layout: name, parent, offset, the joint of _SKELETON whose rotation it carries
# (None: identity). Zero-length LHipJoint / RHipJoint / Spine1 / Neck1 as in the CMU files.
_CMU = (
    ("Hips", -1, (0.0, 0.0, 0.0), 0),
    ("LHipJoint", 0, (0.0, 0.0, 0.0), None),
    ("LeftUpLeg", 1, (9.0, -5.0, 0.0), 11),
    ("LeftLeg", 2, (0.0, -42.0, 0.0), 12),
    ("LeftFoot", 3, (0.0, -40.0, 0.0), 13),
    ("LeftToeBase", 4, (0.0, -6.0, 12.0), 14),
    ("RHipJoint", 0, (0.0, 0.0, 0.0), None),
    ("RightUpLeg", 6, (-9.0, -5.0, 0.0), 15),
    ("RightLeg", 7, (0.0, -42.0, 0.0), 16),
    ("RightFoot", 8, (0.0, -40.0, 0.0), 17),
    ("RightToeBase", 9, (0.0, -6.0, 12.0), 18),
    ("LowerBack", 0, (0.0, 10.0, 0.0), 1),
    ("Spine", 11, (0.0, 15.0, 0.0), 2),
    ("Spine1", 12, (0.0, 0.0, 0.0), None),
    ("Neck", 13, (0.0, 15.0, 0.0), 3),
    ("Neck1", 14, (0.0, 0.0, 0.0), None),
    ("Head", 15, (0.0, 8.0, 0.0), 4),
    ("LeftShoulder", 13, (17.0, 12.0, 0.0), None),
    ("LeftArm", 17, (0.0, 0.0, 0.0), 5),
    ("LeftForeArm", 18, (0.0, -28.0, 0.0), 6),
    ("LeftHand", 19, (0.0, -25.0, 0.0), 7),
    ("LeftFingerBase", 20, (0.0, -4.0, 0.0), None),
    ("LeftHandIndex1", 21, (0.0, -3.0, 0.0), None),
    ("LThumb", 20, (2.0, -3.0, 1.0), None),
    ("RightShoulder", 13, (-17.0, 12.0, 0.0), None),
    ("RightArm", 24, (0.0, 0.0, 0.0), 8),
    ("RightForeArm", 25, (0.0, -28.0, 0.0), 9),
    ("RightHand", 26, (0.0, -25.0, 0.0), 10),
    ("RightFingerBase", 27, (0.0, -4.0, 0.0), None),
    ("RightHandIndex1", 28, (0.0, -3.0, 0.0), None),
    ("RThumb", 27, (-2.0, -3.0, 1.0), None),
)
_CMU_END_SITES = ((5, (0.0, 0.0, 5.0)), (10, (0.0, 0.0, 5.0)), (16, (0.0, 10.0, 0.0)),
                  (22, (0.0, -3.0, 0.0)), (23, (1.0, -3.0, 0.0)), (29, (0.0, -3.0, 0.0)),
                  (30, (-1.0, -3.0, 0.0)))


def _depth_first(ents, ends):
    """Entries reordered depth-first (BVH order: every joint's subtree right after it)."""
    kids = [[] for _ in ents]
    for j, e in enumerate(ents):
        if e[1] >= 0:
            kids[e[1]].append(j)
    order, stack = [], [0]
    while stack:
        j = stack.pop()
        order.append(j)
        stack.extend(reversed(kids[j]))
    new = {old: k for k, old in enumerate(order)}
    out = [(ents[j][0], -1 if ents[j][1] < 0 else new[ents[j][1]], ents[j][2], ents[j][3])
           for j in order]
    return out, [(new[p], o) for p, o in ends]


def _skeleton(kind: str):
    """``(entries, end_sites)``: entries ``(name, parent, offset, role)`` with ``role`` the
    joint of ``_SKELETON`` whose rotation the joint carries (None: identity)."""
    if kind == "simple":
        return [(n, p, o, j) for j, (n, p, o) in enumerate(_SKELETON)], list(_END_SITES)
    if kind == "cmu":
        return list(_CMU), list(_CMU_END_SITES)
    if kind == "fingers":  # a game rig: three-joint fingers under both hands
        ents = [(n, p, o, j) for j, (n, p, o) in enumerate(_SKELETON)]
        ends = [e for e in _END_SITES if e[0] not in (7, 10)]
        for hand, side, sx in ((7, "l", 1.0), (10, "r", -1.0)):
            for f, fname in enumerate(("thumb", "index", "middle", "ring", "pinky")):
                parent = hand
                off = (sx * (2.5 - 1.2 * f), -3.0, 1.5 if f == 0 else 0.0)
                for k in range(3):
                    ents.append((f"{fname}{k + 1}_{side}", parent, off, None))
                    parent = len(ents) - 1
                    off = (0.0, -2.0, 0.0)
                ends.append((parent, (0.0, -1.5, 0.0)))
        return _depth_first(ents, ends)
    raise ValueError(f"skeleton must be simple, cmu or fingers, got {kind!r}")


def _rot(axis: int, a) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    p, q = {0: (1, 2), 1: (2, 0), 2: (0, 1)}[axis]
    R[..., axis, axis] = 1.0
    R[..., p, p] = c
    R[..., q, q] = c
    R[..., p, q] = -s
    R[..., q, p] = s
    return R


def walk_rotations(t, speed: float = 120.0, cadence: float = 1.0):
    """Local rotations ``(T,J,3,3)`` and root positions ``(T,3)`` (Y-up, cm) of the walk at
    times ``t (T,)`` seconds; ``cadence`` gait cycles per second."""
    t = np.asarray(t, dtype=np.float64)
    w = 2 * np.pi * cadence * t
    J = len(_SKELETON)
    R = np.broadcast_to(np.eye(3), t.shape + (J, 3, 3)).copy()
    d = np.radians
    R[:, 0] = _rot(1, d(5) * np.sin(w)) @ _rot(2, d(3) * np.sin(w))  # pelvis yaw, roll
    R[:, 1] = _rot(1, -d(4) * np.sin(w))
    R[:, 2] = _rot(0, d(3) + d(1) * np.sin(2 * w))
    R[:, 4] = _rot(0, d(2) * np.sin(2 * w))
    for side, ph in ((0, 0.0), (1, np.pi)):
        arm, thigh = (5, 11) if side == 0 else (8, 15)
        R[:, arm] = _rot(0, -d(20) * np.sin(w + ph)) @ _rot(2, d(6) * (1 - 2 * side))
        R[:, arm + 1] = _rot(0, -d(15) - d(10) * np.sin(w + ph))
        hip = d(25) * np.sin(w + ph)  # forward swing of the thigh
        # the knee bends in swing only (the thigh swinging forward, cos > 0): both legs are
        # straight and equally low at the double-support instants
        knee = d(60) * np.clip(np.cos(w + ph), 0, None) ** 1.5
        R[:, thigh] = _rot(0, -hip)
        R[:, thigh + 1] = _rot(0, knee)
        R[:, thigh + 2] = _rot(0, hip - knee)  # the foot stays level with the pelvis
        R[:, thigh + 3] = _rot(0, d(15) * np.clip(np.cos(w + ph), 0, None))  # toe, in swing
    root = np.stack([1.5 * np.sin(w), PELVIS_HEIGHT + 2.0 * np.cos(2 * w), speed * t], axis=1)
    return R, root


def planted_root(R, stance) -> np.ndarray:
    """Root positions ``(T,3)`` (Y-up, cm) under which the stance foot does not slide.

    Parameters
    ----------
    R : (T,J,3,3) array_like
        Local rotations of ``_SKELETON`` (:func:`walk_rotations`).
    stance : (T,2) bool array_like
        Left and right foot in stance (the thigh swinging back).

    Returns
    -------
    (T,3) float64 numpy array
        Height: the lowest foot point (ankles, toes, toe tips) on the ground (0). Horizontal:
        the root's step is minus the step, relative to the root, of the lowest point of the
        foot in stance, so that foot stays where it is. The travel follows from the gait
        (about 1.2 m/s at one cycle per second), not from a chosen speed.
    """
    R = np.asarray(R, dtype=np.float64)
    T = R.shape[0]
    n = len(_SKELETON)
    Rw = np.zeros_like(R)
    P = np.zeros((T, n, 3))
    for j, (_, p, o) in enumerate(_SKELETON):  # forward kinematics relative to the root
        Rw[:, j] = R[:, j] if p < 0 else Rw[:, p] @ R[:, j]
        if p >= 0:
            P[:, j] = P[:, p] + Rw[:, p] @ np.asarray(o)
    tip = {j: np.asarray(o) for j, o in _END_SITES}
    feet = [np.stack([P[:, a], P[:, b], P[:, b] + Rw[:, b] @ tip[b]], axis=1)
            for a, b in ((13, 14), (17, 18))]  # (T,3,3) per foot: ankle, toe, toe tip
    pts = np.concatenate(feet, axis=1)  # (T,6,3)
    root = np.zeros((T, 3))
    root[:, 1] = -pts[..., 1].min(axis=1)
    stance = np.asarray(stance, dtype=bool)
    f = np.where(stance[:, 0], 0, 1)  # the foot in stance (left when both)
    k = np.argmin(pts[np.arange(T)[:, None], 3 * f[:, None] + np.arange(3), 1], axis=1)
    piv = 3 * f + k
    step = pts[np.arange(1, T), piv[:-1]] - pts[np.arange(T - 1), piv[:-1]]
    root[1:, [0, 2]] = -np.cumsum(step[:, [0, 2]], axis=0)
    return root


def motion(*, fps: float = 120.0, seconds: float = 2.0, channels: int = 3, order="ZYX",
           up: str = "y", scale: float = 1.0, names: str = "human", speed: float = 120.0,
           cadence: float = 1.0, skeleton: str = "simple", frames: int | None = None,
           lift: float = 0.0, tpose_first: bool = False, root_only: bool = False,
           planted: bool = True):
    """A synthetic walk as a :class:`~shellspline.io.bvh.Motion`.

    Parameters
    ----------
    fps : float
        Frames per second (CMU files: 120).
    seconds : float
        Duration.
    channels : {3, 6}
        Channels of every joint but the root (6 on the root always): 3 rotations, or 3
        positions (equal to the offset, as game-studio exports write them) and 3 rotations.
    order : str or "mixed" or sequence of str
        Euler order of every joint (e.g. ``"ZYX"``), a different order per joint cycling
        through all six (``"mixed"``), or one order per joint.
    up : {"y", "z"}
        Up axis of the file (Z-up: the whole walk turned by +90 degrees about X).
    scale : float
        Unit scale of offsets and positions (1: centimetres; 0.01: metres).
    names : {"human", "numbered", "mixamo"}
        Joint names: ``pelvis, thigh_l, ...`` (``Hips, LeftUpLeg, ...`` for ``cmu``),
        ``j00, j01, ...``, or the human names prefixed with ``mixamorig:``.
    speed, cadence : float
        Walking speed (cm/s) and gait cycles per second.
    skeleton : {"simple", "cmu", "fingers"}
        The joint layout (see the module docstring); the same walk on each.
    frames : int, optional
        Number of frames (overrides ``seconds``; 1 gives a single-frame clip).
    lift : float
        Height (cm) added to the root over the whole clip: the feet never reach the
        file's zero level.
    tpose_first : bool
        Frame 0 is the rest pose (every rotation the identity), as many exports start.
    root_only : bool
        Every joint keeps the rest pose; only the root translates (a sliding statue).
    planted : bool
        The root's path from :func:`planted_root`: the feet do not slide (``speed`` is then
        not used); ``False``: the root travels at ``speed`` with a sway and a bob, and the
        planted feet slide.

    Returns
    -------
    Motion
    """
    from shellspline.animation import euler_angles
    from shellspline.io.bvh import Motion

    if channels not in (3, 6):
        raise ValueError(f"channels must be 3 or 6, got {channels!r}")
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    if names not in ("human", "numbered", "mixamo"):
        raise ValueError(f"names must be human, numbered or mixamo, got {names!r}")
    ents, end_sites = _skeleton(skeleton)
    J = len(ents)
    if isinstance(order, str):
        orders = [ORDERS[j % 6] for j in range(J)] if order == "mixed" else [order.upper()] * J
    else:
        orders = [o.upper() for o in order]
    if len(orders) != J or any(sorted(o) != ["X", "Y", "Z"] for o in orders):
        raise ValueError(f"order: need one permutation of XYZ per joint ({J}), got {order!r}")
    T = max(int(round(seconds * fps)) + 1, 2) if frames is None else int(frames)
    if T < 1:
        raise ValueError(f"frames must be >= 1, got {frames!r}")
    t = np.arange(T) / fps
    R0, root = walk_rotations(t, speed, cadence)
    if planted and not root_only:
        # integrated on a fixed 2,400 Hz grid from t = 0 and sampled at the frames: the
        # same walk at every frame rate (120, 60, 30, 24 Hz frames lie on the grid)
        fine = np.arange(int(np.ceil(t[-1] * _FINE_RATE - 1e-6)) + 2) / _FINE_RATE
        w = 2 * np.pi * cadence * fine
        path = planted_root(walk_rotations(fine, speed, cadence)[0],
                            np.stack([np.cos(w) <= 0, np.cos(w + np.pi) <= 0], axis=1))
        root = np.stack([np.interp(t, fine, path[:, i]) for i in range(3)], axis=1)
    R = np.broadcast_to(np.eye(3), (T, J, 3, 3)).copy()
    for j, (_, _, _, role) in enumerate(ents):
        if role is not None and not root_only:
            R[:, j] = R0[:, role]
    if root_only:
        root[:, :2] = [0.0, PELVIS_HEIGHT]
    if tpose_first:
        R[0] = np.eye(3)
    root[:, 1] += lift
    offsets = np.array([o for _, _, o, _ in ents])
    ends = [(p, np.array(o)) for p, o in end_sites]
    Q = _rot(0, np.pi / 2) if up == "z" else np.eye(3)
    R = Q @ R @ Q.T
    offsets = offsets @ Q.T * scale
    root = root @ Q.T * scale
    ends = [(p, Q @ o * scale) for p, o in ends]
    cols, chans = [], []
    for j in range(J):
        ang = euler_angles(R[:, j], orders[j])
        rot_names = tuple(f"{a}rotation" for a in orders[j])
        if j == 0:
            chans.append(("Xposition", "Yposition", "Zposition") + rot_names)
            cols += [root, ang]
        elif channels == 6:
            chans.append(("Xposition", "Yposition", "Zposition") + rot_names)
            cols += [np.broadcast_to(offsets[j], (T, 3)), ang]
        else:
            chans.append(rot_names)
            cols.append(ang)
    labels = [f"j{j:02d}" if names == "numbered" else
              ("mixamorig:" if names == "mixamo" else "") + n for j, (n, _, _, _) in
              enumerate(ents)]
    return Motion(tuple(labels), np.array([p for _, p, _, _ in ents]), offsets,
                  tuple(chans), 1.0 / fps, np.concatenate(cols, axis=1), tuple(ends))


def main(argv=None) -> int:
    """``python -m data_synth motion OUT.bvh [options]``: write a synthetic walk."""
    from shellspline.io.bvh import write_bvh

    ap = argparse.ArgumentParser(prog="python -m data_synth motion",
                                 description="Write a synthetic biped walk as a BVH file in a "
                                             "chosen channel layout.")
    ap.add_argument("out", help="output .bvh file")
    ap.add_argument("--fps", type=float, default=120.0)
    ap.add_argument("--seconds", type=float, default=2.0)
    ap.add_argument("--channels", type=int, choices=(3, 6), default=3,
                    help="channels per non-root joint (the root has 6)")
    ap.add_argument("--order", default="ZYX", help="Euler order of every joint, or 'mixed'")
    ap.add_argument("--up", choices=("y", "z"), default="y")
    ap.add_argument("--scale", type=float, default=1.0, help="unit scale (0.01: metres)")
    ap.add_argument("--names", choices=("human", "numbered", "mixamo"), default="human")
    ap.add_argument("--skeleton", choices=("simple", "cmu", "fingers"), default="simple")
    ap.add_argument("--frames", type=int, default=None, help="frame count (overrides "
                                                             "--seconds; 1: a single frame)")
    ap.add_argument("--lift", type=float, default=0.0, help="root height added (cm)")
    ap.add_argument("--tpose-first", action="store_true", help="frame 0 is the rest pose")
    ap.add_argument("--root-only", action="store_true", help="only the root moves")
    args = ap.parse_args(argv)
    try:
        m = motion(fps=args.fps, seconds=args.seconds, channels=args.channels,
                   order=args.order, up=args.up, scale=args.scale, names=args.names,
                   skeleton=args.skeleton, frames=args.frames, lift=args.lift,
                   tpose_first=args.tpose_first, root_only=args.root_only)
    except ValueError as exc:
        ap.error(str(exc))
    write_bvh(m, args.out)
    print(f"motion: wrote {m.n_frames} frames at {args.fps:g} fps, {m.n_joints} joints "
          f"({args.channels}-channel, order {args.order}, {args.up}-up) to {args.out}")
    return 0
