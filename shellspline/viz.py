"""See and share results: preview windows, off-screen renders, plots.

The only module that uses pyvista, matplotlib and imageio; all three are imported inside the
functions that need them (``pip install "shellspline[viz]"``), so ``import shellspline``
stays light.

A *source* is anything that holds a sequence:

* an output directory written by ``interpolate`` (read with
  :func:`~shellspline.io.read_sequence`; keyframes from ``report.json``),
* an :class:`~shellspline.pipeline.interpolation.InterpolationResult` (``.V``, ``.F``, ``.frames``,
  ``.report``),
* a tuple ``(V, F)`` or ``(V, F, frames)`` with ``V (K+1,n,3)``, ``F (m,3)``.

Functions taking several sources accept a list of them.

Colours follow the paper's figures: keyframes gray, in-betweens coloured, one colour per
source (orange, green, blue, ...: e.g. spline orange and piecewise geodesic green).

Up axis: cameras are placed around the scene's up axis (``up="x"|"y"|"z"``), by default the
one the source's files imply (:func:`scene_up_axis`): OBJ and glTF are y-up (Blender's OBJ
export, the deformation-transfer animals; glTF by its specification), USD says so in its
metadata, PLY/OFF and in-memory arrays are taken as z-up.

Off-screen rendering needs no display: on Linux without ``DISPLAY``/``WAYLAND_DISPLAY`` VTK is
pointed at its EGL window (``VTK_DEFAULT_OPENGL_WINDOW=vtkEGLRenderWindow``, set before
pyvista is first imported), which renders through Mesa's software renderer.
"""
from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .errors import ShellsplineError
from .io.atomic import temporary_sibling, write_atomically
from .mesh.geometry import vertex_normals

__all__ = ["SequenceViewer", "load_source", "preview", "render_frames", "render_animation",
           "render_strip", "plot", "plot_figure", "plot_half_axes", "half_axes_figure",
           "default_strip_frames", "export_glb", "fitted_camera", "scene_up_axis", "UP_AXES",
           "CameraPath", "checked_camera_path", "CAMERA_CONVENTIONS", "CAMERA_TIMES",
           "KEYFRAME_COLOR", "PALETTE", "AUTO_MIDPOINT_WORK"]

AUTO_MIDPOINT_WORK = 60_000
"""``shell_energy="auto"`` takes the midpoint energy (one Newton solve per frame, ~0.5–1 s per
frame at 5k vertices on one core) up to this many vertices × inner frames, else ``"step"``."""
KEYFRAME_COLOR = "#a6a6a6"
"""Colour of keyframe poses (gray, as in the paper's figures)."""
PALETTE = ("#f28e2b", "#59a14f", "#4e79a7", "#e15759", "#b07aa1", "#76b7b2", "#edc948")
"""Colours of the in-between frames of the 1st, 2nd, ... source."""

_EXTRA = 'pip install "shellspline[viz]"'
_VIEWS = {
    "iso": ((1.0, -1.0, 0.8), (0.0, 0.0, 1.0)),
    "front": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),   # looking along +y, z up
    "side": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),     # looking along -x, z up
    "top": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),      # looking down -z, y up
    "xy": ((0.0, 0.0, 1.0), (0.0, 1.0, 0.0)),
    "xz": ((0.0, -1.0, 0.0), (0.0, 0.0, 1.0)),
    "yz": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
}
_PLANE_VIEWS = ("xy", "xz", "yz")  # named by the file's axes: not turned with the up axis
UP_AXES = ("x", "y", "z")
"""The scene up axes the cameras understand."""
#: Rotations taking the z-up frame in which :data:`_VIEWS` are written to a scene whose up
#: axis is x, y or z (proper rotations: y-up is Blender's OBJ export, (x, y, z) -> (x, z, -y)).
_UP_FRAMES = {"z": np.eye(3),
              "y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
              "x": np.array([[0.0, 0, 1], [1, 0, 0], [0, 1, 0]])}
_VIEW_ANGLE = 30.0  # VTK's default vertical view angle, degrees
_FRAME_FILE_NAMES = ("report.json", "animation.glb", "animation.mdd", "animation.pc2",
                     "animation.usdc", "mesh.obj")  # io.sequences.ANIMATION_NAMES, MESH_NAME
_ANIMATION_SUFFIXES = (".gif", ".mp4")


# ----------------------------------------------------------------------------------------
# Sources
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class _Sequence:
    """A loaded source: poses, faces, keyframe frames, report, label."""

    V: np.ndarray
    F: np.ndarray
    frames: np.ndarray
    report: dict
    label: str
    path: Path | None = None
    inputs: list = field(default_factory=list)

    @property
    def K(self) -> int:
        return int(self.V.shape[0] - 1)

    @property
    def parameters(self) -> dict:
        return dict(self.report.get("parameters") or {})


def load_source(source, label: str | None = None) -> _Sequence:
    """Load a source (see the module docstring) into arrays.

    Parameters
    ----------
    source : path, InterpolationResult, (V, F) or (V, F, frames)
    label : str, optional
        Name used in legends and titles; default the directory name, the method recorded in
        the report, or ``"sequence"``.

    Returns
    -------
    object with ``V (K+1,n,3) float64``, ``F (m,3) int64``, ``frames (J,) int64`` (keyframe
    frames; empty when unknown), ``report`` (dict), ``label``, ``K``.

    Raises
    ------
    ShellsplineError
        For an unreadable directory or arrays of the wrong shape (one line).
    """
    if isinstance(source, _Sequence):
        if label is not None:
            source = _Sequence(source.V, source.F, source.frames, source.report, label,
                               source.path, source.inputs)
        return source
    path, inputs = None, []
    if isinstance(source, (str, os.PathLike)):
        from .io.sequences import FRAME_RE, read_sequence

        path = Path(source)
        V, F, report = read_sequence(path)
        frames = _report_frames(report, path)
        inputs = [path] if path.is_file() else \
            [p for p in path.iterdir() if FRAME_RE.match(p.name) or p.name in _FRAME_FILE_NAMES]
        default_label = path.resolve().parent.name if path.name == "animation.glb" else \
            path.stem if path.is_file() else path.resolve().name
    elif hasattr(source, "V") and hasattr(source, "F"):
        V, F = source.V, source.F
        report = dict(getattr(source, "report", None) or {})
        frames = getattr(source, "frames", None)
        default_label = str((report.get("parameters") or {}).get("method", "sequence"))
    elif isinstance(source, tuple) and len(source) in (2, 3):
        V, F = source[0], source[1]
        frames = source[2] if len(source) == 3 else None
        report = {}
        default_label = "sequence"
    else:
        raise ShellsplineError(f"a source must be an output directory, an InterpolationResult, "
                               f"or a (V, F[, frames]) tuple; got {type(source).__name__}")
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0 or V.shape[1] == 0:
        raise ShellsplineError(f"V must be a (K+1,n,3) array of poses, got shape {V.shape}")
    if not np.isfinite(V).all():
        raise ShellsplineError(f"{path or 'V'}: the sequence has NaN/inf coordinates")
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or \
            not np.issubdtype(F.dtype, np.integer):
        raise ShellsplineError(f"F must be a non-empty (m,3) integer array, got shape {F.shape}")
    F = F.astype(np.int64)
    if F.min() < 0 or F.max() >= V.shape[1]:
        raise ShellsplineError(f"F indexes vertices outside [0, {V.shape[1]})")
    frames = np.zeros(0, dtype=np.int64) if frames is None else \
        np.asarray(frames, dtype=np.int64).ravel()
    frames = frames[(frames >= 0) & (frames <= V.shape[0] - 1)]
    return _Sequence(V, F, frames, report, label or default_label, path, inputs)


