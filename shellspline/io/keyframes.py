"""Keyframes: reading a keyframe set, validating it once, index and frame files.

Every problem is reported as a one-line :class:`~shellspline.errors.MeshError` that names the
file (or the argument) and what was found. Polygons are triangulated once for the whole
keyframe set, seams welded and fin faces and isolated vertices set aside for the solve
(:mod:`shellspline.mesh.source_mesh`); the map back to the input is
:attr:`Keyframes.source`.
"""
from __future__ import annotations

import dataclasses
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import MeshError, ShellsplineError, one_line, tol
from ..mesh.geometry import cross
from ..mesh.source_mesh import SourceMesh, solve_mesh
from ..mesh.topology import Topology, topology
from .meshes import (MESH_EXTENSIONS, check_indices, obj_face, polygon_offsets, read_polygons,
                     wide_text_encoding)
from .gltf import GLTF_EXTENSIONS, read_gltf_mesh
from .usd import USD_EXTENSIONS

__all__ = ["Keyframes", "read_keyframes", "keyframes_from_arrays", "read_indices", "read_frames"]

# ----------------------------------------------------------------------------------------
# Keyframes
# ----------------------------------------------------------------------------------------
@dataclass(eq=False)
class Keyframes:
    """A validated set of keyframe poses of one triangle mesh.

    Build it with :func:`read_keyframes` or :func:`keyframes_from_arrays`, which check
    everything once; constructing it directly skips the checks.

    Attributes
    ----------
    V : (J,n,3) float64 numpy array
        Keyframe poses, one per keyframe on axis 0.
    F : (m,3) int64 numpy array
        Faces shared by all keyframes.
    frames : (J,) int64 numpy array or None
        Frame index of each keyframe, non-negative and strictly increasing; ``None`` lets
        the caller choose later.
    names : list of str
        One name per keyframe (the file path as given, or ``"keyframe j"``); used in
        messages.
    pinned : (p,) int64 numpy array or None
        Sorted, unique indices of vertices to hold fixed, or ``None`` (solve-mesh indices).
    source : SourceMesh or None
        How ``V`` and ``F`` (the *solve mesh*) map back to the input's vertices and polygons
        when they differ (polygons triangulated, seams welded, fins or isolated vertices set
        aside); ``None`` for a clean triangle mesh, whose solve mesh is the input.

    Examples
    --------
    >>> import trimesh
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> kf = keyframes_from_arrays([m.vertices, 2 * m.vertices], m.faces, frames=[0, 10])
    >>> kf.J, kf.n, kf.m, kf.frames.tolist()
    (2, 42, 80, [0, 10])
    >>> kf.topology.n_edges
    120
    """

    V: np.ndarray
    F: np.ndarray
    frames: np.ndarray | None
    names: list[str]
    pinned: np.ndarray | None = None
    source: SourceMesh | None = None
    _topology: Topology | None = field(default=None, init=False, repr=False)

    @property
    def J(self) -> int:
        """Number of keyframes."""
        return int(self.V.shape[0])

    @property
    def n(self) -> int:
        """Number of vertices."""
        return int(self.V.shape[1])

    @property
    def m(self) -> int:
        """Number of faces."""
        return int(self.F.shape[0])

    @property
    def topology(self) -> Topology:
        """Connectivity tables of ``F`` (built on first access, then cached)."""
        if self._topology is None:
            name = self.names[0] if self.names else "keyframes"
            self._topology = topology(self.F, self.n, name=name)
        return self._topology

    def with_frames(self, frames) -> "Keyframes":
        """A copy with validated ``frames`` (sharing arrays and the cached topology).

        Parameters
        ----------
        frames : (J,) int array-like, str or path
            As for :func:`read_keyframes`.

        Returns
        -------
        Keyframes
        """
        new = dataclasses.replace(self, frames=_canonical_frames(frames, self.J))
        new._topology = self._topology
        return new

    def __repr__(self) -> str:
        frames = None if self.frames is None else self.frames.tolist()
        pinned = None if self.pinned is None else f"<{self.pinned.size} vertices>"
        source = "" if self.source is None else f", source=<{self.source.n_source} vertices>"
        return (f"Keyframes(J={self.J}, n={self.n}, m={self.m}, frames={frames}, "
                f"names={self.names!r}, pinned={pinned}{source})")


