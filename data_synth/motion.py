"""Synthetic skeletal motions (BVH) with the layouts real files come in.

A procedural biped walk (hip, knee, ankle swing; arm swing; torso sway; root travel and
bob) written with any frame rate, 3 or 6 channels per joint, any Euler order (one for all
joints or a different order per joint), Y-up or Z-up, any unit scale and plain numbered or
human joint names. The motion is defined by rotation matrices and then encoded in the
requested channels, so the same walk in two layouts is the same motion.

``python -m data_synth motion OUT.bvh [--fps 120] [--channels 3] [--order ZYX|mixed]
[--up y|z] [--seconds 2] [--scale 1] [--names human|numbered]``
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
        R[:, thigh] = _rot(0, -d(25) * np.sin(w + ph))
        R[:, thigh + 1] = _rot(0, d(30) * np.clip(np.sin(w + ph + 1.2), 0, None) + d(3))
        R[:, thigh + 2] = _rot(0, d(10) * np.sin(w + ph + 0.6))
        R[:, thigh + 3] = _rot(0, d(15) * np.clip(np.sin(w + ph - 1.0), 0, None))
    root = np.stack([1.5 * np.sin(w), PELVIS_HEIGHT + 2.0 * np.cos(2 * w), speed * t], axis=1)
    return R, root


def motion(*, fps: float = 120.0, seconds: float = 2.0, channels: int = 3, order="ZYX",
           up: str = "y", scale: float = 1.0, names: str = "human", speed: float = 120.0,
           cadence: float = 1.0):
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
    names : {"human", "numbered"}
        Joint names: ``pelvis, thigh_l, ...`` or ``j00, j01, ...``.
    speed, cadence : float
        Walking speed (cm/s) and gait cycles per second.

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
    J = len(_SKELETON)
    if isinstance(order, str):
        orders = [ORDERS[j % 6] for j in range(J)] if order == "mixed" else [order.upper()] * J
    else:
        orders = [o.upper() for o in order]
    if len(orders) != J or any(sorted(o) != ["X", "Y", "Z"] for o in orders):
        raise ValueError(f"order: need one permutation of XYZ per joint ({J}), got {order!r}")
    T = max(int(round(seconds * fps)) + 1, 2)
    t = np.arange(T) / fps
    R, root = walk_rotations(t, speed, cadence)
    offsets = np.array([o for _, _, o in _SKELETON])
    ends = [(p, np.array(o)) for p, o in _END_SITES]
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
    labels = ([n for n, _, _ in _SKELETON] if names == "human"
              else [f"j{j:02d}" for j in range(J)])
    return Motion(tuple(labels), np.array([p for _, p, _ in _SKELETON]), offsets,
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
    ap.add_argument("--names", choices=("human", "numbered"), default="human")
    args = ap.parse_args(argv)
    try:
        m = motion(fps=args.fps, seconds=args.seconds, channels=args.channels,
                   order=args.order, up=args.up, scale=args.scale, names=args.names)
    except ValueError as exc:
        ap.error(str(exc))
    write_bvh(m, args.out)
    print(f"motion: wrote {m.n_frames} frames at {args.fps:g} fps, {m.n_joints} joints "
          f"({args.channels}-channel, order {args.order}, {args.up}-up) to {args.out}")
    return 0
