"""Command-line front end: ``shellspline interpolate KEYFRAME... -o OUT``.

Uses only the public API. Exit codes: 0 success, 1 finished but some frame did not converge,
the quality check failed or a time limit was reached, 2 bad input or usage (a
:class:`~shellspline.ShellsplineError`) or an I/O error on the user's paths (missing file,
permission, full disk), 3 internal error (a bug: any other exception; ``SHELLSPLINE_DEBUG=1``
prints its traceback), 130/143 interrupted by SIGINT/SIGTERM.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import sys
import time
from contextlib import contextmanager
from pathlib import Path

from ..errors import ShellsplineError
from ..pipeline.options import (AUTO_COARSE_ABOVE, AUTO_COARSE_VERTICES, AUTO_NONLINEAR_ABOVE,
                                SPLINES, TRANSFERS)
from ..version import __version__
from .startup import EXIT_INTERRUPTED, INTERRUPTED, forget_outputs, interrupted_line
from .startup import release as release_startup_guard

__all__ = ["main"]

EXIT_OK, EXIT_WARN, EXIT_USAGE, EXIT_INTERNAL = 0, 1, 2, 3
DEBUG_ENV = "SHELLSPLINE_DEBUG"
"""Environment variable: set (to anything but empty or 0) to print the traceback of an
internal error."""


_notes_seen: set[str] = set()


def _note(text: str, stream=None) -> None:
    """One ``note:`` line, once per run: a solver's warning and the pipeline's message about
    the same event ("nonlinear_spline: ..." and "nonlinear spline: ...") print once."""
    key = " ".join(re.sub(r"[\W_]+", " ", str(text)).lower().split())
    if key in _notes_seen:
        return
    _notes_seen.add(key)
    out = stream or sys.stderr
    out.write(f"  note: {text}\n")
    out.flush()


class _Bar:
    """A small stderr progress display fed by pipeline progress events."""

    def __init__(self, stream=None, quiet: bool = False):
        self.stream = stream or sys.stderr
        self.quiet = quiet
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self._t0 = None
        self._last = 0.0

    def __call__(self, ev) -> None:
        if self.quiet:
            return
        kind = ev.get("kind")
        if kind == "stage_start":
            self._t0 = time.perf_counter()
            if ev.get("total"):
                self._draw(ev["stage"], 0, ev["total"])
        elif kind == "advance":
            now = time.perf_counter()
            text = ev.get("text")
            if self.tty and (now - self._last > 0.1 or ev["done"] == ev["total"] or text):
                self._draw(ev["stage"], ev["done"], ev["total"], text)
                self._last = now
            elif text and not self.tty:  # logs and pipes: one line per described step
                el = now - (self._t0 or now)
                self.stream.write(f"  {ev['stage']:<12s} {text}  {el:6.1f} s\n")
                self.stream.flush()
        elif kind == "stage_end":
            if self.tty and ev.get("total"):
                self.stream.write("\r\033[K")
            self.stream.write(f"  {ev['stage']:<12s} {ev['seconds']:8.3f} s\n")
            self.stream.flush()
        elif kind == "message":
            _note(ev["text"], self.stream)

    def _draw(self, stage, done, total, text=None):
        if not self.tty:
            return
        width = 30
        fill = int(width * min(done, total) / max(total, 1))
        el = time.perf_counter() - (self._t0 or time.perf_counter())
        if text:  # the state says more than an ETA (e.g. an optimiser's gradient norm)
            tail = f"  {text}  {el:5.1f}s"
        else:
            eta = el / done * (total - done) if done else float("nan")
            tail = f" {done}/{total}  {el:5.1f}s  eta {eta:5.1f}s"
        self.stream.write(f"\r\033[K  {stage:<12s} [{'#' * fill}{'.' * (width - fill)}]{tail}")
        self.stream.flush()


def _build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="shellspline",
                                description="The motion of shapes: smooth in-betweens of triangle-mesh "
                                            "keyframes (splines in the space of thin shells), "
                                            "smooth rigid paths on SO(3)/SE(3), and distances, "
                                            "alignment, blends and loops of skeletal and mesh "
                                            "animations.")
    p.add_argument("--version", action="store_true", help="print the version and exit")
    sub = p.add_subparsers(dest="command")
    q = sub.add_parser("interpolate", help="interpolate keyframe meshes (OBJ/PLY/OFF/glTF/USD)",
                       description="Interpolate keyframes of one triangle mesh (same "
                                   "connectivity) and write OUT/frame_0000.obj ... plus "
                                   "OUT/report.json. An option given that the run cannot "
                                   "use is an error (e.g. --spline with --method linear, "
                                   "--fine with --coarse none, --rigid-track where the "
                                   "pins fix the placement).",
                       epilog="exit codes: 0 success; 1 written, but a frame did not converge, "
                              "the quality check failed or --max-time was reached; 2 bad "
                              "input or usage, or an I/O error on your paths; 3 internal "
                              f"error (a bug; {DEBUG_ENV}=1 prints the traceback); 130/143 "
                              "interrupted by SIGINT/SIGTERM")
    q.add_argument("keyframes", nargs="+",
                   help="keyframe mesh files (OBJ, PLY, OFF, glTF/GLB), in time order, or "
                        "one USD file whose mesh has time-sampled points (one keyframe per "
                        "sample)")
    q.add_argument("-o", "--out", required=True, help="output directory (created atomically)")
    g = q.add_mutually_exclusive_group()
    g.add_argument("--frames", help="keyframe frames, e.g. 0,10,20 (or a file of integers)")
    q.add_argument("--K", "-K", type=int, dest="K", help="last frame index (K+1 frames)")
    q.add_argument("--bc", default="natural", choices=["natural", "periodic", "hermite"],
                   help="time boundary conditions (hermite: keyframes at frames 1 and K-1 fix "
                        "the end velocities)")
    q.add_argument("--method", default="lta", choices=["lta", "linear", "geodesic", "nonlinear"],
                   help="lta: LΘA shell spline (default, fast); linear: per-vertex blending "
                        "baseline; geodesic: piecewise discrete geodesics (paper §3); "
                        "nonlinear: nonlinear shell spline (paper §5-6) started from lta, slow")
    q.add_argument("--max-time", type=float, default=None,
                   help="wall-clock limit in seconds of the nonlinear stage, its set-up and "
                        "first evaluation included, or of the geodesic Newton iterations "
                        "(default 600; the last accepted iterate is written, marked 'time "
                        "limit reached', exit 1); with --reference geodesic also of its "
                        "reference geodesic solve, on its own clock (no default with "
                        "--method lta)")
    q.add_argument("--ftol", type=float, default=None,
                   help="nonlinear: also stop when the energy fell by at most FTOL (relative) "
                        "over the last 3 iterations, e.g. 1e-6 (default: off, stop on the "
                        "gradient only)")
    q.add_argument("--eta", type=float, default=1e-3,
                   help="bending weight η = (thickness / D)², relative to D = sqrt(surface "
                        "area of the first keyframe): results do not depend on the unit "
                        "(default 1e-3)")
    q.add_argument("--mu", type=float, default=1.0, help="edge-length weight (default 1)")
    q.add_argument("--lam", type=float, default=1.0, help="area weight (default 1)")
    q.add_argument("--reference",
                   help="reference meshes for the weights: constant (first keyframe, "
                        "default), "
                        "keyframe (nearest keyframe per frame), geodesic (piecewise discrete "
                        "geodesic between the keyframes at every frame, paper §9), or a "
                        "keyframe index")
    q.add_argument("--fixpoint", type=int, default=0, metavar="N",
                   help="N fixpoint iterations (paper §9, Fig. 9): reference meshes <- "
                        "current result, re-solve the LΘA spline and reconstruct; the change "
                        "per iteration goes to report.json 'fixpoint' (default 0)")
    q.add_argument("--rigid-track", choices=("fit", "spline", "linear"),
                   help="where in-betweens are placed rigidly: onto a per-vertex C² cubic "
                        "through the keyframes (fit, default: closest to the truth on skinned "
                        "walks), along a C² SE(3) spline through the keyframes' rigid poses "
                        "(spline: exact for rigid turns, e.g. a circle), or onto the linear "
                        "blend (linear)")
    q.add_argument("--fade-angle", type=float, metavar="RAD",
                   help="an edge whose dihedral angle turns by more than RAD between the "
                        "keyframes of a gap keeps 1%% of its bending weight there (skin "
                        "folding at joints: removes jumps between local minima); 0 = the "
                        "paper's weights (default 0.5)")
    q.add_argument("--spline", choices=SPLINES,
                   help="time spline of the LΘA descriptors: the C² cubic spline in continuous "
                        "time through the keyframe descriptors (continuous, default: no "
                        "velocity kink at the keyframes; with --reference keyframe/geodesic or "
                        "--fixpoint the continuous limit of the weighted discrete spline) or "
                        "the paper's time-discrete spline (discrete: to reproduce the paper; "
                        "--method nonlinear/geodesic: their LΘA start only)")
    q.add_argument("--rigid-subset", metavar="FILE",
                   help="file of vertex indices (like --pinned) that carry the rigid pose, "
                        "e.g. the torso: each keyframe's pose is their Kabsch fit and the "
                        "in-betweens are placed by fitting them onto the --rigid-track, so a "
                        "swinging limb does not drag the body's path (default: all vertices)")
    q.add_argument("--pinned", help="file of vertex indices held fixed (e.g. a base)")
    q.add_argument("--fix-boundary", action="store_true",
                   help="hold the mesh boundary vertices fixed")
    q.add_argument("--coarse",
                   help="multiresolution: decimate all keyframes to N vertices (or a fraction "
                        "0<γ<1), solve there and prolong by detail transfer; 'none' = full "
                        f"resolution; 'auto' (default) = {AUTO_COARSE_VERTICES} vertices for "
                        f"meshes above {AUTO_COARSE_ABOVE} (above {AUTO_NONLINEAR_ABOVE} with "
                        "--method nonlinear)")
    q.add_argument("--transfer", choices=TRANSFERS,
                   help="how --coarse carries the fine detail onto the coarse frames: gradient "
                        "(default) fits the fine edge vectors carried on the base frames; "
                        "displacement adds the paper's per-vertex offsets (§8)")
    q.add_argument("--fine", action="store_true", default=None,
                   help="after --coarse, run the spline and Gauss–Newton at full resolution "
                        "initialised from the prolonged result")
    q.add_argument("--workers", type=int, default=1, help="processes for the reconstruction")
    q.add_argument("--max-iter", type=int, default=None,
                   help="Gauss–Newton iteration limit per frame (default 60, and 40 more "
                        "for a frame still converging steadily there; 200 on the coarse mesh "
                        "of a multiresolution run); a limit given here holds")
    q.add_argument("--format", default="obj",
                   choices=["obj", "ply", "glb", "mdd", "pc2", "usd"],
                   help="output: frame_*.obj (default, exact), frame_*.ply (binary, exact), "
                        "one animation.glb (float32 morph-target animation for Blender, "
                        "three.js, game engines), a point cache animation.mdd or animation.pc2 "
                        "with mesh.obj (float32; Blender's Mesh Cache modifier, Maya, Houdini) "
                        "or animation.usdc (USD, time-sampled points; needs usd-core)")
    q.add_argument("--fps", type=float, default=None,
                   help="frames per second of the GLB/USD animation and the MDD frame times; "
                        "with --topology, turns MDD times into frames (default 24)")
    q.add_argument("--topology", metavar="MESH",
                   help="the keyframes are the samples of one point cache (KEYFRAMES is one "
                        ".mdd or .pc2 file) on the vertices of MESH, at the cache's frames "
                        "unless --frames")
    q.add_argument("--overwrite", action="store_true", help="replace OUT if it exists")
    q.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    # Other subcommands live in their own modules; each registers parsers that set `func`.
    from . import batch as _cli_batch
    from . import blender as _cli_blender
    from . import motion as _cli_motion
    from . import path as _cli_path
    from . import viz as _cli_viz

    _cli_viz.add_parsers(sub)
    _cli_batch.add_parsers(sub)
    _cli_path.add_parsers(sub)
    _cli_motion.add_parsers(sub)
    _cli_blender.add_parsers(sub)
    return p


def _source_line(summary: dict, fmt: str = "obj") -> str:
    """One line on what reading a real export changed (only the non-zero counts) and what the
    output format ``fmt`` writes back of it."""
    words = [("non_triangle_polygons", "polygons triangulated"),
             ("welded_vertices", "seam vertices welded"),
             ("reoriented_polygons", "faces reoriented"),
             ("fin_polygons", "fin faces set aside"),
             ("set_aside_vertices", "vertices set aside")]
    parts = [f"{summary[k]} {w}" for k, w in words if summary.get(k)]
    uv = summary.get("texture_coordinates", 0)
    n = summary["source_vertices"]
    polygons = summary.get("non_triangle_polygons", 0)
    if fmt == "obj":
        back = "written back as given" + (f" ({uv} texture coordinates kept)" if uv else "")
    elif fmt in ("mdd", "pc2"):
        back = (f"the cache written on its {n} vertices, mesh.obj as given"
                + (f" ({uv} texture coordinates kept)" if uv else ""))
    elif fmt == "glb":
        back = (f"written back on its {n} vertices"
                + (", as triangles" if polygons else "")
                + (f"; its {uv} texture coordinates are not written (GLB)" if uv else ""))
    else:  # ply, usd: polygons and numbering, no texture coordinates
        back = (f"written back with its polygons and {n} vertices"
                + (f"; its {uv} texture coordinates are not written ({fmt.upper()})"
                   if uv else ""))
    return (f"{n} vertices, {summary['polygons']} faces; "
            + (", ".join(parts) or "unchanged") + "; " + back)


def _interpolate(args) -> int:
    import numpy as np

    from ..io import check_output_dir, read_frames, read_keyframes, write_sequence
    from ..pipeline import interpolate

    bar = _Bar(quiet=args.quiet)
    given = _given_options(args)
    if args.max_iter is not None and args.max_iter < 1:
        raise ShellsplineError(f"--max-iter must be >= 1, got {args.max_iter}")
    if args.frames is not None and not args.frames.strip():
        raise ShellsplineError("--frames is empty")
    if args.fps is not None and not (args.fps > 0 and args.fps < float("inf")):
        raise ShellsplineError(f"--fps must be a positive number, got {args.fps}")
    fps_note = _unused_fps(args)
    if args.fps is None:
        args.fps = 24.0
    t_read = time.perf_counter()
    try:
        frames = read_frames(args.frames) if args.frames else None
    except OverflowError:
        raise ShellsplineError(f"--frames {args.frames!r}: a frame number is too "
                               "large") from None
    caches = [k for k in args.keyframes if Path(k).suffix.lower() in (".mdd", ".pc2")]
    if caches and not args.topology:
        raise ShellsplineError(f"'{caches[0]}' is a point cache (vertex positions only, no "
                               "faces): give the mesh it animates with --topology MESH")
    if args.topology:
        from ..io.pointcache import keyframes_from_cache

        if len(args.keyframes) != 1:
            raise ShellsplineError(f"--topology: give one point cache (.mdd or .pc2), got "
                                   f"{len(args.keyframes)} files")
        kf = keyframes_from_cache(args.keyframes[0], args.topology, frames, fps=args.fps)
    else:
        kf = read_keyframes(args.keyframes, frames=frames)
    t_read = time.perf_counter() - t_read
    # the files number the input's vertices
    pinned = _vertex_file(args.pinned, "--pinned", kf) if args.pinned else None
    rigid_subset = _vertex_file(args.rigid_subset, "--rigid-subset", kf) \
        if args.rigid_subset else None
    if args.fix_boundary:
        bv = kf.topology.boundary_vertices
        if bv.size == 0:
            raise ShellsplineError("--fix-boundary: the mesh has no boundary")
        pinned = bv if pinned is None else np.union1d(pinned, bv)
    from ..pipeline.options import REFERENCES
    from ..timeline import canonical_frames

    reference = args.reference
    if str(reference).lstrip("-").isdigit():
        reference = int(reference)
    elif str(reference).strip().lower() not in REFERENCES:
        raise ShellsplineError(f"--reference must be one of {', '.join(REFERENCES)} or a keyframe "
                         f"index, got {reference!r}")
    if args.fixpoint < 0:
        raise ShellsplineError(f"--fixpoint must be >= 0, got {args.fixpoint}")
    if args.fixpoint and args.method not in ("lta", "nonlinear"):
        raise ShellsplineError("--fixpoint applies to --method lta (and nonlinear, whose start "
                               "it is)")
    solver_options = {}
    # the reference geodesic's solve takes the limit too (linear blending has no reference)
    ref_geodesic = str(reference).strip().lower() == "geodesic" and args.method != "linear"
    if args.max_time is not None and args.method not in ("nonlinear", "geodesic") \
            and not ref_geodesic:
        raise ShellsplineError("--max-time applies to --method nonlinear and geodesic and to "
                               "--reference geodesic only")
    if args.max_time is not None and not 0 < args.max_time < float("inf"):
        raise ShellsplineError(f"--max-time must be a positive number of seconds, got "
                               f"{args.max_time}")
    if args.ftol is not None and args.method != "nonlinear":
        raise ShellsplineError("--ftol applies to --method nonlinear only")
    if args.ftol is not None and not 0 <= args.ftol < 1:
        raise ShellsplineError(f"--ftol must be in [0, 1), got {args.ftol}")
    if args.method in ("nonlinear", "geodesic"):
        solver_options["max_time_s"] = 600.0 if args.max_time is None else args.max_time
        if args.ftol is not None:
            solver_options["ftol"] = args.ftol
    if ref_geodesic and args.max_time is not None:
        solver_options["max_time_s"] = args.max_time
    unused = _refuse_inapplicable(given, args, kf, pinned) + ([fps_note] if fps_note else [])
    gn_options = {} if args.max_iter is None else {"max_iter": args.max_iter}
    # the output location is checked before any computing (writable, not over an input,
    # room for the estimated output), so a bad -o costs no solve
    protect = list(args.keyframes) + [p for p in (args.pinned, args.frames, args.topology,
                                                   args.rigid_subset)
                                      if p and Path(p).is_file()]
    _, K_out = canonical_frames(kf.J, kf.frames, args.K, args.bc, spell=_flag)
    check_output_dir(args.out, n_frames=K_out + 1, n_vertices=kf.n, n_faces=kf.m,
                     fmt=args.format, overwrite=args.overwrite, protect=protect,
                     overwrite_hint="--overwrite")
    if not args.quiet:
        print(f"shellspline {__version__}: {kf.J} keyframes, "
              f"{kf.V.shape[1]} vertices, method={args.method}, bc={args.bc}", file=sys.stderr)
        if kf.source is not None:
            print(f"  input: {_source_line(kf.source.summary(), args.format)}",
                  file=sys.stderr)
        for text in unused:
            _note(text)
    res = interpolate(kf, K=args.K, method=args.method, bc=args.bc, eta=args.eta, mu=args.mu,
                         lam=args.lam, reference=reference, pinned=pinned,
                         workers=args.workers, gn_options=gn_options,
                         solver_options=solver_options, coarse=args.coarse, fine=args.fine,
                         fixpoint=args.fixpoint, rigid_track=args.rigid_track,
                         rigid_subset=rigid_subset, fade_angle=args.fade_angle,
                         spline=args.spline, transfer=args.transfer, progress=bar)
    res.report["timings"]["read"] = t_read
    t0 = time.perf_counter()
    if res.source is not None:  # the input's polygons and numbering, written back
        res.report["source_mesh"] = res.source.summary()
    V_out = res.V if res.source is None else res.source.expand(res.V, res.frames, res.K, args.bc)
    # what was written: the fps only where the format carries time in seconds (_unused_fps)
    res.report["output"] = {"format": args.format,
                            "fps": args.fps if args.format in _TIMED_FORMATS else None}
    out = write_sequence(args.out, V_out, res.F, res.report, overwrite=args.overwrite,
                            protect=protect, fmt=args.format, fps=args.fps, source=res.source,
                            up_axis=_usd_up_axis(args.topology or args.keyframes[0]),
                            overwrite_hint="--overwrite")
    res.report["timings"]["write"] = time.perf_counter() - t0
    # rewrite report with the write time (inside the now-complete output directory)
    _rewrite_report(Path(out), res.report)
    return _summary(res, Path(out), quiet=args.quiet, fmt=args.format)


#: The ``interpolate`` options that only some runs use (as :func:`shellspline.interpolate`
#: names them): the parser leaves them ``None`` when not given, so that an option given that
#: the run cannot use is told from a default (:func:`_given_options`).
_CONDITIONAL = ("coarse", "fine", "transfer", "reference", "spline", "fade_angle", "rigid_track")
_FLAGS = {"gn_options": "--max-iter"}
_NO_VALUE = object()


def _flag(option: str, value=_NO_VALUE) -> str:
    """The command line's spelling of an option (``--max-iter``) or a setting
    (``--method linear``), for :func:`shellspline.pipeline.interpolation.inapplicable_options`."""
    flag = _FLAGS.get(option, "--" + option.replace("_", "-"))
    if option == "gn_options" and isinstance(value, dict):
        value = value.get("max_iter", _NO_VALUE)
    return flag if value is _NO_VALUE or value is True else f"{flag} {value}"


def _given_options(args) -> dict:
    """``{option: value}`` of the :data:`_CONDITIONAL` options given on the command line (and
    ``gn_options``/``rigid_subset`` for ``--max-iter``/``--rigid-subset``); those not given
    are set to :func:`shellspline.interpolate`'s defaults in ``args``."""
    from ..pipeline.options import InterpolationOptions

    defaults = InterpolationOptions()
    given = {}
    for key in _CONDITIONAL:
        if getattr(args, key) is None:
            setattr(args, key, getattr(defaults, key))
        else:
            given[key] = getattr(args, key)
    if args.max_iter is not None:
        given["gn_options"] = {"max_iter": args.max_iter}
    if args.rigid_subset is not None:
        given["rigid_subset"] = args.rigid_subset
    return given


