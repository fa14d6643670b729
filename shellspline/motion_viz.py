"""Pictures of skeletal motions: stick-figure strips and GIFs, foot, warp and seam-gap plots.

matplotlib only (the ``viz`` extra), imported inside the functions, no pyplot (no global
state, no display); GIF frames are assembled with Pillow (a matplotlib dependency). Every
picture is written atomically (a temporary sibling renamed into place).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .animation import (FootContacts, body_height, body_joints, foot_contacts,
                        stage_kinematics)
from .errors import ShellsplineError
from .io.bvh import Motion

__all__ = ["render_strip", "render_gif", "plot_motion"]

_EXTRA = 'pip install "shellspline[viz]"'
BONE_COLORS = ("#1f4e79", "#9c2f2f")  # the first and the second motion of a comparison
CONTACT_COLOR = "#e07b00"


def _figure_class(what: str):
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ShellsplineError(f"{what} needs the viz extra: {_EXTRA}") from None
    return Figure


def _atomic(path, write) -> Path:
    path = Path(path)
    if not path.parent.is_dir():
        raise ShellsplineError(f"{path}: the folder {path.parent} does not exist")
    tmp = path.with_name(f".{path.stem}.{os.getpid()}.tmp{path.suffix}")
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if tmp.exists():
            tmp.unlink()
        raise
    return path


def _centre(motion: Motion, S: np.ndarray) -> np.ndarray:
    """Along-travel coordinate ``(T,)`` of the body's centroid in side-view coordinates."""
    return S[:, body_joints(motion), 0].mean(axis=1)


def _view(motion: Motion, P: np.ndarray, ax_up: int, sign: float):
    """Side-view coordinates ``(T,J,2)``: along the travel direction (of the body's
    centroid, whichever joint's channels carry it) and up."""
    hor = [a for a in range(3) if a != ax_up]
    H = P[:, :, hor]
    C = H[:, body_joints(motion)].mean(axis=1)
    travel = C - C[0]
    if np.abs(travel).max() > 1e-9:
        _, _, vt = np.linalg.svd(travel - travel.mean(axis=0), full_matrices=False)
        d = vt[0] if vt[0] @ (travel[-1] - travel[0]) >= 0 else -vt[0]
    else:
        flat = H.reshape(-1, 2)
        _, _, vt = np.linalg.svd(flat - flat.mean(axis=0), full_matrices=False)
        d = vt[0]
    x = H @ d
    y = sign * P[..., ax_up]
    return np.stack([x, y], axis=-1)


def _prepare(motions, contacts, up):
    if isinstance(motions, Motion):
        motions = [motions]
    out = []
    for i, m in enumerate(motions):
        c = contacts[i] if isinstance(contacts, (list, tuple)) else contacts
        if c is None:
            c = foot_contacts(m, up=up)
        P = stage_kinematics(m)[0]  # the frame the contacts' up axis is given in
        S = _view(m, P, c.up[0], c.up[1])
        ground = float(np.min(S[..., 1]))
        out.append((m, c, S, ground))
    return out


def _bones(m: Motion) -> list[tuple[int, int]]:
    """``(joint, parent)`` pairs drawn as bones: a joint whose translation in its parent's
    frame changes over the clip is carried by a travel channel (a ground marker above the
    hips, say), not by a bone."""
    _, t = m.local_transforms()
    length = np.linalg.norm(t, axis=2)
    scale = max(float(length.max()), 1e-300)
    rigid = np.ptp(length, axis=0) <= 1e-6 * scale
    return [(j, int(p)) for j, p in enumerate(m.parents) if p >= 0 and rigid[j]]


def _draw(ax, m: Motion, S, f: int, c: FootContacts, dx: float, color: str, ground: float,
          bones):
    for j, p in bones:
        ax.plot([S[f, p, 0] + dx, S[f, j, 0] + dx], [S[f, p, 1] - ground, S[f, j, 1] - ground],
                color=color, lw=1.6, solid_capstyle="round")
    if f < c.joint_contact.shape[0]:
        idx = np.array(c.joints).reshape(-1)
        on = c.joint_contact[f].reshape(-1)
        if on.any():
            ax.plot(S[f, idx[on], 0] + dx, S[f, idx[on], 1] - ground, "o", ms=4,
                    color=CONTACT_COLOR, zorder=5)


def render_strip(motions, path, *, frames: int = 8, contacts=None, up=None,
                 title: str | None = None, dpi: int = 100) -> Path:
    """A film strip of stick figures (side view), feet planted marked, ground line.

    Parameters
    ----------
    motions : Motion or sequence of Motion
        One clip, or several of one duration drawn over each other (e.g. source and result).
    path : str or path-like
        ``.png``, ``.svg`` or ``.pdf``.
    frames : int
        Number of evenly spaced frames shown.
    contacts : FootContacts or list, optional
        Contacts to mark (detected otherwise).
    up : str, optional
        Up axis override.

    Returns
    -------
    Path
    """
    Figure = _figure_class("render_strip")
    items = _prepare(motions, contacts, up)
    bones = [_bones(it[0]) for it in items]
    H = body_height(items[0][0])
    n = max(int(frames), 1)
    fig = Figure(figsize=(1.2 * n + 0.6, 2.6))
    ax = fig.add_subplot(111)
    for k, (m, c, S, ground) in enumerate(items):
        sel = np.linspace(0, m.n_frames - 1, n).round().astype(int)
        for i, f in enumerate(sel):
            dx = i * 0.75 * H - _centre(m, S)[f]
            _draw(ax, m, S, f, c, dx, BONE_COLORS[k % 2], ground, bones[k])
    ax.axhline(0.0, color="0.5", lw=1.0, zorder=0)
    ax.set_aspect("equal")
    ax.axis("off")
    if title:
        ax.set_title(title, fontsize=9)
    fig.tight_layout()
    return _atomic(path, lambda tmp: fig.savefig(tmp, dpi=dpi))


