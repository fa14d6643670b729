"""CLI subcommands ``preview``, ``render`` and ``plot`` (see :mod:`shellspline.viz`)."""
from __future__ import annotations

import argparse
import math
import sys

from ..errors import ShellsplineError
from .startup import output_written

_KEYS = """keys in the window:
  space        play / pause (also the button left of the slider)
  left, right  previous / next frame
  home, end    first / last frame
  l            loop on / off
  q            quit
mouse: drag to rotate, shift-drag to pan, wheel to zoom; all views share one camera.
Keyframes are gray, in-betweens coloured (one colour per OUT)."""


def add_parsers(sub) -> None:
    """Register the visualisation subcommands on the ``shellspline`` subparsers."""
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser("preview", help="play results in a window (pyvista)",
                       description="Play one or several output directories side by side in a "
                                   "pyvista window with a frame slider, play/pause and loop.",
                       epilog=_KEYS, formatter_class=fmt)
    p.add_argument("outs", nargs="+", metavar="OUT",
                   help="output directories written by 'shellspline interpolate'")
    p.add_argument("--track", help="vertex indices whose trajectories are drawn, e.g. 12,345")
    p.add_argument("--fps", type=float, default=24.0, help="playback speed (default 24)")
    p.add_argument("--labels", help="comma-separated titles, one per OUT")
    p.add_argument("--no-loop", action="store_true", help="stop at the last frame")
    p.add_argument("--view", default="iso",
                   help="camera direction: iso (default), front, side, top")
    p.add_argument("--up", choices=["x", "y", "z"],
                   help="the scene's up axis (default from the files: OBJ and glTF y, USD its "
                        "metadata, PLY/OFF z)")
    p.add_argument("--size", help="window size WxH in pixels")
    p.set_defaults(func=_preview)

    r = sub.add_parser("render", help="render GIF/MP4/filmstrip off-screen, export GLB",
                       description="Render an output directory without a window: an animated "
                                   "GIF, an MP4 movie, a PNG filmstrip of chosen frames "
                                   "(keyframes gray, in-betweens coloured, one camera fitted "
                                   "to the whole sequence), and/or a GLB animation.",
                       epilog="examples:\n  shellspline render out/cactus --gif cactus.gif "
                              "--strip cactus.png --glb cactus.glb\n  shellspline render "
                              "out/cactus --mp4 fly.mp4 --camera-path camera.txt",
                       formatter_class=fmt)
    r.add_argument("out", metavar="OUT", help="output directory of 'shellspline interpolate'")
    r.add_argument("--gif", help="animated GIF to write")
    r.add_argument("--mp4", help="MP4 movie to write (needs imageio-ffmpeg)")
    r.add_argument("--strip", help="PNG filmstrip to write")
    r.add_argument("--glb", help="GLB (binary glTF) morph-target animation to write")
    r.add_argument("--frames", help="frames to show, e.g. 0,5,10 (default: all frames for "
                                    "GIF/MP4; keyframes and halfway frames for the strip)")
    r.add_argument("--size", help="pixels WxH of the animation (default 640x480) or of one "
                                  "strip panel (default 240x240)")
    r.add_argument("--columns", type=int, help="strip panels per row (default one row, <= 8)")
    r.add_argument("--fps", type=float, default=24.0, help="frames per second (default 24)")
    r.add_argument("--view", default="iso", help="camera direction: iso, front, side, top")
    r.add_argument("--up", choices=["x", "y", "z"],
                   help="the scene's up axis (default from the files: OBJ and glTF y, USD its "
                        "metadata, PLY/OFF z); also the up rotation of the --glb")
    r.add_argument("--no-labels", action="store_true", help="no frame numbers in the images")
    c = r.add_argument_group("camera path (GIF, MP4 and strip; replaces --view and --up)")
    c.add_argument("--camera-path", metavar="FILE",
                   help="the camera follows a C2 spline through the camera-to-world poses in "
                        "FILE (TUM, KITTI, EuRoC, CSV or JSON, as 'shellspline path' reads)")
    c.add_argument("--camera-convention", choices=["opencv", "opengl"], default="opencv",
                   help="camera axes of the poses: opencv (default; looks along +z, y down: "
                        "TUM RGB-D, KITTI) or opengl (looks along -z, y up: Blender)")
    c.add_argument("--camera-times", choices=["normalized", "frames", "seconds"],
                   default="normalized",
                   help="pose times -> frames: normalized (default; first pose at frame 0, "
                        "last at the last frame), frames (times are frame numbers), seconds "
                        "(frame k at the first pose's time + k/--fps)")
    c.add_argument("--camera-group", choices=["so3xr3", "se3"], default="so3xr3",
                   help="spline metric, as 'shellspline path --group' (default so3xr3)")
    c.add_argument("--camera-bc", choices=["natural", "clamped", "periodic"],
                   default="natural", help="spline ends, as 'shellspline path --bc'")
    r.add_argument("-q", "--quiet", action="store_true", help="print nothing")
    r.set_defaults(func=_render)

    q = sub.add_parser("plot", help="plot energies, speed, trajectories (matplotlib)",
                       description="Plot per-frame quantities of one or several output "
                                   "directories: the LΘA energy and the nonlinear Discrete "
                                   "Shells energy along the curve (paper Figs. 11-12), the "
                                   "speed profile, vertex trajectories (Fig. 8). PNG, SVG or "
                                   "PDF by the suffix of -o.",
                       epilog="example: shellspline plot out/spline out/geodesic --energy "
                              "--speed -o compare.png", formatter_class=fmt)
    q.add_argument("outs", nargs="+", metavar="OUT", help="output directories to compare")
    q.add_argument("-o", "--output", required=True, help="plot file (.png, .svg or .pdf)")
    q.add_argument("--energy", action="store_true", help="energy panels")
    q.add_argument("--speed", action="store_true", help="speed panel")
    q.add_argument("--track", help="vertex indices for a trajectory panel, e.g. 12,345")
    q.add_argument("--labels", help="comma-separated legend labels, one per OUT")
    q.add_argument("--shell-energy", default="auto",
                   choices=["auto", "midpoint", "step", "none"],
                   help="nonlinear energy panel: W[s_k, s̃_k] with geodesic midpoints (paper; "
                        "one Newton solve per frame), W[s_k, s_k+1] (cheap), or none; auto "
                        "uses midpoints up to n*(K-1) = 60000")
    q.add_argument("-q", "--quiet", action="store_true", help="print nothing")
    q.set_defaults(func=_plot)