# ----------------------------------------------------------------------------------------
# Keyframe sets: reading and validation
# ----------------------------------------------------------------------------------------
def read_keyframes(paths, frames=None, *, pinned=None) -> Keyframes:
    """Read and validate the keyframe meshes of one animation.

    Parameters
    ----------
    paths : sequence of str or path-like, or one USD file
        One mesh file per keyframe (OBJ, PLY, OFF, glTF ``.gltf``/``.glb`` holding one mesh
        (:func:`shellspline.io.gltf.read_gltf_mesh`, world space), or a USD file
        ``.usd``/``.usda``/``.usdc`` holding one mesh with one pose; formats may be mixed), in
        time order. Every keyframe
        has the same polygons (triangles, quads, n-gons). A single USD file holding one mesh
        whose points are time-sampled is a keyframe sequence: one keyframe per time sample
        (:func:`shellspline.io.usd.read_usd`, world space).
    frames : (J,) int array-like, str or path, optional
        Frame index of each keyframe: non-negative, strictly increasing integers. A string
        or path is parsed by :func:`read_frames`. ``None`` leaves the choice to the caller,
        except for a single USD file: its time codes less the first (whole numbers apart).
    pinned : (p,) int array-like, (n,) bool mask, str or path, optional
        Vertices to hold fixed (numbered as in the files); a string or path is read with
        :func:`read_indices`.

    Returns
    -------
    Keyframes
        With ``names`` the paths as given and the topology already built. Polygons are
        triangulated once for all keyframes, vertices coincident in every keyframe welded,
        fin faces and unused vertices set aside (:func:`shellspline.mesh.source_mesh.solve_mesh`);
        ``source`` maps back to the files' vertices and polygons.

    Raises
    ------
    MeshError
        With a one-line message naming the file and the problem: unreadable, missing or
        malformed file (or a header that does not match its data), unknown extension, empty
        mesh, different vertex counts or polygon lists between keyframes, indices out of
        range, a polygon repeating a vertex or that cannot be triangulated, an edge that
        stays non-manifold after fins are set aside, inconsistent orientation, degenerate
        (zero-area) faces, NaN/inf or overflowing coordinates, fewer than two keyframes, bad
        ``frames`` or ``pinned`` (or a pinned vertex that is set aside); for USD: no mesh or
        more than one, a topology that changes over time, several poses in a file of a list,
        time samples not whole frames apart; for glTF: no mesh or more than one mesh node, a
        skinned mesh, compressed geometry.
    UsdUnavailableError
        For a USD file when ``pxr`` is not installed (extra ``usd``; a
        :class:`~shellspline.errors.ShellsplineError` and an ImportError).

    Examples
    --------
    >>> import os, tempfile, trimesh
    >>> d = tempfile.mkdtemp()
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> paths = []
    >>> for j, s in enumerate([1.0, 1.5, 2.0]):
    ...     paths.append(os.path.join(d, f"k{j}.ply"))
    ...     _ = trimesh.Trimesh(m.vertices * s, m.faces, process=False).export(paths[-1])
    >>> kf = read_keyframes(paths, frames="0,5,10")
    >>> kf.V.shape, kf.F.shape, kf.frames.tolist()
    ((3, 42, 3), (80, 3), [0, 5, 10])
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    try:
        paths = list(paths)
    except TypeError:
        raise MeshError(f"keyframes: expected a list of mesh file paths, got "
                        f"{type(paths).__name__}") from None
    bad = [p for p in paths if not isinstance(p, (str, os.PathLike))]
    if bad:
        raise MeshError(f"keyframes: expected mesh file paths, got a {type(bad[0]).__name__} "
                        "(for in-memory poses use keyframes_from_arrays)")
    names = [str(p) for p in paths]
    if len(paths) == 1 and Path(paths[0]).suffix.lower() in USD_EXTENSIONS:
        return _usd_keyframes(paths[0], frames, pinned)
    bad = [n for n in names if Path(n).suffix.lower() in (".mdd", ".pc2")]
    if bad:
        raise MeshError(f"'{bad[0]}' is a point cache (vertex positions only, no faces): read "
                        "it with the mesh it animates (keyframes_from_cache; on the command "
                        "line --topology MESH)")
    if len(paths) < 2:
        got = f" ('{names[0]}')" if names else ""
        raise MeshError(f"need at least 2 keyframes, got {len(paths)}{got}")
    frames = _canonical_frames(frames, len(paths))
    Vs: list[np.ndarray] = []
    info: dict = {}
    for j, p in enumerate(paths):
        V, offsets, indices, uv = _read_pose(p, info if j == 0 else None)
        _check_not_empty(V, offsets[:-1], names[j])
        if j == 0:
            off0, idx0, uv0 = offsets, indices, uv
            texture_warning(info)
        else:
            if V.shape[0] != Vs[0].shape[0]:
                raise MeshError(f"{names[j]} has {V.shape[0]} vertices but {names[0]} has "
                                f"{Vs[0].shape[0]}")
            check_same_polygons(offsets, indices, off0, idx0, names[j], names[0])
        Vs.append(V)
    return _validated(np.stack(Vs), off0, idx0, frames, names, pinned, uv0,
                      statements=info.get("statements"), faces_file=names[0])


def texture_warning(info: dict) -> None:
    """Warn (a :class:`UserWarning`; the command line prints it as a note) when
    :func:`~shellspline.io.meshes.read_polygons` left texture coordinates out."""
    if info.get("texture_note"):
        import warnings

        warnings.warn(info["texture_note"], UserWarning, stacklevel=3)


def _read_usd(path):
    """:func:`shellspline.io.usd.read_usd` with its problems as :class:`MeshError` (a missing
    ``pxr`` stays a :class:`~shellspline.io.usd.UsdUnavailableError`)."""
    from .usd import UsdUnavailableError, read_usd

    try:
        return read_usd(path)
    except UsdUnavailableError:
        raise
    except ShellsplineError as exc:
        raise MeshError(str(exc)) from None


def _read_pose(path, info=None):
    """One keyframe file: ``(V (n,3), offsets, indices, uv or None)``; a USD file must hold
    one pose (its points with at most one time sample), a glTF file one mesh
    (:func:`~shellspline.io.gltf.read_gltf_mesh`, world space). ``info``: see
    :func:`~shellspline.io.meshes.read_polygons`."""
    ext = Path(path).suffix.lower()
    if ext in GLTF_EXTENSIONS:
        try:
            V, offsets, indices, _ = read_gltf_mesh(path)
        except ShellsplineError as exc:
            raise MeshError(str(exc)) from None
        return V, offsets, indices, None
    if ext not in USD_EXTENSIONS:
        if ext not in MESH_EXTENSIONS:
            raise MeshError(f"cannot read '{path}': unknown extension '{Path(path).suffix}' "
                            f"(supported: {', '.join(MESH_EXTENSIONS + GLTF_EXTENSIONS)}, "
                            f"{', '.join(USD_EXTENSIONS)})")
        return read_polygons(path, info)
    V, offsets, indices, info = _read_usd(path)
    if V.shape[0] != 1:
        raise MeshError(f"'{path}' holds {V.shape[0]} poses (time samples of "
                        f"{info['prim']}.points): give it alone to read them as the keyframes, "
                        "or one pose per file")
    return V[0], offsets, indices, None


def _usd_keyframes(path, frames, pinned) -> Keyframes:
    """The keyframes of one USD file: every time sample of its mesh's points is one, at frames
    counted from the first sample's time code unless ``frames`` is given."""
    V, offsets, indices, info = _read_usd(path)
    T = V.shape[0]
    if T < 2:
        raise MeshError(f"need at least 2 keyframes, got 1 ('{path}': {info['prim']}.points "
                        f"has {len(info['times'])} time samples)")
    if frames is None:
        at = np.asarray(info["times"], dtype=np.float64)
        rel = at - at[0]
        frames = np.rint(rel).astype(np.int64)
        if np.abs(rel - frames).max() > 1e-6:
            raise MeshError(f"'{path}': the time samples lie at {np.round(at, 3).tolist()[:6]}, "
                            "not whole frames apart; give the keyframe frames")
    else:
        if isinstance(frames, (str, os.PathLike)):
            frames = read_frames(frames)
        if np.size(frames) != T:
            raise MeshError(f"'{path}' holds {T} poses (one keyframe each), but "
                            f"{np.size(frames)} keyframe frames were given: "
                            f"{np.ravel(frames).tolist()[:8]}")
    names = [f"{path} time {t:g}" for t in info["times"]]
    return _validated(V, offsets, indices, _canonical_frames(frames, T), names, pinned)


