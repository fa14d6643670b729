"""Reading one mesh file: OBJ and OFF (own readers), PLY (trimesh, ours where it fails).

-------
* **OBJ** is parsed by a small vectorised reader of our own: ``v`` and ``f`` lines only,
  polygons of any size, ``f a/b/c`` and negative (relative) indices understood, a UTF-8
  byte-order mark skipped, texture coordinates, normals, ``o/g/s/usemtl/mtllib/l/vp`` lines
  ignored. trimesh's OBJ loader is not used because, even with ``process=False``, it drops
  vertices no face uses (unless ``maintain_order=True``), splits vertices at texture/normal
  seams, needs Pillow for any file with ``vt`` lines, and triangulates polygons per file.
* **PLY** (ASCII and binary) is read with ``trimesh.load(path, process=False)``, which
  keeps the vertex order and merges nothing. trimesh triangulates polygons per file (and
  reorders the faces of files that mix triangles and polygons), so when the face count
  declared in the header differs from the number of triangles loaded the polygons are read
  from the file by our own reader (also used for what trimesh cannot read).
* **OFF** (``OFF``, ``COFF``, ``NOFF``...) is read by our own reader: trimesh drops faces of
  fewer than 3 corners without a word.
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np

from ..errors import MeshError, one_line
from ..mesh.source_mesh import triangulate_polygons

__all__ = ["read_mesh", "MESH_EXTENSIONS"]  # and helpers for shellspline.io's own modules

MESH_EXTENSIONS = (".obj", ".off", ".ply")
"""File extensions :func:`read_mesh` understands (case-insensitive)."""

# ----------------------------------------------------------------------------------------
# Reading single meshes
# ----------------------------------------------------------------------------------------
class _Unreadable(Exception):
    """Internal: a file cannot be parsed; the message is the reason."""


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Read a mesh from an OBJ, PLY or OFF file as triangles, keeping the vertex order.

    Nothing is merged, reordered or dropped (vertices no face uses are kept). Coordinates
    are returned as float64 (float32 PLY data is converted exactly). Polygons are
    triangulated by :func:`shellspline.mesh.source_mesh.triangulate_polygons` on this one pose
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
    V, offsets, indices, _ = read_polygons(path)
    name = str(path)
    check_indices(offsets, indices, V.shape[0], name)
    F, _ = triangulate_polygons(V[None], offsets, indices, name)
    return V, F


def read_polygons(path, info: dict | None = None):
    """``V (n,3)``, polygon ``offsets (P+1,)``, corner ``indices (N,)`` of a mesh file and its
    texture coordinates ``(uv (t,2), corner_uv (N,))`` or ``None`` (OBJ ``f v/vt`` only).

    An OBJ file's faces are checked here, in the file's own terms (its line numbers, 1-based
    indices): at least 3 corners, vertex and texture indices in range, no vertex repeated.

    ``info``, a dict, receives what else an OBJ file says: ``"statements"``, its
    ``mtllib/usemtl/o/g/s`` lines (:func:`obj_statements`, written back with the polygons;
    ``mtllib`` lines name their files by absolute path, :func:`mtllib_resolved`), and
    ``"texture_note"``, a sentence saying why texture coordinates were not read when some
    face corners name one and others do not (else ``None``).
    """
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
        with open(p, "rb") as fh:
            wide = wide_text_encoding(fh.read(4))
        if wide:
            raise _Unreadable(f"the file is {wide} encoded; save it as UTF-8")
        if ext == ".obj":
            V, offsets, indices, uv = _parse_obj(p.read_bytes(), name, info)
            if info is not None:
                info["statements"] = mtllib_resolved(info["statements"], p.parent)
        else:
            (V, offsets, indices), uv = _read_with_trimesh(p, ext, name), None
    except MeshError:
        raise
    except _Unreadable as exc:
        raise MeshError(f"cannot read '{name}': {exc}") from None
    except OSError as exc:
        raise MeshError(f"cannot read '{name}': {exc.strerror or exc}") from None
    except (ValueError, IndexError, KeyError, TypeError, OverflowError, EOFError) as exc:
        # malformed content the parsers did not foresee: one line, no traceback (other
        # exceptions are bugs, reported as such by the CLI, never as bad input)
        raise MeshError(f"cannot read '{name}': {one_line(exc)}") from None
    return V, offsets, indices, uv


def wide_text_encoding(head: bytes) -> str | None:
    """``"UTF-16"`` or ``"UTF-32"`` when ``head`` (a file's first bytes) starts with that
    encoding's byte-order mark (Windows editors save text so), else ``None``."""
    if head[:4] in (b"\xff\xfe\x00\x00", b"\x00\x00\xfe\xff"):
        return "UTF-32"
    if head[:2] in (b"\xff\xfe", b"\xfe\xff"):
        return "UTF-16"
    return None


def check_indices(offsets: np.ndarray, indices: np.ndarray, n: int, name: str) -> None:
    """A polygon has at least 3 corners, which are vertices, none repeated."""
    sizes = np.diff(offsets)
    if (sizes < 3).any():
        t = int(np.flatnonzero(sizes < 3)[0])
        raise MeshError(f"{name}: face {t} has {int(sizes[t])} vertices (a face needs at "
                        f"least 3; {int((sizes < 3).sum())} such faces; faces counted from 0)")
    if indices.size and (indices.min() < 0 or indices.max() >= n):
        out = (indices < 0) | (indices >= n)
        c = int(np.flatnonzero(out)[0])
        t = int(np.searchsorted(offsets, c, side="right") - 1)
        faces = np.unique(np.searchsorted(offsets, np.flatnonzero(out), side="right") - 1)
        raise MeshError(f"{name}: face indices must lie in [0, {n}) (vertices and faces "
                        f"counted from 0), got vertex {int(indices[c])} in face {t} "
                        f"{indices[offsets[t]:offsets[t + 1]].tolist()} ({faces.size} such "
                        "faces)")
    bad = repeating_faces(offsets, indices, n)
    if bad.any():
        t = int(np.flatnonzero(bad)[0])
        raise MeshError(f"{name}: face {t} {indices[offsets[t]:offsets[t + 1]].tolist()} "
                        f"repeats a vertex (faces and vertices counted from 0; "
                        f"{int(bad.sum())} such faces)")




def _parse_obj(data: bytes, name: str, info: dict | None = None):
    """Vectorised OBJ reader: ``v``, ``vt`` and ``f`` lines, global numbering; returns ``V``,
    polygon offsets, corner indices and the texture coordinates (see :func:`_obj_texture`).
    Problems with the faces are said in the file's terms (:func:`_obj_face_problem`)."""
    if data[:3] == b"\xef\xbb\xbf":  # UTF-8 byte-order mark (Windows editors, exporters)
        data = data[3:]
    if b"\0" in data:
        raise _Unreadable("binary data in a text OBJ file")
    if b"\\\n" in data or b"\\\r\n" in data:  # line continuations
        data = joined_continuations(data)
    lines = data.splitlines()
    if b"#" in data:
        lines = [ln[:ln.find(b"#")] if b"#" in ln else ln for ln in lines]
    if b"\t" in data or b"\n " in data or b"\r " in data or data[:1] == b" ":
        lines = [ln.strip().replace(b"\t", b" ") for ln in lines]
    vlines = [ln for ln in lines if ln[:2] == b"v "]
    flines = [ln for ln in lines if ln[:2] == b"f "]
    vtlines = [ln for ln in lines if ln[:3] == b"vt "] if b"vt " in data else []
    V = _obj_vertices(vlines, lines)
    offsets, indices, ttok = _obj_faces(flines, lines, name, V.shape[0],
                                        slashes=b"/" in data)
    uv = None
    if ttok is not None:
        uv, note = _obj_texture(vtlines, ttok, offsets, lines, name)
        if info is not None:
            info["texture_note"] = note
    if info is not None:
        info.setdefault("texture_note", None)
        info["statements"] = obj_statements(lines)
    return V, offsets, indices, uv


def joined_continuations(data: bytes) -> bytes:
    """OBJ text with every line that ends in a backslash joined to the next one, the joined
    line followed by one empty line per line it took in, so that later lines keep their
    numbers (messages name the file's lines)."""
    def join(m):
        text = m.group(0)
        return re.sub(rb"\\\r?\n", b" ", text) + b"\n" * text.count(b"\n")

    return re.sub(rb"[^\r\n]*(?:\\\r?\n[^\r\n]*)+", join, data)


_STATEMENTS = (b"mtllib ", b"usemtl ", b"o ", b"g ", b"s ")


def obj_statements(lines: list[bytes]):
    """The ``mtllib/usemtl/o/g/s`` lines of an OBJ file (comments stripped) as
    ``(head, body)``: ``head`` the tuple of those before the first ``v`` and ``f`` line,
    ``body`` a tuple of ``(p, line)``, each line standing before polygon ``p`` (``p`` = the
    number of ``f`` lines before it); ``None`` when there are none."""
    at = [i for i, ln in enumerate(lines)
          if ln[:2] in (b"o ", b"g ", b"s ") or ln[:7] in (b"usemtl ", b"mtllib ")
          or ln.rstrip() == b"g"]
    if not at:
        return None
    faces = [i for i, ln in enumerate(lines) if ln[:2] == b"f "]
    first_v = next((i for i, ln in enumerate(lines) if ln[:2] == b"v "), len(lines))
    first = min(first_v, faces[0] if faces else len(lines))
    pos = np.searchsorted(np.array(faces, dtype=np.int64), np.array(at), side="left")
    text = [b" ".join(lines[i].split()) for i in at]
    head = tuple(t for i, t in zip(at, text) if i < first)
    body = tuple((int(p), t) for i, p, t in zip(at, pos, text) if i >= first)
    return head, body


def mtllib_resolved(statements, folder):
    """``statements`` (:func:`obj_statements`) with each ``mtllib`` line naming one material
    file by its absolute path, resolved from ``folder`` (the OBJ file's) as viewers resolve
    it, so that a writer elsewhere can name the same file
    (:func:`shellspline.io.sequences.write_sequence` names it from its output folder).

    A line's file name is the rest of the line when a file of that name exists (names with
    spaces), else each word is one (``mtllib a.mtl b.mtl`` becomes two lines); the file need
    not exist. Its folder is resolved, not the file itself: a symlinked ``.mtl`` is named as
    the link (its texture maps are read from the link's folder).
    """
    if statements is None:
        return None
    base = Path(folder)

    def lines(t):
        if t[:7] != b"mtllib ":
            return [t]
        rest = t[7:].strip()
        try:
            whole = (base / os.fsdecode(rest)).is_file()
        except (OSError, ValueError):
            whole = False
        names = [rest] if whole else rest.split()
        return [b"mtllib " + os.fsencode(absolute(base / os.fsdecode(n))) for n in names]

    def absolute(path):
        # the folder resolved (symlinks and ".." as the file system takes them), the file's
        # own name kept: a viewer reads a .mtl's texture maps (map_Kd ...) from the folder it
        # named the .mtl in, so a symlinked .mtl is named as the link, not as its target
        try:
            return str(path.parent.resolve() / path.name)
        except (OSError, RuntimeError, ValueError):  # a symlink loop, say: as written
            return os.path.abspath(path)

    head, body = statements
    return (tuple(x for t in head for x in lines(t)),
            tuple((q, x) for q, t in body for x in lines(t)))


def _obj_texture(vtlines: list[bytes], ttok: list[bytes], offsets: np.ndarray,
                 lines: list[bytes], name: str):
    """``((uv (t,2), corner_uv (N,)), None)`` when every face corner names a texture
    coordinate (``f v/vt ...``); ``(None, note)`` when some do and others do not (``note``
    says so; ``None`` when no corner names one). A texture index that is not an integer or
    out of range, or a ``vt`` line that is not numbers, is a :class:`MeshError` naming the
    line."""
    has = np.fromiter(map(bool, ttok), dtype=bool, count=len(ttok))
    if not has.any():
        return None, None
    try:
        ti = np.array([int(t) if t else 1 for t in ttok], dtype=np.int64)
    except (ValueError, OverflowError):
        raise MeshError(_obj_face_problem(lines, name)) from None
    if (ti == 0).any():
        raise MeshError(_obj_face_problem(lines, name))
    nvt = len(vtlines)
    if (ti < 0).any():  # relative: counted back from the last vt line before the face line
        kinds = [ln[:3] for ln in lines if ln[:3] == b"vt " or ln[:2] == b"f "]
        is_t = np.array([k == b"vt " for k in kinds], dtype=bool)
        before = np.repeat(np.cumsum(is_t)[~is_t], np.diff(offsets))
        ti = np.where(ti < 0, ti + before, ti - 1)
    else:
        ti -= 1
    if ti.size and (ti.min() < 0 or ti.max() >= nvt):
        raise MeshError(_obj_face_problem(lines, name))
    if not has.all():
        t = int(np.searchsorted(offsets, np.flatnonzero(~has)[0], side="right") - 1)
        line, _ = _face_line(lines, t)
        return None, (f"{name}: {int((~has).sum())} of {has.size} face corners name no "
                      f"texture coordinate (the first on line {line}, face {t + 1}); texture "
                      "coordinates are kept only when every corner names one, so none are "
                      "written back")
    try:
        tokens = _regular_tokens(vtlines, 3)  # "vt u v" everywhere: the fast path
        if tokens is not None:
            del tokens[::3]
            uv = np.array(list(map(float, tokens)), dtype=np.float64).reshape(-1, 2)
        else:
            uv = np.array([[float(x) for x in (ln.split()[1:3] + [b"0"])[:2]]
                           for ln in vtlines], dtype=np.float64).reshape(-1, 2)
    except ValueError:
        for k, ln in enumerate(vtlines):
            try:
                [float(x) for x in ln.split()[1:3]]
            except ValueError:
                raise MeshError(f"{name}: line {_nth_line(lines, b'vt ', k)}: texture "
                                f"coordinate {k + 1} ({_shown(ln)}) is not numbers u v") from None
        raise  # pragma: no cover
    return (uv, ti), None


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


def _obj_vertices(vlines: list[bytes], lines: list[bytes]) -> np.ndarray:
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
                raise _Unreadable(f"line {_nth_line(lines, b'v ', i)}: vertex {i + 1} has "
                                  f"{len(t) - 1} coordinates, expected 3")
            tokens.extend(t[1:4])  # extra values (w, colours) are ignored
    try:
        return np.array(list(map(float, tokens)), dtype=np.float64).reshape(-1, 3)
    except ValueError:
        for i in range(0, len(tokens), 3):
            try:
                list(map(float, tokens[i:i + 3]))
            except ValueError:
                bad = b" ".join(tokens[i:i + 3]).decode("ascii", "replace")
                raise _Unreadable(f"line {_nth_line(lines, b'v ', i // 3)}: vertex "
                                  f"{i // 3 + 1} has non-numeric coordinates '{bad}'") from None
        raise  # pragma: no cover


def _obj_faces(flines: list[bytes], lines: list[bytes], name: str, n: int, *, slashes: bool):
    """Polygon offsets and zero-based vertex indices of the ``f`` lines, and (with
    ``slashes``) every corner's texture-index token (``b""`` where a corner has none) or
    ``None``. Any problem (fewer than 3 corners, an index that is not an integer, 0, out of
    range, a vertex repeated in a face) is a :class:`MeshError` in the file's terms."""
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
            raise MeshError(_obj_face_problem(lines, name))
        tokens = [t for t in tokens if t != b"f"]
    ttok = None
    if slashes:
        parts = [t.split(b"/", 2) for t in tokens]
        tokens = [q[0] for q in parts]
        ttok = [q[1] if len(q) > 1 else b"" for q in parts]
    try:
        idx = np.array(list(map(int, tokens)), dtype=np.int64)
    except (OverflowError, ValueError):
        raise MeshError(_obj_face_problem(lines, name)) from None
    if sizes is None:
        sizes = np.full(len(flines), 3, dtype=np.int64)
    offsets = np.zeros(sizes.size + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    if (idx == 0).any():
        raise MeshError(_obj_face_problem(lines, name))
    neg = idx < 0
    if neg.any():
        # relative indices count back from the last vertex defined before the face line
        kinds = [ln[:2] for ln in lines if ln[:2] in (b"v ", b"f ")]
        is_v = np.array([k == b"v " for k in kinds], dtype=bool)
        v_before = np.repeat(np.cumsum(is_v)[~is_v], sizes)
        idx = np.where(neg, idx + v_before, idx - 1)
    else:
        idx -= 1
    if idx.size and (idx.min() < 0 or idx.max() >= n) or repeating_faces(offsets, idx,
                                                                          n).any():
        raise MeshError(_obj_face_problem(lines, name))
    return offsets, idx, ttok


def _obj_face_problem(lines: list[bytes], name: str) -> str:
    """The message for the first bad face of an OBJ file, in its own terms: line number,
    1-based face number, the line as written, the index as written (error path only: one
    pass over the file in Python), and how many faces have such problems."""
    n = sum(1 for ln in lines if ln[:2] == b"v ")
    nvt = sum(1 for ln in lines if ln[:3] == b"vt ")
    v_seen = vt_seen = face = bad = 0
    first = None
    for i, ln in enumerate(lines):
        if ln[:2] == b"v ":
            v_seen += 1
            continue
        if ln[:3] == b"vt ":
            vt_seen += 1
            continue
        if ln[:2] != b"f ":
            continue
        face += 1
        why = _bad_face(ln.split()[1:], n, v_seen, nvt, vt_seen)
        if why is None:
            continue
        bad += 1
        if first is None:
            first = f"{name}: line {i + 1}, face {face} ({_shown(ln)}): {why}"
    if first is None:  # pragma: no cover - the vectorised checks and this scan agree
        return f"{name}: bad face indices"
    return first + (f" ({bad} faces have such problems)" if bad > 1 else "")


def _bad_face(corners: list[bytes], n: int, v_seen: int, nvt: int, vt_seen: int) -> str | None:
    """What is wrong with one ``f`` line's corners, or None."""
    if len(corners) < 3:
        return f"has {len(corners)} vertices (a face needs at least 3)"
    used = set()
    for c in corners:
        parts = c.split(b"/")
        for k, (tok, what, total, before) in enumerate(
                ((parts[0], "vertex", n, v_seen),
                 (parts[1] if len(parts) > 1 else b"", "texture coordinate", nvt, vt_seen))):
            if k == 1 and not tok:
                continue
            shown = tok.decode("utf-8", "replace")
            if not re.fullmatch(rb"[+-]?\d+", tok):
                return f"{what} index '{shown}' is not an integer"
            i = int(tok)
            if abs(i) >= 2 ** 63:
                return f"{what} index '{shown}' is too large"
            if i == 0:
                return f"uses {what} index 0 (OBJ indices start at 1)"
            kind = "vertices" if k == 0 else "vt lines"
            if i < 0 and -i > before:
                return (f"relative {what} index {i} reaches before the first one (only "
                        f"{before} {kind} are defined above this line)")
            if i > total:
                return f"{what} {i} does not exist (the file has {total} {kind})"
            if k == 0:
                a = i if i > 0 else before + i + 1  # the file's 1-based number
                if a in used:
                    return f"repeats vertex {a}"
                used.add(a)
    return None


def _shown(line: bytes, limit: int = 60) -> str:
    """A line of the file as written (whitespace collapsed, long lines cut)."""
    text = " ".join(line.decode("utf-8", "replace").split())
    return text if len(text) <= limit else text[:limit - 1] + "…"


def _nth_line(lines: list[bytes], key: bytes, occurrence: int) -> int:
    """1-based number of the ``occurrence``-th line starting with ``key`` (error paths)."""
    seen = 0
    for i, ln in enumerate(lines):
        if ln[:len(key)] == key:
            if seen == occurrence:
                return i + 1
            seen += 1
    return -1  # pragma: no cover


def _face_line(lines: list[bytes], t: int) -> tuple[int, str]:
    """Line number and text of face ``t`` (zero-based) of an OBJ file's lines."""
    at = _nth_line(lines, b"f ", t)
    return at, _shown(lines[at - 1]) if at > 0 else ""


def obj_face(path, t: int) -> str | None:
    """Face ``t`` (zero-based) of the OBJ file ``path`` in the file's own terms, e.g.
    ``"face 5 on line 212 (f 1 2 3 4)"``; ``None`` if ``path`` is not a readable OBJ file
    (error paths only: the file is read again)."""
    p = Path(str(path))
    if p.suffix.lower() != ".obj" or not p.is_file():
        return None
    try:
        data = p.read_bytes()
    except OSError:
        return None
    if b"\\\n" in data or b"\\\r\n" in data:
        data = joined_continuations(data)
    lines = [ln.strip().replace(b"\t", b" ") for ln in data.lstrip(b"\xef\xbb\xbf").splitlines()]
    at, text = _face_line(lines, t)
    if at < 0:
        return None
    return f"face {t + 1} on line {at} ({text})"


def repeating_faces(offsets: np.ndarray, indices: np.ndarray, n: int) -> np.ndarray:
    """Mask of the polygons that name a vertex twice."""
    sizes = np.diff(offsets)
    if sizes.size and (sizes == 3).all():
        F = indices.reshape(-1, 3)
        return (F[:, 0] == F[:, 1]) | (F[:, 1] == F[:, 2]) | (F[:, 2] == F[:, 0])
    key = np.sort(np.repeat(np.arange(sizes.size), sizes) * np.int64(max(n, 1)) + indices)
    bad = np.zeros(sizes.size, dtype=bool)
    bad[key[1:][key[1:] == key[:-1]] // max(n, 1)] = True
    return bad


def _read_with_trimesh(p: Path, ext: str, name: str):
    import trimesh

    if ext == ".off":  # ours: trimesh drops faces of fewer than 3 corners without a word
        return _own_reader(_read_off, p, _off_header_counts(p))
    _check_ply_header(p)
    declared = _ply_header_counts(p)
    own = _read_ply
    try:
        # skip_materials: a PLY comment naming a missing TextureFile (MeshLab) would make
        # trimesh log a traceback to the user's terminal
        loaded = trimesh.load(str(p), file_type=ext[1:], process=False, skip_materials=True)
    except Exception:
        # trimesh does not read binary PLY files that mix polygon sizes; and what it cannot
        # read, ours says in words (its messages are about its own code)
        return _own_reader(own, p, declared)
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
            return _own_reader(own, p, declared)
        if nv is not None and V.shape[0] != nv:
            raise _Unreadable(f"the file declares {nv} vertices but {V.shape[0]} were found "
                              "(truncated?)")
    return V, polygon_offsets(np.full(F.shape[0], 3)), F.ravel()


def _own_reader(own, p: Path, declared):
    """Our PLY/OFF reader on ``p``; its parsing failures become one worded reason."""
    try:
        return own(p)
    except _Unreadable as exc:
        if "truncated" not in str(exc) and "does not match" not in str(exc):
            raise  # a header problem, said as such
        why = str(exc)
    except (ValueError, IndexError, KeyError, TypeError, OverflowError) as exc:
        text = str(exc)
        bad = re.search(r"(?:invalid literal for int\(\) with base 10|could not convert "
                        r"string to float): b?'([^']*)'", text)
        why = (f"'{bad.group(1)}' is not {'an integer' if 'int()' in text else 'a number'}"
               if bad else "values missing or malformed")
    nv, nf = declared if declared is not None else (None, None)
    head = "" if nv is None or nf is None else f", which declares {nv} vertices and {nf} faces"
    raise _Unreadable(f"the data does not match the header{head} ({why}; truncated file or "
                      "wrong counts?)")


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
                # the declared type, as in binary files and trimesh's reader: an ASCII
                # "property float x" is a float32, whichever digits the text has
                cols = {n: rec[:, i].astype(k) if k[0] == "f" else rec[:, i]
                        for i, (n, k) in enumerate(props)}
                pos += count * width
            else:
                dt = np.dtype([(n, order + k) for n, k in props])
                if pos + count * dt.itemsize > len(body):
                    raise _Unreadable(f"element '{ename}' is truncated")
                rec = np.frombuffer(body, dtype=dt, count=count, offset=pos)
                cols = {n: rec[n] for n, _ in props}
                pos += count * dt.itemsize
            if ename == "vertex":
                missing = [c for c in "xyz" if c not in cols]
                if missing:
                    raise _Unreadable(f"the vertex element has no '{missing[0]}' property")
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
                        vals = tokens[pos + 1:pos + 1 + k]  # texcoord lists are floats
                        pos += 1 + k
                    else:
                        cdt, idt = np.dtype(order + kind[1]), np.dtype(order + kind[2])
                        k = int(np.frombuffer(body, cdt, 1, pos)[0])
                        vals = np.frombuffer(body, idt, k, pos + cdt.itemsize)
                        pos += cdt.itemsize + k * idt.itemsize
                    if len(vals) != k:
                        raise _Unreadable(f"element '{ename}' is truncated")
                    if pname in ("vertex_indices", "vertex_index"):
                        lists.append([int(x) for x in vals] if tokens is not None else vals)
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
    return V, polygon_offsets(sizes), indices


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
    if nv < 0 or nf < 0:
        raise _Unreadable(f"the header's vertex and face counts must not be negative, got "
                          f"{nv} and {nf}")
    vrows, frows = rows[start:start + nv], rows[start + nv:start + nv + nf]
    if len(vrows) != nv or len(frows) != nf:
        raise _Unreadable(f"the file declares {nv} vertices and {nf} faces but is shorter")
    V = np.array([r[:3] for r in vrows], dtype=np.float64).reshape(-1, 3)
    sizes = np.array([int(r[0]) for r in frows], dtype=np.int64)
    if any(len(r) <= k for r, k in zip(frows, sizes)):
        raise _Unreadable("a face line is shorter than its vertex count")
    indices = np.array([int(i) for r, k in zip(frows, sizes) for i in r[1:k + 1]],
                       dtype=np.int64)
    return V, polygon_offsets(sizes), indices


def polygon_offsets(sizes: np.ndarray) -> np.ndarray:
    offsets = np.zeros(len(sizes) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    return offsets


def _check_ply_header(p: Path) -> None:
    """Header problems said in words before any reader sees the data: element counts that
    are not non-negative integers, property types PLY does not have, a face element
    without a list of vertex indices."""
    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply"):
        raise _Unreadable("not a PLY file (it does not start with 'ply')")
    if end < 0:
        raise _Unreadable("the PLY header has no end_header (truncated file?)")
    element = None
    face_lists = None
    for k, ln in enumerate(head[:end].decode("ascii", "replace").splitlines(), start=1):
        t = ln.split()
        if len(t) >= 2 and t[0] == "element":
            if len(t) != 3 or not t[2].isdigit():
                raise _Unreadable(f"header line {k}: element '{t[1]}' needs a non-negative "
                                  f"count, got {' '.join(t[2:]) or 'none'!r}")
            element = t[1]
            if element == "face":
                face_lists = []
        elif t and t[0] == "property" and element is not None:
            types = t[2:4] if len(t) >= 2 and t[1] == "list" else t[1:2]
            bad = [x for x in types if x not in _PLY_TYPES]
            if bad or len(t) < (5 if t[1:2] == ["list"] else 3):
                raise _Unreadable(f"header line {k}: not a PLY property: '{ln.strip()}'"
                                  + (f" (unknown type '{bad[0]}')" if bad else ""))
            if element == "face" and t[1] == "list":
                face_lists.append(t[-1])
    if face_lists is not None and not any(n in ("vertex_indices", "vertex_index")
                                          for n in face_lists):
        raise _Unreadable("the face element has no 'vertex_indices' list property")


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


