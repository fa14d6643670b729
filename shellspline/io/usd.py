"""USD export of a pose sequence: one mesh with time-sampled points.

Written with Pixar's ``pxr`` bindings (the ``usd-core`` wheel, extra ``usd``), imported
inside the functions. The stage holds

* a ``Mesh`` prim (``/<name>``, the stage's default prim) with the topology
  (``faceVertexCounts``, ``faceVertexIndices``: triangles or the input's polygons),
  ``subdivisionScheme = "none"`` (the mesh is a polygon mesh, not a subdivision cage) and
  ``orientation = "rightHanded"`` (counter-clockwise front faces, as in OBJ);
* ``points`` and ``extent`` time-sampled at the time codes ``start .. start + K`` (one per
  frame), ``points`` also as the default value (frame 0), so that a reader that ignores time
  still sees the mesh;
* stage metadata ``timeCodesPerSecond = framesPerSecond = fps``, ``startTimeCode``,
  ``endTimeCode`` and ``upAxis`` (``UsdGeom.SetStageUpAxis``), ``metersPerUnit`` left at the
  USD default.

``usdview``, Blender (File > Import > Universal Scene Description: the points become a
*Mesh Sequence Cache* modifier) and Houdini (Solaris, File SOP) play it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from .atomic import write_atomically

__all__ = ["write_usd", "read_usd", "require_usd", "UsdUnavailableError", "USD_EXTENSIONS",
           "UP_AXIS_CONVENTIONS", "conventional_up_axis"]


class UsdUnavailableError(ShellsplineError, ImportError):
    """``pxr`` (the ``usd-core`` wheel, extra ``usd``) is not installed: an ImportError that is
    also a :class:`~shellspline.errors.ShellsplineError`, so the CLI reports it in one line
    with exit 2 (a missing extra is not a bug)."""

USD_EXTENSIONS = (".usd", ".usda", ".usdc")
"""Extensions of the USD files :func:`write_usd` writes (``.usd``/``.usdc``: binary crate,
``.usda``: text)."""


UP_AXIS_CONVENTIONS = {".obj": "y", ".glb": "y", ".gltf": "y", ".ply": "z", ".off": "z"}
"""The up axis of mesh files by extension: OBJ is y-up by convention (Blender's OBJ exporter by
default, Maya, the deformation-transfer animals), glTF y-up by its specification; PLY and OFF
have no convention and are mostly written by scanners and CAD tools, which are z-up."""


def conventional_up_axis(path) -> str:
    """The up axis (``"x"``, ``"y"`` or ``"z"``) a file's format implies.

    ``.usd``/``.usda``/``.usdc``: the stage's ``upAxis`` metadata (``"y"``, USD's default,
    when it is absent, the file cannot be opened or ``pxr`` is not installed); an existing
    ``.glb``: :func:`shellspline.io.gltf.glb_up_axis` (its node's rotation); other
    extensions:
    :data:`UP_AXIS_CONVENTIONS`, ``"z"`` for anything else.

    Examples
    --------
    >>> conventional_up_axis("horse-01.obj"), conventional_up_axis("cactus0.PLY")
    ('y', 'z')
    """
    ext = Path(path).suffix.lower()
    if ext in USD_EXTENSIONS:
        try:
            from pxr import Usd, UsdGeom
        except ImportError:
            return "y"
        try:
            stage = Usd.Stage.Open(str(path)) if Path(path).is_file() else None
        except Exception:  # pxr raises Tf.ErrorException on a damaged file: USD's default
            stage = None
        return str(UsdGeom.GetStageUpAxis(stage)).lower() if stage else "y"
    if ext == ".glb" and Path(path).is_file():  # z/x-up data carry a node rotation
        from .gltf import glb_up_axis

        return glb_up_axis(path)
    return UP_AXIS_CONVENTIONS.get(ext, "z")


def _pxr():
    try:
        from pxr import Sdf, Usd, UsdGeom, Vt
    except ImportError:
        raise UsdUnavailableError("USD needs the 'pxr' module: pip install 'shellspline[usd]' "
                                  "(the usd-core wheel)") from None
    return Sdf, Usd, UsdGeom, Vt


def require_usd() -> None:
    """Raise :class:`UsdUnavailableError` unless ``pxr`` imports (a check before computing)."""
    _pxr()


def write_usd(path, V, F=None, *, polygons=None, fps: float = 24.0, up_axis: str = "Y",
              start: int = 0, name: str = "shellspline") -> Path:
    """Write the poses ``V`` as a USD stage with one mesh and time-sampled points.

    Parameters
    ----------
    path : str or path-like
        The file to write; ``.usda`` gives a text layer, ``.usd``/``.usdc`` binary crate.
    V : (K+1,n,3) float array
        Poses (stored as float32 ``point3f[]``), frame ``k`` at time code ``start + k``.
    F : (m,3) int array, optional
        Triangles (zero-based); not used when ``polygons`` is given.
    polygons : tuple of ((p+1,) int array, (c,) int array), optional
        Polygon offsets and corner indices (CSR form, as in
        :class:`shellspline.io.SourceMesh`): written as they are.
    fps : float
        Frames per second: ``timeCodesPerSecond`` and ``framesPerSecond``.
    up_axis : {"y", "z"}
        The stage's up axis (USD knows only these two; either case).
    start : int
        Time code of frame 0.
    name : str
        Name of the mesh prim (a valid USD identifier).

    Returns
    -------
    pathlib.Path
        ``path``.

    Raises
    ------
    ShellsplineError
        For bad poses, faces, ``fps``, ``up_axis``, extension or prim name.
    UsdUnavailableError
        If ``pxr`` is not installed (extra ``usd``; an ImportError).

    Notes
    -----
    One ``Set`` per frame: USD's API takes time samples one at a time (~0.1 ms per frame
    of 10 000 points here), so the loop over frames is not the hot path.
    """
    p = Path(path)
    if p.suffix.lower() not in USD_EXTENSIONS:
        raise ShellsplineError(f"'{path}': a USD file must end in .usd, .usda or .usdc")
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0 or V.shape[1] == 0:
        raise ShellsplineError(f"V must be a (K+1,n,3) array of poses, got shape {V.shape}")
    big = ~(np.abs(V) <= np.finfo(np.float32).max)  # NaN, inf, or inf once stored as float32
    if big.any():
        k, i, _ = np.argwhere(big)[0]
        raise ShellsplineError(f"V must be finite and within float32 range, got "
                               f"{V[k, i].tolist()} at frame {k}, point {i}")
    n = V.shape[1]
    if polygons is not None:
        offsets, indices = (np.asarray(a, dtype=np.int64) for a in polygons)
        counts = np.diff(offsets)
    else:
        F = np.asarray(F if F is not None else np.zeros((0, 3), np.int64))
        if F.ndim != 2 or F.shape[1] != 3 or (F.size and not np.issubdtype(F.dtype, np.integer)):
            raise ShellsplineError(f"F must be an (m,3) integer array, got shape {F.shape} and "
                                   f"dtype {F.dtype}")
        indices = F.astype(np.int64).ravel()
        counts = np.full(F.shape[0], 3, dtype=np.int64)
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise ShellsplineError(f"faces index vertices outside [0, {n}): range "
                               f"[{indices.min()}, {indices.max()}]")
    fps = float(fps)
    if not (0 < fps < np.inf):
        raise ShellsplineError(f"fps must be a positive number, got {fps}")
    up = str(up_axis).upper()
    if up not in ("Y", "Z"):
        raise ShellsplineError(f"up_axis must be 'Y' or 'Z' (USD has no x-up stages), got "
                               f"{up_axis!r}")
    Sdf, Usd, UsdGeom, Vt = _pxr()
    if not Sdf.Path.IsValidIdentifier(name):
        raise ShellsplineError(f"name must be a USD identifier, got {name!r}")
    layer = Sdf.Layer.CreateAnonymous(p.suffix.lower())
    stage = Usd.Stage.Open(layer)
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y if up == "Y" else UsdGeom.Tokens.z)
    stage.SetTimeCodesPerSecond(fps)
    stage.SetFramesPerSecond(fps)
    start = int(start)
    K = V.shape[0] - 1
    stage.SetStartTimeCode(start)
    stage.SetEndTimeCode(start + K)
    mesh = UsdGeom.Mesh.Define(stage, Sdf.Path("/" + name))
    stage.SetDefaultPrim(mesh.GetPrim())
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(counts.astype(np.int32)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(indices.astype(np.int32)))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    V32 = V.astype(np.float32)
    lo, hi = V32.min(axis=1), V32.max(axis=1)
    points, extent = mesh.CreatePointsAttr(), mesh.CreateExtentAttr()
    points.Set(Vt.Vec3fArray.FromNumpy(V32[0]))
    extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([lo[0], hi[0]])))
    for k in range(K + 1):
        t = Usd.TimeCode(start + k)
        points.Set(Vt.Vec3fArray.FromNumpy(V32[k]), t)
        extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([lo[k], hi[k]])), t)

    def export(tmp):  # the temporary keeps the suffix: USD picks text or crate by it
        if not layer.Export(str(tmp)):
            raise ShellsplineError(f"cannot write USD file '{path}'")

    return write_atomically(p, export, shown=path)


def read_usd(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """Read the one mesh of a USD stage with its time-sampled points.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    V : (T,n,3) float64 numpy array
        Points at every authored time sample of ``points`` (in time order), or the default
        value alone (``T = 1``) when there are no samples; in world space (the prim's
        local-to-world transform at each of these times applied, the identity for the
        stages :func:`write_usd` writes).
    offsets : (p+1,) int64 numpy array
        Polygon offsets into ``indices``.
    indices : (c,) int64 numpy array
        Polygon corners, counter-clockwise about the front side (a ``leftHanded`` mesh, or
        one under a mirroring transform, has its corners reversed).
    info : dict
        ``times`` (list of time codes; empty when ``points`` has no samples), ``fps``
        (``timeCodesPerSecond``), ``up_axis`` (``"Y"``/``"Z"``), ``prim`` (the mesh's path).

    Raises
    ------
    ShellsplineError
        If the file cannot be opened, holds no mesh or more than one, its mesh has no points
        or no faces, its faces do not fit its points, or its topology changes over time
        (points changing in number, time-sampled faces that differ).
    UsdUnavailableError
        If ``pxr`` is not installed (an ImportError).

    Notes
    -----
    Only the points' time samples are read: a rigid motion carried by a transform alone
    (points without samples) is one pose.
    """
    Sdf, Usd, UsdGeom, Vt = _pxr()
    try:
        stage = Usd.Stage.Open(str(path))
    except Exception as exc:  # pxr raises Tf.ErrorException
        raise ShellsplineError(f"cannot open USD file '{path}': "
                               f"{str(exc).strip().splitlines()[-1]}") from None
    if stage is None:
        raise ShellsplineError(f"cannot open USD file '{path}'")
    prims = [q for q in stage.Traverse() if q.IsA(UsdGeom.Mesh)]
    if not prims:
        raise ShellsplineError(f"'{path}' holds no Mesh prim")
    if len(prims) > 1:
        shown = ", ".join(str(q.GetPath()) for q in prims[:3]) + (", ..." if len(prims) > 3
                                                                    else "")
        raise ShellsplineError(f"'{path}' holds {len(prims)} Mesh prims ({shown}); one mesh "
                               "per file is read")
    prim = prims[0]
    mesh = UsdGeom.Mesh(prim)
    pts = mesh.GetPointsAttr()
    times = list(pts.GetTimeSamples())
    codes = [Usd.TimeCode(t) for t in times] or [Usd.TimeCode.Default()]
    values = [pts.Get(c) for c in codes]
    if any(v is None for v in values):
        raise ShellsplineError(f"'{path}': the mesh {prim.GetPath()} has no points")
    frames = [np.asarray(v, dtype=np.float64).reshape(-1, 3) for v in values]
    sizes = sorted({f.shape[0] for f in frames})
    if len(sizes) != 1:
        raise ShellsplineError(f"'{path}': the topology of {prim.GetPath()} changes over time "
                               f"(its points change in number: {sizes[0]}..{sizes[-1]})")
    faces = []
    for attr in (mesh.GetFaceVertexCountsAttr(), mesh.GetFaceVertexIndicesAttr()):
        samples = attr.GetTimeSamples()
        first = attr.Get(codes[0])
        if first is not None and len(samples) > 1 and any(
                not np.array_equal(np.asarray(attr.Get(t)), np.asarray(first))
                for t in samples):
            raise ShellsplineError(f"'{path}': the topology of {prim.GetPath()} changes over "
                                   f"time ({attr.GetName()} differs between time samples)")
        faces.append(first)
    counts, indices = faces
    if counts is None or indices is None or len(counts) == 0:
        raise ShellsplineError(f"'{path}': the mesh {prim.GetPath()} has no faces "
                               "(faceVertexCounts / faceVertexIndices)")
    counts = np.asarray(counts, dtype=np.int64)
    indices = np.asarray(indices, dtype=np.int64)
    n = frames[0].shape[0]
    if counts.min() < 3 or counts.sum() != indices.size or indices.min() < 0 or \
            indices.max() >= n:
        raise ShellsplineError(f"'{path}': the faces of {prim.GetPath()} are inconsistent: "
                               f"{counts.size} faces of {counts.min()}..{counts.max()} corners, "
                               f"{indices.size} corner indices in [{indices.min()}, "
                               f"{indices.max()}] for {n} points")
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    V = np.stack(frames)
    xf = UsdGeom.Xformable(prim)
    M = np.stack([np.array(xf.ComputeLocalToWorldTransform(c)) for c in codes])  # row vectors
    if not np.array_equal(M, np.broadcast_to(np.eye(4), M.shape)):
        V = np.einsum("kni,kij->knj", V, M[:, :3, :3]) + M[:, None, 3, :3]
    mirrored = np.linalg.det(M[0, :3, :3]) < 0
    if (mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded) != mirrored:
        poly = np.repeat(np.arange(counts.size), counts)
        indices = indices[offsets[poly] + offsets[poly + 1] - 1 - np.arange(indices.size)]
    info = {"times": times, "fps": stage.GetTimeCodesPerSecond(),
            "up_axis": str(UsdGeom.GetStageUpAxis(stage)), "prim": str(prim.GetPath())}
    return V, offsets, indices, info