def _refuse_inapplicable(given: dict, args, kf, pinned) -> list:
    """Refuse an option given that the run cannot use (:class:`ShellsplineError`, named by
    its flag); return the notes on those that this run only leaves unused (a ``--coarse``
    count not below the mesh's vertices: run as ``--coarse none``; a ``--transfer`` where
    nothing is prolonged; ``--max-iter`` with ``--method linear``), which ``args`` then no
    longer carries."""
    from ..pipeline.interpolation import inapplicable_options, pins_fix_placement
    from ..pipeline.options import InterpolationOptions

    placing = "rigid_track" in given or "rigid_subset" in given
    refused, unused = inapplicable_options(
        given, args.method, args.coarse, n_vertices=kf.n, spell=_flag,
        pins_fix=placing and pins_fix_placement(kf.V, kf.topology.F, pinned))
    if refused:
        raise ShellsplineError(refused[0][1])
    applied = {"coarse": ("coarse", "none"), "gn_options": ("max_iter", None),
               # report.json records transfer null where nothing is prolonged
               "transfer": ("transfer", InterpolationOptions().transfer)}
    for key, _ in unused:  # run as applied
        setattr(args, *applied[key])
    return [text for _, text in unused]


#: The ``--format`` outputs that carry time in seconds, at ``--fps``.
_TIMED_FORMATS = ("glb", "mdd", "usd")