def keyframes_from_arrays(V, F, frames=None, names=None, pinned=None) -> Keyframes:
    """Validate in-memory keyframes exactly as :func:`read_keyframes` validates files.

    Parameters
    ----------
    V : (J,n,3) float array-like, or sequence of J (n,3) arrays
        Keyframe poses.
    F : (m,3) int array-like
        Shared triangles, zero-based.
    frames : (J,) int array-like, str or path, optional
        See :func:`read_keyframes`.
    names : sequence of J str, optional
        Names used in messages; default ``"keyframe 0"``, ``"keyframe 1"``, ...
    pinned : (p,) int array-like, (n,) bool mask, str or path, optional
        See :func:`read_keyframes`.

    Returns
    -------
    Keyframes
        Holding float64/int64 copies of the inputs. As for files, vertices coincident in
        every keyframe are welded and fin faces and unused vertices set aside; ``source``
        then maps back to the arrays given (``None`` when nothing changed).

    Raises
    ------
    MeshError
        As :func:`read_keyframes`.

    Examples
    --------
    >>> import numpy as np
    >>> V0 = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    >>> F = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]
    >>> keyframes_from_arrays([V0, 2 * V0], F, frames=[0, 4]).V.shape
    (2, 4, 3)
    >>> keyframes_from_arrays([V0, 2 * V0], F, frames=[4, 0])
    Traceback (most recent call last):
    ...
    shellspline.errors.MeshError: frames must be strictly increasing, got [4, 0]
    """
    if isinstance(V, np.ndarray):
        poses = list(V) if V.ndim == 3 else None
        if poses is None and V.ndim == 2 and V.shape[-1] == 3:
            raise MeshError(f"need at least 2 keyframes, got a single pose of shape {V.shape}")
        if poses is None:
            raise MeshError(f"V must be a (J,n,3) array of poses, got shape {V.shape}")
    else:
        poses = list(V)
    J = len(poses)
    if names is None:
        names = [f"keyframe {j}" for j in range(J)]
    else:
        names = [str(s) for s in names]
        if len(names) != J:
            raise MeshError(f"names must have one entry per keyframe ({J}), got {len(names)}")
    if J < 2:
        got = f" ('{names[0]}')" if names else ""
        raise MeshError(f"need at least 2 keyframes, got {J}{got}")
    frames = _canonical_frames(frames, J)
    try:
        F = np.asarray(F)
    except Exception as exc:
        raise MeshError(f"F: cannot convert to an array: {one_line(exc)}") from None
    if F.ndim != 2 or F.shape[1] != 3:
        raise MeshError(f"F must be an (m,3) array of triangles, got shape {F.shape}")
    if F.size and not np.issubdtype(F.dtype, np.integer):
        raise MeshError(f"F must hold integer vertex indices, got dtype {F.dtype}")
    F = F.astype(np.int64)
    Vs = []
    for j, X in enumerate(poses):
        try:
            X = np.array(X, dtype=np.float64)
        except Exception as exc:
            raise MeshError(f"{names[j]}: cannot convert the pose to a float array: "
                            f"{one_line(exc)}") from None
        if X.ndim != 2 or X.shape[1] != 3:
            raise MeshError(f"{names[j]}: a pose must be an (n,3) array, got shape {X.shape}")
        _check_not_empty(X, F, names[j])
        if j and X.shape[0] != Vs[0].shape[0]:
            raise MeshError(f"{names[j]} has {X.shape[0]} vertices but {names[0]} has "
                            f"{Vs[0].shape[0]}")
        Vs.append(X)
    return _validated(np.stack(Vs), polygon_offsets(np.full(F.shape[0], 3)), F.ravel(),
                      frames, names, pinned)