def render_gif(motions, path, *, fps: float | None = None, step: int | None = None,
               contacts=None, up=None, size: float = 3.0, dpi: int = 60) -> Path:
    """An animated GIF of stick figures, the camera following the root (side view), with
    ground marks so that sliding feet show.

    Parameters
    ----------
    motions : Motion or sequence of Motion
        Clips drawn together (same frame count after ``step``).
    path : str or path-like
        ``.gif``.
    fps : float, optional
        GIF frame rate (default: the clip's, at most 30).
    step : int, optional
        Draw every ``step``-th frame (default: to reach ``fps``).
    """
    Figure = _figure_class("render_gif")
    try:
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from PIL import Image
    except ImportError:
        raise ShellsplineError(f"render_gif needs the viz extra: {_EXTRA}") from None
    items = _prepare(motions, contacts, up)
    bones = [_bones(it[0]) for it in items]
    m0 = items[0][0]
    H = body_height(m0)
    if step is None:
        step = max(1, int(round(m0.fps / (fps or min(m0.fps, 30.0)))))
    fps = fps or m0.fps / step
    images = []
    centre = _centre(m0, items[0][2])
    for f in range(0, m0.n_frames, step):
        fig = Figure(figsize=(size, size))
        ax = fig.add_subplot(111)
        cx = centre[f]
        for k, (m, c, S, ground) in enumerate(items):
            if f < m.n_frames:
                _draw(ax, m, S, f, c, 0.0, BONE_COLORS[k % 2], ground, bones[k])
        marks = np.arange(np.floor((cx - H) / (0.25 * H)), np.ceil((cx + H) / (0.25 * H)) + 1)
        ax.plot(marks * 0.25 * H, np.zeros_like(marks), "|", color="0.4", ms=6)
        ax.axhline(0.0, color="0.5", lw=1.0, zorder=0)
        ax.set_xlim(cx - 0.7 * H, cx + 0.7 * H)
        ax.set_ylim(-0.1 * H, 1.3 * H)
        ax.set_aspect("equal")
        ax.axis("off")
        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        buf = np.asarray(canvas.buffer_rgba())
        images.append(Image.fromarray(buf[..., :3].copy()).convert("P", palette=Image.ADAPTIVE))
    duration = int(round(1000.0 / fps))
    return _atomic(path, lambda tmp: images[0].save(tmp, format="GIF", save_all=True,
                                                    append_images=images[1:], loop=0,
                                                    duration=duration))


def plot_motion(path, *, motions=(), contacts=None, labels=None, warp=None,
                seam_history=None, up=None, dpi: int = 100) -> Path:
    """Plots like the seeds' figures: foot heights over time (contacts shaded), the warp
    φ(t), the seam gap per closing iteration; the panels that have data.

    Parameters
    ----------
    path : str or path-like
        ``.png``, ``.svg`` or ``.pdf``.
    motions : sequence of Motion
        Clips whose feet are plotted.
    contacts : list of FootContacts, optional
    labels : list of str, optional
    warp : (N,) array_like or (t (N,), phi (N,)), optional
        A time warp on ``[0, 1]``.
    seam_history : (k,) array_like, optional
        Seam gap per closing iteration (log scale).
    """
    Figure = _figure_class("plot_motion")
    if isinstance(motions, Motion):
        motions = [motions]
    panels = (["feet"] if len(motions) else []) + (["warp"] if warp is not None else []) + \
        (["seam"] if seam_history is not None else [])
    if not panels:
        raise ShellsplineError("plot_motion: nothing to plot (no motion, warp or seam history)")
    fig = Figure(figsize=(4.2 * len(panels), 3.2))
    axes = [fig.add_subplot(1, len(panels), i + 1) for i in range(len(panels))]
    for ax, what in zip(axes, panels):
        if what == "feet":
            for k, m in enumerate(motions):
                c = contacts[k] if contacts is not None else foot_contacts(m, up=up)
                t = np.arange(m.n_frames) * m.frame_time
                lab = labels[k] if labels else f"clip {k}"
                for i, foot in enumerate(c.feet):
                    h = c.heights[:, i].min(axis=1)
                    ax.plot(t, h, color=BONE_COLORS[k % 2], lw=1.2,
                            ls="-" if i == 0 else "--", label=f"{lab}: {m.names[foot]}")
                    on = c.contact[:, i]
                    ax.plot(t[on], h[on], ".", color=CONTACT_COLOR, ms=3)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("foot height above its lowest (file units)")
            ax.set_title("feet (dots: planted)", fontsize=9)
            ax.legend(fontsize=7)
        elif what == "warp":
            w = warp
            if isinstance(w, tuple):
                t, phi = np.asarray(w[0]), np.asarray(w[1])
            else:
                phi = np.asarray(w)
                t = np.linspace(0.0, 1.0, phi.size)
            ax.plot(t, t, color="0.6", lw=1.0, ls=":")
            ax.plot(t, phi, color=BONE_COLORS[0], lw=1.5)
            ax.set_xlabel("t")
            ax.set_ylabel("φ(t)")
            ax.set_title("time warp", fontsize=9)
            ax.set_aspect("equal")
        else:
            g = np.asarray(seam_history, dtype=np.float64)
            ax.semilogy(np.arange(g.size), np.maximum(g, 1e-300), "o-", color=BONE_COLORS[0])
            ax.set_xlabel("iteration")
            ax.set_ylabel("seam gap")
            ax.set_title("closing", fontsize=9)
    fig.tight_layout()
    return _atomic(path, lambda tmp: fig.savefig(tmp, dpi=dpi))