def _unused_fps(args) -> str:
    """The note for an ``--fps`` given that nothing of the run uses (``""`` otherwise): OBJ
    and PLY frames carry no time, a PC2 cache counts it in frames (start 0, one sample per
    frame); only GLB, MDD and USD outputs and an MDD keyframe cache (``--topology``) have
    seconds. A note, not an error: one set of options serves several formats."""
    if args.fps is None or args.format in _TIMED_FORMATS:
        return ""
    if args.topology and any(Path(k).suffix.lower() == ".mdd" for k in args.keyframes):
        return ""
    why = ("counts time in frames (start frame 0, one sample per frame)" if args.format == "pc2"
           else "writes one file per frame, with no time")
    return f"--fps {args.fps:g} is not applied: --format {args.format} {why}"


def _vertex_file(path, option: str, kf):
    """Vertex indices read from ``path`` (numbering the input's vertices), checked and mapped to
    the solve mesh's."""
    from ..io import read_indices

    try:
        idx = read_indices(path)
    except OverflowError:
        raise ShellsplineError(f"{option} {path}: a vertex index is too large") from None
    n_input = kf.n if kf.source is None else kf.source.n_source
    bad = (idx < 0) | (idx >= n_input)
    if bad.any():
        raise ShellsplineError(f"{option} {path}: vertex indices must lie in [0, {n_input}), "
                               f"got {int(idx[bad][0])} ({int(bad.sum())} out of range)")
    return idx if kf.source is None else kf.source.solve_vertices(idx, option)


