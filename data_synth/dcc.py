"""Keyframes as a DCC tool (Blender, Maya, 3ds Max) exports them: the stress cases of real files.

:func:`dcc_tube` builds one mesh with everything a clean triangle mesh lacks:

* **quads** (the tube's wall) and an **n-gon** (the 16-sided cap closing its top);
* a **UV seam**: the wall's first column of vertices is duplicated (coincident in every pose),
  and the last column of quads uses the copies, as exporters split vertices at seams;
* a **fin**: a triangle standing out of the wall on an edge that already has two quads;
* an **isolated vertex** (on the axis, used by no face);
* a **second component**: a small quad patch beside the tube, moved rigidly.

Poses bend the tube (the fin, the isolated vertex and the cap follow the same map).
:func:`write_dcc_obj` writes such a mesh the way exporters do: ``mtllib/o/g/s/usemtl`` lines,
``vt``/``vn`` blocks, ``f v/vt/vn`` and ``f v/vt`` corners, negative (relative) indices, an
``l`` line, optionally a UTF-8 byte-order mark and CRLF line ends. :func:`write_polygon_mesh`
writes ASCII PLY or OFF with polygons.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ._common import positive_int
from .io import pose_filenames

__all__ = ["DCC_NAMES", "dcc_tube", "write_dcc_obj", "write_polygon_mesh", "write_dcc"]

#: Names of the DCC stress sets (``python -m data_synth dcc_tube OUT``).
DCC_NAMES = ("dcc_tube",)


def _bend(X: np.ndarray, angle: float, length: float) -> np.ndarray:
    """Bend points about the y axis: the segment ``z in [0, length]`` turns by ``angle``."""
    if abs(angle) < 1e-12:
        return X.copy()
    R = length / angle
    th = angle * X[:, 2] / length
    r = R - X[:, 0]
    return np.stack([R - r * np.cos(th), X[:, 1], r * np.sin(th)], axis=1)


def dcc_tube(around: int = 16, rings: int = 9, bends=(0.0, 1.0, -0.7)) -> dict:
    """A seamed quad tube with an n-gon cap, a fin, an isolated vertex and a second component.

    Parameters
    ----------
    around : int
        Quads around the tube (the cap is an ``around``-gon), at least 4.
    rings : int
        Vertex rings along the tube (``rings - 1`` rows of quads), at least 2.
    bends : sequence of float
        Bend angle (radians) of the tube in each pose; one pose per entry.

    Returns
    -------
    dict
        ``V`` (J,n,3) float64 poses of the exported vertices; ``offsets`` (P+1,) and
        ``indices`` (N,) int64 polygons (``indices[offsets[p]:offsets[p+1]]``, zero-based,
        outward orientation); ``frames`` (J,) int64; ``seam`` (s,2) int64 pairs of
        coincident vertices; ``fin`` the fin's polygon index; ``fin_vertex`` and
        ``isolated`` vertex indices; ``patch`` (q,) the second component's vertices;
        ``uv`` (n,2) texture coordinates; ``pinned`` None.
    """
    around = positive_int(around, "around", 4)
    rings = positive_int(rings, "rings", 2)
    bends = [float(b) for b in bends]
    if len(bends) < 2:
        raise ValueError(f"bends needs at least 2 poses, got {len(bends)}")
    L = 3.0
    a = 2 * np.pi * np.arange(around) / around
    z = np.linspace(0.0, L, rings)
    wall = np.stack([np.tile(np.cos(a), rings), np.tile(np.sin(a), rings),
                     np.repeat(z, around)], axis=1)                  # (rings*around, 3)
    vid = np.arange(rings * around).reshape(rings, around)
    seam = vid[:, 0]
    copies = rings * around + np.arange(rings)                       # duplicated seam column
    col = np.concatenate([vid, copies[:, None]], axis=1)             # (rings, around+1)
    polys: list[list[int]] = []
    for r in range(rings - 1):
        for c in range(around):
            # outward normal for counter-clockwise a and increasing z
            polys.append([col[r, c], col[r, c + 1], col[r + 1, c + 1], col[r + 1, c]])
    polys.append(list(vid[-1]))                                      # cap: outward (+z)
    n_wall = rings * around + rings
    fin_vertex = n_wall
    r_mid, c_mid = rings // 2, around // 4
    e0, e1 = vid[r_mid, c_mid], vid[r_mid + 1, c_mid]
    fin = len(polys)
    polys.append([e0, e1, fin_vertex])
    isolated = n_wall + 1
    patch0 = n_wall + 2
    patch = patch0 + np.arange(9)
    gx, gy = np.meshgrid(np.arange(3) * 0.4, np.arange(3) * 0.4)
    pv = np.stack([gx.ravel() + 2.0, gy.ravel() - 0.4, np.full(9, 0.5)], axis=1)
    for i in range(2):
        for j in range(2):
            q = patch0 + 3 * i + j
            polys.append([q, q + 1, q + 4, q + 3])
    base = np.vstack([wall, wall[seam], wall[e0] + [0.6 * np.cos(a[c_mid]), 0.6 *
                      np.sin(a[c_mid]), 0.5 * L / (rings - 1)], [0.0, 0.0, 0.5 * L], pv])
    V = []
    for j, b in enumerate(bends):
        X = base.copy()
        X[:patch0] = _bend(base[:patch0], b, L)
        t = 0.4 * j
        Rz = np.array([[np.cos(t), -np.sin(t), 0], [np.sin(t), np.cos(t), 0], [0, 0, 1]])
        X[patch0:] = (base[patch0:] - pv.mean(0)) @ Rz.T + pv.mean(0) + [0.3 * j, 0, 0]
        V.append(X)
    V = np.stack(V)
    sizes = np.array([len(p) for p in polys])
    offsets = np.zeros(len(polys) + 1, dtype=np.int64)
    np.cumsum(sizes, out=offsets[1:])
    uv = np.zeros((V.shape[1], 2))
    uv[:rings * around] = np.stack([np.tile(a / (2 * np.pi), rings), np.repeat(z / L, around)], 1)
    uv[rings * around:n_wall] = np.stack([np.ones(rings), z / L], 1)
    return {"V": V, "offsets": offsets,
            "indices": np.concatenate([np.asarray(p, dtype=np.int64) for p in polys]),
            "frames": np.arange(len(bends), dtype=np.int64) * 10,
            "seam": np.stack([seam, copies], axis=1).astype(np.int64), "fin": fin,
            "fin_vertex": fin_vertex, "isolated": isolated, "patch": patch, "uv": uv,
            "pinned": None}


def write_dcc_obj(path, V, offsets, indices, uv=None, *, bom: bool = False,
                  crlf: bool = False) -> Path:
    """Write one pose as an exporter would (see module doc); coordinates with ``%.17g``.

    Parameters
    ----------
    path : str or path-like
    V : (n,3) float array
    offsets : (P+1,) int array
    indices : (N,) int array
        Zero-based polygon corners.
    uv : (n,2) float array, optional
        Texture coordinates (one per vertex); default zeros.
    bom : bool
        Start the file with a UTF-8 byte-order mark.
    crlf : bool
        End lines with CRLF.

    Returns
    -------
    Path
    """
    V = np.asarray(V, dtype=np.float64)
    n = V.shape[0]
    uv = np.zeros((n, 2)) if uv is None else np.asarray(uv, dtype=np.float64)
    offsets, indices = np.asarray(offsets), np.asarray(indices)
    P = offsets.size - 1
    lines = ["# exported by data_synth.dcc", "mtllib tube.mtl", "o Tube"]
    lines += ["v %.17g %.17g %.17g" % tuple(v) for v in V]
    lines += ["vt %.6f %.6f" % tuple(t) for t in uv]
    lines += ["vn 0.0 0.0 1.0", "vp 0.5", "g wall", "s 1", "usemtl skin"]
    for p in range(P):
        c = indices[offsets[p]:offsets[p + 1]] + 1
        if p == P - 1:                       # relative indices, as some exporters write
            lines.append("f " + " ".join(f"{i - n - 1}/{i - n - 1}/-1" for i in c))
        elif p % 3 == 1:
            lines.append("f " + " ".join(f"{i}/{i}" for i in c))
        else:
            lines.append("f " + " ".join(f"{i}/{i}/1" for i in c))
        if p == P // 2:
            lines += ["g other", "s off", "usemtl bark"]
    lines.append("l 1 2")
    text = ("\r\n" if crlf else "\n").join(lines) + ("\r\n" if crlf else "\n")
    path = Path(path)
    path.write_bytes((b"\xef\xbb\xbf" if bom else b"") + text.encode("ascii"))
    return path


def write_polygon_mesh(path, V, offsets, indices, fmt: str | None = None) -> Path:
    """Write one pose as ASCII PLY or OFF with polygon faces (zero-based, as given).

    Parameters
    ----------
    path : str or path-like
    V : (n,3) float array
    offsets, indices : int arrays
        Polygons as in :func:`write_dcc_obj`.
    fmt : {"ply", "off"}, optional
        Default: from the file suffix.

    Returns
    -------
    Path
    """
    path = Path(path)
    fmt = (fmt or path.suffix.lstrip(".")).lower()
    if fmt not in ("ply", "off"):
        raise ValueError(f"fmt must be 'ply' or 'off', got {fmt!r}")
    V = np.asarray(V, dtype=np.float64)
    P = len(offsets) - 1
    faces = ["%d %s" % (offsets[p + 1] - offsets[p],
                        " ".join(map(str, indices[offsets[p]:offsets[p + 1]])))
             for p in range(P)]
    verts = ["%.17g %.17g %.17g" % tuple(v) for v in V]
    if fmt == "ply":
        head = ["ply", "format ascii 1.0", f"element vertex {len(V)}", "property double x",
                "property double y", "property double z", f"element face {P}",
                "property list uchar int vertex_indices", "end_header"]
    else:
        head = ["OFF", f"{len(V)} {P} 0"]
    path.write_text("\n".join(head + verts + faces) + "\n", encoding="ascii")
    return path


def write_dcc(name: str, out_dir, fmt: str = "obj") -> list[Path]:
    """Write a DCC stress set: ``pose_00.<fmt> ...`` and ``frames.txt``.

    Parameters
    ----------
    name : str
        One of :data:`DCC_NAMES`.
    out_dir : str or path-like
        Created if missing.
    fmt : {"obj", "ply", "off"}
        OBJ files get a byte-order mark and CRLF line ends.

    Returns
    -------
    list of Path
    """
    if name not in DCC_NAMES:
        raise ValueError(f"name must be one of {DCC_NAMES}, got {name!r}")
    if fmt not in ("obj", "ply", "off"):
        raise ValueError(f"fmt must be 'obj', 'ply' or 'off', got {fmt!r}")
    d = dcc_tube()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for fname, X in zip(pose_filenames(d["V"].shape[0], fmt), d["V"]):
        if fmt == "obj":
            paths.append(write_dcc_obj(out / fname, X, d["offsets"], d["indices"], d["uv"],
                                       bom=True, crlf=True))
        else:
            paths.append(write_polygon_mesh(out / fname, X, d["offsets"], d["indices"], fmt))
    np.savetxt(out / "frames.txt", d["frames"], fmt="%d")
    return paths
