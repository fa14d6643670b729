"""Binary glTF 2.0 (GLB) export of a pose sequence as morph-target animation.

Written by hand with :mod:`struct` and :mod:`json` (no dependency). The file holds

* one mesh whose base shape is frame 0 (``POSITION`` float32, ``indices`` uint32, optionally
  smooth vertex ``NORMAL`` s),
* one morph target per later frame ``k = 1..K``: ``POSITION`` deltas ``V[k] − V[0]`` (and
  ``NORMAL`` deltas), named ``frame_0001 …`` in ``mesh.extras.targetNames`` (Blender reads
  these as shape-key names),
* one animation with a ``weights`` channel: at time ``k / fps`` the weight of target ``k`` is
  1 and all others 0 (frame 0: all 0). ``LINEAR`` interpolation blends consecutive frames
  linearly in between; ``STEP`` holds each frame.

Standard viewers (Blender, three.js / the glTF sample viewers, Babylon.js, Windows 3D Viewer)
play it as a loop. :func:`read_glb` reads such a file back (it is not a general glTF reader).

Size: ``K × n × 3`` float32 per attribute, i.e. 12 bytes per vertex and frame for positions
(24 with normals), plus ``(K+1) × K`` animation weights.
"""
from __future__ import annotations

import json
import struct

import numpy as np

from ..errors import ShellsplineError
from ..mesh.geometry import vertex_normals
from .atomic import write_bytes_atomic

__all__ = ["glb_bytes", "write_glb", "read_glb", "glb_up_axis", "UP_ROTATIONS",
           "vertex_normals"]  # the last: mesh.geometry's

_GLB_MAGIC = 0x46546C67  # b"glTF"
_CHUNK_JSON = 0x4E4F534A  # b"JSON"
_CHUNK_BIN = 0x004E4942  # b"BIN\0"
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963


UP_ROTATIONS = {"y": None,
                "z": [-0.7071067811865476, 0.0, 0.0, 0.7071067811865476],
                "x": [0.0, 0.0, 0.7071067811865476, 0.7071067811865476]}
"""Node rotation (glTF quaternion ``[x, y, z, w]``) that turns data whose up axis is the key
onto glTF's y-up: −90° about x for z-up (``(x, y, z) → (x, z, −y)``), +90° about z for x-up."""


def _up_node(up_axis) -> dict:
    if up_axis not in UP_ROTATIONS:
        raise ShellsplineError(f"up_axis must be one of 'y', 'z', 'x', got {up_axis!r}")
    q = UP_ROTATIONS[up_axis]
    return {} if q is None else {"rotation": q}


def glb_up_axis(path) -> str:
    """The up axis of the vertex data of a GLB file: ``"z"`` or ``"x"`` when its first node
    carries the matching rotation of :data:`UP_ROTATIONS` (as :func:`glb_bytes` writes for
    such data), else ``"y"`` (glTF's convention; also for a file that cannot be read).

    Examples
    --------
    >>> import os, tempfile, numpy as np
    >>> V = np.array([[[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]])
    >>> p = os.path.join(tempfile.mkdtemp(), "z.glb")
    >>> write_glb(p, V, [[0, 1, 2]], up_axis="z")
    >>> glb_up_axis(p), glb_up_axis(os.path.join(tempfile.mkdtemp(), "missing.glb"))
    ('z', 'y')
    """
    try:
        with open(path, "rb") as fh:
            head = fh.read(20)
            magic, version, _ = struct.unpack_from("<III", head, 0)
            jlen, jtype = struct.unpack_from("<II", head, 12)
            if magic != _GLB_MAGIC or jtype != _CHUNK_JSON:
                return "y"
            doc = json.loads(fh.read(jlen))
        rot = (doc.get("nodes") or [{}])[0].get("rotation")
    except (OSError, ValueError, struct.error, AttributeError, IndexError):
        return "y"
    for axis, q in UP_ROTATIONS.items():
        if q is not None and rot is not None and np.allclose(rot, q, atol=1e-7):
            return axis
    return "y"