def _report_frames(report, path: Path):
    """``parameters.frames`` of an output's ``report.json`` (None when absent), checked."""
    where = (path.parent if path.is_file() else path) / "report.json"
    if not isinstance(report, dict):
        raise ShellsplineError(f"{where}: expected a JSON object, got {type(report).__name__}")
    for key in ("parameters", "mesh", "energies"):
        if report.get(key) is not None and not isinstance(report[key], dict):
            raise ShellsplineError(f"{where}: {key!r} must be a JSON object, got "
                                   f"{type(report[key]).__name__}")
    params = report.get("parameters")
    if params is None:
        return None
    frames = params.get("frames")
    if frames is None:
        return None
    if not isinstance(frames, list) or not all(
            isinstance(f, (int, float)) and not isinstance(f, bool) and np.isfinite(f)
            and f == int(f) for f in frames):
        raise ShellsplineError(f"{where}: 'parameters.frames' must be a list of integer frame "
                               f"indices, got {str(frames)[:60]!r}")
    return frames


def _load_all(sources, labels) -> list[_Sequence]:
    if isinstance(sources, list):
        sources = list(sources)
    else:
        sources = [sources]
    if not sources:
        raise ShellsplineError("no source given")
    labels = _labels(labels, len(sources))
    seqs = [load_source(s, lab) for s, lab in zip(sources, labels)]
    return seqs


def _labels(labels, count: int) -> list:
    if labels is None:
        return [None] * count
    if isinstance(labels, str):
        labels = [s.strip() for s in labels.split(",")]
    labels = [str(s) for s in labels]
    if len(labels) != count:
        raise ShellsplineError(f"labels: need one per source ({count}), got {len(labels)}: "
                               f"{labels}")
    return labels


def _int_list(value, what: str, example: str) -> np.ndarray:
    """``value`` (a comma/space separated string or an array-like) as a flat int64 array."""
    if isinstance(value, str):
        try:
            value = [int(t) for t in value.replace(",", " ").split()]
        except ValueError:
            raise ShellsplineError(f"{what}: expected integers such as '{example}', got "
                                   f"{value!r}") from None
    a = np.asarray(value).ravel()
    if a.size and not np.issubdtype(a.dtype, np.integer):
        raise ShellsplineError(f"{what} must be integers, got {a.tolist()}")
    return a.astype(np.int64)


def _track_indices(track, seqs) -> np.ndarray:
    if track is None:
        return np.zeros(0, dtype=np.int64)
    idx = _int_list(track, "track", "12,345")
    for s in seqs:
        n = s.V.shape[1]
        bad = (idx < 0) | (idx >= n)
        if bad.any():
            raise ShellsplineError(f"track: vertex {int(idx[bad][0])} is outside [0, {n}) of "
                                   f"'{s.label}'")
    return idx


def _is_keyframe(seq: _Sequence, k: int) -> bool:
    return bool(np.any(seq.frames == k))


# ----------------------------------------------------------------------------------------
# Output files: atomic, never over an input
# ----------------------------------------------------------------------------------------
def checked_output(path, suffixes, seqs=(), what: str = "output") -> Path:
    """The absolute target of an output file, checked before any work is done.

    Parameters
    ----------
    path : str or path-like
    suffixes : sequence of str
        Allowed suffixes (lower case, with the dot).
    seqs : sequence of _Sequence
        Sources whose input files may not be overwritten.
    what : str
        Names the output in messages (e.g. ``"--strip"`` or ``"filmstrip"``).

    Raises
    ------
    ShellsplineError
        Wrong suffix, a directory, an input file, or a directory that cannot be written.
    """
    out = Path(path)
    if out.suffix.lower() not in suffixes:
        allowed = " or ".join([", ".join(suffixes[:-1]), suffixes[-1]]) if len(suffixes) > 1 \
            else suffixes[0]
        raise ShellsplineError(f"{what} '{out}': expected a {allowed} file")
    target = out.resolve()
    if target.is_dir():
        raise ShellsplineError(f"{what} '{out}' is a directory; give a file name")
    for s in seqs:
        for p in s.inputs:
            if Path(p).resolve() == target:
                raise ShellsplineError(f"refusing to write '{out}': it is an input file of "
                                       f"'{s.label}'")
    probe = temporary_sibling(target)
    try:  # a file created and removed: os.access does not know read-only mounts or sysfs
        target.parent.mkdir(parents=True, exist_ok=True)
        probe.touch(exist_ok=False)
        probe.unlink()
    except OSError as exc:
        raise ShellsplineError(f"{what} '{out}': cannot write in '{target.parent}': "
                               f"{exc.strerror or exc}") from None
    return target


def _write_atomically(path, write, seqs=(), suffixes=None, what: str = "output") -> Path:
    """Call ``write(tmp)`` for a temporary sibling of ``path`` and rename it into place."""
    target = checked_output(path, suffixes or (Path(path).suffix.lower(),), seqs, what)
    return write_atomically(target, write, shown=path)


# ----------------------------------------------------------------------------------------
# pyvista helpers
# ----------------------------------------------------------------------------------------
def _headless() -> bool:
    return sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                     or os.environ.get("WAYLAND_DISPLAY"))


def _pyvista(what: str, off_screen: bool):
    if off_screen and _headless():
        # must be set before VTK creates its first render window
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        import pyvista as pv
    except ImportError:
        raise ShellsplineError(f"{what} needs the viz extra: {_EXTRA}") from None
    return pv


def _polydata(pv, V: np.ndarray, F: np.ndarray):
    faces = np.hstack([np.full((F.shape[0], 1), 3, dtype=np.int64), F]).ravel()
    mesh = pv.PolyData(np.array(V, dtype=np.float64), faces)
    mesh.point_data["Normals"] = vertex_normals(V, F)
    mesh.point_data.active_normals_name = "Normals"
    return mesh


def checked_up(up) -> str:
    """``up`` as ``"x"``, ``"y"`` or ``"z"`` (case and a leading ``+`` ignored)."""
    key = str(up).strip().lower().lstrip("+")
    if key not in UP_AXES:
        raise ShellsplineError(f"up must be x, y or z, got {up!r}")
    return key


def view_vectors(view, up="z"):
    """Unit direction towards the camera ``d (3,)`` and view-up vector ``u (3,)`` (``u ⊥ d``).

    Named views (``iso``, ``front``, ``side``, ``top``) are turned with the scene's up axis
    (``front`` of a y-up scene looks along −z with y up, as Blender's front view of the
    exported file); plane views (``xy``, ``xz``, ``yz``) and directions are the file's axes,
    with the up axis on screen up where it is not the viewing direction.
    """
    R = _UP_FRAMES[checked_up(up)]
    if isinstance(view, str):
        key = view.strip().lower()
        if key not in _VIEWS:
            raise ShellsplineError(f"view must be one of {', '.join(_VIEWS)} or a direction "
                                   f"(x, y, z), got {view!r}")
        d, u = _VIEWS[key]
        if key in _PLANE_VIEWS:
            u = R[:, 2]
        else:
            d, u = R @ d, R @ u
    else:
        d = tuple(float(x) for x in view)
        if len(d) != 3 or not np.isfinite(d).all() or not any(d):
            raise ShellsplineError(f"view direction must be three finite numbers, got {view!r}")
        u = R[:, 2]
    d = np.asarray(d, dtype=np.float64)
    d /= np.linalg.norm(d)
    u = np.asarray(u, dtype=np.float64)
    u = u - (u @ d) * d
    if np.linalg.norm(u) < 1e-8:  # looking along the up axis: the scene's "forward" is up
        u = R[:, 1] - (R[:, 1] @ d) * d
    return d, u / np.linalg.norm(u)