def _rewrite_report(out: Path, report: dict) -> None:
    from ..io.atomic import write_atomically

    def dump(tmp: Path) -> None:
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2, default=_json_default, allow_nan=False)

    write_atomically(out / "report.json", dump)


def _json_default(o):
    import numpy as np

    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    raise TypeError(type(o))


def _usd_up_axis(path) -> str:
    """The USD stage's up axis: the input's convention (OBJ y-up, PLY/OFF z-up); USD has no x."""
    from ..io.usd import conventional_up_axis

    return "z" if conventional_up_axis(path) == "z" else "y"


def _time_line(timings: dict, within: dict) -> str:
    """The summary's ``time:`` line: reading, the interpolation's stages and writing, whose
    sum is at most the total printed (``timings["total"]``, the interpolation's, plus reading
    and writing); a stage timed inside another (``within``, e.g. the reference geodesic in
    describe) is listed in parentheses after it, its name without their common prefix
    (``coarse describe 1.20s (reference geodesic 1.10s)``), not beside it."""
    t = dict(timings)
    total = t.pop("total", 0.0)
    read, write = t.pop("read", None), t.pop("write", None)
    inside: dict = {}
    for name in t:
        if within.get(name) in t:
            inside.setdefault(within[name], []).append(name)

    def item(name, parent=""):
        common = os.path.commonprefix([parent, name])
        label = name[common.rfind(" ") + 1:] if " " in common else name
        text = f"{label} {t[name]:.2f}s"
        if name in inside:
            text += " (" + ", ".join(item(c, name) for c in inside[name]) + ")"
        return text

    parts = [item(k) for k in t if within.get(k) not in t]
    if read is not None:
        parts.insert(0, f"read {read:.2f}s")
    if write is not None:
        parts.append(f"write {write:.2f}s")
    return f"time: {', '.join(parts)}; total {total + (read or 0.0) + (write or 0.0):.2f}s"