def keyframes_from_polygons(V, offsets, indices, frames=None, names=None, pinned=None, *,
                            uv=None, statements=None, faces_file=None) -> Keyframes:
    """Validate keyframe poses ``V`` (J,n,3) of one polygon mesh (``offsets``, ``indices``, as
    :func:`~shellspline.io.meshes.read_polygons` returns them) as :func:`read_keyframes`
    does: ``uv`` and ``statements`` (texture coordinates and OBJ material/group lines) are
    carried to the output, ``faces_file`` (the file the polygons come from) names faces in
    its own terms in messages. Used for point caches on a mesh
    (:func:`shellspline.io.pointcache.keyframes_from_cache`)."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    J = V.shape[0]
    names = [f"keyframe {j}" for j in range(J)] if names is None else [str(x) for x in names]
    if J < 2:
        raise MeshError(f"need at least 2 keyframes, got {J}" + (f" ('{names[0]}')" if J else ""))
    _check_not_empty(V[0], offsets[:-1], faces_file or names[0])
    check_indices(offsets, indices, V.shape[1], faces_file or names[0])
    return _validated(V, offsets, indices, _canonical_frames(frames, J), names, pinned, uv,
                      statements=statements, faces_file=faces_file)


def _check_not_empty(V: np.ndarray, F: np.ndarray, name: str) -> None:
    if V.shape[0] == 0:
        raise MeshError(f"{name}: empty mesh (no vertices)")
    if F.shape[0] == 0:
        raise MeshError(f"{name}: empty mesh (no faces)")


def check_same_polygons(offsets, indices, off0, idx0, name: str, name0: str) -> None:
    """The polygons of a keyframe must be those of the first, face by face; a polygon may
    start at another corner (an exporter's choice: the same face, same orientation)."""
    if offsets.shape == off0.shape and np.array_equal(offsets, off0) and \
            np.array_equal(indices, idx0):
        return
    if offsets.shape != off0.shape:
        raise MeshError(f"{name}: face list differs from {name0} ({name} has "
                        f"{offsets.size - 1} faces, {name0} has {off0.size - 1})")
    P = offsets.size - 1
    diff = np.diff(offsets) != np.diff(off0)
    if not diff.any():
        if np.array_equal(polygons_from_lowest(offsets, indices),
                          polygons_from_lowest(off0, idx0)):
            return
        diff = np.add.reduceat(indices != idx0, offsets[:-1]) > 0 if P else diff
    t = int(np.flatnonzero(diff)[0])
    here, there = obj_face(name, t), obj_face(name0, t)  # OBJ files: in their own terms
    a, b = (indices[offsets[t]:offsets[t + 1]].tolist(), idx0[off0[t]:off0[t + 1]].tolist())
    if here is None and there is None:
        where = f"face {t} (counted from 0): {a} vs {b}"
    else:
        where = (f"{here or f'face {t} {a} (counted from 0)'} vs "
                 f"{there or f'face {t} {b} (counted from 0)'}")
    raise MeshError(f"{name}: face list differs from {name0} (first difference at {where}); "
                    "every keyframe must be the same mesh with the same vertex order "
                    "(Blender: Keep Vertex Order)")


def polygons_from_lowest(offsets: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Corner indices with every polygon turned cyclically to start at its lowest vertex
    (orientation kept): equal for two lists of the same faces written from other corners."""
    sizes = np.diff(offsets)
    if indices.size == 0:
        return indices
    start = np.repeat(offsets[:-1], sizes)
    size = np.repeat(sizes, sizes)
    local = np.arange(indices.size) - start
    lowest = np.repeat(np.minimum.reduceat(indices, offsets[:-1]), sizes)
    first = np.where(indices == lowest, local, np.iinfo(np.int64).max)
    shift = np.repeat(np.minimum.reduceat(first, offsets[:-1]), sizes)
    return indices[start + (local + shift) % size]


#: Coordinates are refused above this magnitude: the shell energy's Hessians hold fourth
#: powers of lengths (squared areas), and (1e75)^4 = 1e300 still fits a float64.
MAX_COORDINATE = 1e75


def _validated(Vs: np.ndarray, offsets: np.ndarray, indices: np.ndarray, frames,
               names: list[str], pinned, uv=None, *, statements=None,
               faces_file=None) -> Keyframes:
    """Checks shared by both constructors; ``Vs`` (J,n,3) float64, shapes already agree;
    the polygons (``offsets``, ``indices``) are those of every keyframe; ``uv`` the first
    keyframe's texture coordinates and ``statements`` its OBJ material and group lines
    (carried to the output) or ``None``; ``faces_file`` the file the polygons were read from
    (messages name its faces in its own terms)."""
    J, n = Vs.shape[:2]
    for j in range(J):
        finite = np.isfinite(Vs[j]).all(axis=1)
        if not finite.all():
            bad = np.flatnonzero(~finite)
            raise MeshError(f"{names[j]}: {bad.size} vertices have NaN/inf coordinates "
                            f"(first: vertex {int(bad[0])} = {Vs[j, bad[0]].tolist()})")
        big = np.abs(Vs[j]).max()
        if big > MAX_COORDINATE:
            raise MeshError(f"{names[j]}: coordinates overflow: the largest magnitude is "
                            f"{big:.3g}, above {MAX_COORDINATE:g} squared areas do not fit a "
                            "float64 (rescale the mesh)")
    check_indices(offsets, indices, n, names[0])
    V, F, source, tri_poly = solve_mesh(Vs, offsets, indices, names[0], uv,
                                        statements=statements)
    for j in range(J):
        _check_degenerate(V[j], F, names[j], source, tri_poly, faces_file)
    T = topology(F, V.shape[1], name=names[0])
    pinned = _canonical_pinned(pinned, n)
    if source is not None and pinned is not None:
        pinned = source.solve_vertices(pinned)
    kf = Keyframes(V=V, F=T.F, frames=frames, names=list(names), pinned=pinned, source=source)
    kf._topology = T
    return kf


def _check_degenerate(V: np.ndarray, F: np.ndarray, name: str, source=None,
                      tri_poly=None, faces_file=None) -> None:
    """Raise for faces with area below ``tol.degenerate_area * mean_edge_length**2``."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    area = 0.5 * np.linalg.norm(cross(e1, e2), axis=1)
    mean_len = (np.linalg.norm(e1, axis=1).sum() + np.linalg.norm(e2, axis=1).sum()
                + np.linalg.norm(c - b, axis=1).sum()) / (3 * F.shape[0])
    bad = area <= tol.degenerate_area * mean_len ** 2
    if bad.any():
        idx = np.flatnonzero(bad)
        t = int(idx[0])
        in_file = obj_face(faces_file, int(tri_poly[t]) if source is not None else t) \
            if faces_file is not None else None
        if source is None:
            what = in_file or f"face {t} {F[t].tolist()} (counted from 0)"
        else:
            p = int(tri_poly[t])
            corners = source.poly_indices[source.poly_offsets[p]:source.poly_offsets[p + 1]]
            what = (f"a triangle of {in_file}" if in_file else
                    f"face {t} (of input face {p} {corners.tolist()}, counted from 0)")
        raise MeshError(f"{name}: {idx.size} degenerate (zero-area) faces, first is {what} "
                        f"(area {area[t]:.3g} <= {tol.degenerate_area:g} x "
                        f"mean edge length^2 = {tol.degenerate_area * mean_len ** 2:.3g})")


def _canonical_frames(frames, J: int) -> np.ndarray | None:
    """Validate keyframe frames: ``None`` or (J,) int64, non-negative, strictly increasing."""
    if frames is None:
        return None
    if isinstance(frames, (str, os.PathLike)):
        frames = read_frames(frames)
    try:
        arr = np.asarray(frames)
    except Exception as exc:
        raise MeshError(f"frames: cannot convert to an array: {one_line(exc)}") from None
    if arr.ndim != 1:
        raise MeshError(f"frames must be a 1-D sequence of integers, got shape {arr.shape}")
    shown = arr.tolist()
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer)
                                 or np.issubdtype(arr.dtype, np.floating)):
        raise MeshError(f"frames must be integers, got {shown}")
    if np.issubdtype(arr.dtype, np.floating):
        if not np.isfinite(arr).all() or (arr != np.round(arr)).any():
            raise MeshError(f"frames must be integers, got {shown}")
    arr = arr.astype(np.int64)
    if arr.shape[0] != J:
        raise MeshError(f"frames must have one entry per keyframe ({J}), got {arr.shape[0]}: "
                        f"{arr.tolist()}")
    if (arr < 0).any():
        raise MeshError(f"frames must be non-negative, got {arr.tolist()}")
    if (np.diff(arr) <= 0).any():
        raise MeshError(f"frames must be strictly increasing, got {arr.tolist()}")
    return arr