def glb_bytes(V, F, *, fps: float = 24.0, interpolation: str = "LINEAR", normals: bool = True,
              name: str = "shellspline", up_axis: str = "y") -> bytes:
    """The bytes of a GLB file that animates the poses ``V`` by morph targets.

    Parameters
    ----------
    V : (K+1,n,3) float array
        Poses; frame 0 is the base mesh, frames ``1..K`` become morph targets.
    F : (m,3) int array
        Triangles (counter-clockwise seen from outside = front faces in glTF).
    fps : float
        Frames per second of the animation: frame ``k`` is shown at ``t = k / fps``.
    interpolation : {"LINEAR", "STEP"}
        Animation sampler interpolation between frames.
    normals : bool
        Also store smooth vertex normals (base and per-target deltas); without them viewers
        shade flat. A vertex without a defined normal (no face uses it, or its face normals
        cancel) gets ``(0, 0, 1)``: glTF requires unit normals.
    name : str
        Name of the mesh, node and animation.
    up_axis : {"y", "z", "x"}
        The up axis of ``V``'s coordinates. glTF is y-up (specification §3.4); for z- or x-up
        data the node gets the rotation (:data:`UP_ROTATIONS`) that turns the data's up onto
        glTF's +y, so viewers show the scene standing. The vertex data stay in the input's
        coordinates (:func:`read_glb` gives them back unchanged; :func:`glb_up_axis` reads the
        axis back from the node).

    Returns
    -------
    bytes

    Raises
    ------
    ShellsplineError
        For bad shapes, non-finite coordinates, out-of-range faces or a bad ``fps`` /
        ``interpolation``.
    """
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0 or V.shape[1] == 0:
        raise ShellsplineError(f"V must be a (K+1,n,3) array of poses, got shape {V.shape}")
    if not np.isfinite(V).all():
        raise ShellsplineError("V has NaN/inf coordinates; cannot write a GLB file")
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or F.shape[0] == 0 or not np.issubdtype(F.dtype, np.integer):
        raise ShellsplineError(f"F must be a non-empty (m,3) integer array, got shape {F.shape} "
                               f"and dtype {F.dtype}")
    n = V.shape[1]
    if F.min() < 0 or F.max() >= n:
        raise ShellsplineError(f"F indexes vertices outside [0, {n})")
    fps = float(fps)
    if not np.isfinite(fps) or fps <= 0:
        raise ShellsplineError(f"fps must be a positive number, got {fps!r}")
    interp = str(interpolation).upper()
    if interp not in ("LINEAR", "STEP"):
        raise ShellsplineError(f"interpolation must be 'LINEAR' or 'STEP', got {interpolation!r}")
    K = V.shape[0] - 1

    bin_parts: list[bytes] = []
    views: list[dict] = []
    accessors: list[dict] = []
    offset = 0

    def add(arr: np.ndarray, *, ctype: int, atype: str, target: int | None,
            minmax: bool) -> int:
        nonlocal offset
        data = np.ascontiguousarray(arr).tobytes()
        view = {"buffer": 0, "byteOffset": offset, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        pad = (-len(data)) % 4
        bin_parts.append(data + b"\0" * pad)
        offset += len(data) + pad
        count = arr.shape[0]
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": int(count),
               "type": atype}
        if minmax:
            a2 = arr.reshape(count, -1)
            acc["min"] = [float(x) for x in a2.min(axis=0)]
            acc["max"] = [float(x) for x in a2.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    base = V[0].astype(np.float32)
    i_idx = add(F.astype(np.uint32).ravel(), ctype=_UINT, atype="SCALAR",
                target=_ELEMENT_ARRAY_BUFFER, minmax=True)
    attributes = {"POSITION": add(base, ctype=_FLOAT, atype="VEC3", target=_ARRAY_BUFFER,
                                  minmax=True)}
    N = None
    if normals:
        N = vertex_normals(V, F)
        # glTF requires unit normals: a vertex that no face uses, or whose face normals
        # cancel, gets +z instead of the zero vector
        N[~np.any(N, axis=-1)] = (0.0, 0.0, 1.0)
        N = N.astype(np.float32)
        attributes["NORMAL"] = add(N[0], ctype=_FLOAT, atype="VEC3", target=_ARRAY_BUFFER,
                                   minmax=False)
    targets = []
    for k in range(1, K + 1):
        # deltas in float32 from the float32 base: base + delta reproduces float32(V[k]) up to
        # one rounding of the sum
        d = (V[k] - base.astype(np.float64)).astype(np.float32)
        t = {"POSITION": add(d, ctype=_FLOAT, atype="VEC3", target=_ARRAY_BUFFER, minmax=True)}
        if N is not None:
            t["NORMAL"] = add(N[k] - N[0], ctype=_FLOAT, atype="VEC3", target=_ARRAY_BUFFER,
                              minmax=False)
        targets.append(t)

    primitive = {"attributes": attributes, "indices": i_idx, "mode": 4, "material": 0}
    if targets:
        primitive["targets"] = targets
    mesh = {"name": name, "primitives": [primitive]}
    doc = {
        "asset": {"version": "2.0", "generator": "shellspline"},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [dict({"mesh": 0, "name": name}, **_up_node(up_axis))],
        "meshes": [mesh],
        "materials": [{"name": "shell", "doubleSided": True,
                       "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.55, 0.3, 1.0],
                                                "metallicFactor": 0.0,
                                                "roughnessFactor": 0.6}}],
    }
    if targets:
        mesh["weights"] = [0.0] * K
        mesh["extras"] = {"targetNames": [f"frame_{k:04d}" for k in range(1, K + 1)]}
        times = (np.arange(K + 1) / fps).astype(np.float32)
        W = np.zeros((K + 1, K), dtype=np.float32)
        W[np.arange(1, K + 1), np.arange(K)] = 1.0
        i_t = add(times, ctype=_FLOAT, atype="SCALAR", target=None, minmax=True)
        i_w = add(W.ravel(), ctype=_FLOAT, atype="SCALAR", target=None, minmax=False)
        doc["animations"] = [{"name": name,
                              "samplers": [{"input": i_t, "output": i_w,
                                            "interpolation": interp}],
                              "channels": [{"sampler": 0,
                                            "target": {"node": 0, "path": "weights"}}]}]
        doc["extras"] = {"fps": fps, "frames": K + 1}
    doc["buffers"] = [{"byteLength": offset}]
    doc["bufferViews"] = views
    doc["accessors"] = accessors

    js = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    js += b" " * ((-len(js)) % 4)
    binary = b"".join(bin_parts)
    total = 12 + 8 + len(js) + 8 + len(binary)
    return b"".join([struct.pack("<III", _GLB_MAGIC, 2, total),
                     struct.pack("<II", len(js), _CHUNK_JSON), js,
                     struct.pack("<II", len(binary), _CHUNK_BIN), binary])