def _summary(res, out: Path, quiet: bool, fmt: str = "obj") -> int:
    from ..io.sequences import ANIMATION_NAMES

    rep = res.report
    q = rep["quality"]
    gn = rep.get("gauss_newton")
    what = ("animation.glb (one morph target per frame)" if fmt == "glb"
            else f"{ANIMATION_NAMES[fmt]} and mesh.obj" if fmt in ("mdd", "pc2")
            else f"{ANIMATION_NAMES[fmt]} (time-sampled points)" if fmt == "usd"
            else f"frame_0000.{fmt} …")
    lines = [f"wrote {res.K + 1} frames to {out}/ as {what} and report.json"]
    if "multires" in rep:
        lines.append(f"multiresolution: solved on {rep['multires']['coarse_vertices']} coarse "
                     f"vertices, prolonged to {res.V.shape[1]}"
                     + (" and refined at full resolution" if rep["parameters"]["fine"] else ""))
    lines.append(_time_line(rep["timings"], rep.get("timings_within") or {}))
    if gn:
        # the frames' kept solves, and all the solves (discarded ones and bridges too)
        work = gn.get("work")
        line = (f"Gauss–Newton: {gn['converged']}/{gn['frames']} frames converged, "
                f"{gn['iterations_total']} iterations in kept solves (median "
                f"{gn.get('iterations_median', 0):g}, max {gn['iterations_max']})"
                + (f", {work['iterations']} in all" if work else "")
                + f"; {gn['factorizations_total']} factorizations"
                + (f" ({work['factorizations']} in all)" if work else ""))
        for key, what in (("stalled", "stalled"), ("iteration_limit", "at the iteration limit"),
                          ("resumed", "resumed (still converging at the limit)")):
            if gn.get(key):
                fr = gn[key]
                line += f"; {what}: frames {fr[:8]}{' …' if len(fr) > 8 else ''}"
        lines.append(line)
    groups = [("seams", rep.get("frames", []))]
    if rep["parameters"].get("fine"):
        # the refinement starts from the prolonged coarse frames, whose seams the quality
        # line counts defects at too (report.seam_defects)
        groups.append(("seams of the coarse solve",
                       (rep.get("multires") or {}).get("coarse_frames") or []))
    for label, records in groups:
        seams = [r for r in records if "seam_jump" in r]
        if not seams:
            continue
        kept = [r for r in seams if r.get("bridge", {}).get("kept")]
        line = (f"{label}: {len(seams)} (the two runs of a gap meet in different minima: "
                f"frames {[r['frame'] for r in seams][:8]}), {len(kept)} bridged")
        if kept:
            line += " (window step ratio " + ", ".join(
                f"{r['bridge']['step_ratio_before']:.2f} -> {r['bridge']['step_ratio_after']:.2f}"
                for r in kept[:4]) + ")"
        lines.append(line)
    from ..pipeline.report import convergence_problems, quality_ok, start_frames_note

    note = start_frames_note(rep)
    if note:
        not_done = list(gn.get("iteration_limit", [])) + list(gn.get("stalled", []))
        lines.append(f"{note} (frames {not_done[:8]}{' …' if len(not_done) > 8 else ''}); "
                     "they only start the nonlinear stage, whose result is written")
    line = (f"quality: keyframes exact={q['keyframes_exact']}, new flipped faces "
            f"{q['flipped_faces']}, collapsed {q.get('collapsed_faces', 0)}, folded edges "
            f"{q.get('folded_edges', 0)}, degenerate {q['degenerate_faces']}, pop "
            f"{q.get('pop', 0.0):.2f}")
    from ..pipeline.report import seam_defects

    at = seam_defects(rep)
    if at["flipped"] or at["folded"] or at["collapsed"]:
        line += (f"; at the seams (steps into frames {at['frames'][:12]}"
                 f"{' …' if len(at['frames']) > 12 else ''}): {at['flipped']} flipped, "
                 f"{at['folded']} folded, {at['collapsed']} collapsed")
    if q.get("worst_frames"):
        line += f"; worst frames {q['worst_frames']} (report.json quality.per_frame)"
    lines.append(line)
    for name in ("geodesic", "nonlinear"):
        if name in rep:
            r = rep[name]
            line = (f"{name}: {'converged' if r['success'] else 'NOT converged'} after "
                    f"{r['nit']} iterations ({r['message']})")
            if name == "nonlinear" and r.get("grad_norm_initial"):
                line += (f"; F {r['energy_initial']:.6g} -> {r['energy_final']:.6g}, |g|/|g0| "
                         f"{r['grad_norm_final'] / r['grad_norm_initial']:.1e} in "
                         f"{r['seconds']:.1f} s")
            lines.append(line)
    ref = rep.get("reference_geodesic")
    if ref:
        lines.append(f"reference geodesic: {'converged' if ref['success'] else 'NOT converged'} "
                     f"after {ref.get('nit', 0)} iterations ({ref['message']})")
    ok = quality_ok(q) and not convergence_problems(rep)
    if not quiet:
        print("\n".join(lines), file=sys.stderr)
    return EXIT_OK if ok else EXIT_WARN


