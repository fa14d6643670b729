"""Writing and reading interpolated sequences, atomically.

Output: :func:`write_sequence` writes ``frame_0000.obj ... frame_K.obj`` (or binary
little-endian PLY with ``double`` coordinates) and ``report.json`` atomically: all files go
into a temporary sibling directory which is renamed into place at the end.
"""
from __future__ import annotations

import dataclasses
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np

from ..errors import MeshError, ShellsplineError, one_line
from ..mesh.source_mesh import triangulate_polygons
from .atomic import move_into_place, on_user_path, temporary_directory
from .keyframes import check_same_polygons
from .meshes import check_indices, read_polygons

__all__ = ["write_sequence", "check_output_dir", "read_sequence", "jsonable", "GLB_NAME",
           "SEQUENCE_FORMATS", "ANIMATION_NAMES", "MESH_NAME", "write_obj_frame",
           "write_ply_frame", "natural_key", "frame_files"]

FRAME_RE = re.compile(r"^frame_(\d+)\.(obj|ply)$")
GLB_NAME = "animation.glb"
"""File name of the sequence in an output directory written with ``fmt="glb"``."""
SEQUENCE_FORMATS = ("obj", "ply", "glb", "mdd", "pc2", "usd")
"""The ``fmt`` values of :func:`write_sequence`."""
ANIMATION_NAMES = {"glb": GLB_NAME, "mdd": "animation.mdd", "pc2": "animation.pc2",
                   "usd": "animation.usdc"}
"""The one animation file of an output directory, by format (``obj``/``ply``: frame files)."""
MESH_NAME = "mesh.obj"
"""The mesh a point cache (``mdd``/``pc2``) animates, beside it in the output directory."""



def natural_key(name: str) -> list:
    """Sort key that orders the digit runs of a name by value: ``mesh.2.obj`` before
    ``mesh.10.obj`` (Houdini's ``$F``, Maya's ``name.#`` write frame numbers unpadded)."""
    return [(1, int(t), "") if t.isdigit() else (0, 0, t)
            for t in re.split(r"(\d+)", str(name)) if t]


def frame_files(folder) -> list[Path]:
    """The mesh files (OBJ/PLY/OFF) of ``folder`` in natural name order
    (:func:`natural_key`), e.g. the frames of an animation exported one file per frame.

    Other files (``report.json``, materials, notes) are left out, and so are hidden ones
    (a name that starts with ``.``: the ``._frame_0001.obj`` resource forks macOS writes
    beside every file on a FAT/exFAT drive or a network share, binary data that were read
    as frames or refused as another sequence). Formats may be mixed.

    The frame number is the run of digits that differs between the names, wherever it
    stands: ``frame_0001_v2.obj, frame_0002_v2.obj ...`` (a version suffix, as DCC tools
    export) are frames 1, 2 ... (they were refused as one sequence per file, each numbered
    by its last digits). Where several runs differ, the last one is the frame number and
    the others must not differ: two takes in one folder (``take1_0001.obj ...
    take2_0001.obj ...``) are refused as two sequences, not read as one.

    Raises
    ------
    MeshError
        When the mesh files are not one numbered sequence: a file named otherwise than the
        others (``rest.obj`` beside ``frame_0001.obj ...``; it was read as the first frame),
        or two files of one frame number (``frame_3.obj`` and ``frame_0003.ply``; both were
        read, one after the other).
    """
    from .meshes import MESH_EXTENSIONS

    files = sorted((f for f in Path(folder).iterdir() if f.suffix.lower() in MESH_EXTENSIONS
                    and not f.name.startswith(".") and f.is_file()),
                   key=lambda f: (natural_key(f.name), f.name))  # ties: not the listing's
    number = _frame_number_runs([f.stem for f in files])
    patterns: dict = {}  # the name with its frame number as '#' (no extension): its files
    numbers = []
    for f in files:
        parts = re.split(r"(\d+)", f.stem)  # text, digits, text, ..., text
        i = number[tuple(parts[0::2])]
        if i is None:
            patterns.setdefault(f.stem, []).append(f)
            numbers.append(None)
        else:
            patterns.setdefault("".join(parts[:2 * i + 1] + ["#"] + parts[2 * i + 2:]),
                                []).append(f)
            numbers.append(int(parts[2 * i + 1]))
    if len(patterns) > 1:
        (_, f0), (_, f1) = sorted(patterns.items(), key=lambda kv: -len(kv[1]))[:2]
        raise MeshError(f"{folder}: the mesh files are not one numbered sequence: "
                        f"{len(f0)} named like {f0[0].name}, {len(f1)} like {f1[0].name}; "
                        "keep one animation's frames in the folder")
    for i in range(1, len(files)):  # natural order: one number's files are neighbours
        if numbers[i] is not None and numbers[i] == numbers[i - 1]:
            raise MeshError(f"{folder}: two files of frame {numbers[i]}: {files[i - 1].name} "
                            f"and {files[i].name}")
    return files


