"""Point caches: MDD and PC2 files (vertex positions per frame, no topology).

Both formats store float32 positions of a fixed number of points for a run of frames; the
mesh they animate comes from elsewhere (Blender's *Mesh Cache* modifier, Maya's geometry
cache import, Houdini's File SOP read them onto a mesh with the same vertex order). Written
and read here with :mod:`numpy` (no dependency), vectorised over frames and points.

MDD (LightWave / NewTek; Blender, Maya and Houdini read it), **big-endian** throughout::

    int32   numFrames
    int32   numPoints
    float32 times[numFrames]                      # seconds; frame k at k / fps
    float32 points[numFrames][numPoints][3]       # x y z

PC2 (3ds Max *Point Cache 2*; Blender, Maya and Houdini read it), **little-endian**::

    char    signature[12] = "POINTCACHE2\\0"
    int32   fileVersion   = 1
    int32   numPoints
    float32 startFrame
    float32 sampleRate                            # frames between samples
    int32   numSamples
    float32 points[numSamples][numPoints][3]

Sample ``i`` of a PC2 file lies at frame ``startFrame + i * sampleRate``. Blender's own MDD
exporter writes one extra block of points (the rest pose) before the frames it declares;
:func:`read_mdd` recognises a file that is exactly one block longer than its header says and
skips that first block.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import MeshError, ShellsplineError
from .atomic import write_bytes_atomic

__all__ = ["mdd_bytes", "write_mdd", "read_mdd", "pc2_bytes", "write_pc2", "read_pc2",
           "read_point_cache", "keyframes_from_cache", "POINT_CACHE_FORMATS"]

POINT_CACHE_FORMATS = ("mdd", "pc2")
"""Point-cache formats (file extensions) this module reads and writes."""

_PC2_SIGNATURE = b"POINTCACHE2\0"
_PC2_HEADER = np.dtype([("signature", "S12"), ("version", "<i4"), ("points", "<i4"),
                        ("start", "<f4"), ("rate", "<f4"), ("samples", "<i4")])
_F32_MAX = float(np.finfo(np.float32).max)


def _poses(V, name: str = "V") -> np.ndarray:
    """``V`` as a C-contiguous (frames, n, 3) float64 array, finite and float32-representable."""
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0 or V.shape[1] == 0:
        raise ShellsplineError(f"{name} must be a (frames,n,3) array of poses with at least one "
                               f"frame and one point, got shape {V.shape}")
    big = ~(np.abs(V) <= _F32_MAX)  # also catches NaN
    if big.any():
        k, i, _ = np.argwhere(big)[0]
        raise ShellsplineError(f"{name} must be finite and within float32 range, got "
                               f"{V[k, i].tolist()} at frame {k}, point {i}")
    return V


def _positive(value, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ShellsplineError(f"{name} must be a positive number, got {value!r}") from None
    if not (0 < x < np.inf):
        raise ShellsplineError(f"{name} must be a positive number, got {value!r}")
    return x


def mdd_bytes(V, *, fps: float = 24.0, times=None) -> bytes:
    """The bytes of an MDD file holding the poses ``V``.

    Parameters
    ----------
    V : (frames,n,3) float array
        Point positions per frame (written as big-endian float32).
    fps : float
        Frames per second: frame ``k`` gets the time ``k / fps`` seconds (ignored when
        ``times`` is given).
    times : (frames,) float array, optional
        The frame times in seconds, non-decreasing.

    Returns
    -------
    bytes
        ``8 + 4 * frames + 12 * frames * n`` bytes.

    Raises
    ------
    ShellsplineError
        For poses that are not ``(frames,n,3)``, not finite or beyond float32, a non-positive
        ``fps``, or ``times`` of the wrong length or decreasing.

    Examples
    --------
    >>> import numpy as np
    >>> b = mdd_bytes(np.zeros((3, 2, 3)), fps=30)
    >>> len(b), np.frombuffer(b[:8], ">i4").tolist(), np.frombuffer(b[8:20], ">f4").tolist()
    (92, [3, 2], [0.0, 0.03333333507180214, 0.06666667014360428])
    """
    V = _poses(V)
    if times is None:
        times = np.arange(V.shape[0]) / _positive(fps, "fps")
    else:
        times = np.asarray(times, dtype=np.float64)
        if times.shape != (V.shape[0],) or not np.isfinite(times).all() or \
                (np.diff(times) < 0).any():
            raise ShellsplineError(f"times must be {V.shape[0]} finite non-decreasing seconds, "
                                   f"got shape {times.shape}")
    head = np.array(V.shape[:2], dtype=">i4").tobytes()
    return head + times.astype(">f4").tobytes() + V.astype(">f4").tobytes()


def write_mdd(path, V, *, fps: float = 24.0, times=None) -> Path:
    """Write :func:`mdd_bytes` to ``path`` atomically (:mod:`shellspline.io.atomic`).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    return write_bytes_atomic(path, mdd_bytes(V, fps=fps, times=times))