def _say(args, text: str) -> None:
    if not getattr(args, "quiet", False):
        print(text, file=sys.stderr)


def _preview(args) -> int:
    from .. import viz

    viz.preview(*args.outs, track=args.track, fps=args.fps, loop=not args.no_loop,
                labels=args.labels, window_size=args.size and viz.checked_size(args.size, None),
                view=args.view, up=args.up)
    return 0


def _render(args) -> int:
    from .. import viz

    if not any((args.gif, args.mp4, args.strip, args.glb)):
        raise ShellsplineError("render: nothing to write; give --gif, --mp4, --strip and/or --glb")
    seq = viz.load_source(args.out)
    frames = None if args.frames is None else viz.checked_frames(args.frames, seq.K)
    # every option and output checked before the first (slow) render
    for option, path, suffixes in (("--gif", args.gif, (".gif",)), ("--mp4", args.mp4, (".mp4",)),
                                   ("--strip", args.strip, (".png",)),
                                   ("--glb", args.glb, (".glb",))):
        if path:
            viz.checked_output(path, suffixes, [seq], option)
    viz.checked_size(args.size, None)
    viz.view_vectors(args.view, args.up or "z")
    if not (math.isfinite(args.fps) and args.fps > 0):
        raise ShellsplineError(f"--fps must be a positive number, got {args.fps}")
    if args.columns is not None and args.columns < 1:
        raise ShellsplineError(f"--columns must be >= 1, got {args.columns}")
    camera = None
    if args.camera_path:
        camera = viz.CameraPath(args.camera_path, times=args.camera_times, fps=args.fps,
                                convention=args.camera_convention, group=args.camera_group,
                                bc=args.camera_bc)
        if args.gif or args.mp4:
            camera.frame_times(range(seq.K + 1) if frames is None else frames, seq.K)
        if args.strip:
            camera.frame_times(viz.default_strip_frames(seq.K, seq.frames) if frames is None
                               else frames, seq.K)
    annotate = not args.no_labels
    for path in (args.gif, args.mp4):
        if path:
            out = viz.render_animation(seq, path, fps=args.fps, frames=frames,
                                       window_size=args.size or (640, 480), view=args.view,
                                       annotate=annotate, up=args.up, camera_path=camera)
            output_written(out)  # an interrupt then says it was written
            _say(args, f"wrote {out}")
    if args.strip:
        out = viz.render_strip(seq, args.strip, frames=frames, columns=args.columns,
                               window_size=args.size or (240, 240), view=args.view,
                               annotate=annotate, up=args.up, camera_path=camera)
        output_written(out)
        _say(args, f"wrote {out}")
    if args.glb:
        out = viz.export_glb(seq, args.glb, fps=args.fps, frames=frames, up=args.up)
        output_written(out)
        _say(args, f"wrote {out}")
    return 0


def _plot(args) -> int:
    from .. import viz

    what = [w for w, on in (("energy", args.energy), ("speed", args.speed)) if on]
    if not what and not args.track:
        what = ["energy", "speed"]
    out = viz.plot(list(args.outs), args.output, what, track=args.track, labels=args.labels,
                   shell_energy=args.shell_energy)
    _say(args, f"wrote {out}")
    return 0