def _frame_number_runs(stems) -> dict:
    """For each shape of name among ``stems`` (its text between the runs of digits), which
    run of digits is the frame number (0 the first), or None for a name without digits.

    It is the run whose value differs between the names of that shape, the last one where
    several differ (the others then name several sequences, which :func:`frame_files`
    refuses), and the last run where none differs (one file, or one frame written twice).
    """
    values: dict = {}  # shape: the set of values of each run
    for stem in stems:
        parts = re.split(r"(\d+)", stem)
        runs = values.setdefault(tuple(parts[0::2]), [set() for _ in parts[1::2]])
        for seen, digits in zip(runs, parts[1::2]):
            seen.add(int(digits))
    out = {}
    for shape, runs in values.items():
        varying = [i for i, seen in enumerate(runs) if len(seen) > 1]
        out[shape] = varying[-1] if varying else (len(runs) - 1 if runs else None)
    return out


# ----------------------------------------------------------------------------------------
# Writing sequences
# ----------------------------------------------------------------------------------------
def write_sequence(out_dir, V, F, report=None, *, fmt: str = "obj", overwrite: bool = False,
                   protect=(), workers: int = 1, fps: float = 24.0, source=None,
                   up_axis: str = "y", overwrite_hint: str = "overwrite=True") -> Path:
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
    fmt : {"obj", "ply", "glb", "mdd", "pc2", "usd"}
        ``"obj"``: text, coordinates with 17 significant digits (``%.17g``), so that every
        float64 reads back bit-identically. ``"ply"``: binary little-endian PLY with
        ``double`` coordinates (exact, smaller and faster). ``"glb"``: one file
        ``animation.glb`` (binary glTF: frame 0 as the base mesh, one morph target per later
        frame, an animation playing them at ``fps``; float32, see :mod:`shellspline.io.gltf`).
        ``"mdd"``/``"pc2"``: a point cache ``animation.mdd`` / ``animation.pc2`` (float32,
        :mod:`shellspline.io.pointcache`; MDD times ``k / fps``, PC2 start frame 0 and one
        sample per frame) and the mesh it animates, ``mesh.obj`` (frame 0). ``"usd"``:
        ``animation.usdc``, one mesh with time-sampled points at ``fps``
        (:mod:`shellspline.io.usd`, needs ``pxr``).
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
        Frames per second of the GLB animation, the MDD frame times and the USD stage.
    source : SourceMesh, optional
        Write the input's mesh back (:attr:`Keyframes.source`): ``V`` is then
        ``(K+1,n_source,3)`` in the input's vertex indexing (:meth:`SourceMesh.expand`), and
        OBJ and PLY frames get the input's polygons (OBJ also its texture coordinates and
        ``mtllib/usemtl/o/g/s`` lines), as does the ``mesh.obj`` of a point cache (whose
        points are the input's vertices); USD gets the polygons, GLB the triangles; ``F``
        is not used.
    up_axis : {"y", "z"}
        The up axis of ``V``'s coordinates: the USD stage's ``upAxis`` (``fmt="usd"``) and the
        GLB node's rotation onto glTF's y-up (``fmt="glb"``; the vertex data are unchanged).
    overwrite_hint : str
        As for :func:`check_output_dir`.

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
    try:
        V = np.asarray(V, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ShellsplineError(f"V must be a numeric (K+1,n,3) array of poses: "
                               f"{str(exc).splitlines()[0] if str(exc) else exc!r}") from None
    if V.ndim != 3 or V.shape[2] != 3 or V.shape[0] == 0:
        raise ShellsplineError(f"V must be a (K+1,n,3) array of poses, got shape {V.shape}")
    finite = np.isfinite(V).all(axis=2)
    if not finite.all():
        k, i = (int(x) for x in np.argwhere(~finite)[0])
        raise ShellsplineError(f"V has NaN/inf coordinates ({int((~finite).sum())} vertex "
                               f"positions; first: frame {k}, vertex {i}); nothing written")
    polygons = None
    if source is not None:
        if V.shape[1] != source.n_source:
            raise ShellsplineError(f"with `source`, V must hold the input's {source.n_source} "
                                   f"vertices (SourceMesh.expand), got shape {V.shape}")
        F = source.triangles
        statements = getattr(source, "statements", None)
        if (np.diff(source.poly_offsets) != 3).any() or source.uv is not None or \
                statements is not None:
            polygons = (source.poly_offsets, source.poly_indices, source.uv, source.corner_uv,
                        statements)
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
    if fmt not in SEQUENCE_FORMATS:
        raise ShellsplineError(f"fmt must be one of {', '.join(SEQUENCE_FORMATS)}, got {fmt!r}")
    if fmt == "glb":
        from .gltf import glb_bytes

        glb = glb_bytes(V, F, fps=fps, up_axis=up_axis)  # validated before anything is made
    elif fmt in ("mdd", "pc2"):
        from .pointcache import mdd_bytes, pc2_bytes

        glb = mdd_bytes(V, fps=fps) if fmt == "mdd" else pc2_bytes(V)  # validated here
    workers = int(workers)
    if workers < 1:
        raise ShellsplineError(f"workers must be >= 1, got {workers}")
    report_text = json.dumps(jsonable({} if report is None else report, "report"),
                             indent=2) + "\n"

    out = Path(out_dir)
    target = check_output_dir(out, n_frames=V.shape[0], n_vertices=n, n_faces=F.shape[0],
                              fmt=fmt, overwrite=overwrite, protect=protect,
                              overwrite_hint=overwrite_hint)
    if polygons is not None and polygons[4] is not None:
        polygons = polygons[:4] + (_mtllib_from(polygons[4], target),)
    parent = target.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
        tmp = temporary_directory(target)
    except OSError as exc:
        raise on_user_path(exc, out, "creating") from None
    try:
        if fmt in ("glb", "mdd", "pc2"):
            (tmp / ANIMATION_NAMES[fmt]).write_bytes(glb)
            if fmt != "glb":
                _write_frames([tmp / MESH_NAME], V[:1], F, "obj", 1, polygons)
        elif fmt == "usd":
            from .usd import write_usd

            write_usd(tmp / ANIMATION_NAMES[fmt], V, F, fps=fps, up_axis=up_axis,
                      polygons=None if polygons is None else polygons[:2])
        else:
            K = V.shape[0] - 1
            width = max(4, len(str(K)))
            paths = [tmp / f"frame_{k:0{width}d}.{fmt}" for k in range(K + 1)]
            _write_frames(paths, V, F, fmt, workers, polygons)
        (tmp / "report.json").write_text(report_text, encoding="utf-8")
        move_into_place(tmp, target, overwrite)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, FileExistsError) and exc.errno is None:
            raise  # our own message: the output appeared while we were writing
        raise on_user_path(exc, out, "writing", tmp) from None
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


#: Lower estimates of the bytes per vertex and per face of one frame (the space check must
#: never refuse an output that fits): OBJ ``v x y z`` lines with 17 significant digits are
#: 55-65 bytes, a face line ``f a b c`` 8 bytes and more; PLY stores 3 doubles per vertex and
#: 13 bytes per face; GLB 24 bytes per vertex and frame (float32 position and normal deltas);
#: MDD, PC2 and USD 12 (float32 positions; the faces are written once).
_BYTES_PER_VERTEX = {"obj": 50, "ply": 24, "glb": 24, "mdd": 12, "pc2": 12, "usd": 12}
_BYTES_PER_FACE = {"obj": 8, "ply": 13, "glb": 0, "mdd": 0, "pc2": 0, "usd": 0}


def check_output_dir(out_dir, *, n_frames: int = 0, n_vertices: int = 0, n_faces: int = 0,
                     fmt: str = "obj", overwrite: bool = False, protect=(),
                     overwrite_hint: str = "overwrite=True") -> Path:
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
    fmt : {"obj", "ply", "glb", "mdd", "pc2", "usd"}
        Output format (bytes per vertex differ; ``"usd"`` also needs ``pxr``).
    overwrite, protect
        As for :func:`write_sequence`.
    overwrite_hint : str
        How the message for an existing ``out_dir`` says to replace it (the command line
        passes ``"--overwrite"``).

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
        replace a protected input, the file system has too little free space, or ``fmt`` is
        ``"usd"`` and ``pxr`` is not installed.

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
        raise ShellsplineError(f"fmt must be one of {', '.join(SEQUENCE_FORMATS)}, got {fmt!r}")
    if fmt == "usd":  # the missing extra before the solve, not after it
        from .usd import require_usd
        require_usd()
    target = out.resolve()
    _check_destination(target, out, overwrite, protect, overwrite_hint)
    base = target.parent
    while not base.is_dir():
        if base.exists() or base.is_symlink():
            raise ShellsplineError(f"cannot create output directory '{out}': '{base}' is a "
                                   "file, not a directory")
        base = base.parent
    try:  # a directory created and removed: os.access knows neither read-only mounts nor root
        temporary_directory(base / target.name).rmdir()
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


def _check_destination(target: Path, out: Path, overwrite: bool, protect,
                       hint: str = "overwrite=True") -> None:
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
        raise FileExistsError(f"output directory '{out}' already exists (use {hint} to "
                              "replace it)")
    cwd = Path.cwd().resolve()
    if cwd == target or target in cwd.parents:
        raise ShellsplineError(f"refusing to replace '{out}': it contains the current working "
                               "directory")
    if any(target.iterdir()) and not (target / "report.json").is_file():
        raise ShellsplineError(f"refusing to replace '{out}': it is not empty and has no "
                               "report.json, so it does not look like an earlier output")


def _write_frames(paths: list[Path], V: np.ndarray, F: np.ndarray, fmt: str,
                  workers: int, polygons=None) -> None:
    head = b""
    if polygons is None:
        block = _obj_faces_block(F) if fmt == "obj" else _ply_faces_bytes(F)
        m = F.shape[0]
    else:  # the input's polygons (offsets, indices, uv, corner_uv, OBJ statements)
        if fmt == "obj":
            head, block = _obj_polygons_block(*polygons)
        else:
            block = _ply_polygons_bytes(*polygons[:2])
        m = polygons[0].size - 1
    workers = min(workers, len(paths))
    if workers <= 1:
        for k, p in enumerate(paths):
            if fmt == "obj":
                _obj_frame(p, V[k], block, head)
            else:
                write_ply_frame(p, V[k], block, m)
        return
    from ..parallel import process_pool

    chunks = np.array_split(np.arange(len(paths)), workers)
    with process_pool(workers) as ex:  # workers stopped at once on Ctrl-C/SIGTERM
        futures = [ex.submit(_write_frames_chunk, [paths[k] for k in c], V[c], block, fmt,
                             m, head) for c in chunks]
        try:
            for fut in futures:
                fut.result()
        except BaseException:
            for fut in futures:
                fut.cancel()
            raise


def _write_frames_chunk(paths, Vc, block, fmt, m, head=b"") -> None:
    for p, X in zip(paths, Vc):
        if fmt == "obj":
            _obj_frame(p, X, block, head)
        else:
            write_ply_frame(p, X, block, m)


def _obj_frame(path, X, block, head) -> None:
    """:func:`write_obj_frame`, called with ``head`` only when there is one."""
    if head:
        write_obj_frame(path, X, block, head)
    else:
        write_obj_frame(path, X, block)


def _obj_faces_block(F: np.ndarray) -> bytes:
    """The ``f a b c`` lines (1-based) of every frame, formatted once."""
    return (("f %d %d %d\n" * F.shape[0]) % tuple((F + 1).ravel().tolist())).encode("ascii")


def _mtllib_from(statements, folder: Path):
    """``statements`` with each ``mtllib`` file, named by absolute path
    (:func:`~shellspline.io.meshes.mtllib_resolved`), named as seen from ``folder``."""
    # The output frames name the input's own .mtl file rather than a copy of it: a viewer
    # resolves the texture maps a .mtl names (map_Kd ...) from the .mtl's folder, so a copy
    # next to the outputs would lose them (and copying the textures too would copy files we
    # know nothing of), and nothing is written beside the frames that could replace a .mtl of
    # the user's. The path is relative (the output folder and the input's moved together keep
    # their materials) unless the two share no folder but the root (or lie on other drives):
    # then absolute, which survives moving the output alone. Lines that name no absolute path
    # (statements made in Python) are written as given.
    def line(t):
        if t[:7] != b"mtllib ":
            return t
        name = os.fsdecode(t[7:].strip())
        if not os.path.isabs(name):
            return t
        try:
            common = os.path.commonpath([name, str(folder)])
            rel = os.path.relpath(name, folder)
        except ValueError:  # other drives (Windows)
            return t
        if common == os.path.dirname(common):  # only the root (or a drive) in common
            return t
        return b"mtllib " + os.fsencode(Path(rel).as_posix())

    head, body = statements
    return tuple(map(line, head)), tuple((q, line(t)) for q, t in body)


def _obj_polygons_block(offsets: np.ndarray, indices: np.ndarray, uv=None,
                        corner_uv=None, statements=None) -> tuple[bytes, bytes]:
    """``(head, block)``: the input's OBJ lines that go before the vertices (``mtllib``,
    ``o``...) and the ``f a b c ...`` lines (1-based) of polygons, formatted once; with
    texture coordinates the ``vt`` lines first and ``f a/ta b/tb ...`` corners; the input's
    ``usemtl/g/o/s`` lines (``statements``, :attr:`SourceMesh.statements`) where they stood
    among the faces."""
    sizes = np.diff(offsets)
    corner = " %d" if uv is None else " %d/%d"
    lines = ["f" + corner * int(s) + "\n" for s in sizes]
    head = b""
    if statements is not None:
        top, body = statements
        head = b"".join(t + b"\n" for t in top)
        for p, t in reversed(body):  # later positions first: earlier ones stay valid
            text = t.decode("utf-8", "surrogateescape").replace("%", "%%")
            lines.insert(min(int(p), len(lines)), text + "\n")
    fmt = "".join(lines)
    if uv is None:
        text = fmt % tuple((indices + 1).tolist())
    else:
        vt = ("vt %.17g %.17g\n" * uv.shape[0]) % tuple(uv.ravel().tolist())
        corners = np.stack([indices + 1, corner_uv + 1], axis=1).ravel()
        text = vt + fmt % tuple(corners.tolist())
    return head, text.encode("utf-8", "surrogateescape")


def _ply_polygons_bytes(offsets: np.ndarray, indices: np.ndarray) -> bytes:
    """Binary PLY face records ``uchar count, int32 indices...`` of polygons."""
    sizes = np.diff(offsets)
    P = sizes.size
    out = np.zeros(P + 4 * indices.size, dtype=np.uint8)
    out[4 * offsets[:-1] + np.arange(P)] = sizes
    pos = 4 * np.arange(indices.size) + np.repeat(np.arange(P), sizes) + 1
    out[pos[:, None] + np.arange(4)] = indices.astype("<i4").view(np.uint8).reshape(-1, 4)
    return out.tobytes()


def write_obj_frame(path: Path, V: np.ndarray, faces_block: bytes, head: bytes = b"") -> None:
    """Write one OBJ frame (a plain write into :func:`write_sequence`'s temporary directory).

    Parameters
    ----------
    path : pathlib.Path
    V : (n,3) float array
        The pose; ``%.17g`` round-trips every float64 exactly.
    faces_block : bytes
        The ``f`` lines, formatted once for all frames.
    head : bytes
        Lines written before the vertices (the input's ``mtllib``, ``o`` ...).
    """
    verts = ("v %.17g %.17g %.17g\n" * V.shape[0]) % tuple(V.ravel().tolist())
    with open(path, "wb") as fh:
        fh.write(head)
        fh.write(verts.encode("ascii"))
        fh.write(faces_block)


def _ply_faces_bytes(F: np.ndarray) -> bytes:
    rec = np.zeros(F.shape[0], dtype=[("count", "u1"), ("idx", "<i4", (3,))])
    rec["count"] = 3
    rec["idx"] = F
    return rec.tobytes()


def write_ply_frame(path: Path, V: np.ndarray, faces_bytes: bytes, m: int) -> None:
    """Write one binary little-endian PLY frame (double coordinates; a plain write, as
    :func:`write_obj_frame`): ``V (n,3)``, the ``m`` faces' records ``faces_bytes``."""
    header = ("ply\nformat binary_little_endian 1.0\ncomment written by shellspline\n"
              f"element vertex {V.shape[0]}\nproperty double x\nproperty double y\n"
              f"property double z\nelement face {m}\n"
              "property list uchar int vertex_indices\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(np.ascontiguousarray(V, dtype="<f8").tobytes())
        fh.write(faces_bytes)


def jsonable(obj, where: str = "report", *, finite: bool = False):
    """``obj`` with JSON-native types only: numpy scalars and arrays, paths, tuples, sets and
    dataclasses converted; with ``finite=True`` non-finite floats become ``None`` (strict
    JSON, ``json.dumps(..., allow_nan=False)`` accepts the result).

    Raises
    ------
    ShellsplineError
        Naming the offending entry (``where`` and its keys) for a value or key JSON cannot
        hold.
    """
    if obj is None or isinstance(obj, (str, bool, int)):
        return obj
    if isinstance(obj, float):
        return None if finite and not np.isfinite(obj) else obj
    if isinstance(obj, np.generic):
        return jsonable(obj.item(), where, finite=finite)
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist(), where, finite=finite) if finite else obj.tolist()
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
            out[key] = jsonable(v, f"{where}[{k!r}]", finite=finite)
        return out
    if isinstance(obj, (list, tuple)):
        return [jsonable(v, f"{where}[{i}]", finite=finite) for i, v in enumerate(obj)]
    if isinstance(obj, (set, frozenset)):
        return [jsonable(v, where, finite=finite) for v in sorted(obj, key=repr)]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable({f.name: getattr(obj, f.name) for f in dataclasses.fields(obj)},
                        where, finite=finite)
    raise ShellsplineError(f"{where}: value of type {type(obj).__name__} cannot be written to "
                           "JSON")


def read_sequence(out_dir) -> tuple[np.ndarray, np.ndarray, dict]:
    """Read a directory written by :func:`write_sequence`, or a ``.glb`` animation file.

    Frame files (``frame_*.obj`` / ``frame_*.ply``) are read when present, else
    ``animation.glb`` (float32 coordinates, see :func:`shellspline.io.gltf.read_glb`), else
    ``animation.mdd`` / ``animation.pc2`` with ``mesh.obj``, else ``animation.usdc``. Frames
    written with the input's polygons are triangulated once for the whole sequence
    (:func:`shellspline.mesh.source_mesh.triangulate_polygons`), on the keyframes that
    ``report.json`` names (``parameters.frames``: the triangles the solve used) or, without
    them, on every frame.

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
        mt = FRAME_RE.match(p.name)
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
        for fmt in ("mdd", "pc2", "usd"):
            if (d / ANIMATION_NAMES[fmt]).is_file():
                report = _read_report(d)
                return (*_read_animation(d, fmt, report), report)
        raise MeshError(f"{d}: no frame_*.obj, frame_*.ply or "
                        f"{', '.join(ANIMATION_NAMES.values())} files")
    ks = sorted(found)
    if ks != list(range(len(ks))):
        missing = sorted(set(range(ks[-1] + 1)) - set(ks))
        raise MeshError(f"{d}: frames are not numbered 0..{ks[-1]} without gaps (missing "
                        f"{missing[:5]})")
    Vs = []
    for k in ks:
        name = str(found[k])
        V, offsets, indices, _ = read_polygons(found[k])
        if not Vs:
            off0, idx0, name0 = offsets, indices, name
            check_indices(offsets, indices, V.shape[0], name)
        else:
            if V.shape[0] != Vs[0].shape[0]:
                raise MeshError(f"{name} has {V.shape[0]} vertices but {name0} has "
                                f"{Vs[0].shape[0]}")
            check_same_polygons(offsets, indices, off0, idx0, name, name0)
        Vs.append(V)
    V = np.stack(Vs)
    report = _read_report(d)
    F, _ = triangulate_polygons(_keyframe_poses(V, report), off0, idx0, name0)
    return V, F, report


def _keyframe_poses(V: np.ndarray, report: dict) -> np.ndarray:
    """The poses to triangulate a written sequence's polygons on: its keyframes, when
    ``report.json`` names them (``parameters.frames``, as :func:`shellspline.interpolate`
    writes it; the keyframes are written exactly, so the triangles are those it solved on),
    else every frame."""
    try:
        frames = np.asarray(report["parameters"]["frames"], dtype=np.int64).ravel()
    except (KeyError, TypeError, ValueError, OverflowError):
        return V
    if frames.size < 1 or frames.min() < 0 or frames.max() >= V.shape[0]:
        return V
    return V[frames]


def _read_animation(d: Path, fmt: str, report=None) -> tuple[np.ndarray, np.ndarray]:
    """Poses and triangles of a point cache with its ``mesh.obj``, or of a USD file."""
    p = d / ANIMATION_NAMES[fmt]
    try:
        if fmt == "usd":
            from .usd import read_usd

            V, offsets, indices, _ = read_usd(p)
            name = str(p)
        else:
            from .pointcache import read_mdd, read_pc2

            V = read_mdd(p)[0] if fmt == "mdd" else read_pc2(p)[0]
            name = str(d / MESH_NAME)
            V0, offsets, indices, _ = read_polygons(d / MESH_NAME)
            if V0.shape[0] != V.shape[1]:
                raise MeshError(f"{p} has {V.shape[1]} points but {name} has {V0.shape[0]} "
                                "vertices")
    except ShellsplineError as exc:
        raise MeshError(str(exc)) from None
    check_indices(offsets, indices, V.shape[1], name)
    F, _ = triangulate_polygons(_keyframe_poses(V, report or {}), offsets, indices, name)
    return V, F


def _read_report(d: Path) -> dict:
    rp = d / "report.json"
    if not rp.is_file():
        return {}
    try:
        return json.loads(rp.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise MeshError(f"cannot read '{rp}': {one_line(exc)}") from None