def _read_bytes(path, what: str) -> bytes:
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise ShellsplineError(f"cannot read {what} '{path}': "
                               f"{(exc.strerror or str(exc)).lower()}") from None


def read_mdd(path) -> tuple[np.ndarray, np.ndarray]:
    """Read an MDD file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    V : (frames,n,3) float64 numpy array
        Point positions (float32 values, widened).
    times : (frames,) float64 numpy array
        Frame times in seconds.

    Raises
    ------
    ShellsplineError
        If the file cannot be read, its header is not a plausible MDD header, its size does
        not match the header (neither exactly nor with Blender's extra rest block), or a frame
        time is not finite.
    """
    data = _read_bytes(path, "MDD file")
    if len(data) < 8:
        raise ShellsplineError(f"'{path}' is not an MDD file: {len(data)} bytes, shorter than "
                               "the 8-byte header")
    frames, n = (int(x) for x in np.frombuffer(data, ">i4", 2))
    if frames < 1 or n < 1:
        raise ShellsplineError(f"'{path}' is not an MDD file: header says {frames} frames of "
                               f"{n} points")
    block = 12 * n
    size = 8 + 4 * frames + block * frames
    if len(data) not in (size, size + block):
        raise ShellsplineError(f"'{path}': {len(data)} bytes, but an MDD file of {frames} frames "
                               f"of {n} points has {size}")
    times = np.frombuffer(data, ">f4", frames, 8).astype(np.float64)
    if not np.isfinite(times).all():
        k = int(np.argmin(np.isfinite(times)))
        raise ShellsplineError(f"'{path}': the time of frame {k} is {times[k]}, not a finite "
                               "number (a damaged MDD file)")
    start = 8 + 4 * frames + (len(data) - size)  # skip Blender's rest block when present
    V = np.frombuffer(data, ">f4", 3 * n * frames, start).reshape(frames, n, 3)
    return V.astype(np.float64), times


def pc2_bytes(V, *, start_frame: float = 0.0, sample_rate: float = 1.0) -> bytes:
    """The bytes of a PC2 file holding the poses ``V``.

    Parameters
    ----------
    V : (samples,n,3) float array
        Point positions per sample (written as little-endian float32).
    start_frame : float
        Frame of the first sample.
    sample_rate : float
        Frames between consecutive samples (``1``: one sample per frame).

    Returns
    -------
    bytes
        ``32 + 12 * samples * n`` bytes.

    Raises
    ------
    ShellsplineError
        For bad poses (see :func:`mdd_bytes`), a non-finite ``start_frame`` or a non-positive
        ``sample_rate``.

    Examples
    --------
    >>> import numpy as np
    >>> b = pc2_bytes(np.zeros((4, 2, 3)), start_frame=1)
    >>> len(b), b[:12], np.frombuffer(b[12:20], "<i4").tolist()
    (128, b'POINTCACHE2\\x00', [1, 2])
    """
    V = _poses(V)
    try:
        start = float(start_frame)
    except (TypeError, ValueError):
        start = np.nan
    if not np.isfinite(start):
        raise ShellsplineError(f"start_frame must be a finite number, got {start_frame!r}")
    head = np.array([(_PC2_SIGNATURE, 1, V.shape[1], start, _positive(sample_rate, "sample_rate"),
                      V.shape[0])], dtype=_PC2_HEADER)
    return head.tobytes() + V.astype("<f4").tobytes()