def scene_up_axis(source) -> str:
    """The up axis a source's files imply: ``"x"``, ``"y"`` or ``"z"``.

    The heuristic, first match wins:

    1. the keyframe files named in ``report.json`` (``mesh.names``, as ``interpolate``
       records them), by :func:`shellspline.io.usd.conventional_up_axis`: ``.obj`` y-up
       (Blender's OBJ export by default, Maya, the deformation-transfer animals), ``.glb``
       the axis its node's rotation says (:func:`shellspline.io.gltf.glb_up_axis`; y-up, the
       glTF specification's, without one), ``.gltf`` y-up, ``.usd*`` the stage's ``upAxis``, ``.ply`` /
       ``.off`` z-up (scanners and CAD write them);
    2. the output's own files: ``animation.usdc`` (its metadata), ``animation.glb`` or a
       ``.glb`` file (y), the frame files or ``mesh.obj`` (by extension);
    3. otherwise (arrays in memory) z-up.

    Parameters
    ----------
    source : a source (see the module docstring)

    Returns
    -------
    str
    """
    from .io.usd import UP_AXIS_CONVENTIONS, USD_EXTENSIONS, conventional_up_axis

    seq = load_source(source)
    known = set(UP_AXIS_CONVENTIONS) | set(USD_EXTENSIONS)
    for name in (seq.report.get("mesh") or {}).get("names") or []:
        if Path(str(name)).suffix.lower() in known:
            return conventional_up_axis(name)
    files = sorted(seq.inputs)
    if seq.path is not None and seq.path.is_file():
        files = [seq.path]
    for f in files:
        if f.suffix.lower() in known:
            return conventional_up_axis(f)
    return "z"


def fitted_camera(points, aspect: float, view="iso", margin: float = 1.06, up="z"):
    """A camera that shows all ``points`` from direction ``view`` in a window of ``aspect``.

    Parameters
    ----------
    points : (p, 3) array
        Every position the camera must show (e.g. all vertices of all frames).
    aspect : float
        Window width / height.
    view : str or (3,) array
        ``"iso"`` (default), ``"front"``/``"xz"``, ``"side"``/``"yz"``, ``"top"``/``"xy"``, or
        a direction from the focal point towards the camera.
    margin : float
        Extra distance factor (1 = points touch the border).
    up : {"x", "y", "z"}
        The scene's up axis (see :func:`view_vectors`).

    Returns
    -------
    [position, focal_point, view_up] : list of three 3-tuples
        For ``plotter.camera_position``; perspective with a 30° vertical view angle.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    d, up = view_vectors(view, up)
    right = np.cross(d, up)
    c = 0.5 * (P.min(axis=0) + P.max(axis=0))
    R = P - c
    x, y, z = np.abs(R @ right), np.abs(R @ up), R @ d
    tv = np.tan(np.radians(_VIEW_ANGLE) / 2)
    th = tv * float(aspect)
    dist = float(np.max(np.maximum(z + x / th, z + y / tv)))
    scale = float(np.abs(R).max()) or 1.0
    dist = max(dist, 1e-3 * scale) * margin
    pos = c + d * dist
    return [tuple(pos), tuple(c), tuple(up)]


# ----------------------------------------------------------------------------------------
# The viewer (preview window; also drives the off-screen renders)
# ----------------------------------------------------------------------------------------
class SequenceViewer:
    """Shows one or several sequences side by side, one frame at a time.

    Holds a pyvista plotter with one subplot per source (cameras linked), and the frame logic
    that the preview window's slider, play/pause button, timer and keys call. Everything works
    off-screen, so tests (and :func:`render_animation`) drive it without a display.

    Parameters
    ----------
    sources : source or list of sources
        See the module docstring. Sources of different lengths are clamped at their last frame.
    track : sequence of int or str, optional
        Vertex indices whose trajectories (polylines over all frames) are drawn, with a marker
        at the current frame.
    fps : float
        Playback speed (frames per second) of :meth:`play` in a window.
    loop : bool
        Restart at frame 0 after the last frame (else stop).
    labels : list of str or comma-separated str, optional
        One title per source.
    off_screen : bool
        Render into an off-screen buffer (no window).
    window_size : (int, int), optional
        Pixels; default 600×600 per source plus a control strip.
    view : str or (3,) array
        Camera direction, see :func:`fitted_camera`.
    up : {"x", "y", "z"}, optional
        The scene's up axis; default that of the first source (:func:`scene_up_axis`).
    widgets : bool
        Add the frame slider, play/pause checkbox and key bindings (needs an interactor;
        off by default off-screen).
    annotate : bool
        Show the frame number (lower left of each view).
    titles : bool
        Show each source's label (upper left of its view).

    Attributes
    ----------
    k : int
        Current frame.
    K : int
        Last frame of the longest source.
    playing, loop : bool
    plotter : pyvista.Plotter
    meshes : list of pyvista.PolyData
        One per source; ``meshes[i].points`` is the current pose of source ``i``.
    actors : list of pyvista.Actor
    """

    keys = {"space": "play / pause", "Right": "next frame", "Left": "previous frame",
            "Home": "first frame", "End": "last frame", "l": "loop on/off",
            "q": "quit"}

    def __init__(self, sources, *, track=None, fps: float = 24.0, loop: bool = True,
                 labels=None, off_screen: bool = False, window_size=None, view="iso",
                 widgets: bool | None = None, annotate: bool = True, titles: bool = True,
                 up=None):
        self.seqs = _load_all(sources, labels)
        self.up = scene_up_axis(self.seqs[0]) if up is None else checked_up(up)
        self.track = _track_indices(track, self.seqs)
        fps = float(fps)
        if not (np.isfinite(fps) and fps > 0):
            raise ShellsplineError(f"fps must be a positive number, got {fps!r}")
        self.fps = fps
        self.loop = bool(loop)
        self.playing = False
        self.annotate = bool(annotate)
        self.titles = bool(titles)
        self.K = max(s.K for s in self.seqs)
        self.k = 0
        S = len(self.seqs)
        widgets = (not off_screen) if widgets is None else bool(widgets)
        self.widgets = widgets
        pv = _pyvista("the preview window" if not off_screen else "rendering", off_screen)
        if window_size is None:
            window_size = (min(600 * S, 1800), 600 + (60 if widgets else 0))
        self.window_size = (int(window_size[0]), int(window_size[1]))
        if widgets:
            # a control strip under the views, spanning all columns
            self.plotter = pv.Plotter(shape=(2, S), row_weights=[10, 1],
                                      groups=[(1, np.s_[:])], off_screen=off_screen,
                                      window_size=self.window_size, border=False)
        else:
            self.plotter = pv.Plotter(shape=(1, S), off_screen=off_screen,
                                      window_size=self.window_size, border=False)
        pl = self.plotter
        pl.set_background("white")
        h_view = int(self.window_size[1] * (10 / 11 if widgets else 1.0))
        self.meshes, self.actors, self.markers = [], [], []
        for i, s in enumerate(self.seqs):
            pl.subplot(0, i)
            mesh = _polydata(pv, s.V[0], s.F)
            actor = pl.add_mesh(mesh, color=self.color(i, 0), smooth_shading=False,
                                ambient=0.25, diffuse=0.8, specular=0.15, show_edges=False)
            actor.prop.interpolation = "gouraud"
            self.meshes.append(mesh)
            self.actors.append(actor)
            if self.track.size:
                for v in self.track:
                    pl.add_mesh(pv.lines_from_points(s.V[:, v]), color="#333333", line_width=2)
                marker = pv.PolyData(np.array(s.V[0, self.track]))
                pl.add_mesh(marker, color="#d62728", point_size=10,
                            render_points_as_spheres=True)
                self.markers.append(marker)
            if titles:
                pl.add_text(s.label, position=(8, h_view - 24), font_size=11, color="black",
                            name=f"label{i}")
        # one camera for every subplot, fitted to every pose of every source
        w_view = self.window_size[0] / S
        self.camera_position = fitted_camera(np.concatenate([s.V.reshape(-1, 3)
                                                             for s in self.seqs]),
                                             w_view / h_view, view, up=self.up)
        for i in range(S):
            pl.subplot(0, i)
            pl.camera_position = self.camera_position
        if S > 1:
            pl.link_views(views=list(range(S)))
        self.slider = self.checkbox = None
        self._frame_texts = []
        if widgets:
            self._add_widgets(pl, S)
        self.set_frame(0)

    # -- colours -----------------------------------------------------------------------------
    def color(self, i: int, k: int) -> str:
        """Colour of source ``i`` at frame ``k``: gray on its keyframes, else its own colour."""
        s = self.seqs[i]
        return KEYFRAME_COLOR if _is_keyframe(s, min(k, s.K)) else PALETTE[i % len(PALETTE)]

    # -- frame logic ---------------------------------------------------------------------------
    def set_frame(self, k) -> int:
        """Show frame ``k`` (clamped to ``0..K``) in every view; returns the frame shown."""
        from .io.gltf import vertex_normals

        k = int(min(max(int(round(float(k))), 0), self.K))
        self.k = k
        for i, s in enumerate(self.seqs):
            ks = min(k, s.K)
            mesh = self.meshes[i]
            mesh.points = s.V[ks]
            mesh.point_data["Normals"] = vertex_normals(s.V[ks], s.F)
            self.actors[i].prop.color = self.color(i, k)
            if self.markers:
                self.markers[i].points = s.V[ks, self.track]
        if self.annotate:
            self._label_frame()
        if self.slider is not None:
            self.slider.GetRepresentation().SetValue(k)
        return k

    def _label_frame(self):
        short = not self.titles  # renders: a small "k=5" in the upper left corner
        if not self._frame_texts:  # created once; later frames only change the text
            pl = self.plotter
            h_view = int(self.window_size[1] * (10 / 11 if self.widgets else 1.0))
            font = max(6, min(10, self.window_size[0] // (26 * len(self.seqs))))
            pos = (4, h_view - 2 * font - 4) if short else (8, 6)
            for i in range(len(self.seqs)):
                pl.subplot(0, i)
                self._frame_texts.append(pl.add_text(" ", position=pos, color="#444444",
                                                     font_size=font if short else 9,
                                                     name=f"frame{i}"))
        for i, s in enumerate(self.seqs):
            ks = min(self.k, s.K)
            key = _is_keyframe(s, ks)
            text = (f"k={ks}" + (" key" if key else "")) if short else \
                (f"frame {ks}/{s.K}" + ("  keyframe" if key else ""))
            self._frame_texts[i].SetInput(text)

    def step(self, delta: int = 1) -> int:
        """Move ``delta`` frames (wrapping around when looping, else clamped)."""
        k = self.k + int(delta)
        if self.loop:
            k %= self.K + 1
        return self.set_frame(k)

    def tick(self) -> int:
        """Advance one frame as the playback timer does: wrap when looping, else stop at K."""
        if self.k >= self.K:
            if self.loop:
                return self.set_frame(0)
            self.pause()
            return self.k
        return self.set_frame(self.k + 1)

    def play(self) -> None:
        self.playing = True
        self._sync_checkbox()

    def pause(self) -> None:
        self.playing = False
        self._sync_checkbox()

    def toggle(self) -> bool:
        """Play if paused, pause if playing; returns ``playing``."""
        self.pause() if self.playing else self.play()
        return self.playing

    def toggle_loop(self) -> bool:
        self.loop = not self.loop
        return self.loop

    def on_slider(self, value) -> int:
        """Slider callback: show the frame nearest to ``value``."""
        return self.set_frame(value)

    def screenshot(self) -> np.ndarray:
        """The current image, ``(h, w, 3) uint8`` (rendered now)."""
        self.plotter.render()  # pyvista's screenshot renders by itself only the first time
        return np.asarray(self.plotter.screenshot(return_img=True))

    def close(self) -> None:
        self.plotter.close()

    # -- widgets and events ----------------------------------------------------------------------
    def _add_widgets(self, pl, S):
        pl.subplot(1, 0)
        pl.set_background("#eeeeee", all_renderers=False)
        h = max(self.window_size[1] // 11, 20)
        size = max(h - 12, 12)
        self.checkbox = pl.add_checkbox_button_widget(
            lambda on: self.play() if on else self.pause(), value=False,
            position=(6, (h - size) // 2), size=size, border_size=2, color_on="#59a14f",
            color_off="#9e9e9e", background_color="#eeeeee")
        pl.add_text("play", position=(size + 12, h // 2 - 6), font_size=8, color="#333333")
        self.slider = pl.add_slider_widget(
            lambda v: (self.on_slider(v), self._render()), [0, self.K], value=0,
            pointa=(min(0.3, (size + 60) / self.window_size[0]), 0.5), pointb=(0.97, 0.5),
            fmt="%.0f", style="modern", interaction_event="always", title_height=0.0,
            slider_width=0.06, tube_width=0.015)
        rep = self.slider.GetRepresentation()
        rep.SetSliderLength(0.025)
        rep.GetSliderProperty().SetColor(0.35, 0.35, 0.35)
        rep.SetShowSliderLabel(False)
        bindings = {"space": self.toggle, "Right": lambda: self.step(1),
                    "Left": lambda: self.step(-1), "Home": lambda: self.set_frame(0),
                    "End": lambda: self.set_frame(self.K), "l": self.toggle_loop}
        for key, fn in bindings.items():
            pl.add_key_event(key, lambda fn=fn: (fn(), self._render()))
        if pl.iren is not None and not pl.off_screen:
            # our own observer (not add_timer_event, which re-renders on every tick even
            # while paused): render only when a frame advances
            pl.iren.add_observer("TimerEvent", lambda obj, event: self.on_timer())
            pl.iren.create_timer(max(1, int(round(1000 / self.fps))), repeating=True)
        pl.subplot(0, 0)

    def _sync_checkbox(self):
        if self.checkbox is not None:
            rep = self.checkbox.GetRepresentation()
            if bool(rep.GetState()) != self.playing:
                rep.SetState(int(self.playing))

    def on_timer(self):
        """The playback timer's callback: while playing, one :meth:`tick` and a render."""
        if self.playing:
            self.tick()
            self._render()

    def _render(self):
        self.plotter.render()


