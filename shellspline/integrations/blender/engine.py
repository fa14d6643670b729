"""The add-on's engine: keyframe arrays in, interpolated frames out; no ``bpy`` here.

Two back ends:

* ``"library"``: ``import shellspline`` in Blender's own Python (installed there with
  Blender's pip) and call :func:`shellspline.interpolate` in-process (progress per frame);
* ``"cli"``: run an external ``shellspline`` executable (any Python environment) on OBJ
  keyframes written to a temporary folder, with ``--format pc2``, and read the PC2 file and
  ``report.json`` back. This module must therefore work without ``shellspline`` importable:
  it needs only numpy (bundled with Blender) and the standard library, and carries its own
  small OBJ writer and PC2 reader for this path.

Frames: keyframe ``j`` sits at Blender frame ``frames[j]``; the result covers the frames
``frames[0] .. frames[0] + K`` (``K = frames[-1] - frames[0]`` unless given).
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass, field

import numpy as np

BACKENDS = ("auto", "library", "cli")
METHODS = ("lta", "linear", "geodesic", "nonlinear")
BOUNDARY_CONDITIONS = ("natural", "periodic", "hermite")
RIGID_TRACKS = ("fit", "spline", "linear")


@dataclass
class Options:
    """Interpolation settings, as the CLI spells them (``shellspline interpolate --help``)."""

    method: str = "lta"
    bc: str = "natural"
    eta: float = 1e-3
    coarse: str = "auto"
    fine: bool = False
    rigid_track: str = "fit"
    max_iter: int = 0  # 0: the library's default

    def __post_init__(self):
        for name, allowed in (("method", METHODS), ("bc", BOUNDARY_CONDITIONS),
                              ("rigid_track", RIGID_TRACKS)):
            if getattr(self, name) not in allowed:
                raise ValueError(f"{name} must be one of {', '.join(allowed)}, got "
                                 f"{getattr(self, name)!r}")
        if not (self.eta > 0 and np.isfinite(self.eta)):
            raise ValueError(f"eta must be a positive number, got {self.eta}")


@dataclass
class Result:
    """Interpolated frames ``V (K+1,n,3)`` at Blender frames ``start .. start + K``."""

    V: np.ndarray
    start: int
    report: dict = field(default_factory=dict)
    backend: str = "library"

    @property
    def problems(self) -> list:
        """:func:`problems` of the report, frames numbered as Blender's timeline."""
        return problems(self.report, start=self.start)


def problems(report: dict, start: int = 0) -> list:
    """One line per problem the report records: frames whose Gauss–Newton stalled or hit the
    iteration limit, new flipped/collapsed faces, folded edges, pops, keyframes not exact,
    a geodesic/nonlinear solver that did not converge.

    The report numbers frames from 0 (the first keyframe); ``start`` (the first keyframe's
    Blender frame) is added, so that the lines name the frames of Blender's timeline."""
    out = []
    gn = report.get("gauss_newton") or {}
    for key, what in (("stalled", "stalled"), ("iteration_limit", "at the iteration limit")):
        fr = [int(f) + start for f in gn.get(key) or []]
        if fr:
            out.append(f"Gauss-Newton {what} at frames {fr[:8]}{' ...' if len(fr) > 8 else ''}")
    q = report.get("quality") or {}
    if q and not q.get("keyframes_exact", True):
        out.append("keyframes are not reproduced exactly")
    for key, what in (("flipped_faces", "new flipped faces"),
                      ("collapsed_faces", "collapsed faces"), ("folded_edges", "folded edges")):
        if q.get(key):
            worst = [int(f) + start for f in q.get("worst_frames", [])[:5]]
            out.append(f"{q[key]} {what} (worst frames {worst})")
    if q.get("pop", 0.0) > q.get("pop_limit", 2.0):
        at = q.get("pop_frame")
        out.append(f"pop {q['pop']:.2f} at frame {at if at is None else int(at) + start} "
                   "(a jump between frames)")
    for name in ("geodesic", "nonlinear"):
        r = report.get(name)
        if r and not r.get("success", True):
            out.append(f"{name} solver did not converge: {r.get('message', '')}")
    return out