def write_pc2(path, V, *, start_frame: float = 0.0, sample_rate: float = 1.0) -> Path:
    """Write :func:`pc2_bytes` to ``path`` atomically (:mod:`shellspline.io.atomic`).

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    return write_bytes_atomic(path, pc2_bytes(V, start_frame=start_frame,
                                              sample_rate=sample_rate))


def read_pc2(path) -> tuple[np.ndarray, float, float]:
    """Read a PC2 file.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    V : (samples,n,3) float64 numpy array
        Point positions (float32 values, widened).
    start_frame : float
        Frame of the first sample.
    sample_rate : float
        Frames between samples.

    Raises
    ------
    ShellsplineError
        If the file cannot be read, has no PC2 signature, a version other than 1, a start
        frame or sample rate that is not finite, or a size that does not match its header.
    """
    data = _read_bytes(path, "PC2 file")
    if not data.startswith(_PC2_SIGNATURE):
        raise ShellsplineError(f"'{path}' is not a PC2 file: it does not start with "
                               f"{_PC2_SIGNATURE!r}")
    if len(data) < _PC2_HEADER.itemsize:
        raise ShellsplineError(f"'{path}': {len(data)} bytes, shorter than the "
                               f"{_PC2_HEADER.itemsize}-byte PC2 header (a truncated file)")
    h = np.frombuffer(data, _PC2_HEADER, 1)[0]
    version, n, samples = int(h["version"]), int(h["points"]), int(h["samples"])
    if version != 1:
        raise ShellsplineError(f"'{path}': PC2 version {version}, only version 1 is defined")
    if n < 1 or samples < 1:
        raise ShellsplineError(f"'{path}': PC2 header says {samples} samples of {n} points")
    if not (np.isfinite(h["start"]) and np.isfinite(h["rate"])):
        raise ShellsplineError(f"'{path}': PC2 header has start frame {float(h['start'])} and "
                               f"sample rate {float(h['rate'])}, not finite numbers")
    size = _PC2_HEADER.itemsize + 12 * n * samples
    if len(data) != size:
        raise ShellsplineError(f"'{path}': {len(data)} bytes, but a PC2 file of {samples} "
                               f"samples of {n} points has {size}")
    V = np.frombuffer(data, "<f4", 3 * n * samples, _PC2_HEADER.itemsize)
    return V.reshape(samples, n, 3).astype(np.float64), float(h["start"]), float(h["rate"])


def read_point_cache(path, *, fps: float = 24.0) -> tuple[np.ndarray, np.ndarray]:
    """Read an MDD or PC2 file (by extension) with the frame number of every sample.

    Parameters
    ----------
    path : str or path-like
        A ``.mdd`` or ``.pc2`` file.
    fps : float
        Frames per second that turn MDD times (seconds) into frames.

    Returns
    -------
    V : (samples,n,3) float64 numpy array
    frames : (samples,) float64 numpy array
        MDD: ``times * fps``; PC2: ``startFrame + i * sampleRate``.

    Raises
    ------
    ShellsplineError
        For another extension, or as :func:`read_mdd` / :func:`read_pc2`.
    """
    ext = Path(path).suffix.lower().lstrip(".")
    if ext == "mdd":
        V, times = read_mdd(path)
        return V, times * _positive(fps, "fps")
    if ext == "pc2":
        V, start, rate = read_pc2(path)
        return V, start + rate * np.arange(V.shape[0])
    raise ShellsplineError(f"'{path}' is not a point cache: the extension must be .mdd or .pc2")


def keyframes_from_cache(cache, mesh, frames=None, *, fps: float = 24.0, pinned=None):
    """Keyframes from the samples of a point cache on the vertices of a mesh file.

    Every sample of ``cache`` is a keyframe pose of ``mesh`` (same vertex count and order, as
    Blender's Mesh Cache modifier and other tools read them). The mesh's polygons are read
    as keyframe files are (:func:`shellspline.io.read_keyframes`): triangulated once for all
    poses, seams welded, fins and isolated vertices set aside, and ``source`` maps back to
    the mesh's own vertices, polygons, texture coordinates and OBJ material/group lines, so
    the output is written on the mesh as given.

    Parameters
    ----------
    cache : str or path-like
        A ``.mdd`` or ``.pc2`` file.
    mesh : str or path-like
        The mesh the cache animates (OBJ, PLY or OFF); its faces (and an OBJ's texture
        coordinates and material/group lines) are used, its vertex positions are not.
    frames : (J,) int array-like, optional
        Keyframe frames; default the samples' own frames (:func:`read_point_cache`) less the
        first, which must be whole numbers.
    fps : float
        Frames per second that turn MDD times into frames.
    pinned : optional
        As for :func:`shellspline.io.keyframes_from_arrays`.

    Returns
    -------
    Keyframes

    Raises
    ------
    MeshError
        If the cache and the mesh disagree in vertex count, the cache's frames (when
        ``frames`` is not given) are not whole numbers or not increasing, or as
        :func:`shellspline.io.keyframes_from_arrays`.

    Examples
    --------
    >>> import os, tempfile, numpy as np
    >>> d = tempfile.mkdtemp()
    >>> V0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> with open(os.path.join(d, "tet.obj"), "w") as fh:
    ...     _ = fh.write("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nv 0 0 1\\n"
    ...                  "f 1 3 2\\nf 1 2 4\\nf 1 4 3\\nf 2 3 4\\n")
    >>> _ = write_pc2(os.path.join(d, "poses.pc2"), [V0, 2 * V0], sample_rate=10)
    >>> kf = keyframes_from_cache(os.path.join(d, "poses.pc2"), os.path.join(d, "tet.obj"))
    >>> kf.V.shape, kf.frames.tolist()
    ((2, 4, 3), [0, 10])
    """
    from .keyframes import keyframes_from_polygons, texture_warning
    from .meshes import read_polygons

    try:
        V, at = read_point_cache(cache, fps=fps)
    except ShellsplineError as exc:
        raise MeshError(str(exc)) from None
    if isinstance(frames, (str, os.PathLike)):
        from .keyframes import read_frames

        frames = read_frames(frames)
    info: dict = {}
    V0, offsets, indices, uv = read_polygons(mesh, info)
    texture_warning(info)
    if V0.shape[0] != V.shape[1]:
        raise MeshError(f"{cache} holds {V.shape[1]} points but {mesh} has {V0.shape[0]} "
                        "vertices")
    if frames is not None and np.size(frames) != V.shape[0]:
        raise MeshError(f"{cache} holds {V.shape[0]} samples (one keyframe each), but "
                        f"{np.size(frames)} keyframe frames were given: "
                        f"{np.ravel(frames).tolist()[:8]}")
    if frames is None:
        rel = at - at[0]
        frames = np.rint(rel).astype(np.int64)
        if np.abs(rel - frames).max() > 1e-3:
            raise MeshError(f"{cache}: the samples lie at frames {np.round(at, 3).tolist()[:6]}, "
                            "not whole numbers apart; give the keyframe frames")
        if np.any(np.diff(frames) <= 0):
            k = int(np.argmax(np.diff(frames) <= 0))
            raise MeshError(f"{cache}: sample {k + 1} lies at frame {at[k + 1]:g}, not after "
                            f"sample {k} at {at[k]:g}; give the keyframe frames")
    names = [f"{cache} sample {i}" for i in range(V.shape[0])]
    if V.shape[0] < 2:
        raise MeshError(f"need at least 2 keyframes, got 1 ('{cache}' holds one sample)")
    return keyframes_from_polygons(V, offsets, indices, frames, names, pinned, uv=uv,
                                   statements=info.get("statements"), faces_file=str(mesh))