def preview(*sources, track=None, fps: float = 24.0, loop: bool = True, labels=None,
            off_screen: bool = False, window_size=None, view="iso",
            up=None) -> SequenceViewer:
    """Open a window that plays one or several sequences side by side.

    Controls: frame slider and play/pause button under the views; keys ``space`` play/pause,
    ``←``/``→`` step, ``Home``/``End`` first/last frame, ``l`` loop on/off, ``q`` quit (mouse:
    rotate, shift-drag pan, wheel zoom; all views share one camera).

    Parameters
    ----------
    *sources : sources (see the module docstring)
    track, fps, loop, labels, window_size, view, up
        See :class:`SequenceViewer`.
    off_screen : bool
        Build everything without opening a window (for tests and screenshots); the window
        is not shown and the viewer is returned at frame 0.

    Returns
    -------
    SequenceViewer
        After the window was closed (or, off-screen, ready to drive).

    Raises
    ------
    ShellsplineError
        Without a display (use :func:`render_animation` / :func:`render_strip` instead), or
        without the viz extra.
    """
    if not sources:
        raise ShellsplineError("preview: no source given")
    if not off_screen and _headless():
        raise ShellsplineError("preview needs a display (DISPLAY is not set); render files "
                               "instead: shellspline render OUT --gif out.gif --strip out.png")
    viewer = SequenceViewer(list(sources), track=track, fps=fps, loop=loop, labels=labels,
                            off_screen=off_screen, window_size=window_size, view=view,
                            widgets=True, up=up)
    if not off_screen:
        viewer.plotter.show(title="shellspline preview")
    return viewer


# ----------------------------------------------------------------------------------------
# Camera paths
# ----------------------------------------------------------------------------------------
CAMERA_CONVENTIONS = ("opencv", "opengl")
"""Camera axes of a pose: ``opencv`` looks along its +z with x right and y down (TUM RGB-D and
KITTI camera poses), ``opengl`` along its −z with x right and y up (OpenGL, Blender, VTK)."""
CAMERA_TIMES = ("normalized", "frames", "seconds")
"""How a camera path's pose times map to the frames (see :class:`CameraPath`)."""
#: camera axes of each convention in VTK's (OpenGL) camera frame: T_gl = T @ _GL_FROM[conv]
_GL_FROM = {"opencv": np.diag([1.0, -1.0, -1.0, 1.0]), "opengl": np.eye(4)}


