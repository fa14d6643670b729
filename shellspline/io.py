"""Reading keyframe meshes and writing interpolated sequences.

Everything that touches the file system lives here. Keyframes are validated once, at
:func:`read_keyframes` / :func:`keyframes_from_arrays`; every problem is reported as a
one-line :class:`~shellspline._errors.MeshError` that names the file (or the argument) and
what was found, never as a traceback from inside numpy or trimesh.

Formats
-------
* **OBJ** is parsed by a small vectorised reader of our own: ``v`` and ``f`` lines only,
  polygons of any size, ``f a/b/c`` and negative (relative) indices understood, a UTF-8
  byte-order mark skipped, texture coordinates, normals, ``o/g/s/usemtl/mtllib/l/vp`` lines
  ignored. trimesh's OBJ loader is not used because, even with ``process=False``, it drops
  vertices no face uses (unless ``maintain_order=True``), splits vertices at texture/normal
  seams, needs Pillow for any file with ``vt`` lines, and triangulates polygons per file.
* **PLY** (ASCII and binary) and **OFF** are read with
  ``trimesh.load(path, process=False)``, which keeps the vertex order and merges nothing.
  trimesh triangulates polygons per file (and reorders the faces of files that mix triangles
  and polygons), so when the face count declared in the header differs from the number of
  triangles loaded the polygons are taken from the file itself (PLY: trimesh's raw element
  data; OFF: the face lines).

Polygons are triangulated once for the whole keyframe set, seams welded and fin faces and
isolated vertices set aside for the solve (:mod:`shellspline.source_mesh`); the map back to
the input is :attr:`Keyframes.source`.

Output: :func:`write_sequence` writes ``frame_0000.obj ... frame_K.obj`` (or binary
little-endian PLY with ``double`` coordinates) and ``report.json`` atomically: all files go
into a temporary sibling directory which is renamed into place at the end.
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import secrets
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._errors import MeshError, ShellsplineError, tol
from .source_mesh import SourceMesh, solve_mesh, triangulate_polygons
from .topology import Topology, topology

__all__ = [
    "Keyframes",
    "read_mesh",
    "read_keyframes",
    "keyframes_from_arrays",
    "read_indices",
    "read_frames",
    "write_sequence",
    "check_output_dir",
    "read_sequence",
    "MESH_EXTENSIONS",
]

MESH_EXTENSIONS = (".obj", ".off", ".ply")
"""File extensions :func:`read_mesh` understands (case-insensitive)."""

_FRAME_RE = re.compile(r"^frame_(\d+)\.(obj|ply)$")
GLB_NAME = "animation.glb"
"""File name of the sequence in an output directory written with ``fmt="glb"``."""


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
# Reading single meshes
# ----------------------------------------------------------------------------------------
class _Unreadable(Exception):
    """Internal: a file cannot be parsed; the message is the reason."""


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh from an OBJ, PLY or OFF file as triangles, keeping the vertex order.

    Nothing is merged, reordered or dropped (vertices no face uses are kept). Coordinates
    are returned as float64 (float32 PLY data is converted exactly). Polygons are
    triangulated by :func:`shellspline.source_mesh.triangulate_polygons` on this one pose
    (:func:`read_keyframes` triangulates once for all keyframes instead). Only parsing
    problems are checked here; see :func:`read_keyframes` for the geometric checks.

    Parameters
    ----------
    path : str or path-like
        A ``.obj``, ``.ply`` (ASCII or binary) or ``.off`` file.

    Returns
    -------
    V : (n,3) float64 numpy array
        Vertex positions.
    F : (m,3) int64 numpy array
        Triangles, zero-based vertex indices.

    Raises
    ------
    MeshError
        "cannot read '<path>': <reason>" if the file is missing, unreadable, malformed or
        has an unknown extension; "<path>: ... separate objects" for a multi-object scene;
        "<path>: ... face indices must lie in [0, n)" for an index out of range.

    Examples
    --------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> p = os.path.join(d, "tri.obj")
    >>> _ = open(p, "w").write("v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf 1 2 3\\n")
    >>> V, F = read_mesh(p)
    >>> V.shape, F.tolist()
    ((3, 3), [[0, 1, 2]])
    """
    V, offsets, indices, _ = _read_polygons(path)
    name = str(path)
    _check_indices(offsets, indices, V.shape[0], name)
    F, _ = triangulate_polygons(V[None], offsets, indices, name)
    return V, F


def _read_polygons(path):
    """``V (n,3)``, polygon ``offsets (P+1,)``, corner ``indices (N,)`` of a mesh file and its
    texture coordinates ``(uv (t,2), corner_uv (N,))`` or ``None`` (OBJ ``f v/vt`` only)."""
    name = str(path)
    p = Path(path)
    ext = p.suffix.lower()
    if ext not in MESH_EXTENSIONS:
        raise MeshError(f"cannot read '{name}': unknown extension '{p.suffix}' "
                        f"(supported: {', '.join(MESH_EXTENSIONS)})")
    try:
        if not p.exists():
            raise _Unreadable("no such file")
        if p.is_dir():
            raise _Unreadable("is a directory")
        if ext == ".obj":
            V, offsets, indices, uv = _parse_obj(p.read_bytes(), name)
        else:
            (V, offsets, indices), uv = _read_with_trimesh(p, ext, name), None
    except MeshError:
        raise
    except _Unreadable as exc:
        raise MeshError(f"cannot read '{name}': {exc}") from None
    except OSError as exc:
        raise MeshError(f"cannot read '{name}': {exc.strerror or exc}") from None
    except Exception as exc:  # trimesh raises many kinds; report one line, no traceback
        raise MeshError(f"cannot read '{name}': {_one_line(exc)}") from None
    return V, offsets, indices, uv