def _canonical_pinned(pinned, n: int) -> np.ndarray | None:
    """Validate pinned vertices: ``None`` or sorted unique (p,) int64 in ``[0, n)``."""
    if pinned is None:
        return None
    if isinstance(pinned, (str, os.PathLike)):
        pinned = read_indices(pinned)
    try:
        arr = np.asarray(pinned)
    except Exception as exc:
        raise MeshError(f"pinned: cannot convert to an array: {one_line(exc)}") from None
    if arr.dtype == bool:
        if arr.shape != (n,):
            raise MeshError(f"a boolean pinned mask must have one entry per vertex ({n}), "
                            f"got shape {arr.shape}")
        return np.flatnonzero(arr).astype(np.int64)
    arr = arr.ravel()
    if arr.size and not np.issubdtype(arr.dtype, np.integer):
        if not np.issubdtype(arr.dtype, np.floating) or (arr != np.round(arr)).any():
            raise MeshError(f"pinned vertex indices must be integers, got dtype {arr.dtype}")
    arr = arr.astype(np.int64)
    out = (arr < 0) | (arr >= n)
    if out.any():
        raise MeshError(f"pinned vertex indices must lie in [0, {n}), got {int(arr[out][0])} "
                        f"({int(out.sum())} out of range)")
    return np.unique(arr)