class CameraPath:
    """A camera that follows a C² spline through camera poses, for the off-screen renders.

    The poses are camera-to-world rigid motions (the camera's pose in the world, as TUM and
    our CSV/JSON files store them). They are interpolated by
    :func:`shellspline.curves.cubic_spline` (the curve ``shellspline path --kind interp``
    builds) and evaluated at the times of the rendered frames.

    Parameters
    ----------
    poses : str, path-like, PoseTrack or (t (n,), T (n,4,4))
        A pose file in any format :func:`shellspline.io.posefiles.read_poses` reads, a
        :class:`~shellspline.io.posefiles.PoseTrack`, or times and poses; at least 2 poses.
    times : {"normalized", "frames", "seconds"}
        How pose times map to the sequence's frames ``0..K``: ``"normalized"`` (default) the
        first pose at frame 0 and the last at frame ``K``, linearly in between; ``"frames"``
        the pose times are frame numbers (a KITTI file's pose index is its frame);
        ``"seconds"`` frame ``k`` is at ``t_0 + k / fps``, ``t_0`` the first pose's time.
    fps : float
        Frames per second of ``times="seconds"``.
    convention : {"opencv", "opengl"}
        The camera's axes in its pose (:data:`CAMERA_CONVENTIONS`): ``"opencv"`` (default)
        looks along +z with y down, ``"opengl"`` along −z with y up.
    group : {"so3xr3", "se3"}
        Metric of the spline (as ``shellspline path --group``).
    bc : {"natural", "clamped", "periodic"}
        End conditions (as ``shellspline path --bc``).

    Attributes
    ----------
    t : (n,) float64 array
    T : (n,4,4) float64 array
        The poses (camera to world).
    spline : PiecewiseBezier
    name : str
        The file (or ``"camera path"``), named in error messages.

    Notes
    -----
    The view angle is VTK's default, 30° vertically; the image's x axis is the camera's x.
    A frame whose time lies outside the poses' span raises (no extrapolation).

    Examples
    --------
    >>> import numpy as np
    >>> from shellspline.groups import se3, so3
    >>> a = np.linspace(0, np.pi, 3)            # half a circle around the z axis
    >>> R = so3.exp(np.c_[0 * a, 0 * a, a]) @ so3.exp([np.pi / 2, 0, 0])
    >>> T = se3.from_rt(R, 5 * np.c_[np.sin(a), -np.cos(a), 0 * a])
    >>> cam = CameraPath((a, T))
    >>> cam.poses([0, 10], K=10).shape
    (2, 4, 4)
    >>> bool(np.allclose(cam.poses([5], K=10)[0], T[1]))
    True
    """

    def __init__(self, poses, *, times: str = "normalized", fps: float = 24.0,
                 convention: str = "opencv", group: str = "so3xr3", bc: str = "natural"):
        from .curves import cubic_spline
        from .io.posefiles import PoseTrack, read_poses

        self.name = "camera path"
        if isinstance(poses, (str, os.PathLike)):
            self.name = str(poses)
            poses = read_poses(poses)
        if isinstance(poses, PoseTrack):
            t, T = poses.t, poses.T
        elif isinstance(poses, tuple) and len(poses) == 2:
            t, T = poses
        else:
            raise ShellsplineError(f"camera_path must be a pose file, a PoseTrack or (t, T), "
                                   f"got {type(poses).__name__}")
        t = np.asarray(t, dtype=np.float64).ravel()
        T = np.asarray(T, dtype=np.float64)
        if T.shape != (t.size, 4, 4):
            raise ShellsplineError(f"{self.name}: poses must be (n,4,4) for {t.size} times, got "
                                   f"shape {T.shape}")
        if t.size < 2:
            raise ShellsplineError(f"{self.name}: a camera path needs at least 2 poses, got "
                                   f"{t.size}")
        self.times = _checked_choice(times, CAMERA_TIMES, "camera times")
        self.convention = _checked_choice(convention, CAMERA_CONVENTIONS, "camera convention")
        self.fps = float(fps)
        if not (np.isfinite(self.fps) and self.fps > 0):
            raise ShellsplineError(f"fps must be a positive number, got {fps!r}")
        self.group = _checked_choice(group, ("so3xr3", "se3"), "camera group")
        self.bc = _checked_choice(bc, ("natural", "clamped", "periodic"), "camera bc")
        self.t, self.T = t, T
        try:
            self.spline = cubic_spline(self.group, t, T, self.bc)
        except ShellsplineError as exc:
            raise ShellsplineError(f"{self.name}: {exc}") from None

    def frame_times(self, frames, K: int) -> np.ndarray:
        """Times on the path (the poses' unit) of frames ``frames (p,)`` of a sequence ``0..K``.

        Raises
        ------
        ShellsplineError
            When a frame lies outside the poses' time span (one line naming the file).
        """
        k = np.asarray(frames, dtype=np.float64).ravel()
        t0, t1 = self.t[0], self.t[-1]
        if self.times == "normalized":
            tq = t0 + (t1 - t0) * k / max(int(K), 1)
        elif self.times == "frames":
            tq = k
        else:
            tq = t0 + k / self.fps
        tol = 1e-9 * max(1.0, abs(t0), abs(t1))
        bad = (tq < t0 - tol) | (tq > t1 + tol)
        if bad.any():
            i = int(np.argmax(bad))
            raise ShellsplineError(f"{self.name}: poses cover times {t0:.9g}..{t1:.9g}, frame "
                                   f"{k[i]:g} is at {tq[i]:.9g} (camera times {self.times!r})")
        return np.clip(tq, t0, t1)

    def poses(self, frames, K: int) -> np.ndarray:
        """Camera-to-world poses ``(p,4,4)`` at frames ``frames`` of a sequence ``0..K``."""
        return self.spline(self.frame_times(frames, K))

    def view_matrices(self, frames, K: int) -> np.ndarray:
        """World-to-camera matrices ``(p,4,4)`` in VTK's (OpenGL) camera axes at ``frames``.

        ``opengl`` poses give ``T⁻¹``; ``opencv`` poses ``diag(1,−1,−1,1) T⁻¹``. VTK's
        ``camera.GetModelViewTransformMatrix()`` of a rendered frame equals this.
        """
        from .groups import se3

        return _GL_FROM[self.convention] @ se3.inverse(self.poses(frames, K))

    def camera_positions(self, frames, K: int, center=None) -> list:
        """``[position, focal_point, view_up]`` per frame, for ``plotter.camera_position``.

        The focal point lies on the viewing axis at the distance of ``center (3,)`` (e.g. the
        scene's centre) along it, at least 1e-3 of the distance to it; 1 without ``center``.
        """
        G = self.poses(frames, K) @ _GL_FROM[self.convention]
        pos, look, up = G[:, :3, 3], -G[:, :3, 2], G[:, :3, 1]
        if center is None:
            dist = np.ones(len(G))
        else:
            rel = np.asarray(center, dtype=np.float64) - pos
            far = np.linalg.norm(rel, axis=1)
            dist = np.maximum(np.einsum("pi,pi->p", rel, look), 1e-3 * far)
            dist = np.where(dist > 0, dist, 1.0)
        focal = pos + look * dist[:, None]
        return [[tuple(p), tuple(f), tuple(u)] for p, f, u in zip(pos, focal, up)]


def _checked_choice(value, choices, what: str) -> str:
    key = str(value).strip().lower()
    if key not in choices:
        raise ShellsplineError(f"{what} must be one of {', '.join(choices)}, got {value!r}")
    return key


def checked_camera_path(camera) -> CameraPath | None:
    """``camera`` (None, a :class:`CameraPath`, a pose file or a PoseTrack) as a CameraPath."""
    if camera is None or isinstance(camera, CameraPath):
        return camera
    return CameraPath(camera)


