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
play it as a loop. :func:`read_glb` reads such a file back (it is not a general glTF reader);
:func:`read_gltf_mesh` reads the one mesh of a glTF scene as a DCC tool exports it (a
keyframe).

Size: ``K × n × 3`` float32 per attribute, i.e. 12 bytes per vertex and frame for positions
(24 with normals), plus ``(K+1) × K`` animation weights.
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from ..mesh.geometry import vertex_normals
from .atomic import write_bytes_atomic

__all__ = ["glb_bytes", "write_glb", "read_glb", "glb_up_axis", "UP_ROTATIONS",
           "read_gltf_mesh", "GLTF_EXTENSIONS",
           "vertex_normals"]  # the last: mesh.geometry's

GLTF_EXTENSIONS = (".gltf", ".glb")
"""Extensions of the glTF files :func:`read_gltf_mesh` reads (JSON or binary)."""

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
        return _first_node_up(doc)
    except (OSError, ValueError, struct.error, AttributeError, IndexError, TypeError):
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


# ----------------------------------------------------------------------------------------
# Reading the mesh of a glTF scene (keyframe input)
# ----------------------------------------------------------------------------------------
_COMPONENTS = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def read_gltf_mesh(path) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The one mesh of a glTF 2.0 scene (``.gltf`` with its buffers, or ``.glb``) in world space.

    Parameters
    ----------
    path : str or path-like

    Returns
    -------
    V : (n,3) float64 numpy array
        The vertices of every triangle primitive of the mesh, primitive after primitive (an
        exporter writes one per material, each with its own vertices), moved by the world
        transform of its node (the node and its ancestors' ``matrix`` or TRS) and with the
        morph targets applied at their default weights (the node's ``weights``, else the
        mesh's: the shape the file shows).
    offsets : (m+1,) int64 numpy array
        Offsets of the triangles (every face has 3 corners).
    indices : (3m,) int64 numpy array
        Triangle corners: the primitive's ``indices``, or its vertices three by three when it
        has none; strips and fans are cut into triangles, point and line primitives are
        skipped. Under a mirroring transform the corners are reversed (counter-clockwise
        front faces in world space).
    info : dict
        ``mesh`` (its name, or ``mesh <i>``) and ``node`` (the node's name, or ``node <i>``).

    Raises
    ------
    ShellsplineError
        In one line naming the file: unreadable or not glTF 2.0, a missing or short buffer,
        no mesh in the scene or more than one mesh node, a skinned mesh (its positions are the
        bind pose, not the pose shown), compressed geometry (Draco, meshopt), a primitive
        whose index count is not a multiple of 3 or whose indices lie out of range.
    """
    import base64
    from urllib.parse import unquote

    name = str(path)
    p = Path(path)

    def bad(why):
        return ShellsplineError(f"cannot read '{name}': {why}")

    try:
        data = p.read_bytes()
    except OSError as exc:
        raise bad(exc.strerror or exc) from None
    try:
        chunk = None
        if data[:4] == b"glTF":
            _, version, total = struct.unpack_from("<III", data, 0)
            if version != 2:
                raise bad(f"glTF version {version}; only glTF 2.0 is read")
            jlen, jtype = struct.unpack_from("<II", data, 12)
            if jtype != _CHUNK_JSON:
                raise bad("the first chunk of the GLB file is not JSON")
            doc = json.loads(data[20:20 + jlen])
            at = 20 + jlen + (-jlen) % 4
            if at + 8 <= len(data):
                blen, btype = struct.unpack_from("<II", data, at)
                if btype == _CHUNK_BIN:
                    chunk = data[at + 8:at + 8 + blen]
        else:
            doc = json.loads(data.decode("utf-8-sig"))
        if not isinstance(doc, dict) or not str(doc.get("asset", {}).get("version", "")
                                                 ).startswith("2"):
            raise bad("not a glTF 2.0 file (asset.version is not 2.x)")
        packed = sorted({"KHR_draco_mesh_compression", "EXT_meshopt_compression",
                         "KHR_meshopt_compression"} & set(doc.get("extensionsUsed", [])))
        if packed:
            raise bad(f"its geometry is compressed ({packed[0]}); export it without "
                      "compression")
        buffers = []
        for b, buf in enumerate(doc.get("buffers", [])):
            uri = buf.get("uri")
            if uri is None:
                if chunk is None:
                    raise bad(f"buffer {b} has no uri and the file has no binary chunk")
                raw = chunk
            elif uri.startswith("data:"):
                raw = base64.b64decode(uri.split(",", 1)[1])
            else:
                try:
                    raw = (p.parent / unquote(uri)).read_bytes()
                except OSError as exc:
                    raise bad(f"buffer {b}: cannot read '{unquote(uri)}' "
                              f"({exc.strerror or exc})") from None
            if len(raw) < int(buf.get("byteLength", 0)):
                raise bad(f"buffer {b} holds {len(raw)} bytes, fewer than its byteLength "
                          f"{buf['byteLength']}")
            buffers.append(raw)

        def accessor(i) -> np.ndarray:
            a = doc["accessors"][i]
            dt = np.dtype(_COMPONENTS[a["componentType"]])
            width, count = _WIDTHS[a["type"]], int(a["count"])
            if "bufferView" in a:
                v = doc["bufferViews"][a["bufferView"]]
                raw = buffers[v["buffer"]]
                start = v.get("byteOffset", 0) + a.get("byteOffset", 0)
                stride = v.get("byteStride") or width * dt.itemsize
                end = start + (count - 1) * stride + width * dt.itemsize if count else start
                if end > v.get("byteOffset", 0) + v["byteLength"] or end > len(raw):
                    raise bad(f"accessor {i} reaches past the end of its buffer view")
                arr = np.ndarray((count, width), dtype=dt, buffer=raw, offset=start,
                                 strides=(stride, dt.itemsize)).astype(np.float64)
            else:
                arr = np.zeros((count, width))
            if "sparse" in a:
                sp = a["sparse"]
                k = int(sp["count"])
                iv, vv = sp["indices"], sp["values"]
                idt = np.dtype(_COMPONENTS[iv["componentType"]])
                ib = doc["bufferViews"][iv["bufferView"]]
                vb = doc["bufferViews"][vv["bufferView"]]
                where = np.frombuffer(buffers[ib["buffer"]], idt, k,
                                      ib.get("byteOffset", 0) + iv.get("byteOffset", 0))
                vals = np.frombuffer(buffers[vb["buffer"]], dt, k * width,
                                     vb.get("byteOffset", 0) + vv.get("byteOffset", 0))
                arr[where.astype(np.int64)] = vals.reshape(k, width)
            if a.get("normalized") and dt.kind in "iu":  # the sparse values too
                arr = np.maximum(arr / np.iinfo(dt).max, -1.0)
            return arr

        # the scene's nodes with a mesh, depth first, with their world transforms
        nodes = doc.get("nodes", [])
        scenes = doc.get("scenes")
        if scenes:
            roots = scenes[doc.get("scene", 0)].get("nodes", [])
        else:
            children = {c for nd in nodes for c in nd.get("children", [])}
            roots = [i for i in range(len(nodes)) if i not in children]
        found, stack = [], [(i, np.eye(4)) for i in reversed(roots)]
        while stack:
            i, parent = stack.pop()
            nd = nodes[i]
            M = parent @ _node_matrix(nd)
            if "mesh" in nd:
                found.append((i, M))
            stack += [(c, M) for c in reversed(nd.get("children", []))]
        if not found:
            raise ShellsplineError(f"'{name}' holds no mesh in its scene")
        if len(found) > 1:
            shown = ", ".join(nodes[i].get("name") or f"node {i}" for i, _ in found[:3])
            raise ShellsplineError(f"'{name}' holds {len(found)} mesh nodes ({shown}"
                                   f"{', ...' if len(found) > 3 else ''}); one mesh per file "
                                   "is read (join them into one object before export)")
        i, M = found[0]
        nd = nodes[i]
        mesh = doc["meshes"][nd["mesh"]]
        where = f"mesh '{mesh.get('name') or nd['mesh']}'"
        if "skin" in nd:
            raise ShellsplineError(f"'{name}': {where} is skinned (glTF skin): its vertex "
                                   "positions are the bind pose, not the pose shown; export "
                                   "the deformed mesh (Blender: glTF export without "
                                   "Skinning, modifiers applied)")
        weights = nd.get("weights", mesh.get("weights"))
        Vs, faces, base = [], [], 0
        for k, prim in enumerate(mesh["primitives"]):
            mode = prim.get("mode", 4)
            if mode not in (4, 5, 6):
                continue  # points and lines: nothing the shell model can use
            X = accessor(prim["attributes"]["POSITION"])[:, :3]
            for t, target in enumerate(prim.get("targets", [])):
                w = float(weights[t]) if weights is not None and t < len(weights) else 0.0
                if w != 0.0 and "POSITION" in target:
                    X = X + w * accessor(target["POSITION"])[:, :3]
            n = X.shape[0]
            idx = (accessor(prim["indices"])[:, 0] if "indices" in prim
                   else np.arange(n, dtype=np.float64)).astype(np.int64)
            if mode == 4:
                if idx.size % 3:
                    raise ShellsplineError(f"'{name}': primitive {k} of {where} has "
                                           f"{idx.size} triangle indices, not a multiple of 3")
                T = idx.reshape(-1, 3)
            elif mode == 5:  # strip: every other triangle turned to keep the winding
                j = np.arange(max(idx.size - 2, 0))
                T = np.stack([idx[j + (j % 2)], idx[j + 1 - (j % 2)], idx[j + 2]], axis=1)
            else:            # fan about the first vertex
                j = np.arange(1, max(idx.size - 1, 1))
                T = np.stack([np.full(j.size, idx[0] if idx.size else 0), idx[j], idx[j + 1]],
                             axis=1)
            if T.size and (T.min() < 0 or T.max() >= n):
                raise ShellsplineError(f"'{name}': primitive {k} of {where} indexes vertex "
                                       f"{int(T.max())} of its {n}")
            Vs.append(X)
            faces.append(T + base)
            base += n
    except ShellsplineError:
        raise
    except (ValueError, KeyError, IndexError, TypeError, struct.error, OverflowError) as exc:
        raise bad(f"malformed glTF ({type(exc).__name__}: {exc})") from None
    V = np.concatenate(Vs) if Vs else np.zeros((0, 3))
    F = np.concatenate(faces) if faces else np.zeros((0, 3), dtype=np.int64)
    if not np.array_equal(M, np.eye(4)):
        V = V @ M[:3, :3].T + M[:3, 3]
        if np.linalg.det(M[:3, :3]) < 0:
            F = F[:, ::-1]
    up = _first_node_up(doc) if data[:4] == b"glTF" else "y"
    if up != "y":
        # the GLB says its data are z-up (x-up) by the rotation of its first node, as
        # glb_up_axis reads it and our writer puts it: the positions in that frame, so that
        # the file's up axis (shellspline.io.usd.conventional_up_axis) describes them and a
        # GLB we wrote reads back as the poses it holds
        V = V @ _quat_matrix(UP_ROTATIONS[up])
    offsets = np.arange(F.shape[0] + 1, dtype=np.int64) * 3
    return V, offsets, np.ascontiguousarray(F).ravel(), {
        "mesh": mesh.get("name") or f"mesh {nd['mesh']}", "node": nd.get("name") or f"node {i}"}


def _first_node_up(doc) -> str:
    """``"z"`` or ``"x"`` where the first node of a glTF document carries the rotation of
    :data:`UP_ROTATIONS` for that axis and holds a mesh (its own, or a descendant's: the
    rotation moves the mesh data), else ``"y"``. (A DCC tool's first node may be a camera or
    a light: one added in Blender looks down with just that rotation, and turned the mesh.)"""
    nodes = doc.get("nodes") or [{}]
    rot = nodes[0].get("rotation") if isinstance(nodes[0], dict) else None
    if rot is None or not _holds_mesh(nodes, 0):
        return "y"
    for axis, q in UP_ROTATIONS.items():
        if q is not None and np.allclose(rot, q, atol=1e-7):
            return axis
    return "y"


def _holds_mesh(nodes, first: int) -> bool:
    """Whether the node ``first`` or one of its descendants has a mesh (children that are
    not nodes skipped, a cycle walked once)."""
    seen, todo = set(), [first]
    while todo:
        i = todo.pop()
        if not isinstance(i, int) or not 0 <= i < len(nodes) or i in seen or \
                not isinstance(nodes[i], dict):
            continue
        if "mesh" in nodes[i]:
            return True
        seen.add(i)
        children = nodes[i].get("children")
        todo += children if isinstance(children, list) else []
    return False


def _quat_matrix(q) -> np.ndarray:
    """The rotation matrix of a glTF quaternion ``[x, y, z, w]``."""
    return _node_matrix({"rotation": q})[:3, :3]


def _node_matrix(node: dict) -> np.ndarray:
    """The local transform (4x4, column vectors) of a glTF node: ``matrix`` (column-major)
    or translation x rotation (quaternion ``[x, y, z, w]``) x scale."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    x, y, z, w = (float(c) for c in node.get("rotation", (0.0, 0.0, 0.0, 1.0)))
    q = np.array([x, y, z, w])
    q = q / (np.linalg.norm(q) or 1.0)
    x, y, z, w = q
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    M = np.eye(4)
    M[:3, :3] = R * np.asarray(node.get("scale", (1.0, 1.0, 1.0)), dtype=np.float64)
    M[:3, 3] = node.get("translation", (0.0, 0.0, 0.0))
    return M