def _check_indices(offsets: np.ndarray, indices: np.ndarray, n: int, name: str) -> None:
    """Polygon corners must be vertices; a polygon must not repeat a vertex."""
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        raise MeshError(f"{name}: face indices must lie in [0, {n}), got range "
                        f"[{indices.min()}, {indices.max()}]")
    sizes = np.diff(offsets)
    if sizes.size and (sizes == 3).all():
        F = indices.reshape(-1, 3)
        bad = (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    else:
        key = np.sort(np.repeat(np.arange(sizes.size), sizes) * np.int64(max(n, 1)) + indices)
        bad = np.zeros(sizes.size, dtype=bool)
        bad[key[1:][key[1:] == key[:-1]] // max(n, 1)] = True
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise MeshError(f"{name}: face {t} {indices[offsets[t]:offsets[t + 1]].tolist()} "
                        f"repeats a vertex ({int(bad.sum())} such faces)")


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    if len(text) > 200:
        text = text[:197] + "..."
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _parse_obj(data: bytes, name: str):
    """Vectorised OBJ reader: ``v``, ``vt`` and ``f`` lines, global numbering; returns ``V``,
    polygon offsets, corner indices and the texture coordinates (see :func:`_obj_texture`)."""
    if data[:3] == b"\xef\xbb\xbf":  # UTF-8 byte-order mark (Windows editors, exporters)
        data = data[3:]
    if b"\0" in data:
        raise _Unreadable("binary data in a text OBJ file")
    if b"\\\n" in data or b"\\\r\n" in data:  # line continuations
        data = re.sub(rb"\\\r?\n", b" ", data)
    lines = data.splitlines()
    if b"#" in data:
        lines = [ln[:ln.find(b"#")] if b"#" in ln else ln for ln in lines]
    if b"\t" in data or b"\n " in data or b"\r " in data or data[:1] == b" ":
        lines = [ln.strip().replace(b"\t", b" ") for ln in lines]
    vlines = [ln for ln in lines if ln[:2] == b"v "]
    flines = [ln for ln in lines if ln[:2] == b"f "]
    vtlines = [ln for ln in lines if ln[:3] == b"vt "] if b"vt " in data else []
    V = _obj_vertices(vlines)
    offsets, indices, ttok = _obj_faces(flines, lines, name, slashes=b"/" in data,
                                        texture=bool(vtlines))
    uv = None if ttok is None else _obj_texture(vtlines, ttok, offsets, lines)
    return V, offsets, indices, uv


def _obj_texture(vtlines: list[bytes], ttok: list[bytes], offsets: np.ndarray,
                 lines: list[bytes]):
    """``(uv (t,2), corner_uv (N,))`` when every face corner names a valid texture
    coordinate (``f v/vt ...``), else ``None`` (texture coordinates are then not carried)."""
    if not all(ttok):
        return None
    try:
        ti = np.array(list(map(int, ttok)), dtype=np.int64)
        tokens = _regular_tokens(vtlines, 3)  # "vt u v" everywhere: the fast path
        if tokens is not None:
            del tokens[::3]
            uv = np.array(list(map(float, tokens)), dtype=np.float64).reshape(-1, 2)
        else:
            uv = np.array([[float(x) for x in (ln.split()[1:3] + [b"0"])[:2]]
                           for ln in vtlines], dtype=np.float64).reshape(-1, 2)
    except ValueError:
        return None
    if (ti < 0).any():  # relative: counted back from the last vt line before the face line
        kinds = [ln[:3] for ln in lines if ln[:3] == b"vt " or ln[:2] == b"f "]
        is_t = np.array([k == b"vt " for k in kinds])
        before = np.repeat(np.cumsum(is_t)[~is_t], np.diff(offsets))
        ti = np.where(ti < 0, ti + before, ti - 1)
    else:
        ti -= 1
    if ti.size and (ti.min() < 0 or ti.max() >= uv.shape[0]):
        return None
    return uv, ti


def _regular_tokens(rows: list[bytes], width: int) -> list[bytes] | None:
    """Tokens of ``rows`` if every row has exactly ``width`` tokens, else ``None``."""
    tokens = b" ".join(rows).split()
    if len(tokens) != width * len(rows):
        return None
    key = rows[0].split(None, 1)[0] if rows else b""
    # a row with a wrong token count shifts the keyword out of every later slot
    if tokens[::width].count(key) != len(rows):
        return None
    return tokens


def _obj_vertices(vlines: list[bytes]) -> np.ndarray:
    if not vlines:
        return np.zeros((0, 3))
    tokens = _regular_tokens(vlines, 4)
    if tokens is not None:
        del tokens[::4]
    else:
        tokens = []
        for i, ln in enumerate(vlines):
            t = ln.split()
            if len(t) < 4:
                raise _Unreadable(f"vertex {i + 1} has {len(t) - 1} coordinates, expected 3")
            tokens.extend(t[1:4])  # extra values (w, colours) are ignored
    try:
        return np.array(list(map(float, tokens)), dtype=np.float64).reshape(-1, 3)
    except ValueError:
        for i in range(0, len(tokens), 3):
            try:
                list(map(float, tokens[i:i + 3]))
            except ValueError:
                bad = b" ".join(tokens[i:i + 3]).decode("ascii", "replace")
                raise _Unreadable(f"vertex {i // 3 + 1} has non-numeric coordinates "
                                  f"'{bad}'") from None
        raise  # pragma: no cover


def _obj_faces(flines: list[bytes], lines: list[bytes], name: str, *, slashes: bool,
               texture: bool = False):
    """Polygon offsets and vertex indices of the ``f`` lines, and (with ``texture``) every
    corner's texture-index token (``b""`` where a corner has none) or ``None``."""
    if not flines:
        return np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), None
    tokens = _regular_tokens(flines, 4)
    if tokens is not None:  # triangles only: the fast path
        del tokens[::4]
        sizes = None
    else:  # polygons: every face line starts with the token b"f", no index token is b"f"
        tokens = b" ".join(flines).split()
        starts = [i for i, t in enumerate(tokens) if t == b"f"]
        sizes = np.diff(np.array(starts + [len(tokens)], dtype=np.int64)) - 1
        if (sizes < 3).any():
            t = int(np.flatnonzero(sizes < 3)[0])
            raise _Unreadable(f"face {t} on line {_line_number(lines, t)} has {sizes[t]} "
                              "vertices (a face needs at least 3)")
        tokens = [t for t in tokens if t != b"f"]
    ttok = None
    if slashes and texture:
        parts = [t.split(b"/", 2) for t in tokens]
        tokens = [q[0] for q in parts]
        ttok = [q[1] if len(q) > 1 else b"" for q in parts]
    elif slashes:
        tokens = [t.split(b"/", 1)[0] for t in tokens]
    try:
        idx = np.array(list(map(int, tokens)), dtype=np.int64)
    except ValueError:
        bad = next(t for t in tokens if not re.fullmatch(rb"[+-]?\d+", t))
        raise _Unreadable(f"face index '{bad.decode('ascii', 'replace')}' is not an "
                          "integer") from None
    if sizes is None:
        sizes = np.full(len(flines), 3, dtype=np.int64)
    offsets = np.zeros(sizes.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    if (idx == 0).any():
        t = int(np.searchsorted(offsets, np.flatnonzero(idx == 0)[0], side="right") - 1)
        raise _Unreadable(f"face {t} uses vertex index 0 (OBJ indices start at 1)")
    neg = idx < 0
    if neg.any():
        # relative indices count back from the last vertex defined before the face line
        kinds = [ln[:2] for ln in lines if ln[:2] in (b"v ", b"f ")]
        is_v = np.array([k == b"v " for k in kinds])
        v_before = np.repeat(np.cumsum(is_v)[~is_v], sizes)
        idx = np.where(neg, idx + v_before, idx - 1)
    else:
        idx -= 1
    return offsets, idx, ttok


def _line_number(lines: list[bytes], occurrence: int) -> int:
    """1-based number of the ``occurrence``-th face line (best effort, error path only)."""
    seen = 0
    for i, ln in enumerate(lines):
        if ln[:2] == b"f ":
            if seen == occurrence:
                return i + 1
            seen += 1
    return -1  # pragma: no cover


def _read_with_trimesh(p: Path, ext: str, name: str):
    import trimesh

    declared = _ply_header_counts(p) if ext == ".ply" else _off_header_counts(p)
    own = _read_ply if ext == ".ply" else _read_off
    try:
        loaded = trimesh.load(str(p), file_type=ext[1:], process=False)
    except Exception as exc:
        if declared is None or not isinstance(exc, (ValueError, IndexError, TypeError)):
            raise
        # trimesh reads neither binary PLY nor OFF files that mix polygon sizes
        try:
            return own(p)
        except (_Unreadable, ValueError, IndexError):
            nv, nf = declared
            raise _Unreadable(f"the data does not match the header, which declares {nv} "
                              f"vertices and {nf} faces (truncated file or wrong counts; "
                              f"{_one_line(exc)})") from None
    if isinstance(loaded, trimesh.Scene):
        geoms = list(loaded.geometry.values())
        if len(geoms) > 1:
            raise MeshError(f"{name}: the file holds {len(geoms)} separate objects; expected "
                            "a single mesh")
        loaded = geoms[0] if geoms else None
    if loaded is None:
        V, F = np.zeros((0, 3)), np.zeros((0, 3), dtype=np.int64)
    else:
        V = np.array(loaded.vertices, dtype=np.float64).reshape(-1, 3)
        faces = getattr(loaded, "faces", None)  # a PointCloud has none
        F = (np.zeros((0, 3), dtype=np.int64) if faces is None or len(faces) == 0
             else np.array(faces, dtype=np.int64).reshape(-1, 3))
    if declared is not None:
        nv, nf = declared
        if nf is not None and F.shape[0] != nf:
            if F.shape[0] < nf:
                raise _Unreadable(f"the file declares {nf} faces but {F.shape[0]} were found "
                                  "(truncated?)")
            # polygons, which trimesh triangulated (and may have reordered): read as written
            return own(p)
        if nv is not None and V.shape[0] != nv:
            raise _Unreadable(f"the file declares {nv} vertices but {V.shape[0]} were found "
                              "(truncated?)")
    return V, _polygon_offsets(np.full(F.shape[0], 3)), F.ravel()


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2",
              "int16": "i2", "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4",
              "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8",
              "float64": "f8"}


def _read_ply(p: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A PLY reader for polygon faces of mixed sizes (ASCII or binary, any element layout;
    list properties are read record by record)."""
    data = p.read_bytes()
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise _Unreadable("not a PLY file (no 'ply' magic or no end_header)")
    body = data[data.index(b"\n", end) + 1:]
    fmt, elements = None, []
    for ln in data[:end].decode("ascii", "replace").splitlines()[1:]:
        t = ln.split()
        if not t or t[0] in ("comment", "obj_info"):
            continue
        if t[0] == "format":
            fmt = t[1]
        elif t[0] == "element":
            elements.append((t[1], int(t[2]), []))
        elif t[0] == "property" and elements:
            kind = ("list", _PLY_TYPES[t[2]], _PLY_TYPES[t[3]]) if t[1] == "list" \
                else _PLY_TYPES[t[1]]
            elements[-1][2].append((t[-1], kind))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise _Unreadable(f"unknown PLY format {fmt!r}")
    order = "<" if fmt == "binary_little_endian" else ">"
    tokens = body.split() if fmt == "ascii" else None
    pos = 0
    V = faces = None
    for ename, count, props in elements:
        if all(not isinstance(k, tuple) for _, k in props):   # fixed-size records
            if tokens is not None:
                width = len(props)
                rec = np.array(tokens[pos:pos + count * width], dtype=np.float64)
                if rec.size != count * width:
                    raise _Unreadable(f"element '{ename}' is truncated")
                rec = rec.reshape(count, width)
                cols = {n: rec[:, i] for i, (n, _) in enumerate(props)}
                pos += count * width
            else:
                dt = np.dtype([(n, order + k) for n, k in props])
                if pos + count * dt.itemsize > len(body):
                    raise _Unreadable(f"element '{ename}' is truncated")
                rec = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                cols = {n: rec[n] for n, _ in props}
                pos += count * dt.itemsize
            if ename == "vertex":
                V = np.stack([cols[c].astype(np.float64) for c in "xyz"], axis=1)
            continue
        if tokens is None and ename == "face" and len(props) == 1 and \
                np.dtype(props[0][1][1]).itemsize == 1:
            faces, pos = _ply_binary_lists(body, pos, count, np.dtype(order + props[0][1][2]))
            continue
        lists = []
        for _ in range(count):                                    # record by record
            for pname, kind in props:
                if isinstance(kind, tuple):
                    if tokens is not None:
                        k = int(tokens[pos])
                        vals = [int(x) for x in tokens[pos + 1:pos + 1 + k]]
                        pos += 1 + k
                    else:
                        cdt, idt = np.dtype(order + kind[1]), np.dtype(order + kind[2])
                        k = int(np.frombuffer(body, cdt, 1, pos)[0])
                        vals = np.frombuffer(body, idt, k, pos + cdt.itemsize)
                        pos += cdt.itemsize + k * idt.itemsize
                    if len(vals) != k:
                        raise _Unreadable(f"element '{ename}' is truncated")
                    if pname in ("vertex_indices", "vertex_index"):
                        lists.append(vals)
                else:
                    pos += 1 if tokens is not None else np.dtype(kind).itemsize
        if ename == "face":
            faces = (np.array([len(f) for f in lists], dtype=np.int64),
                     np.concatenate([np.asarray(f, dtype=np.int64) for f in lists])
                     if lists else np.zeros(0, dtype=np.int64))
    if tokens is None and pos != len(body) or tokens is not None and pos != len(tokens):
        raise _Unreadable("the data does not match the header")
    if V is None:
        V = np.zeros((0, 3))
    sizes, indices = faces if faces is not None else (np.zeros(0, np.int64),
                                                      np.zeros(0, np.int64))
    return V, _polygon_offsets(sizes), indices


def _ply_binary_lists(body: bytes, pos: int, count: int, idt: np.dtype):
    """Sizes and items of ``count`` binary list records ``uchar k, k x idt`` from ``pos``;
    returns ``((sizes, indices), end)``: one pass over the counts, one gather of the items."""
    isz = idt.itemsize
    sizes = np.zeros(count, dtype=np.int64)
    p = pos
    for r in range(count):
        if p >= len(body):
            raise _Unreadable("element 'face' is truncated")
        k = body[p]
        sizes[r] = k
        p += 1 + k * isz
    if p > len(body):
        raise _Unreadable("element 'face' is truncated")
    starts = pos + np.concatenate([[0], np.cumsum(1 + sizes * isz)[:-1]]) + 1
    first = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    corner = np.arange(int(sizes.sum()))
    item = np.repeat(starts, sizes) + isz * (corner - np.repeat(first, sizes))
    raw = np.frombuffer(body, dtype=np.uint8)
    indices = raw[item[:, None] + np.arange(isz)].copy().view(idt).ravel().astype(np.int64)
    return (sizes, indices), p


def _read_off(p: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An OFF reader for polygon faces ``k i1 .. ik [colour]`` of mixed sizes."""
    rows = [ln.split("#", 1)[0].split()
            for ln in p.read_text(encoding="ascii", errors="replace").splitlines()]
    rows = [r for r in rows if r]
    if not rows or not rows[0][0].upper().endswith("OFF"):
        raise _Unreadable("not an OFF file")
    head = rows[0][1:] if len(rows[0]) > 1 else rows[1]
    start = 1 if len(rows[0]) > 1 else 2
    nv, nf = int(head[0]), int(head[1])
    vrows, frows = rows[start:start + nv], rows[start + nv:start + nv + nf]
    if len(vrows) != nv or len(frows) != nf:
        raise _Unreadable(f"the file declares {nv} vertices and {nf} faces but is shorter")
    V = np.array([r[:3] for r in vrows], dtype=np.float64).reshape(-1, 3)
    sizes = np.array([int(r[0]) for r in frows], dtype=np.int64)
    if any(len(r) <= k for r, k in zip(frows, sizes)):
        raise _Unreadable("a face line is shorter than its vertex count")
    indices = np.array([int(i) for r, k in zip(frows, sizes) for i in r[1:k + 1]],
                       dtype=np.int64)
    return V, _polygon_offsets(sizes), indices


def _polygon_offsets(sizes: np.ndarray) -> np.ndarray:
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    return offsets


def _ply_header_counts(p: Path) -> tuple[int | None, int | None] | None:
    """Vertex and face counts declared in a PLY header (``None`` if not parseable)."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        return None  # let trimesh report the problem
    counts: dict[str, int] = {}
    for ln in head[:end].decode("ascii", "replace").splitlines():
        parts = ln.split()
        if len(parts) == 3 and parts[0] == "element" and parts[2].isdigit():
            counts[parts[1]] = int(parts[2])
    return counts.get("vertex"), counts.get("face")


def _off_header_counts(p: Path) -> tuple[int | None, int | None] | None:
    """Vertex and face counts on the header line(s) of an OFF file."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16).decode("ascii", "replace")
    tokens: list[str] = []
    for ln in head.splitlines():
        tokens.extend(ln.split("#", 1)[0].split())
        if len(tokens) >= 4:
            break
    if not tokens or not tokens[0].upper().endswith("OFF") or len(tokens) < 3:
        return None
    if not (tokens[1].isdigit() and tokens[2].isdigit()):
        return None
    return int(tokens[1]), int(tokens[2])


# ----------------------------------------------------------------------------------------
# Keyframe sets: reading and validation
# ----------------------------------------------------------------------------------------
def read_keyframes(paths, frames=None, *, pinned=None) -> Keyframes:
    """Read and validate the keyframe meshes of one animation.

    Parameters
    ----------
    paths : sequence of str or path-like
        One mesh file per keyframe (OBJ, PLY or OFF; formats may be mixed), in time order.
        Every keyframe has the same polygons (triangles, quads, n-gons).
    frames : (J,) int array-like, str or path, optional
        Frame index of each keyframe: non-negative, strictly increasing integers. A string
        or path is parsed by :func:`read_frames`. ``None`` leaves the choice to the caller.
    pinned : (p,) int array-like, (n,) bool mask, str or path, optional
        Vertices to hold fixed (numbered as in the files); a string or path is read with
        :func:`read_indices`.

    Returns
    -------
    Keyframes
        With ``names`` the paths as given and the topology already built. Polygons are
        triangulated once for all keyframes, vertices coincident in every keyframe welded,
        fin faces and unused vertices set aside (:func:`shellspline.source_mesh.solve_mesh`);
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
        ``frames`` or ``pinned`` (or a pinned vertex that is set aside).

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
    paths = list(paths)
    names = [str(p) for p in paths]
    if len(paths) < 2:
        got = f" ('{names[0]}')" if names else ""
        raise MeshError(f"need at least 2 keyframes, got {len(paths)}{got}")
    frames = _canonical_frames(frames, len(paths))
    Vs: list[np.ndarray] = []
    for j, p in enumerate(paths):
        V, offsets, indices, uv = _read_polygons(p)
        _check_not_empty(V, offsets[:-1], names[j])
        if j == 0:
            off0, idx0, uv0 = offsets, indices, uv
        else:
            if V.shape[0] != Vs[0].shape[0]:
                raise MeshError(f"{names[j]} has {V.shape[0]} vertices but {names[0]} has "
                                f"{Vs[0].shape[0]}")
            _check_same_polygons(offsets, indices, off0, idx0, names[j], names[0])
        Vs.append(V)
    return _validated(np.stack(Vs), off0, idx0, frames, names, pinned, uv0)


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
    shellspline._errors.MeshError: frames must be strictly increasing, got [4, 0]
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
        raise MeshError(f"F: cannot convert to an array: {_one_line(exc)}") from None
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
                            f"{_one_line(exc)}") from None
        if X.ndim != 2 or X.shape[1] != 3:
            raise MeshError(f"{names[j]}: a pose must be an (n,3) array, got shape {X.shape}")
        _check_not_empty(X, F, names[j])
        if j and X.shape[0] != Vs[0].shape[0]:
            raise MeshError(f"{names[j]} has {X.shape[0]} vertices but {names[0]} has "
                            f"{Vs[0].shape[0]}")
        Vs.append(X)
    return _validated(np.stack(Vs), _polygon_offsets(np.full(F.shape[0], 3)), F.ravel(),
                      frames, names, pinned)


def _check_not_empty(V: np.ndarray, F: np.ndarray, name: str) -> None:
    if V.shape[0] == 0:
        raise MeshError(f"{name}: empty mesh (no vertices)")
    if F.shape[0] == 0:
        raise MeshError(f"{name}: empty mesh (no faces)")


def _check_same_polygons(offsets, indices, off0, idx0, name: str, name0: str) -> None:
    if offsets.shape == off0.shape and np.array_equal(offsets, off0) and \
            np.array_equal(indices, idx0):
        return
    if offsets.shape != off0.shape:
        raise MeshError(f"{name}: face list differs from {name0} ({name} has "
                        f"{offsets.size - 1} faces, {name0} has {off0.size - 1})")
    P = offsets.size - 1
    diff = np.diff(offsets) != np.diff(off0)
    if not diff.any():
        diff = np.add.reduceat(indices != idx0, offsets[:-1]) > 0 if P else diff
    t = int(np.flatnonzero(diff)[0])
    raise MeshError(f"{name}: face list differs from {name0} (first difference at face {t}: "
                    f"{indices[offsets[t]:offsets[t + 1]].tolist()} vs "
                    f"{idx0[off0[t]:off0[t + 1]].tolist()})")


#: Coordinates are refused above this magnitude: the shell energy's Hessians hold fourth
#: powers of lengths (squared areas), and (1e75)^4 = 1e300 still fits a float64.
MAX_COORDINATE = 1e75


def _validated(Vs: np.ndarray, offsets: np.ndarray, indices: np.ndarray, frames,
               names: list[str], pinned, uv=None) -> Keyframes:
    """Checks shared by both constructors; ``Vs`` (J,n,3) float64, shapes already agree;
    the polygons (``offsets``, ``indices``) are those of every keyframe; ``uv`` the first
    keyframe's texture coordinates (carried to the output) or ``None``."""
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
    _check_indices(offsets, indices, n, names[0])
    V, F, source, tri_poly = solve_mesh(Vs, offsets, indices, names[0], uv)
    for j in range(J):
        _check_degenerate(V[j], F, names[j], source, tri_poly)
    T = topology(F, V.shape[1], name=names[0])
    pinned = _canonical_pinned(pinned, n)
    if source is not None and pinned is not None:
        pinned = source.solve_vertices(pinned)
    kf = Keyframes(V=V, F=T.F, frames=frames, names=list(names), pinned=pinned, source=source)
    kf._topology = T
    return kf


def _check_degenerate(V: np.ndarray, F: np.ndarray, name: str, source=None,
                      tri_poly=None) -> None:
    """Raise for faces with area below ``tol.degenerate_area * mean_edge_length**2``."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    e1, e2 = b - a, c - a
    area = 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    mean_len = (np.linalg.norm(e1, axis=1).sum() + np.linalg.norm(e2, axis=1).sum()
                + np.linalg.norm(c - b, axis=1).sum()) / (3 * F.shape[0])
    bad = area <= tol.degenerate_area * mean_len ** 2
    if bad.any():
        idx = np.flatnonzero(bad)
        t = int(idx[0])
        if source is None:
            what = f"face {t} {F[t].tolist()}"
        else:
            p = int(tri_poly[t])
            corners = source.poly_indices[source.poly_offsets[p]:source.poly_offsets[p + 1]]
            what = f"face {t} (of input face {p} {corners.tolist()})"
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
        raise MeshError(f"frames: cannot convert to an array: {_one_line(exc)}") from None
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
        raise MeshError(f"pinned: cannot convert to an array: {_one_line(exc)}") from None
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
        raise MeshError(f"frames: cannot convert to an array: {_one_line(exc)}") from None
    if arr.ndim != 1 or (arr.size and not np.issubdtype(arr.dtype, np.integer)):
        raise MeshError(f"frames must be a 1-D sequence of integers, got {arr.tolist()}")
    return arr.astype(np.int64)


def _read_integers(path, what: str) -> np.ndarray:
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8", errors="replace")
    except OSError as exc:
        raise MeshError(f"cannot read '{name}': {exc.strerror or exc}") from None
    return _parse_integers(text, f"{what} '{name}'")


def _parse_integers(text: str, what: str) -> np.ndarray:
    values: list[int] = []
    for line_no, line in enumerate(text.splitlines(), 1):
        for tok in line.split("#", 1)[0].replace(",", " ").split():
            try:
                values.append(int(tok))
            except ValueError:
                raise MeshError(f"{what}: line {line_no}: '{tok}' is not an integer") from None
    return np.array(values, dtype=np.int64)


# ----------------------------------------------------------------------------------------
# Writing sequences
# ----------------------------------------------------------------------------------------
def write_sequence(out_dir, V, F, report=None, *, fmt: str = "obj", overwrite: bool = False,
                   protect=(), workers: int = 1, fps: float = 24.0, source=None) -> Path:
    """Write a sequence of poses as ``frame_0000.obj ...`` plus ``report.json``, atomically.

    Everything is written into a temporary sibling directory
    (``.<out_dir>.tmp-<pid>-<random>``) that is renamed to ``out_dir`` at the end, so a crash
    or an exception never leaves a half-written output; the temporary directory is removed
    on any error. An existing output is replaced only with ``overwrite=True``, by renaming
    it aside, renaming the new one into place and then deleting the old one.

    Parameters
    ----------
    out_dir : str or path-like
        Output directory; its parent is created if needed.
    V : (K+1,n,3) float array
        Poses of frames ``0..K``.
    F : (m,3) int array
        Faces, zero-based (written 1-based in OBJ).
    report : dict, optional
        Written as ``report.json`` (indent 2); numpy arrays and scalars, paths, tuples and
        dataclasses are converted. Default ``{}``.
    fmt : {"obj", "ply", "glb"}
        ``"obj"``: text, coordinates with 17 significant digits (``%.17g``), so that every
        float64 reads back bit-identically. ``"ply"``: binary little-endian PLY with
        ``double`` coordinates (exact, smaller and faster). ``"glb"``: one file
        ``animation.glb`` (binary glTF: frame 0 as the base mesh, one morph target per later
        frame, an animation playing them at ``fps``; float32, see :mod:`shellspline.gltf`).
    overwrite : bool
        Replace an existing ``out_dir``. Only a directory that is empty or holds a
        ``report.json`` (i.e. looks like an earlier output) is ever replaced.
    protect : iterable of str or path-like
        Input paths (the keyframe files) that must survive: it is an error if ``out_dir``
        resolves to one of them or contains one.
    workers : int
        Number of processes that format and write frames (``1``: in this process).
        Formatting OBJ text is CPU bound, so more workers help on long sequences. The
        workers (:func:`shellspline.parallel.process_pool`) die with this process and are
        stopped at once on Ctrl-C or SIGTERM (the temporary directory is then removed).
    fps : float
        Frames per second of the GLB animation (``fmt="glb"`` only).
    source : SourceMesh, optional
        Write the input's mesh back (:attr:`Keyframes.source`): ``V`` is then
        ``(K+1,n_source,3)`` in the input's vertex indexing (:meth:`SourceMesh.expand`), and
        OBJ and PLY frames get the input's polygons, GLB its triangles; ``F`` is not used.

    Returns
    -------
    pathlib.Path
        The absolute path of the written directory.

    Raises
    ------
    FileExistsError
        If ``out_dir`` exists and ``overwrite`` is false, or it exists and is not a
        directory.
    ShellsplineError
        For bad arguments, a non-serialisable report, an ``out_dir`` that contains a
        protected input or the working directory, or one that does not look like an earlier
        output when ``overwrite=True``.

    Notes
    -----
    Frame files are named ``frame_{k:0{w}d}`` with ``w = max(4, len(str(K)))``. The face
    block of an OBJ file is the same for every frame and is formatted once.

    Examples
    --------
    >>> import tempfile, os, numpy as np
    >>> V = np.random.default_rng(0).random((3, 4, 3))
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> out = write_sequence(os.path.join(tempfile.mkdtemp(), "out"), V, F, {"K": 2})
    >>> sorted(p.name for p in out.iterdir())
    ['frame_0000.obj', 'frame_0001.obj', 'frame_0002.obj', 'report.json']
    >>> V2, F2, rep = read_sequence(out)
    >>> bool((V2 == V).all()), rep
    (True, {'K': 2})
    """
    V = np.asarray(V, dtype=np.float64)
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0:
        raise ShellsplineError(f"V must be a (K+1,n,3) array of poses, got shape {V.shape}")
    polygons = None
    if source is not None:
        if V.shape[1] != source.n_source:
            raise ShellsplineError(f"with `source`, V must hold the input's {source.n_source} "
                                   f"vertices (SourceMesh.expand), got shape {V.shape}")
        F = source.triangles
        if (np.diff(source.poly_offsets) != 3).any() or source.uv is not None:
            polygons = (source.poly_offsets, source.poly_indices, source.uv, source.corner_uv)
    F = np.asarray(F)
    if F.ndim != 2 or F.shape[1] != 3 or (F.size and not np.issubdtype(F.dtype, np.integer)):
        raise ShellsplineError(f"F must be an (m,3) integer array, got shape {F.shape} and "
                               f"dtype {F.dtype}")
    F = F.astype(np.int64)
    n = V.shape[1]
    if F.size and (F.min() < 0 or F.max() >= n):
        raise ShellsplineError(f"F indexes vertices outside [0, {n}): range "
                               f"[{F.min()}, {F.max()}]")
    fmt = str(fmt).lower().lstrip(".")
    if fmt not in ("obj", "ply", "glb"):
        raise ShellsplineError(f"fmt must be 'obj', 'ply' or 'glb', got {fmt!r}")
    if fmt == "glb":
        from .gltf import glb_bytes

        glb = glb_bytes(V, F, fps=fps)  # validates fps before anything is created
    workers = int(workers)
    if workers < 1:
        raise ShellsplineError(f"workers must be >= 1, got {workers}")
    report_text = json.dumps(_jsonable({} if report is None else report, "report"),
                             indent=2) + "\n"

    out = Path(out_dir)
    target = check_output_dir(out, n_frames=V.shape[0], n_vertices=n, n_faces=F.shape[0],
                              fmt=fmt, overwrite=overwrite, protect=protect)
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = _fresh_sibling(parent, f".{target.name}.tmp-{os.getpid()}-")
    except OSError as exc:
        raise _on_user_path(exc, None, out, "creating") from None
    try:
        if fmt == "glb":
            (tmp / GLB_NAME).write_bytes(glb)
        else:
            K = V.shape[0] - 1
            width = max(4, len(str(K)))
            paths = [tmp / f"frame_{k:0{width}d}.{fmt}" for k in range(K + 1)]
            _write_frames(paths, V, F, fmt, workers, polygons)
        (tmp / "report.json").write_text(report_text, encoding="utf-8")
        _move_into_place(tmp, target, overwrite)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, FileExistsError) and exc.errno is None:
            raise  # our own message: the output appeared while we were writing
        raise _on_user_path(exc, tmp, out, "writing") from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


#: Lower estimates of the bytes per vertex and per face of one frame (the space check must
#: never refuse an output that fits): OBJ ``v x y z`` lines with 17 significant digits are
#: 55-65 bytes, a face line ``f a b c`` 8 bytes and more; PLY stores 3 doubles per vertex and
#: 13 bytes per face; GLB 24 bytes per vertex and frame (float32 position and normal deltas).
_BYTES_PER_VERTEX = {"obj": 50, "ply": 24, "glb": 24}
_BYTES_PER_FACE = {"obj": 8, "ply": 13, "glb": 0}


def check_output_dir(out_dir, *, n_frames: int = 0, n_vertices: int = 0, n_faces: int = 0,
                     fmt: str = "obj", overwrite: bool = False, protect=()) -> Path:
    """Check, before any computing, that :func:`write_sequence` can write ``out_dir``.

    Nothing is created: the nearest existing ancestor of ``out_dir`` must be a directory
    in which a directory can be created (probed by creating and removing one, which also
    catches read-only mounts and permissions that the superuser ignores), ``out_dir`` must
    not contain or replace an input, must not exist unless ``overwrite`` (and then only
    as an earlier output), and, where the platform tells (:func:`shutil.disk_usage`), the
    file system must have room for the estimated size of the output.

    Parameters
    ----------
    out_dir : str or path-like
        The output directory.
    n_frames, n_vertices, n_faces : int
        Size of the sequence to be written (``K+1`` frames), for the free-space estimate;
        ``0`` skips that check.
    fmt : {"obj", "ply", "glb"}
        Output format (bytes per vertex differ).
    overwrite, protect
        As for :func:`write_sequence`.

    Returns
    -------
    pathlib.Path
        The absolute path that will be written.

    Raises
    ------
    FileExistsError
        If ``out_dir`` exists and ``overwrite`` is false, or it exists and is not a directory.
    ShellsplineError
        If ``out_dir`` lies under a file, its parent cannot be written, it would contain or
        replace a protected input, or the file system has too little free space.

    Examples
    --------
    >>> import tempfile, os
    >>> d = tempfile.mkdtemp()
    >>> check_output_dir(os.path.join(d, "new", "out"), n_frames=21, n_vertices=5000,
    ...                  n_faces=9996).name
    'out'
    >>> os.listdir(d)  # nothing was created
    []
    """
    out = Path(out_dir)
    fmt = str(fmt).lower().lstrip(".")
    if fmt not in _BYTES_PER_VERTEX:
        raise ShellsplineError(f"fmt must be 'obj', 'ply' or 'glb', got {fmt!r}")
    target = out.resolve()
    _check_destination(target, out, overwrite, protect)
    base = target.parent
    while not base.is_dir():
        if base.exists() or base.is_symlink():
            raise ShellsplineError(f"cannot create output directory '{out}': '{base}' is a "
                                   "file, not a directory")
        base = base.parent
    try:  # a directory created and removed: os.access knows neither read-only mounts nor root
        _fresh_sibling(base, f".{target.name}.probe-{os.getpid()}-").rmdir()
    except OSError as exc:
        raise ShellsplineError(f"cannot create output directory '{out}': cannot write in "
                               f"'{base}': {(exc.strerror or str(exc)).lower()}") from None
    need = int(n_frames) * (int(n_vertices) * _BYTES_PER_VERTEX[fmt]
                            + int(n_faces) * _BYTES_PER_FACE[fmt])
    if need > 0:
        try:
            free = shutil.disk_usage(base).free
        except (OSError, AttributeError):  # the platform does not say
            free = None
        if free is not None and free < need:
            raise ShellsplineError(f"not enough space for output directory '{out}': about "
                                   f"{_megabytes(need)} needed, {_megabytes(free)} free in "
                                   f"'{base}'")
    return target


def _megabytes(nbytes: int) -> str:
    return f"{nbytes / 1e6:,.1f} MB" if nbytes < 1e9 else f"{nbytes / 1e9:,.1f} GB"


def _on_user_path(exc: OSError, tmp: Path | None, out: Path, doing: str) -> OSError:
    """``exc`` again (same type and errno) with a message that names the user's path.

    A file inside the hidden temporary directory ``tmp`` is named by where it would have
    landed in ``out``; ``No space left on device`` becomes ``no space left on device
    writing 'OUT/frame_0012.obj'``.
    """
    where = out
    for name in (exc.filename, exc.filename2):
        if name is None or tmp is None:
            continue
        try:
            where = out / Path(os.fsdecode(name)).relative_to(tmp)
            break
        except ValueError:
            continue
    what = exc.strerror or str(exc) or type(exc).__name__
    what = what[:1].lower() + what[1:]
    return OSError(exc.errno, f"{what} {doing} '{where}'")  # the errno picks the subclass


def _check_destination(target: Path, out: Path, overwrite: bool, protect) -> None:
    for p in protect:
        rp = Path(p).resolve()
        if rp == target or target in rp.parents:
            raise ShellsplineError(f"refusing to write to '{out}': it would contain or "
                                   f"replace the input '{p}'")
    if not (target.exists() or target.is_symlink()):
        return
    if not target.is_dir():
        raise FileExistsError(f"'{out}' exists and is not a directory")
    if not overwrite:
        raise FileExistsError(f"output directory '{out}' already exists (use overwrite=True "
                              "to replace it)")
    cwd = Path.cwd().resolve()
    if cwd == target or target in cwd.parents:
        raise ShellsplineError(f"refusing to replace '{out}': it contains the current working "
                               "directory")
    if any(target.iterdir()) and not (target / "report.json").is_file():
        raise ShellsplineError(f"refusing to replace '{out}': it is not empty and has no "
                               "report.json, so it does not look like an earlier output")


def _fresh_sibling(parent: Path, prefix: str) -> Path:
    while True:
        p = parent / f"{prefix}{secrets.token_hex(4)}"
        try:
            p.mkdir()
            return p
        except FileExistsError:  # pragma: no cover - 32 random bits
            continue


def _move_into_place(tmp: Path, target: Path, overwrite: bool) -> None:
    if target.exists() or target.is_symlink():
        if not overwrite:  # created by someone else while we were writing
            raise FileExistsError(f"output directory '{target}' already exists")
        aside = target.parent / f".{target.name}.old-{os.getpid()}-{secrets.token_hex(4)}"
        os.rename(target, aside)
        try:
            os.rename(tmp, target)
        except BaseException:
            os.rename(aside, target)
            raise
        shutil.rmtree(aside, ignore_errors=True)
    else:
        os.rename(tmp, target)


def _write_frames(paths: list[Path], V: np.ndarray, F: np.ndarray, fmt: str,
                  workers: int, polygons=None) -> None:
    if polygons is None:
        block = _obj_faces_block(F) if fmt == "obj" else _ply_faces_bytes(F)
        m = F.shape[0]
    else:  # the input's polygons (offsets, indices)
        block = (_obj_polygons_block(*polygons) if fmt == "obj"
                 else _ply_polygons_bytes(*polygons[:2]))
        m = polygons[0].size - 1
    workers = min(workers, len(paths))
    if workers <= 1:
        for k, p in enumerate(paths):
            if fmt == "obj":
                _write_obj_frame(p, V[k], block)
            else:
                _write_ply_frame(p, V[k], block, m)
        return
    from .parallel import process_pool

    chunks = np.array_split(np.arange(len(paths)), workers)
    with process_pool(workers) as ex:  # workers stopped at once on Ctrl-C/SIGTERM
        futures = [ex.submit(_write_frames_chunk, [paths[k] for k in c], V[c], block, fmt,
                             m) for c in chunks]
        try:
            for fut in futures:
                fut.result()
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _write_frames_chunk(paths, Vc, block, fmt, m) -> None:
    for p, X in zip(paths, Vc):
        if fmt == "obj":
            _write_obj_frame(p, X, block)
        else:
            _write_ply_frame(p, X, block, m)


def _obj_faces_block(F: np.ndarray) -> bytes:
    """The ``f a b c`` lines (1-based) of every frame, formatted once."""
    return (("f %d %d %d\n" * F.shape[0]) % tuple((F + 1).ravel().tolist())).encode("ascii")


def _obj_polygons_block(offsets: np.ndarray, indices: np.ndarray, uv=None,
                        corner_uv=None) -> bytes:
    """The ``f a b c ...`` lines (1-based) of polygons, formatted once; with texture
    coordinates the ``vt`` lines first and ``f a/ta b/tb ...`` corners."""
    if uv is None:
        fmt = "".join("f" + " %d" * int(s) + "\n" for s in np.diff(offsets))
        return (fmt % tuple((indices + 1).tolist())).encode("ascii")
    vt = ("vt %.17g %.17g\n" * uv.shape[0]) % tuple(uv.ravel().tolist())
    fmt = "".join("f" + " %d/%d" * int(s) + "\n" for s in np.diff(offsets))
    corners = np.stack([indices + 1, corner_uv + 1], axis=1).ravel()
    return (vt + fmt % tuple(corners.tolist())).encode("ascii")


def _ply_polygons_bytes(offsets: np.ndarray, indices: np.ndarray) -> bytes:
    """Binary PLY face records ``uchar count, int32 indices...`` of polygons."""
    sizes = np.diff(offsets)
    P = sizes.size
    out = np.zeros(P + 4 * indices.size, dtype=np.uint8)
    out[4 * offsets[:-1] + np.arange(P)] = sizes
    pos = 4 * np.arange(indices.size) + np.repeat(np.arange(P), sizes) + 1
    out[pos[:, None] + np.arange(4)] = indices.astype("<i4").view(np.uint8).reshape(-1, 4)
    return out.tobytes()


def _write_obj_frame(path: Path, V: np.ndarray, faces_block: bytes) -> None:
    """One OBJ frame; ``%.17g`` round-trips every float64 exactly."""
    verts = ("v %.17g %.17g %.17g\n" * V.shape[0]) % tuple(V.ravel().tolist())
    with open(path, "wb") as fh:
        fh.write(verts.encode("ascii"))
        fh.write(faces_block)


def _ply_faces_bytes(F: np.ndarray) -> bytes:
    rec = np.zeros(F.shape[0], dtype=[("count", "u1"), ("idx", "<i4", (3,))])
    rec["count"] = 3
    rec["idx"] = F
    return rec.tobytes()


def _write_ply_frame(path: Path, V: np.ndarray, faces_bytes: bytes, m: int) -> None:
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by shellspline\n"
              f"element vertex {V.shape[0]}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {m}\n"
              "property list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(V, dtype="<f8").tobytes())
        fh.write(faces_bytes)


def _jsonable(obj, where: str):
    """Convert a report to JSON-native types; raise naming the offending entry."""
    if obj is None or isinstance(obj, (str, bool, int)):
        return obj
    if isinstance(obj, float):
        return obj
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    if isinstance(obj, dict):
        out = {}
        for k, v in obj.items():
            key = k.item() if isinstance(k, np.generic) else k
            if isinstance(key, os.PathLike):
                key = os.fspath(key)
            if not isinstance(key, (str, int, float, bool)) and key is not None:
                raise ShellsplineError(f"{where}: key {k!r} of type {type(k).__name__} cannot "
                                       "be written to JSON")
            out[key] = _jsonable(v, f"{where}[{k!r}]")
        return out
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v, f"{where}[{i}]") for i, v in enumerate(obj)]
    if isinstance(obj, (set, frozenset)):
        return [_jsonable(v, where) for v in sorted(obj, key=repr)]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return _jsonable({f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)},
                         where)
    raise ShellsplineError(f"{where}: value of type {type(obj).__name__} cannot be written to "
                           "JSON")


def read_sequence(out_dir) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a directory written by :func:`write_sequence`, or a ``.glb`` animation file.

    Frame files (``frame_*.obj`` / ``frame_*.ply``) are read when present, else
    ``animation.glb`` (float32 coordinates, see :func:`shellspline.gltf.read_glb`). Frames
    written with the input's polygons are triangulated once for the whole sequence
    (:func:`shellspline.source_mesh.triangulate_polygons`).

    Parameters
    ----------
    out_dir : str or path-like
        An output directory, or the path of a ``.glb`` file.

    Returns
    -------
    V : (K+1,n,3) float64 numpy array
        Poses, in frame order.
    F : (m,3) int64 numpy array
        Faces.
    report : dict
        The contents of ``report.json`` (``{}`` if there is none).

    Raises
    ------
    MeshError
        If the directory has no frame files, frames are missing, or the frames disagree in
        vertex count or faces.
    """
    d = Path(out_dir)
    if d.suffix.lower() == ".glb" and d.is_file():
        from .gltf import read_glb

        try:
            Vg, Fg, _ = read_glb(d)
        except ShellsplineError as exc:
            raise MeshError(str(exc)) from None
        return Vg, Fg, _read_report(d.parent) if d.name == GLB_NAME else {}
    if not d.is_dir():
        raise MeshError(f"cannot read sequence '{d}': not a directory or a .glb file")
    found = {}
    for p in d.iterdir():
        mt = _FRAME_RE.match(p.name)
        if mt:
            k = int(mt.group(1))
            if k in found:
                raise MeshError(f"{d}: frame {k} appears twice ({found[k].name}, {p.name})")
            found[k] = p
    if not found:
        if (d / GLB_NAME).is_file():
            from .gltf import read_glb

            try:
                Vg, Fg, _ = read_glb(d / GLB_NAME)
            except ShellsplineError as exc:
                raise MeshError(str(exc)) from None
            return Vg, Fg, _read_report(d)
        raise MeshError(f"{d}: no frame_*.obj, frame_*.ply or {GLB_NAME} files")
    ks = sorted(found)
    if ks != list(range(len(ks))):
        missing = sorted(set(range(ks[-1] + 1)) - set(ks))
        raise MeshError(f"{d}: frames are not numbered 0..{ks[-1]} without gaps (missing "
                        f"{missing[:5]})")
    Vs = []
    for k in ks:
        name = str(found[k])
        V, offsets, indices, _ = _read_polygons(found[k])
        if not Vs:
            off0, idx0, name0 = offsets, indices, name
            _check_indices(offsets, indices, V.shape[0], name)
        else:
            if V.shape[0] != Vs[0].shape[0]:
                raise MeshError(f"{name} has {V.shape[0]} vertices but {name0} has "
                                f"{Vs[0].shape[0]}")
            _check_same_polygons(offsets, indices, off0, idx0, name, name0)
        Vs.append(V)
    V = np.stack(Vs)
    F, _ = triangulate_polygons(V, off0, idx0, name0)
    return V, F, _read_report(d)


def _read_report(d: Path) -> dict:
    rp = d / "report.json"
    if not rp.is_file():
        return {}
    try:
        return json.loads(rp.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise MeshError(f"cannot read '{rp}': {_one_line(exc)}") from None