# ----------------------------------------------------------------------------------------
# Off-screen renders
# ----------------------------------------------------------------------------------------
def checked_frames(frames, K: int) -> np.ndarray:
    f = _int_list(frames, "frames", "0,5,10")
    if f.size == 0:
        raise ShellsplineError("frames: no frame given")
    bad = (f < 0) | (f > K)
    if bad.any():
        raise ShellsplineError(f"frames: {int(f[bad][0])} is outside 0..{K}")
    return f


def checked_size(window_size, default):
    if window_size is None:
        return default
    given = window_size
    if isinstance(window_size, str):
        parts = window_size.lower().replace("×", "x").split("x")
        try:
            window_size = tuple(int(p) for p in parts)
        except ValueError:
            window_size = ()
    if len(window_size) != 2 or min(window_size) < 16 or max(window_size) > 8192:
        raise ShellsplineError(f"window size must be WIDTHxHEIGHT with 16..8192 pixels, got "
                               f"{given!r}")
    return int(window_size[0]), int(window_size[1])


def render_frames(source, frames=None, *, window_size=(640, 480), view="iso",
                  annotate: bool = True, up=None, camera_path=None) -> np.ndarray:
    """Render frames of one source off-screen with one camera fitted to the whole sequence
    (or a camera that moves along ``camera_path``).

    Parameters
    ----------
    source : a source (see the module docstring)
    frames : (p,) int array-like, optional
        Default all frames ``0..K``.
    window_size : (int, int)
    view : str or (3,) array
        See :func:`fitted_camera`.
    annotate : bool
        Write the frame number into the image.
    up : {"x", "y", "z"}, optional
        The scene's up axis; default :func:`scene_up_axis` of the source.
    camera_path : CameraPath, pose file or PoseTrack, optional
        The camera follows this path (:class:`CameraPath`; a file or track with its defaults:
        OpenCV axes, pose times normalised to the frames); ``view`` and ``up`` are then
        unused.

    Returns
    -------
    (p, h, w, 3) uint8 array
    """
    return np.stack(list(_iter_frames(load_source(source), frames, window_size, view,
                                      annotate, up, camera_path)))


def _iter_frames(seq, frames, window_size, view, annotate, up=None, camera=None):
    """Yield rendered frames one at a time (the viewer is closed at the end)."""
    frames = np.arange(seq.K + 1) if frames is None else checked_frames(frames, seq.K)
    size = checked_size(window_size, (640, 480))
    camera = checked_camera_path(camera)
    views = None
    if camera is not None:  # every frame's camera, checked before the first render
        views = camera.camera_positions(frames, seq.K, 0.5 * (seq.V.reshape(-1, 3).min(axis=0)
                                                              + seq.V.reshape(-1, 3).max(axis=0)))
    viewer = SequenceViewer(seq, off_screen=True, window_size=size, view=view, widgets=False,
                            annotate=annotate, titles=False, up=up)
    try:
        for i, k in enumerate(frames):
            viewer.set_frame(k)
            if views is not None:  # after the new points: the clipping range follows them
                viewer.plotter.camera_position = views[i]
            yield viewer.screenshot()
    finally:
        viewer.close()


def render_animation(source, path, fps: float = 24.0, window_size=(640, 480), frames=None, *,
                     view="iso", annotate: bool = True, up=None, camera_path=None) -> Path:
    """Render a sequence off-screen to an animated GIF or an MP4 movie (by ``path``'s suffix).

    Parameters
    ----------
    source : a source (see the module docstring)
    path : str or path-like
        ``.gif`` (imageio/Pillow, loops forever) or ``.mp4`` (H.264 through imageio-ffmpeg).
        Written atomically; never over an input file.
    fps : float
        Frames per second.
    window_size : (int, int) or "WxH"
        Pixels (MP4 sizes are rounded up to even numbers).
    frames : (p,) int array-like, optional
        Frames to show, default all.
    view, annotate, up, camera_path
        See :func:`render_frames`.

    Returns
    -------
    pathlib.Path
        The absolute path written.
    """
    seq = load_source(source)
    up = None if up is None else checked_up(up)
    fps = float(fps)
    if not (np.isfinite(fps) and fps > 0):
        raise ShellsplineError(f"fps must be a positive number, got {fps!r}")
    suffix = checked_output(path, _ANIMATION_SUFFIXES, [seq], "animation").suffix.lower()
    size = checked_size(window_size, (640, 480))
    if suffix == ".mp4":
        size = (size[0] + size[0] % 2, size[1] + size[1] % 2)
    try:
        import imageio.v2 as iio2
        import imageio.v3 as iio
    except ImportError:
        raise ShellsplineError(f"render_animation needs the viz extra: {_EXTRA}") from None
    frames = None if frames is None else checked_frames(frames, seq.K)
    camera = checked_camera_path(camera_path)
    if camera is not None:  # fail before the file is opened
        camera.frame_times(np.arange(seq.K + 1) if frames is None else frames, seq.K)

    def write(tmp):
        imgs = _iter_frames(seq, frames, size, view, annotate, up, camera)
        if suffix == ".gif":  # Pillow needs every frame at once
            iio.imwrite(tmp, np.stack(list(imgs)), extension=".gif", duration=1000.0 / fps,
                        loop=0)
        else:  # streamed: one frame in memory at a time
            try:
                writer = iio2.get_writer(tmp, format="FFMPEG", fps=fps, codec="libx264",
                                         quality=7, macro_block_size=2,
                                         ffmpeg_log_level="error")
            except (ImportError, ValueError) as exc:
                raise ShellsplineError(f"MP4 output needs imageio-ffmpeg ({_EXTRA}): "
                                       f"{exc}") from None
            with writer:
                for img in imgs:
                    writer.append_data(img)

    return _write_atomically(path, write, [seq], _ANIMATION_SUFFIXES, "animation")


def default_strip_frames(K: int, keyframes, max_panels: int = 12) -> np.ndarray:
    """Frames of a filmstrip: keyframes plus the frame halfway between consecutive ones.

    Falls back to the keyframes alone, then to ``max_panels`` evenly spaced frames, when there
    are too many; without keyframes, 5 evenly spaced frames.

    Returns
    -------
    (p,) int64 array, sorted, unique.
    """
    key = np.unique(np.asarray(keyframes, dtype=np.int64))
    key = key[(key >= 0) & (key <= K)]
    if key.size == 0:
        return np.unique(np.round(np.linspace(0, K, min(5, K + 1))).astype(np.int64))
    mids = (key[:-1] + key[1:]) // 2
    f = np.unique(np.concatenate([key, mids]))
    if f.size > max_panels:
        f = key
    if f.size > max_panels:
        f = np.unique(np.round(np.linspace(0, K, max_panels)).astype(np.int64))
    return f