def _value_options(parser: argparse.ArgumentParser) -> set[str]:
    """Option strings of ``parser`` and its subcommands that take exactly one value."""
    found = set()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                found |= _value_options(sub)
        elif action.option_strings and action.nargs is None:
            found.update(action.option_strings)
    return found


_NEGATIVE = re.compile(r"^-[0-9.]")


def _protect_negative_values(argv, parser=None):
    """Attach a negative-looking value to its option (``--frames -3,5`` → ``--frames=-3,5``).

    argparse takes a token such as ``-3,5,10`` or ``-1e-3`` for an option and reports
    "expected one argument"; attached, the value reaches the option's own check, whose
    message says what is wrong with it.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    options = _value_options(parser or _build_parser())
    out, i = [], 0
    while i < len(argv):
        tok = str(argv[i])
        if tok == "--":
            out.extend(argv[i:])
            break
        if tok in options and i + 1 < len(argv) and _NEGATIVE.match(str(argv[i + 1])):
            glue = "=" if tok.startswith("--") else ""
            out.append(f"{tok}{glue}{argv[i + 1]}")
            i += 2
            continue
        out.append(argv[i])
        i += 1
    return out


def _one_line_error(exc: BaseException) -> str:
    """The message of an input or I/O error on one line (no ``[Errno N]`` prefix)."""
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        if exc.filename is not None:
            text += f": '{os.fsdecode(exc.filename)}'"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def _internal_error(exc: BaseException) -> int:
    """Report an exception that is not an input error as a bug; return :data:`EXIT_INTERNAL`."""
    import traceback

    where = ""
    tb = traceback.extract_tb(exc.__traceback__)
    if tb:
        where = f" at {Path(tb[-1].filename).name}:{tb[-1].lineno}"
    debug = os.environ.get(DEBUG_ENV, "").strip() not in ("", "0")
    if debug:
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    msg = " ".join(str(exc).split())
    if len(msg) > 200:
        msg = msg[:197] + "..."
    hint = "" if debug else f"; rerun with {DEBUG_ENV}=1 for the traceback"
    print(f"shellspline: internal error (a bug in shellspline, not a problem with your input): "
          f"{type(exc).__name__}: {msg}{where}{hint}", file=sys.stderr)
    return EXIT_INTERNAL


@contextmanager
def _warnings_as_notes(stream=None):
    """Python warnings become one-line ``note:`` lines on stderr (no source lines)."""
    import warnings

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if "encountered in" in text:  # numpy floating-point warning: say where
            text += f" (numerical warning at {Path(filename).name}:{lineno})"
        _note(text, stream)

    with warnings.catch_warnings():
        warnings.simplefilter("always")  # repeats are dropped by _note, once per run
        warnings.showwarning = show
        yield


def main(argv=None) -> int:
    """Entry point of the ``shellspline`` console script; returns the exit code."""
    try:
        # a Ctrl-C from here on is a KeyboardInterrupt, reported in one line (while the
        # package was imported, startup.guard did the same)
        release_startup_guard()
        parser = _build_parser()
        args = parser.parse_args(_protect_negative_values(argv, parser))
    except KeyboardInterrupt:
        print(INTERRUPTED, file=sys.stderr)
        return EXIT_INTERRUPTED
    _notes_seen.clear()
    forget_outputs()
    if args.version:

        print(__version__)
        return EXIT_OK
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    from ..parallel import interrupt_exit_code, stop_signals_unwind

    try:
        # SIGTERM and SIGINT unwind like Ctrl-C (temp outputs removed, workers stopped) and
        # exit with 128 + the signal (130 SIGINT, 143 SIGTERM)
        with stop_signals_unwind(), _warnings_as_notes():
            if args.command == "interpolate":
                return _interpolate(args)
            if hasattr(args, "func"):
                return args.func(args)
    except (ShellsplineError, OSError) as exc:
        print(f"shellspline: error: {_one_line_error(exc)}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError:
        print("shellspline: error: out of memory (fewer frames, --coarse, or more memory)",
              file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt as exc:
        print(interrupted_line(), file=sys.stderr)  # says which outputs were written
        return interrupt_exit_code(exc)
    except Exception as exc:  # not the input: a bug, never passed off as bad input
        return _internal_error(exc)
    return EXIT_USAGE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