def library_available() -> bool:
    """Whether ``shellspline`` can be imported in this Python."""
    from importlib.util import find_spec

    return find_spec("shellspline") is not None


def _checked(Vkeys, F, frames, K):
    Vkeys = np.asarray(Vkeys, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    frames = np.asarray(frames, dtype=np.int64)
    if Vkeys.ndim != 3 or Vkeys.shape[0] < 2 or Vkeys.shape[2] != 3:
        raise ValueError(f"need at least two keyframe poses (J,n,3), got shape {Vkeys.shape}")
    if frames.shape != (Vkeys.shape[0],) or (np.diff(frames) <= 0).any():
        raise ValueError(f"keyframe frames must be {Vkeys.shape[0]} strictly increasing "
                         f"integers, got {frames.tolist()}")
    start = int(frames[0])
    K = int(frames[-1] - start) if not K else int(K)
    return Vkeys, F, frames - start, K, start


def interpolate(Vkeys, F, frames, *, K=None, options: Options | None = None, pinned=None,
                backend: str = "auto", executable: str = "", progress=None) -> Result:
    """Interpolate keyframe poses of one mesh with the chosen back end.

    Parameters
    ----------
    Vkeys : (J,n,3) float array
        Keyframe poses in Blender's vertex order.
    F : (m,3) int array
        Triangles (zero-based).
    frames : (J,) int array
        Blender frames of the keyframes, strictly increasing.
    K : int, optional
        Last frame relative to ``frames[0]`` (default ``frames[-1] - frames[0]``).
    options : Options
    pinned : (p,) int array, optional
        Vertices held fixed.
    backend : {"auto", "library", "cli"}
        ``"auto"``: the library when importable, else the executable.
    executable : str
        Path of the ``shellspline`` command for the ``"cli"`` back end (default: found on PATH).
    progress : callable(float fraction, str text), optional

    Returns
    -------
    Result
    """
    options = options or Options()
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {backend!r}")
    if backend == "auto":
        backend = "library" if library_available() else "cli"
    Vkeys, F, rel, K, start = _checked(Vkeys, F, frames, K)
    if backend == "library":
        V, report = _run_library(Vkeys, F, rel, K, options, pinned, progress)
    else:
        V, report = _run_cli(executable, Vkeys, F, rel, K, options, pinned, progress)
    return Result(V=V, start=start, report=report, backend=backend)


def _run_library(Vkeys, F, frames, K, options, pinned, progress):
    from shellspline.io import keyframes_from_arrays
    from shellspline.pipeline import interpolate

    kf = keyframes_from_arrays(Vkeys, F, frames=frames, pinned=pinned)
    total = max(K + 1 - len(frames), 1)
    done = [0]

    def on_event(ev):
        if progress is None:
            return
        if ev.get("kind") == "advance" and ev.get("stage", "").endswith("reconstruct"):
            done[0] = ev.get("done", done[0] + 1)
        progress(min(done[0] / total, 1.0), str(ev.get("stage") or ev.get("text") or ""))

    gn = {"max_iter": int(options.max_iter)} if options.max_iter else None
    coarse = options.coarse
    if str(coarse).strip().lower() not in ("auto", "none"):
        coarse = float(coarse) if "." in str(coarse) else int(coarse)
    res = interpolate(kf, K=K, method=options.method, bc=options.bc, eta=options.eta,
                         coarse=coarse, fine=options.fine, rigid_track=options.rigid_track,
                         gn_options=gn, progress=on_event)
    V = res.V if res.source is None else res.source.expand(res.V, res.frames, res.K, options.bc)
    return V, res.report


def _write_obj(path, V, F) -> None:
    lines = ["v %.17g %.17g %.17g" % tuple(v) for v in V.tolist()]  # exact float64
    lines += ["f %d %d %d" % tuple(f) for f in (F + 1).tolist()]
    with open(path, "w", encoding="ascii") as fh:
        fh.write("\n".join(lines) + "\n")


def read_pc2(path) -> np.ndarray:
    """The points of a PC2 file, ``(samples,n,3)`` float64 (same layout as
    :func:`shellspline.io.pointcache.read_pc2`, kept here for the CLI back end)."""
    with open(path, "rb") as fh:
        data = fh.read()
    if data[:12] != b"POINTCACHE2\0" or len(data) < 32:
        raise ValueError(f"'{path}' is not a PC2 file")
    n = int(np.frombuffer(data, "<i4", 1, 16)[0])  # header: signature, version, numPoints,
    samples = int(np.frombuffer(data, "<i4", 1, 28)[0])  # startFrame, sampleRate, numSamples
    if len(data) != 32 + 12 * n * samples:
        raise ValueError(f"'{path}': size does not match its header")
    return np.frombuffer(data, "<f4", 3 * n * samples, 32).reshape(samples, n, 3).astype(float)


def write_pc2(path, V, *, start_frame: float = 0.0, sample_rate: float = 1.0) -> None:
    """Write ``V (samples,n,3)`` as a PC2 file (the layout of
    :func:`shellspline.io.pointcache.pc2_bytes`, kept here for Blender without shellspline)."""
    V = np.asarray(V, dtype=np.float64)
    head = np.array([(b"POINTCACHE2\0", 1, V.shape[1], start_frame, sample_rate, V.shape[0])],
                    dtype=[("s", "S12"), ("v", "<i4"), ("n", "<i4"), ("f", "<f4"),
                           ("r", "<f4"), ("k", "<i4")])
    with open(path, "wb") as fh:
        fh.write(head.tobytes() + V.astype("<f4").tobytes())


def _run_cli(executable, Vkeys, F, frames, K, options, pinned, progress):
    exe = executable or shutil.which("shellspline")
    if not exe:
        raise RuntimeError("shellspline is neither importable in Blender's Python nor on PATH: "
                           "install it into Blender's Python, or set the executable in the "
                           "add-on preferences")
    tmp = tempfile.mkdtemp(prefix="shellspline-blender-")
    try:
        paths = []
        for j, V in enumerate(Vkeys):
            paths.append(os.path.join(tmp, f"key_{j:04d}.obj"))
            _write_obj(paths[-1], V, F)
        out = os.path.join(tmp, "out")
        cmd = [exe, "interpolate", *paths, "-o", out, "--frames",
               ",".join(str(int(f)) for f in frames), "-K", str(K), "--method", options.method,
               "--bc", options.bc, "--eta", repr(float(options.eta)), "--coarse",
               str(options.coarse), "--format", "pc2", "-q"]
        if options.rigid_track != "fit":  # as the library back end: "fit" is the default,
            # and a track given must be usable (not with --method linear or fixing pins)
            cmd += ["--rigid-track", options.rigid_track]
        if options.fine:
            cmd.append("--fine")
        if options.max_iter:
            cmd += ["--max-iter", str(int(options.max_iter))]
        if pinned is not None and len(pinned):
            pin = os.path.join(tmp, "pinned.txt")
            with open(pin, "w", encoding="ascii") as fh:
                fh.write("\n".join(str(int(i)) for i in pinned) + "\n")
            cmd += ["--pinned", pin]
        if progress is not None:
            progress(0.0, "running " + os.path.basename(exe))
        proc = subprocess.run(cmd, capture_output=True, text=True)
        if proc.returncode not in (0, 1):  # 1: written, with warnings (see the report)
            last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
            raise RuntimeError(f"shellspline exited with code {proc.returncode}: {last}")
        V = read_pc2(os.path.join(out, "animation.pc2"))
        with open(os.path.join(out, "report.json"), encoding="utf-8") as fh:
            report = json.load(fh)
        if progress is not None:
            progress(1.0, "done")
        return V, report
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