# ----------------------------------------------------------------------------------------
# Small text inputs
# ----------------------------------------------------------------------------------------
def read_indices(path) -> np.ndarray:
    """Read a vertex-index file: integers separated by whitespace, newlines or commas.

    ``#`` starts a comment that runs to the end of the line.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    (p,) int64 numpy array
        The indices in file order (range checks happen in :func:`read_keyframes`).

    Raises
    ------
    MeshError
        If the file cannot be read or holds something other than integers.

    Examples
    --------
    >>> import tempfile, os
    >>> p = os.path.join(tempfile.mkdtemp(), "pins.txt")
    >>> _ = open(p, "w").write("# base ring\\n3, 4 5\\n7  # last\\n")
    >>> read_indices(p).tolist()
    [3, 4, 5, 7]
    """
    return _read_integers(path, "vertex-index file")


def read_frames(spec) -> np.ndarray:
    """Parse keyframe frames from a string such as ``"0,10,20"`` or from a file of integers.

    Parameters
    ----------
    spec : str, path-like or sequence of int
        A comma/whitespace-separated list of integers, the path of a file holding them
        (``#`` comments allowed), or a sequence of integers.

    Returns
    -------
    (J,) int64 numpy array
        The frames as given; monotonicity and length are checked by
        :func:`read_keyframes`.

    Raises
    ------
    MeshError
        If ``spec`` is neither an integer list nor a readable file of integers.

    Examples
    --------
    >>> read_frames("0, 10,20").tolist()
    [0, 10, 20]
    """
    if isinstance(spec, os.PathLike):
        return _read_integers(spec, "frames file")
    if isinstance(spec, str):
        if re.fullmatch(r"[\s,+\-0-9]*", spec) and re.search(r"\d", spec):
            return _parse_integers(spec, f"frames '{spec}'")
        if Path(spec).is_file():
            return _read_integers(spec, "frames file")
        raise MeshError(f"frames '{spec}' is neither a list of integers such as '0,10,20' nor "
                        "an existing file")
    try:
        arr = np.asarray(spec)
    except Exception as exc:
        raise MeshError(f"frames: cannot convert to an array: {one_line(exc)}") from None
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise MeshError(f"frames must be a 1-D sequence of integers, got {arr.tolist()}")
    return arr.astype(np.int64)


def _read_integers(path, what: str) -> np.ndarray:
    name = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise MeshError(f"cannot read '{name}': {exc.strerror or exc}") from None
    wide = wide_text_encoding(data[:4])
    if wide:
        raise MeshError(f"{what} '{name}' is {wide} encoded; save it as UTF-8")
    if b"\0" in data:
        raise MeshError(f"{what} '{name}' is not a text file (it holds NUL bytes; UTF-16 "
                        "without a byte-order mark? save it as UTF-8)")
    # utf-8-sig: a byte-order mark (Windows editors) is not part of the first number
    return _parse_integers(data.decode("utf-8-sig", errors="replace"), f"{what} '{name}'")


def _parse_integers(text: str, what: str) -> np.ndarray:
    values: list[int] = []
    for line_no, line in enumerate(text.splitlines(), 1):
        for tok in line.split("#", 1)[0].replace(",", " ").split():
            try:
                values.append(int(tok))
            except ValueError:
                raise MeshError(f"{what}: line {line_no}: '{tok}' is not an integer") from None
    return np.array(values, dtype=np.int64)