def _compose(panels: np.ndarray, columns: int, gap: int, background=255) -> np.ndarray:
    p, h, w, c = panels.shape
    rows = -(-p // columns)
    out = np.full((rows * h + (rows - 1) * gap, columns * w + (columns - 1) * gap, c),
                  background, dtype=np.uint8)
    for i in range(p):
        r, q = divmod(i, columns)
        out[r * (h + gap):r * (h + gap) + h, q * (w + gap):q * (w + gap) + w] = panels[i]
    return out


def render_strip(source, path, frames=None, columns=None, window_size=(240, 240), *,
                 gap: int = 8, view="iso", annotate: bool = True, up=None,
                 camera_path=None) -> Path:
    """A PNG filmstrip of chosen frames, like the paper's figures.

    Keyframes are gray, in-betweens coloured; every panel uses the same camera (fitted to the
    whole sequence), so the motion reads from left to right.

    Parameters
    ----------
    source : a source (see the module docstring)
    path : str or path-like
        ``.png`` file, written atomically, never over an input.
    frames : (p,) int array-like, optional
        Default :func:`default_strip_frames` (keyframes and the frames halfway between).
    columns : int, optional
        Panels per row; default all in one row (at most 8 per row).
    window_size : (int, int) or "WxH"
        Pixels of one panel.
    gap : int
        White pixels between panels.
    view, annotate, up, camera_path
        See :func:`render_frames` (with a camera path each panel has its own camera).

    Returns
    -------
    pathlib.Path
        The absolute path written. The image is
        ``rows × h + (rows−1) × gap`` by ``columns × w + (columns−1) × gap`` pixels.
    """
    seq = load_source(source)
    up = None if up is None else checked_up(up)
    checked_output(path, (".png",), [seq], "filmstrip")
    frames = default_strip_frames(seq.K, seq.frames) if frames is None else \
        checked_frames(frames, seq.K)
    if columns is None:
        columns = min(len(frames), 8)
    columns = int(columns)
    if columns < 1:
        raise ShellsplineError(f"columns must be >= 1, got {columns}")
    gap = int(gap)
    if gap < 0:
        raise ShellsplineError(f"gap must be >= 0, got {gap}")
    size = checked_size(window_size, (240, 240))
    try:
        import imageio.v3 as iio
    except ImportError:
        raise ShellsplineError(f"render_strip needs the viz extra: {_EXTRA}") from None
    panels = render_frames(seq, frames, window_size=size, view=view, annotate=annotate, up=up,
                           camera_path=camera_path)
    strip = _compose(panels, min(columns, len(frames)), gap)
    return _write_atomically(path, lambda tmp: iio.imwrite(tmp, strip, extension=".png"),
                             [seq], (".png",), "filmstrip")


def export_glb(source, path, *, fps: float = 24.0, frames=None,
               interpolation: str = "LINEAR", up=None) -> Path:
    """Write a source as a GLB morph-target animation (see :mod:`shellspline.io.gltf`).

    Parameters
    ----------
    source : a source (see the module docstring)
    path : str or path-like
        ``.glb`` file, written atomically, never over an input.
    fps : float
    frames : (p,) int array-like, optional
        Frames to export (in this order), default all.
    interpolation : {"LINEAR", "STEP"}
    up : {"x", "y", "z"}, optional
        The up axis of the source's coordinates (default :func:`scene_up_axis`, as for the
        renders): the node gets the rotation that turns it onto glTF's +y
        (:data:`shellspline.io.gltf.UP_ROTATIONS`).

    Returns
    -------
    pathlib.Path
    """
    from .io.gltf import glb_bytes

    seq = load_source(source)
    up_axis = scene_up_axis(seq) if up is None else checked_up(up)
    checked_output(path, (".glb",), [seq], "GLB")
    V = seq.V if frames is None else seq.V[checked_frames(frames, seq.K)]
    data = glb_bytes(V, seq.F, fps=fps, interpolation=interpolation, up_axis=up_axis)
    return _write_atomically(path, lambda tmp: tmp.write_bytes(data), [seq], (".glb",), "GLB")


# ----------------------------------------------------------------------------------------
# Plots (matplotlib, no pyplot: no global state, no display)
# ----------------------------------------------------------------------------------------
_PLOT_SUFFIXES = (".png", ".svg", ".pdf")
_WHAT = ("energy", "speed", "track")


def _matplotlib(what: str):
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise ShellsplineError(f"{what} needs the viz extra: {_EXTRA}") from None
    return Figure


def _lta_energy(seq: _Sequence) -> tuple[np.ndarray, str]:
    en = seq.report.get("energies") or {}
    e = en.get("lta_output_energy_per_frame")
    if e is not None and en.get("resolution", "full") == "full" and len(e) == seq.K + 1:
        return np.asarray(e, dtype=np.float64), "report"
    from .metrics import lta_energies

    p = seq.parameters
    V, T = _solve_sequence(seq)
    return lta_energies(V, T, bc=p.get("bc", "natural"), mu=p.get("mu", 1.0),
                        lam=p.get("lam", 1.0), eta=p.get("eta", 1e-3)), "recomputed"


def _solve_sequence(seq: _Sequence):
    """The poses and topology of ``seq`` as ``interpolate`` solves them: UV-seam duplicates
    welded, fin faces and isolated vertices set aside
    (:func:`~shellspline.mesh.source_mesh.solve_mesh`), so that an output written back with
    its input's polygons can be measured like the solve."""
    from .mesh.source_mesh import solve_mesh
    from .mesh.topology import topology

    F = np.asarray(seq.F, dtype=np.int64)
    offsets = np.arange(0, 3 * F.shape[0] + 1, 3, dtype=np.int64)
    V, Fs, _, _ = solve_mesh(np.asarray(seq.V, dtype=np.float64), offsets, F.ravel(),
                             name=seq.label)
    return V, topology(Fs, V.shape[1], name=seq.label)


def _shell_energy(seq: _Sequence, mode: str) -> np.ndarray:
    from .metrics import shell_energies

    p = seq.parameters
    V, T = _solve_sequence(seq)
    return shell_energies(V, T, bc=p.get("bc", "natural"), mu=p.get("mu", 1.0),
                          lam=p.get("lam", 1.0), eta=p.get("eta", 1e-3),
                          midpoints=(mode == "midpoint"))


def _shell_mode(mode, seqs) -> str:
    mode = str(mode).strip().lower()
    if mode not in ("auto", "midpoint", "step", "none"):
        raise ShellsplineError(f"shell_energy must be 'auto', 'midpoint', 'step' or 'none', got "
                               f"{mode!r}")
    if mode == "auto":
        work = max(s.V.shape[1] * max(s.K - 1, 0) for s in seqs)
        mode = "midpoint" if work <= AUTO_MIDPOINT_WORK else "step"
    return mode


def _keyframe_lines(ax, seqs):
    key = np.unique(np.concatenate([s.frames for s in seqs]))
    for f in key:
        ax.axvline(f, color=KEYFRAME_COLOR, lw=1.0, ls="--", zorder=0, label="_keyframe")


def plot_figure(sources, what=("energy", "speed"), *, track=None, labels=None,
                shell_energy: str = "auto", figsize=None):
    """A matplotlib Figure of per-frame quantities of one or several sequences.

    Panels, top to bottom (each one axes, one line per source, keyframes as dashed gray
    vertical lines):

    * ``"energy"``: the LΘA energy ``Ŵ[z_k, z̃_k]`` per frame (from ``report.json`` when it
      has it at full resolution, else recomputed with the report's parameters) and the
      nonlinear Discrete Shells energy (paper Figs. 11–12): ``W[s_k, s̃_k]`` with the geodesic
      midpoint ``s̃_k`` (``shell_energy="midpoint"``), the cheaper ``W[s_k, s_{k+1}]``
      (``"step"``), chosen by size (``"auto"``: midpoints up to n·(K−1) = 60 000), or left
      out (``"none"``).
    * ``"speed"``: root-mean-square vertex speed between frames
      (:func:`shellspline.metrics.speed`, plotted at ``k + 1/2``).
    * ``"track"`` (implied by ``track``): trajectories of the tracked vertices projected onto
      their principal plane, keyframe positions marked (paper Fig. 8).

    Parameters
    ----------
    sources : a source or a list of sources
    what : sequence of {"energy", "speed", "track"} or comma-separated str
    track : sequence of int or str, optional
        Vertex indices for the trajectory panel.
    labels : list of str or comma-separated str, optional
    shell_energy : {"auto", "midpoint", "step", "none"}
    figsize : (float, float), optional

    Returns
    -------
    matplotlib.figure.Figure
        Not attached to pyplot. Data lines carry the source label (``line.get_label()``).
    """
    Figure = _matplotlib("plot")
    seqs = _load_all(sources, labels)
    if isinstance(what, str):
        what = [w.strip() for w in what.split(",") if w.strip()]
    what = [str(w).lower() for w in what]
    for w in what:
        if w not in _WHAT:
            raise ShellsplineError(f"what: unknown plot {w!r} (choose from {', '.join(_WHAT)})")
    idx = _track_indices(track, seqs)
    if idx.size and "track" not in what:
        what.append("track")
    if "track" in what and not idx.size:
        raise ShellsplineError("a trajectory plot needs vertex indices (track=...)")
    mode = _shell_mode(shell_energy, seqs) if "energy" in what else "none"
    panels = []
    for w in _WHAT:
        if w not in what:
            continue
        if w == "energy":
            panels.append("lta")
            if mode != "none":
                panels.append("shell")
        else:
            panels.append(w)
    if not panels:
        raise ShellsplineError("nothing to plot: choose energy, speed and/or track")
    fig = Figure(figsize=figsize or (7.0, 2.4 * len(panels) + 0.4), layout="constrained")
    axes = fig.subplots(len(panels), 1, squeeze=False)[:, 0]
    colors = [PALETTE[i % len(PALETTE)] for i in range(len(seqs))]
    for ax, panel in zip(axes, panels):
        if panel == "lta":
            for s, c in zip(seqs, colors):
                e, _ = _lta_energy(s)
                ax.plot(np.arange(s.K + 1), e, color=c, lw=1.8, marker=".", label=s.label)
            ax.set_ylabel("LΘA energy")
            ax.set_title(r"LΘA energy $\widehat{W}[z_k, \tilde z_k]$ per frame", fontsize=10)
        elif panel == "shell":
            for s, c in zip(seqs, colors):
                e = _shell_energy(s, mode)
                if mode == "midpoint":
                    ax.plot(np.arange(s.K + 1), e, color=c, lw=1.8, marker=".", label=s.label)
                else:  # one value per step k -> k+1, drawn between the frames like the speed
                    ax.plot(np.arange(s.K) + 0.5, e[:s.K], color=c, lw=1.8, marker=".",
                            label=s.label)
            ax.set_ylabel("shell energy")
            ax.set_title(r"Discrete Shells energy $W[s_k, \tilde s_k]$ ($\tilde s_k$ geodesic "
                         r"midpoint of $s_{k-1}, s_{k+1}$)" if mode == "midpoint" else
                         r"Discrete Shells energy $W[s_k, s_{k+1}]$ between frames",
                         fontsize=10)
        elif panel == "speed":
            from .metrics import speed

            for s, c in zip(seqs, colors):
                ax.plot(np.arange(s.K) + 0.5, speed(s.V), color=c, lw=1.8, marker=".",
                        label=s.label)
            ax.set_ylabel("speed")
            ax.set_title("RMS vertex speed (length per unit time, t ∈ [0, 1])", fontsize=10)
        if panel in ("lta", "shell", "speed"):
            _keyframe_lines(ax, seqs)
            ax.set_xlabel("frame k")
            ax.set_xlim(0, max(s.K for s in seqs))
            ax.grid(alpha=0.3)
        elif panel == "track":
            _trajectory_panel(ax, seqs, idx, colors)
        ax.legend(fontsize=8, loc="best")
    return fig


def _trajectory_panel(ax, seqs, idx, colors):
    P = np.concatenate([s.V[:, idx].reshape(-1, 3) for s in seqs])
    c = P.mean(axis=0)
    _, _, Vt = np.linalg.svd(P - c, full_matrices=False)
    basis = Vt[:2].T  # principal plane of all tracked positions
    for s, col in zip(seqs, colors):
        for j, v in enumerate(idx):
            xy = (s.V[:, v] - c) @ basis
            ax.plot(xy[:, 0], xy[:, 1], color=col, lw=1.8,
                    label=s.label if j == 0 else "_nolegend_")
            if s.frames.size:
                kxy = xy[s.frames]
                ax.plot(kxy[:, 0], kxy[:, 1], ls="none", marker="o", ms=5,
                        color=KEYFRAME_COLOR, mec="#555555", label="_keyframe")
    for v in idx:
        xy0 = (seqs[0].V[0, v] - c) @ basis
        ax.annotate(str(int(v)), xy0, fontsize=8, color="#333333")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(f"trajectories of vertices {', '.join(map(str, idx.tolist()))} "
                 "(principal plane; keyframes ●)", fontsize=10)
    ax.grid(alpha=0.3)


def _save_figure(fig, path, seqs=()) -> Path:
    suffix = checked_output(path, _PLOT_SUFFIXES, seqs, "plot").suffix.lower()
    return _write_atomically(path, lambda tmp: fig.savefig(tmp, format=suffix[1:], dpi=120),
                             seqs, _PLOT_SUFFIXES, "plot")


def plot(sources, path, what=("energy", "speed"), track=None, labels=None, *,
         shell_energy: str = "auto") -> Path:
    """Save :func:`plot_figure` as PNG, SVG or PDF (by ``path``'s suffix), atomically.

    Returns
    -------
    pathlib.Path
        The absolute path written.

    Examples
    --------
    ``plot(["out/spline", "out/geodesic"], "energy.png", what="energy")`` compares a spline
    with a piecewise geodesic as in the paper's Fig. 11.
    """
    seqs = _load_all(sources, labels)
    checked_output(path, _PLOT_SUFFIXES, seqs, "plot")  # before the (slow) energies
    fig = plot_figure(seqs, what, track=track, shell_energy=shell_energy)
    return _save_figure(fig, path, seqs)


def half_axes_figure(curves: dict, *, frames=None, figsize=(7.0, 3.6)):
    """Half-axes of ellipsoid-like shapes along the curve (paper Fig. 3).

    Parameters
    ----------
    curves : dict label -> (K+1,3) array or source
        Half-extents along x, y, z per frame (e.g. from
        :func:`shellspline.metrics.half_axes`), or a source whose half-axes are computed.
    frames : (J,) int array-like, optional
        Keyframe frames, drawn as dashed gray lines (default: those of the first source
        given, if any).

    Returns
    -------
    matplotlib.figure.Figure
        One axes; one line per label and axis (x solid, y dashed, z dotted).
    """
    from .metrics import half_axes

    Figure = _matplotlib("plot_half_axes")
    if not isinstance(curves, dict) or not curves:
        raise ShellsplineError("curves must be a non-empty dict label -> (K+1,3) half-axes")
    fig = Figure(figsize=figsize, layout="constrained")
    fig._shellspline_sources = []  # loaded sources, so a saved plot never replaces an input
    ax = fig.add_subplot()
    key = None if frames is None else np.asarray(frames, dtype=np.int64).ravel()
    for i, (label, c) in enumerate(curves.items()):
        if isinstance(c, (np.ndarray, list)):
            H = np.asarray(c, dtype=np.float64)
        else:
            seq = load_source(c, str(label))
            fig._shellspline_sources.append(seq)
            H = half_axes(seq.V)
            if key is None and seq.frames.size:
                key = seq.frames
        if H.ndim != 2 or H.shape[1] != 3:
            raise ShellsplineError(f"curves[{label!r}] must be a (K+1,3) array, got shape "
                                   f"{H.shape}")
        col = PALETTE[i % len(PALETTE)]
        for j, (ls, name) in enumerate(zip(("-", "--", ":"), "xyz")):
            ax.plot(np.arange(H.shape[0]), H[:, j], color=col, ls=ls, lw=1.8,
                    label=f"{label}: {name}")
    if key is not None:
        for f in key:
            ax.axvline(f, color=KEYFRAME_COLOR, lw=1.0, ls="--", zorder=0, label="_keyframe")
    ax.set_xlabel("frame k")
    ax.set_ylabel("half-axis length")
    ax.set_title("half-axes along the curve (x solid, y dashed, z dotted)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=max(1, len(curves)), loc="best")
    return fig


def plot_half_axes(curves: dict, path, *, frames=None) -> Path:
    """Save :func:`half_axes_figure` as PNG, SVG or PDF, atomically.

    Returns
    -------
    pathlib.Path
    """
    checked_output(path, _PLOT_SUFFIXES, (), "plot")
    fig = half_axes_figure(curves, frames=frames)
    return _save_figure(fig, path, fig._shellspline_sources)