def write_glb(path, V, F, *, fps: float = 24.0, interpolation: str = "LINEAR",
              normals: bool = True, up_axis: str = "y") -> None:
    """Write :func:`glb_bytes` to ``path`` atomically (:mod:`shellspline.io.atomic`).

    Parameters
    ----------
    path : str or path-like
    V, F, fps, interpolation, normals, up_axis
        As for :func:`glb_bytes`.

    Examples
    --------
    >>> import os, tempfile, numpy as np, trimesh
    >>> m = trimesh.creation.icosphere(subdivisions=1)
    >>> V = np.stack([m.vertices * s for s in (1.0, 1.2, 1.5)])
    >>> p = os.path.join(tempfile.mkdtemp(), "a.glb")
    >>> write_glb(p, V, m.faces, fps=12)
    >>> V2, F2, fps = read_glb(p)
    >>> V2.shape, F2.shape, fps, bool(np.allclose(V2, V, atol=1e-6))
    ((3, 42, 3), (80, 3), 12.0, True)
    """
    write_bytes_atomic(path, glb_bytes(V, F, fps=fps, interpolation=interpolation,
                                       normals=normals, up_axis=up_axis))


def read_glb(path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read the poses back from a GLB file written by :func:`write_glb`.

    Only the layout this module writes is understood (one mesh, one primitive, morph targets
    with one-hot animation weights); positions come back as float64 of the float32 data.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    V : (K+1,n,3) float64 array
    F : (m,3) int64 array
    fps : float
        From the animation times (24 when there is a single frame).

    Raises
    ------
    ShellsplineError
        If the file is not such a GLB file.
    """
    name = str(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise ShellsplineError(f"cannot read '{name}': {exc.strerror or exc}") from None
    try:
        magic, version, total = struct.unpack_from("<III", data, 0)
        if magic != _GLB_MAGIC or version != 2 or total != len(data):
            raise ValueError("not a glTF 2.0 binary file")
        jlen, jtype = struct.unpack_from("<II", data, 12)
        if jtype != _CHUNK_JSON:
            raise ValueError("first chunk is not JSON")
        doc = json.loads(data[20:20 + jlen])
        blen, btype = struct.unpack_from("<II", data, 20 + jlen)
        if btype != _CHUNK_BIN:
            raise ValueError("second chunk is not BIN")
        binary = memoryview(data)[28 + jlen:28 + jlen + blen]

        def acc(i):
            a = doc["accessors"][i]
            v = doc["bufferViews"][a["bufferView"]]
            dt = {_FLOAT: "<f4", _UINT: "<u4"}[a["componentType"]]
            width = {"SCALAR": 1, "VEC3": 3}[a["type"]]
            start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
            arr = np.frombuffer(binary, dtype=dt, count=a["count"] * width, offset=start)
            return arr.reshape(a["count"], width) if width > 1 else arr

        prim = doc["meshes"][0]["primitives"][0]
        base = acc(prim["attributes"]["POSITION"]).astype(np.float64)
        F = acc(prim["indices"]).astype(np.int64).reshape(-1, 3)
        # sum in float32, as a viewer does
        poses = [base] + [(acc(t["POSITION"]) + base.astype(np.float32)).astype(np.float64)
                          for t in prim.get("targets", [])]
        fps = float(doc.get("extras", {}).get("fps", 24.0))
        anims = doc.get("animations") or []
        if anims and "fps" not in doc.get("extras", {}):
            times = acc(anims[0]["samplers"][0]["input"])
            if times.size > 1 and times[1] > 0:
                fps = float(np.round(1.0 / float(times[1]), 6))
    except (ValueError, KeyError, IndexError, TypeError, struct.error) as exc:
        raise ShellsplineError(f"cannot read '{name}': {exc}") from None
    return np.stack(poses), F, fps
