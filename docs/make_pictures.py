"""Make the README's pictures of rigid motions (issue 16).

::

    python3 docs/make_pictures.py                 # both pictures, into docs/
    python3 docs/make_pictures.py camera_path     # one of them

* ``docs/camera_path.png``: the TUM RGB-D camera ground truth
  (``../shared/data/camera/freiburg1_xyz-groundtruth.txt``), every 25th pose kept as a
  keyframe, the C² spline on SO(3) x R^3 through them (``shellspline.cli.path.build_curve``, as
  ``shellspline path --keep-every 25`` builds it), camera frames drawn at the keyframes.
* ``docs/rigid_track.png``: a deforming body (the ``data_synth`` cactus, laid down, bent
  sideways, straight, bent down) whose keyframes turn by 90° and travel a quarter circle each
  (their rigid poses, Kabsch against the first keyframe, lie exactly on the circle); the
  centroid of every frame of ``interpolate --rigid-track linear|fit|spline`` seen from above,
  and its distance from the circle's centre per frame.

Needs matplotlib (``pip install "shellspline[viz]"``); the camera picture needs the shared data.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
CAMERA = REPO.parent / "shared" / "data" / "camera" / "freiburg1_xyz-groundtruth.txt"
COLORS = {"linear": "#4e79a7", "fit": "#59a14f", "spline": "#f28e2b"}


def _figure(figsize):
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=100)


def _save(fig, path):
    fig.savefig(path, dpi=100)
    print(f"wrote {path} ({path.stat().st_size // 1024} kB)")


def camera_path(out=HERE / "camera_path.png", every=25):
    """3-D camera path: ground truth, keyframes, the C² spline, camera frames at keyframes;
    positions and errors over 4 s against the piecewise geodesic (linear + Slerp)."""
    from shellspline.cli.path import build_curve, keyframe_indices
    from shellspline.curves import geodesic_interpolant
    from shellspline.io.posefiles import read_poses

    track = read_poses(CAMERA)
    keys = keyframe_indices(track.t.size, every)
    curve = build_curve(track.t[keys], track.T[keys], "interp", "so3xr3", "natural")
    p = curve(track.t)[:, :3, 3]
    q = geodesic_interpolant("so3xr3", track.t[keys], track.T[keys])(track.t)[:, :3, 3]
    pk, truth = track.T[keys, :3, 3], track.T[:, :3, 3]
    err, err_lin = (np.linalg.norm(x - truth, axis=1) for x in (p, q))
    rest = np.setdiff1d(np.arange(track.t.size), keys)
    rms, rms_lin = (1e3 * np.sqrt(np.mean(e[rest] ** 2)) for e in (err, err_lin))

    fig = _figure((8.0, 4.6))
    ax = fig.add_subplot(1, 2, 1, projection="3d")
    ax.plot(*truth.T, color="#bbbbbb", lw=2.4, label="ground truth (3,000 poses, 30 s)")
    ax.plot(*p.T, color=COLORS["spline"], lw=0.8, label="C² spline on SO(3) x R³")
    ax.scatter(*pk.T, color="black", s=4, depthshade=False,
               label=f"{keys.size} keyframes (every {every}th pose)")
    L = 0.05
    for j in keys[::3]:
        R, o = track.T[j, :3, :3], track.T[j, :3, 3]
        for axis, c in zip(range(3), ("#d62728", "#2ca02c", "#1f77b4")):
            ax.plot(*np.c_[o, o + L * R[:, axis]], color=c, lw=0.8)
    ax.set_xlabel("x (m)", labelpad=-4, fontsize=8)
    ax.set_ylabel("y (m)", labelpad=-4, fontsize=8)
    ax.set_zlabel("z (m)", labelpad=-6, fontsize=8)
    ax.tick_params(labelsize=6, pad=-2)
    ax.view_init(elev=24, azim=-62)
    ax.legend(loc="upper center", fontsize=7, frameon=False, bbox_to_anchor=(0.5, 1.12))
    fig.text(0.25, 0.02, "camera frames at every 3rd keyframe: x red, y green, viewing "
             "direction z blue", ha="center", fontsize=7)

    t = track.t - track.t[0]
    lo, hi = np.searchsorted(t, [10.0, 14.0])
    kin = keys[(keys >= lo) & (keys < hi)]
    bx = fig.add_subplot(2, 2, 2)
    for i, c in enumerate(("#d62728", "#2ca02c", "#1f77b4")):
        bx.plot(t[lo:hi], truth[lo:hi, i], color="#bbbbbb", lw=2.4)
        bx.plot(t[lo:hi], p[lo:hi, i], color=c, lw=0.9, label="xyz"[i])
        bx.plot(t[kin], truth[kin, i], "k.", ms=3.5)
    bx.set_ylabel("position (m)", fontsize=8)
    bx.set_title("10-14 s: the spline (colour) through the keyframes (dots)", fontsize=8.5)
    bx.legend(fontsize=7, ncol=3, frameon=False, loc="center right")
    bx.tick_params(labelsize=7)
    cx = fig.add_subplot(2, 2, 4, sharex=bx)
    cx.semilogy(t[lo:hi], 1e3 * err_lin[lo:hi], color=COLORS["linear"], lw=0.9,
                label=f"linear + Slerp (rms {rms_lin:.2f} mm over 30 s)")
    cx.semilogy(t[lo:hi], 1e3 * err[lo:hi], color=COLORS["spline"], lw=0.9,
                label=f"C² spline (rms {rms:.2f} mm)")
    cx.set_ylim(1e-2, 1e2)
    cx.set_xlabel("time (s)", fontsize=8)
    cx.set_ylabel("position error (mm)", fontsize=8)
    cx.set_title("error at the dropped poses (0 at keyframes)", fontsize=8.5)
    cx.legend(fontsize=7, frameon=False, loc="upper left", ncol=1)
    cx.tick_params(labelsize=7)
    fig.subplots_adjust(left=0.0, right=0.98, top=0.93, bottom=0.1, wspace=0.15, hspace=0.4)
    _save(fig, out)


def _body_keyframes(tmp, n_keys=5, radius=1.5):
    """The data_synth cactus laid along +y, bent sideways, turned by 90° and moved a quarter
    circle per keyframe: keyframe j sits at angle 90° j, its axis along the circle."""
    import shellspline as ss

    subprocess.run([sys.executable, "-m", "data_synth", "cactus", str(tmp), "--vertices", "800"],
                   check=True, cwd=REPO, capture_output=True)
    poses = [ss.read_mesh(tmp / f"pose_{i:02d}.obj") for i in range(3)]
    F = poses[0][1]
    lay = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])      # (x, y, z) -> (x, z, -y)
    shapes = [V @ lay.T - (V @ lay.T).mean(axis=0) for V, _ in poses]
    # each bent shape turned so that its best rigid fit (Kabsch) to the first is the identity:
    # the keyframes' rigid poses then lie exactly on the circle, 90° apart
    for i in (1, 2):
        U, _, Wt = np.linalg.svd(shapes[i].T @ shapes[0])
        shapes[i] = shapes[i] @ (U @ np.diag([1, 1, np.linalg.det(U @ Wt)]) @ Wt)
    order = [0, 1, 2, 1, 0][:n_keys]
    keys = []
    for j, s in enumerate(order):
        a = np.radians(90.0 * j)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        keys.append(shapes[s] @ R.T + radius * np.array([np.cos(a), np.sin(a), 0.0]))
    return np.stack(keys), F


def rigid_track(out=HERE / "rigid_track.png", step=8, radius=1.5):
    """Centroid paths of ``interpolate --rigid-track linear|fit|spline`` for a body that turns
    and travels on a circle."""
    import shellspline as ss

    with tempfile.TemporaryDirectory() as tmp:
        keys, F = _body_keyframes(Path(tmp), radius=radius)
    frames = step * np.arange(len(keys))
    runs = {kind: ss.interpolate((keys, F), frames=frames, rigid_track=kind).V
            for kind in ("linear", "fit", "spline")}

    fig = _figure((8.0, 3.9))
    ax = fig.add_subplot(1, 2, 1)
    s = np.linspace(0, 2 * np.pi, 200)
    ax.plot(radius * np.cos(s), radius * np.sin(s), color="#999999", lw=0.8, ls=":")
    V = runs["spline"]
    for k in range(0, frames[-1] + 1, 2):
        key = k in frames
        ax.scatter(V[k, :, 0], V[k, :, 1], s=0.3, lw=0,
                   color="#777777" if key else "#f6c89f", zorder=1 if not key else 2)
    for kind, Vk in runs.items():
        c = Vk.mean(axis=1)
        ax.plot(c[:, 0], c[:, 1], color=COLORS[kind], lw=1.4, label=f"--rigid-track {kind}",
                zorder=3)
    ck = keys.mean(axis=1)
    ax.plot(ck[:, 0], ck[:, 1], "k.", ms=7, zorder=4, label="keyframe centroids")
    ax.set_aspect("equal")
    ax.set_title("centroid of every frame, seen from above\n(spline's frames: gray keyframes, "
                 "orange every 2nd in-between)", fontsize=8.5)
    ax.legend(fontsize=7, loc="center", frameon=False)
    ax.tick_params(labelsize=7)

    bx = fig.add_subplot(1, 2, 2)
    k = np.arange(frames[-1] + 1)
    for kind, Vk in runs.items():
        r = np.linalg.norm(Vk.mean(axis=1)[:, :2], axis=1)
        bx.plot(k, r, color=COLORS[kind], lw=1.4, label=kind)
    for f in frames:
        bx.axvline(f, color="#cccccc", lw=0.8, zorder=0)
    bx.axhline(radius, color="#999999", lw=0.8, ls=":")
    bx.set_xlabel("frame (keyframes every 8: gray lines)", fontsize=8)
    bx.set_ylabel("centroid distance from the circle's centre", fontsize=8)
    bx.set_title("only the SE(3) spline keeps the circle;\nlinear and per-vertex cubic "
                 "cut the corners", fontsize=8.5)
    bx.legend(fontsize=7, frameon=False)
    bx.tick_params(labelsize=7)
    fig.subplots_adjust(left=0.06, right=0.98, top=0.86, bottom=0.12, wspace=0.28)
    _save(fig, out)


PICTURES = {"camera_path": camera_path, "rigid_track": rigid_track}

if __name__ == "__main__":
    sys.path.insert(0, str(REPO))
    for name in sys.argv[1:] or list(PICTURES):
        PICTURES[name]()
