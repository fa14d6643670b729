"""``shellspline motion``: distances, time alignment, blending and loop closing of BVH clips.

Subcommands ``distance``, ``align``, ``blend`` and ``close`` (see :mod:`shellspline.animation`)
on BVH clips, on mesh sequences (a folder of OBJ/PLY/OFF frames of one mesh, in name order;
a point cache with ``--topology MESH``; a folder with one animation file: LΘA descriptor
curves, frames reconstructed by Gauss–Newton, a sequence folder written in the input's
format), or
on rigid pose tracks (any file :func:`shellspline.io.posefiles.read_poses` reads: curves in
SO(3) x R^3, written back in the input's format);
pictures with ``--render STRIP.png|ANIM.gif`` (stick figures) and ``--plot PNG`` (feet, warp,
seam gap). Outputs are written atomically, never replace an existing file without
``--overwrite`` and never an input (with it or not); every output path is checked before any
work. Errors are one line naming the file, exit status 2.
"""
from __future__ import annotations

import argparse
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..errors import ShellsplineError
from .outputs import ANIMATIONS, PICTURES, Output, check_outputs

EXIT_OK, EXIT_WARN = 0, 1

_EPILOG = """examples:
  shellspline motion distance walk.bvh walk_tired.bvh --align dp --features contacts
  shellspline motion align walk.bvh walk_tired.bvh -o warp.csv --plot warp.png
  shellspline motion blend walk.bvh walk_happy.bvh --s 0.5 -o blend.bvh --render blend.gif
  shellspline motion close walk.bvh -o loop.bvh --iterations 10 --c1 --plot loop.png
  shellspline motion close frames/ -o loop/          # a mesh sequence (folder of frames)
  shellspline motion close camera.txt -o loop.txt --c1   # a pose track (TUM, KITTI, EuRoC...)

features: 'contacts' pairs the foot touch-downs detected in both clips (feet and up axis found
from the data; --up overrides the axis); a CSV file gives pairs 'time_a,time_b' in seconds,
one per line ('#' comments); 'none' (default) aligns on the motion alone.

pose tracks: a file that is not a .bvh is read as poses (format detected as by 'shellspline
path'); positions are divided by --position-scale (default: the tracks' RMS distance from
their mean position) so that they weigh like radians of rotation."""


def add_parsers(sub) -> None:
    """Register ``shellspline motion`` and its subcommands."""
    p = sub.add_parser("motion", help="distance, align, blend and close skeletal motions (BVH)",
                       description="Shape analysis of skeletal animations on SO(3)^d x R^m: "
                                   "SRV distance, time alignment with feature points, "
                                   "blending and loop closing.",
                       epilog=_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    ms = p.add_subparsers(dest="motion_command", metavar="{distance,align,blend,close}")
    ms.required = True

    def common(q, two=True, out=None):
        if two:
            q.add_argument("a", metavar="A", help="first BVH clip (or mesh sequence folder, "
                                                  "or pose file)")
            q.add_argument("b", metavar="B", help="second BVH clip of the same skeleton (or "
                                                  "a mesh sequence folder of the same mesh, "
                                                  "or a pose file)")
        else:
            q.add_argument("a", metavar="IN", help="BVH clip (or mesh sequence folder, or "
                                                   "pose file)")
        if out:
            q.add_argument("-o", "--out", required=True, metavar="OUT", help=out)
        q.add_argument("--up", metavar="AXIS", default=None,
                       help="up axis (x, y, z, or negative as --up=-y; default: detected "
                            "from the data)")
        q.add_argument("--render", metavar="STRIP.png|ANIM.gif",
                       help="stick figures: a strip (.png/.svg/.pdf) or an animated .gif "
                            "(needs the viz extra)")
        q.add_argument("--plot", metavar="PNG",
                       help="plot foot heights and contacts, the warp, the seam gap per "
                            "iteration (needs the viz extra)")
        q.add_argument("--topology", metavar="MESH",
                       help="mesh sequences given as point caches (.mdd, .pc2 files): the mesh "
                            "they animate (OBJ, PLY or OFF; its faces, UVs and polygons)")
        q.add_argument("--position-scale", type=float, default=None, metavar="L",
                       help="pose tracks: file units of position that weigh like one radian "
                            "(default: the RMS distance from the mean position)")
        q.add_argument("--overwrite", action="store_true",
                       help="replace output files that exist")
        q.add_argument("-q", "--quiet", action="store_true", help="no progress output")

    def heading(q):
        q.add_argument("--heading", choices=["align", "keep"], default=None,
                       help="BVH: align (default) turns B about the up axis and moves it on "
                            "the ground to face and start like A (takes recorded facing "
                            "other ways are one motion); keep: as recorded")

    def aligning(q, default="dp"):
        heading(q)
        q.add_argument("--align", choices=["dp", "none"], default=default,
                       help=f"time alignment by dynamic programming or none (default {default})")
        q.add_argument("--features", metavar="F", default="none",
                       help="feature points: contacts, none, or a CSV of time pairs (seconds; "
                            "pose tracks: in the files' times, EuRoC nanoseconds)")
        weight(q)

    def iterations(q):
        q.add_argument("--iterations", type=int, default=None, metavar="N",
                       help="iteration limit of the warp's refinement (default max(5000, 4 x "
                            "frames)); stopping there is reported, exit status 1")

    def weight(q):
        q.add_argument("--feature-weight", type=float, default=None, metavar="LAM",
                       help="weight of the feature term lam * sum (phi(a_i) - b_i)^2 in "
                            "normalised times (default 100: pulls to about a frame on the "
                            "real walks; larger forces features that contradict the motion)")

    q = ms.add_parser("distance", help="print the SRV distance of two clips",
                      description="Print the SRV distance of two clips of one skeleton (the "
                                  "symmetric shape distance with --align dp).")
    common(q)
    aligning(q)
    iterations(q)
    q.set_defaults(func=_distance)

    q = ms.add_parser("align", help="write the time warp aligning B to A",
                      description="Write the warp phi aligning B to A as CSV: time_a,time_b "
                                  "in seconds, one row per frame of the common grid.")
    common(q, out="warp CSV file")
    heading(q)
    q.add_argument("--features", metavar="F", default="none",
                   help="feature points: contacts, none, or a CSV of time pairs (seconds; "
                        "pose tracks: in the files' times, EuRoC nanoseconds)")
    weight(q)
    iterations(q)
    q.set_defaults(func=_align)

    q = ms.add_parser("blend", help="blend two clips into a new BVH",
                      description="Blend two clips of one skeleton along the SRV geodesic, "
                                  "aligned in time first (--align dp).")
    common(q, out="BVH file to write (a sequence folder for mesh sequences)")
    q.add_argument("--s", type=float, default=0.5, metavar="S",
                   help="weight of B, from 0 (A) to 1 (B); default 0.5")
    aligning(q)
    q.add_argument("--plant", action="store_true",
                   help="correct the root where the blend's planted feet slide")
    q.set_defaults(func=_blend)

    q = ms.add_parser("close", help="make a clip loop seamlessly",
                      description="Close a clip into a loop with the smallest SRV change that "
                                  "closes the seam (Gauss-Newton form of seed 000's gradient "
                                  "flow), optionally C1, then keep planted feet from sliding "
                                  "by moving the root.")
    common(q, two=False, out="BVH file to write (a sequence folder for a mesh sequence)")
    q.add_argument("--iterations", type=int, default=10, metavar="N",
                   help="closing iterations (default 10)")
    q.add_argument("--c1", action="store_true", help="also match the velocities at the seam")
    q.add_argument("--root-motion", choices=["keep", "close"], default="keep",
                   help="keep: the root's horizontal travel is the loop's root motion (a walk "
                        "loops forward; default); close: the root returns to its start (mesh "
                        "sequences: the last frame is moved onto the first)")
    q.add_argument("--no-plant", action="store_true",
                   help="do not correct the root where planted feet slide")
    q.add_argument("--trim", action="store_true",
                   help="first cut the clip to the frames that loop best (at least half of "
                        "it): whole cycles close with a much smaller change")
    q.set_defaults(func=_close)


def _say(args):
    return (lambda s: None) if args.quiet else (lambda s: print(s, file=sys.stderr))


def _check_outputs(args, out=None):
    """Fail before any work on a bad --up, and on any output (``out`` = ``-o``, ``--plot``,
    ``--render``) that must not or cannot be written: an input (the clips, the --features
    file), the same file as another output, one that exists (without --overwrite), whose
    folder is missing, or whose picture type is unknown
    (:func:`shellspline.cli.outputs.check_outputs`, shared with ``shellspline path``)."""
    if args.up is not None and args.up.strip().lower().lstrip("+-") not in ("x", "y", "z"):
        raise ShellsplineError(f"--up must be one of x, y, z (optionally signed, e.g. --up=-z), "
                               f"got {args.up!r}")
    meshes = Path(args.a).is_dir() or _animation_file(Path(args.a)) is not None
    if args.topology is not None:
        caches = [q for q in (args.a, getattr(args, "b", None))
                  if q and Path(q).suffix.lower() in _CACHES]
        if not caches:
            raise ShellsplineError("--topology: the mesh of point cache inputs (.mdd, .pc2); "
                                   "none given")
    folder = meshes and args.motion_command in ("blend", "close")  # sequences
    check_outputs([Output("-o", out, folder=folder),
                   Output("--plot", args.plot, PICTURES),
                   Output("--render", args.render, ANIMATIONS)],
                  [args.a, getattr(args, "b", None), _feature_file_name(args), args.topology],
                  overwrite=args.overwrite)
    if args.render or args.plot:
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise ShellsplineError("--render/--plot need matplotlib: pip install "
                                   "'shellspline[viz]'")


_CACHES = (".mdd", ".pc2")


def _read(path, topology=None):
    """A BVH clip (a ``.bvh`` file or one that starts with ``HIERARCHY``), a mesh sequence (a
    folder of mesh frames, natural name order; a folder holding one animation file as
    :func:`~shellspline.io.write_sequence` writes it; a ``.glb`` or USD file; a point cache
    on the mesh ``topology``) or a pose track (any other file)."""
    from ..io import MESH_EXTENSIONS, read_keyframes
    from ..io.bvh import read_bvh
    from ..io.posefiles import read_poses
    from ..io.sequences import frame_files

    p = Path(path)
    anim = _animation_file(p)
    if anim is not None:
        kf = _read_animation(anim, p / "mesh.obj" if p.is_dir() else topology)
    elif p.is_dir():
        frames = frame_files(p)  # natural order: mesh.2.obj before mesh.10.obj
        if len(frames) < 3:
            raise ShellsplineError(f"{path}: a mesh sequence needs at least 3 frames "
                                   f"({', '.join(MESH_EXTENSIONS)} files, or one "
                                   "animation.mdd/.pc2/.glb/.usdc), found {len(frames)}")
        kf = read_keyframes(frames)
    elif not p.is_file():
        raise ShellsplineError(f"{path}: no such file or folder")
    else:
        kf = None
    if kf is not None:
        if kf.J < 3:
            raise ShellsplineError(f"{path}: a mesh sequence needs at least 3 frames, found "
                                   f"{kf.J}")
        return kf
    if p.suffix.lower() != ".bvh":
        with open(p, "rb") as f:
            head = f.read(64).lstrip()
        if not head.upper().startswith(b"HIERARCHY"):
            return read_poses(p)
    return read_bvh(p)


def _animation_file(p: Path):
    """The one animation file of a mesh sequence given as a file (``.mdd``, ``.pc2``,
    ``.glb``, USD) or as a folder that holds one by :data:`~shellspline.io.sequences.
    ANIMATION_NAMES` (the outputs of ``--format mdd|pc2|glb|usd``), or None."""
    from ..io.sequences import ANIMATION_NAMES
    from ..io.usd import USD_EXTENSIONS

    if p.is_dir():
        found = [p / n for n in ANIMATION_NAMES.values() if (p / n).is_file()]
        return found[0] if found else None
    if p.is_file() and p.suffix.lower() in (*_CACHES, ".glb", *USD_EXTENSIONS):
        return p
    return None


def _read_animation(anim: Path, mesh):
    """Keyframes of every frame of an animation file; a point cache on ``mesh``."""
    from ..io import keyframes_from_arrays, read_keyframes, read_sequence
    from ..io.pointcache import keyframes_from_cache, read_point_cache

    if anim.suffix.lower() in _CACHES:
        if mesh is None:
            raise ShellsplineError(f"{anim} is a point cache (vertex positions only, no faces): "
                                   "give the mesh it animates with --topology MESH")
        if not Path(mesh).is_file():
            raise ShellsplineError(f"{mesh}: no such mesh file (the mesh {anim.name} animates)")
        n = read_point_cache(anim)[0].shape[0]  # every sample a frame, evenly spaced
        return keyframes_from_cache(anim, mesh, np.arange(n))
    if anim.suffix.lower() == ".glb":
        V, F, _ = read_sequence(anim)
        return keyframes_from_arrays(V, F, names=[f"{anim} frame {k}"
                                                  for k in range(V.shape[0])])
    return read_keyframes([anim])  # USD: one mesh with time-sampled points


def _sequence_format(path) -> tuple[str, float, str]:
    """The format of a mesh sequence input, its frame rate and up axis, as its output is
    written: ``("mdd" | "pc2" | "glb" | "usd", fps, up)`` for an animation file, ``("ply",
    24, "y")`` for a folder of PLY frames, ``("obj", 24, "y")`` otherwise (OBJ or OFF frames,
    or mixed). ``up``: the axis a GLB's node rotation or a USD stage's ``upAxis`` gives its
    data (:func:`shellspline.io.usd.conventional_up_axis`), written back the same way (a
    z-up GLB or USD input was written y-up: its loop lay on its side in a viewer)."""
    from ..io.sequences import frame_files
    from ..io.usd import USD_EXTENSIONS, conventional_up_axis

    p = Path(path)
    anim = _animation_file(p)
    if anim is None:
        plys = {f.suffix.lower() == ".ply" for f in frame_files(p)}
        return ("ply" if plys == {True} else "obj"), 24.0, "y"
    ext = anim.suffix.lower()
    if ext == ".mdd":
        from ..io.pointcache import read_mdd

        dt = np.diff(read_mdd(anim)[1])
        fps = float(1.0 / np.median(dt)) if dt.size and np.median(dt) > 0 else 24.0
        return "mdd", fps, "y"
    if ext == ".glb":
        from ..io.gltf import read_glb

        return "glb", float(read_glb(anim)[2]), conventional_up_axis(anim)
    if ext in USD_EXTENSIONS:
        return "usd", 24.0, conventional_up_axis(anim)
    return ext.lstrip("."), 24.0, "y"


def _kind(x) -> str:
    """``"bvh"``, ``"mesh"`` or ``"poses"``."""
    from ..io.bvh import Motion
    from ..io.posefiles import PoseTrack

    return "bvh" if isinstance(x, Motion) else "poses" if isinstance(x, PoseTrack) else "mesh"


def _is_mesh(x) -> bool:
    return _kind(x) == "mesh"


def _is_track(x) -> bool:
    return _kind(x) == "poses"


def _track_options(args, a):
    """Reject the options that only BVH clips have, for pose tracks and mesh sequences (they
    were ignored for meshes: ``--up``, ``--no-plant``, ``--root-motion close``);
    ``--position-scale`` for anything but pose tracks. Returns the ``length`` keyword."""
    L = args.position_scale
    if _kind(a) == "bvh":
        if L is not None:
            raise ShellsplineError("--position-scale: pose tracks only")
        return None
    if _is_mesh(a) and L is not None:
        raise ShellsplineError("--position-scale: pose tracks only")
    if L is not None and not (np.isfinite(L) and L > 0):
        raise ShellsplineError(f"--position-scale must be a positive number, got {L!r}")
    bvh_only = [("--up", args.up is not None), ("--render", bool(args.render)),
                ("--features contacts", getattr(args, "features", None) == "contacts"),
                ("--plant", getattr(args, "plant", False)),
                ("--trim", getattr(args, "trim", False)),
                ("--no-plant", getattr(args, "no_plant", False)),
                ("--root-motion close", getattr(args, "root_motion", "keep") != "keep"
                 and not _is_mesh(a))]
    bad = [name for name, given in bvh_only if given]
    if bad:
        what = "mesh sequences" if _is_mesh(a) else "pose tracks"
        raise ShellsplineError(f"{', '.join(bad)}: BVH clips only, not {what}")
    return L


def _pictures_possible(args, a) -> None:
    """Refuse, before any work, a picture the command cannot draw for this kind of input
    (it was silently not drawn): ``--render`` draws stick figures of BVH clips only; for pose
    tracks and mesh sequences ``--plot`` draws the alignment's warp (``align``, ``blend``
    with ``--align dp``) or the seam gap (``close``), and ``distance`` has none to draw."""
    kind = {"mesh": "mesh sequences", "poses": "pose tracks"}.get(_kind(a))
    if kind is None:
        return
    cmd = args.motion_command
    if getattr(args, "render", None):
        raise ShellsplineError(f"--render draws stick figures of BVH clips; for {kind} give "
                               "--plot or none")
    if getattr(args, "plot", None) and (cmd == "distance" or
                                        (cmd == "blend" and args.align == "none")):
        what = "has no picture" if cmd == "distance" else "draws the warp of --align dp"
        raise ShellsplineError(f"--plot: for {kind}, motion {cmd} {what}")


def _read_pair(args):
    a, b = _read(args.a, args.topology), _read(args.b, args.topology)
    if _kind(a) != _kind(b):
        what = {"bvh": "a BVH clip", "mesh": "a mesh sequence folder", "poses": "a pose file"}
        raise ShellsplineError(f"{args.a} and {args.b}: give two BVH files, two mesh "
                               f"sequence folders or two pose files (got {what[_kind(a)]} and "
                               f"{what[_kind(b)]})")
    for path, x in ((args.a, a), (args.b, b)):
        if _is_track(x) and x.t.size < 2:
            raise ShellsplineError(f"{path}: {x.t.size} pose; distance, align and blend need "
                                   "at least 2")
        if _kind(x) == "bvh" and x.n_frames < 2:
            raise ShellsplineError(f"{path}: {x.n_frames} frame; distance, align and blend "
                                   "need at least 2")
    if _kind(a) != "bvh" and getattr(args, "heading", None) is not None:
        raise ShellsplineError("--heading: BVH clips only")
    _pictures_possible(args, a)
    if _kind(a) == "bvh":
        from ..animation import skeleton_mismatch

        why = skeleton_mismatch(a, b)
        if why is not None:
            raise ShellsplineError(f"{args.a} and {args.b}: {why}")
    if _is_mesh(a):
        if args.render:
            raise ShellsplineError("--render draws skeletons: BVH clips only")
        if a.n != b.n or not np.array_equal(a.F, b.F):
            a, b = _read_jointly(args, a, b)
        if a.n != b.n or not np.array_equal(a.F, b.F):
            raise ShellsplineError(f"{args.a} and {args.b} are not frames of one mesh: "
                                   f"{a.n} and {b.n} vertices, {a.m} and {b.m} faces")
    return a, b


def _file_positions(path, topology):
    """A mesh sequence's frames as its files hold them, with the polygons, texture
    coordinates and OBJ lines of its first frame (or mesh): ``(P (J,n,3), offsets, indices,
    uv, statements, faces_file)``; None for a glTF or USD animation."""
    from ..io.meshes import read_polygons
    from ..io.pointcache import read_point_cache
    from ..io.sequences import frame_files

    p, info = Path(path), {}
    anim = _animation_file(p)
    if anim is None:
        files = frame_files(p)
        first = read_polygons(files[0], info)
        P = np.stack([first[0]] + [read_polygons(f)[0] for f in files[1:]])
        return (P, *first[1:], info.get("statements"), str(files[0]))
    if anim.suffix.lower() in _CACHES:
        mesh = p / "mesh.obj" if p.is_dir() else topology
        _, offsets, indices, uv = read_polygons(mesh, info)
        return read_point_cache(anim)[0], offsets, indices, uv, info.get("statements"), str(mesh)
    return None


def _read_jointly(args, a, b):
    """Two sequences of one polygon mesh validated as one keyframe set, so that they share
    the triangles and welds (each sequence alone chose a quad's diagonal by its own frames:
    two animations of one quad mesh were "not frames of one mesh"); ``(a, b)`` unchanged
    when their files' polygons differ."""
    import dataclasses

    from ..io.keyframes import keyframes_from_polygons

    ra, rb = _file_positions(args.a, args.topology), _file_positions(args.b, args.topology)
    if ra is None or rb is None or ra[0].shape[1] != rb[0].shape[1] or \
            not (np.array_equal(ra[1], rb[1]) and np.array_equal(ra[2], rb[2])):
        return a, b
    kf = keyframes_from_polygons(np.concatenate([ra[0], rb[0]]), ra[1], ra[2],
                                 names=a.names + b.names, uv=ra[3], statements=ra[4],
                                 faces_file=ra[5])
    J = a.J

    def part(x, rows, names):
        src = None if kf.source is None else dataclasses.replace(
            kf.source, exact_V=kf.source.exact_V[rows])
        return dataclasses.replace(kf, V=kf.V[rows], names=names, source=src)
    return part(kf, slice(0, J), a.names), part(kf, slice(J, None), b.names)


def _write_mesh(args, Vs, kf, report, times):
    """Write frames of ``kf``'s solve mesh as a sequence folder in the format (and up axis) of
    the input ``args.a`` (:func:`_sequence_format`), on its files' vertices and polygons (UVs,
    seams: :func:`shellspline.animation.mesh_on_source`)."""
    from ..animation import mesh_on_source
    from ..io import write_sequence

    fmt, fps, up = _sequence_format(args.a)
    write_sequence(args.out, mesh_on_source(Vs, kf, times), kf.F, report, fmt=fmt, fps=fps,
                   up_axis=up, overwrite=args.overwrite, source=kf.source,
                   protect=[q for q in (args.a, getattr(args, "b", None), args.topology) if q])


def _feature_kw(args) -> dict:
    """``{"lam": w}`` from ``--feature-weight`` (validated), or ``{}``."""
    w = getattr(args, "feature_weight", None)
    if w is None:
        return {}
    if not (np.isfinite(w) and w > 0):
        raise ShellsplineError(f"--feature-weight must be a positive number, got {w!r}")
    if args.features in (None, "none"):
        raise ShellsplineError("--feature-weight needs --features")
    return {"lam": float(w)}


def _solver_kw(args) -> dict:
    """``{"max_iter": n}`` from ``--iterations`` (validated), or ``{}``."""
    n = getattr(args, "iterations", None)
    if n is None:
        return {}
    if n < 1:
        raise ShellsplineError(f"--iterations must be >= 1, got {n}")
    if getattr(args, "align", "dp") != "dp":
        raise ShellsplineError("--iterations needs --align dp")
    return {"max_iter": n}


def _alignment_status(results) -> str:
    """One status for the alignments of a distance: the first that did not succeed, else
    ``"converged"`` (``"dp"`` without refinement)."""
    return next((r.status for r in results if not r.success),
                results[0].status if results else "converged")


def _feature_file_name(args):
    """The ``--features`` CSV file (an input), or None for ``contacts``/``none``."""
    spec = getattr(args, "features", None)
    return None if spec in (None, "none", "contacts") else spec


def _feature_file(spec):
    """``(pairs (k,2), lines (k,), tokens (k,2))`` of a ``--features`` CSV file: the times as
    numbers, the file line of each pair and the times as written; one-line errors naming the
    file and line."""
    p = Path(spec)
    if not p.is_file():
        raise ShellsplineError(f"--features: expected 'contacts', 'none' or a CSV file, got "
                               f"{spec!r} (no such file)")
    rows, lines, tokens = [], [], []
    for i, line in enumerate(p.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
        s = line.split("#", 1)[0].strip()
        if not s or s.lower().replace(" ", "") in ("time_a,time_b", "t_a,t_b"):
            continue
        parts = [x.strip() for x in s.replace(";", ",").replace("\t", ",").split(",")
                 if x.strip()]
        try:
            vals = [float(x) for x in parts]
        except ValueError:
            raise ShellsplineError(f"{spec}:{i}: expected two times in seconds, got "
                                   f"{s!r}") from None
        if len(vals) != 2:
            raise ShellsplineError(f"{spec}:{i}: expected two times in seconds, got {s!r}")
        if not np.all(np.isfinite(vals)):
            raise ShellsplineError(f"{spec}:{i}: a time is not a finite number: {s!r}")
        rows.append(vals)
        lines.append(i)
        tokens.append(parts)
    if not rows:
        raise ShellsplineError(f"{spec}: no feature pairs")
    return np.array(rows), lines, tokens


def _check_feature_spans(args, P, lines, tokens, spans, unit=""):
    """Refuse, naming the file and line, the first pair whose time lies outside its clip:
    ``spans`` ``((lo_a, hi_a, shown_a), (lo_b, hi_b, shown_b))`` in the units of ``P``, shown
    as the files write them."""
    for k, (lo, hi, shown), path in zip((0, 1), spans, (args.a, args.b)):
        bad = np.flatnonzero((P[:, k] < lo) | (P[:, k] > hi))
        if bad.size:
            i = int(bad[0])
            raise ShellsplineError(f"{args.features}:{lines[i]}: time {tokens[i][k]} is "
                                   f"outside {'AB'[k]} ({path}: {shown[0]}..{shown[1]}{unit})")


def _read_features(args, a=None, b=None):
    """None, ``"contacts"`` or the pairs of the ``--features`` file in seconds, each time
    within its clip (BVH clips ``a`` and ``b``: from 0 to their durations)."""
    spec = args.features
    if spec in (None, "none", "contacts"):
        return None if spec in (None, "none") else "contacts"
    P, lines, tokens = _feature_file(spec)
    if a is not None:
        spans = [(0.0, d, ("0", f"{d:.10g}")) for d in
                 ((m.n_frames - 1) * m.frame_time for m in (a, b))]
        _check_feature_spans(args, P, lines, tokens, spans, " s")
    return P


@contextmanager
def _clips_named(args):
    """The library names the two clips "clip a" and "clip b" in its errors: name the files."""
    try:
        yield
    except ShellsplineError as exc:
        msg = str(exc)
        for which, path in (("clip a: ", args.a), ("clip b: ", args.b)):
            if msg.startswith(which):
                raise ShellsplineError(f"{path}: {msg[len(which):]}") from None
        raise


def _pictures(args, motions, say, *, warp=None, seam=None):
    from ..animation import foot_contacts
    from ..motion_viz import plot_motion, render_gif, render_strip

    if args.render:
        if Path(args.render).suffix.lower() == ".gif":
            render_gif(motions, args.render, up=args.up)
        else:
            render_strip(motions, args.render, up=args.up)
        say(f"  render      {args.render}")
    if args.plot:
        ms = motions if isinstance(motions, (list, tuple)) else [motions]
        plot_motion(args.plot, motions=ms, contacts=[foot_contacts(m, up=args.up) for m in ms],
                    warp=warp, seam_history=seam)
        say(f"  plot        {args.plot}")


def _distance(args) -> int:
    from ..animation import distance

    _check_outputs(args)
    fkw = _feature_kw(args)
    fkw.update(_solver_kw(args))
    say = _say(args)
    a, b = _read_pair(args)
    length = _track_options(args, a)
    results = []  # the alignments' results (--align dp)
    if _is_track(a):
        from ..animation import track_distance, track_length

        if args.features not in (None, "none"):
            raise ShellsplineError("--features: BVH clips only for distance")
        L = track_length(a, b) if length is None else length
        d = track_distance(a, b, align=args.align, length=L, results=results, **fkw)
        print(f"{d:.9g}")
        say(f"  distance    SRV in SO(3) x R^3, align {args.align}, position scale {L:.6g} "
            f"units/rad: {d:.6g}{_distance_status(results)}")
        return _distance_exit(results, say)
    if _is_mesh(a):
        from ..animation import mesh_distance

        if args.features not in (None, "none"):
            raise ShellsplineError("--features: BVH clips only")
        d = mesh_distance(a.V, b.V, a.F, align=args.align, results=results, **fkw)
        print(f"{d:.9g}")
        say(f"  distance    SRV of the LΘA curves, align {args.align}: {d:.6g}"
            f"{_distance_status(results)}")
        return _distance_exit(results, say)
    with _clips_named(args):
        d = distance(a, b, align=args.align, features=_read_features(args, a, b), up=args.up,
                     heading=args.heading or "align", results=results, **fkw)
    print(f"{d:.9g}")
    say(f"  distance    SRV, align {args.align}, features {args.features}: {d:.6g}"
        f"{_distance_status(results)}")
    if args.render or args.plot:
        _pictures(args, [a, b], say)
    return _distance_exit(results, say)


def _distance_status(results) -> str:
    """`` (status, N iterations)`` of a distance's alignments for the summary, or ``""``."""
    if not results:
        return ""
    return (f" ({_alignment_status(results)}, "
            f"{'+'.join(str(r.iterations) for r in results)} refinement iterations)")


def _distance_exit(results, say) -> int:
    """Exit status of a distance: 1 (with a warning) when an alignment did not converge."""
    bad = [r for r in results if not r.success]
    if bad:
        say(f"  warning: the time alignment did not converge ({bad[0].status}: "
            f"{bad[0].message}); the distance is an upper bound")
        return EXIT_WARN
    return EXIT_OK


def _align(args) -> int:
    from ..animation import align
    from ..io.posefiles import write_text_atomic

    _check_outputs(args, args.out)
    fkw = _feature_kw(args)
    fkw.update(_solver_kw(args))
    say = _say(args)
    a, b = _read_pair(args)
    length = _track_options(args, a)
    if _is_track(a):
        return _align_tracks(args, a, b, length, fkw, say)
    if _is_mesh(a):
        from ..animation import mesh_align

        if args.features not in (None, "none"):
            raise ShellsplineError("--features: BVH clips only")
        r = mesh_align(a.V, b.V, a.F, **fkw)
        rows = np.stack([r.t * (a.J - 1), r.phi * (b.J - 1)], axis=1)
        lines = ["frame_a,frame_b"] + [f"{x!r},{y!r}" for x, y in rows.tolist()]
        write_text_atomic(args.out, "\n".join(lines) + "\n")
        say(f"  align       {a.J} frames: energy {r.energy_identity:.4g} -> {r.energy:.4g} "
            f"({r.status} in {r.iterations} iterations: {r.message})")
        say(f"  wrote       {args.out}")
        if args.plot:
            from ..motion_viz import plot_motion

            plot_motion(args.plot, warp=(r.t, r.phi))
            say(f"  plot        {args.plot}")
        return _status(r, say)
    with _clips_named(args):
        rep = align(a, b, features=_read_features(args, a, b), up=args.up,
                    heading=args.heading or "align", **fkw)
    lines = ["time_a,time_b"] + [f"{x!r},{y!r}" for x, y in rep.seconds.tolist()]
    write_text_atomic(args.out, "\n".join(lines) + "\n")
    nf = 0 if rep.features is None else rep.features.shape[0]
    say(f"  align       {rep.t.size} frames, {nf} feature pairs: SRV distance "
        f"{rep.distance_before:.4g} -> {rep.distance_after:.4g} ({rep.result.status} in "
        f"{rep.result.iterations} iterations: {rep.result.message})")
    say(f"  wrote       {args.out}")
    if args.render or args.plot:
        from ..animation import common_grid, warp_motion

        a2, _ = common_grid(a, b, rep.t.size)
        _pictures(args, [a2, warp_motion(b, rep.phi, a2.frame_time)], say,
                  warp=(rep.t, rep.phi))
    return _status(rep.result, say)


def _file_times(track, t) -> list:
    """Times ``t`` of a pose track (its seconds) as its file writes them: integer nanoseconds
    for EuRoC and ROS stamps (``origin_ns + round(t * 1e9)``), else seconds."""
    t = np.asarray(t, dtype=np.float64)
    if track.time_unit == "ns":
        return [str(x) for x in (track.origin_ns + np.round(t * 1e9).astype(np.int64)).tolist()]
    return [repr(x) for x in t.tolist()]


def _track_features(args, a, b):
    """``--features`` time pairs in the files' units, as the tracks' seconds, each within its
    track's span."""
    if _feature_file_name(args) is None:
        return _read_features(args)
    feats, lines, tokens = _feature_file(args.features)
    for k, tr in enumerate((a, b)):
        if tr.time_unit == "ns":  # integer nanoseconds subtracted exactly
            feats[:, k] = [((int(x[k]) if x[k].lstrip("-").isdigit() else float(x[k]))
                            - tr.origin_ns) * 1e-9 for x in tokens]
    _check_feature_spans(args, feats, lines, tokens,
                         [(tr.t[0], tr.t[-1], _file_times(tr, tr.t[[0, -1]])) for tr in (a, b)])
    return feats


def _align_tracks(args, a, b, length, fkw, say) -> int:
    from ..animation import track_align
    from ..io.posefiles import write_text_atomic

    feats = _track_features(args, a, b)
    r = track_align(a, b, length=length, features=feats, **fkw)
    lines = ["time_a,time_b"] + [f"{x},{y}" for x, y in zip(_file_times(a, r.t),
                                                            _file_times(b, r.phi))]
    write_text_atomic(args.out, "\n".join(lines) + "\n")
    say(f"  align       {r.t.size} poses (evenly resampled): energy {r.energy_identity:.4g} "
        f"-> {r.energy:.4g}, SRV distance {r.distance:.4g} ({r.status} in {r.iterations} "
        f"iterations: {r.message})")
    say(f"  wrote       {args.out}")
    if args.plot:
        from ..motion_viz import plot_motion

        span_a, span_b = r.t[-1] - r.t[0], b.t[-1] - b.t[0]
        plot_motion(args.plot, warp=((r.t - r.t[0]) / span_a, (r.phi - b.t[0]) / span_b))
        say(f"  plot        {args.plot}")
    return _status(r, say)


def _status(result, say) -> int:
    """Exit status of a solve: 1 (with a warning naming its status) when it did not
    succeed, else 0."""
    ok = getattr(result, "success", True)
    if not ok:
        status = getattr(result, "status", None)
        say("  warning: " + ("" if status is None else f"did not converge ({status}): ")
            + getattr(result, "message", "the solver did not converge"))
        return EXIT_WARN
    return EXIT_OK


def _blend(args) -> int:
    from ..animation import blend, foot_skate
    from ..io.bvh import write_bvh

    if not 0 <= args.s <= 1:  # (NaN too)
        raise ShellsplineError(f"--s must be between 0 (A) and 1 (B), got {args.s:g}")
    _check_outputs(args, args.out)
    fkw = _feature_kw(args)
    say = _say(args)
    a, b = _read_pair(args)
    length = _track_options(args, a)
    if _is_track(a):
        return _blend_tracks(args, a, b, length, fkw, say)
    if _is_mesh(a):
        return _blend_meshes(args, a, b, say)
    with _clips_named(args):
        m, rep = blend(a, b, args.s, align=args.align, features=_read_features(args, a, b),
                       up=args.up, plant=args.plant, heading=args.heading or "align", **fkw)
    write_bvh(m, args.out)
    sk = foot_skate(m, up=args.up)
    say(f"  blend       s = {args.s:g}, align {args.align}: {m.n_frames} frames at "
        f"{m.fps:.4g} fps" + ("" if rep is None else
                              f"; SRV distance {rep.distance_before:.4g} -> "
                              f"{rep.distance_after:.4g} after alignment"))
    say(f"  foot skate  {sk['speed']:.3g} units/s while planted "
        f"({sk['speed_per_leg']:.3g} leg lengths/s)")
    say(f"  wrote       {args.out}")
    if args.render or args.plot:
        _pictures(args, m, say, warp=None if rep is None else (rep.t, rep.phi))
    return EXIT_OK if rep is None else _status(rep.result, say)


def _blend_tracks(args, a, b, length, fkw, say) -> int:
    from ..animation import track_blend
    from ..io.posefiles import write_poses

    if _feature_file_name(args) is not None and args.align != "dp":
        raise ShellsplineError("--features needs --align dp")
    feats = _track_features(args, a, b)
    out, rep = track_blend(a, b, args.s, align=args.align, length=length, features=feats,
                           **fkw)
    write_poses(args.out, out.t, out.T, out.format, origin_ns=out.origin_ns,
                time_unit=out.time_unit)
    r = rep.result
    say(f"  blend       s = {args.s:g}, align {args.align}: {out.t.size} poses ({out.format}), "
        f"position scale {rep.length:.6g} units/rad" + ("" if r is None else
                                                        f"; SRV distance {r.distance:.4g} "
                                                        "after alignment"))
    say(f"  wrote       {args.out}")
    if args.plot and r is not None:
        from ..motion_viz import plot_motion

        span_a, span_b = r.t[-1] - r.t[0], b.t[-1] - b.t[0]
        plot_motion(args.plot, warp=((r.t - r.t[0]) / span_a, (r.phi - b.t[0]) / span_b))
        say(f"  plot        {args.plot}")
    return EXIT_OK if r is None else _status(r, say)


def _blend_meshes(args, a, b, say) -> int:
    from ..animation import mesh_blend

    if args.features not in (None, "none") or args.plant:
        raise ShellsplineError("--features and --plant: BVH clips only")
    Vs, rep = mesh_blend(a.V, b.V, a.F, args.s, align=args.align)
    _write_mesh(args, Vs, a, {"operation": "motion blend", "s": args.s, "align": args.align,
                              "frames": rep.frames, "converged": rep.converged,
                              "descriptor_error": rep.descriptor_error}, rep.times)
    say(f"  blend       s = {args.s:g}, align {args.align}: {rep.frames} frames, "
        f"{rep.converged} reconstructions converged, descriptor error "
        f"{rep.descriptor_error:.2g}")
    say(f"  wrote       {args.out}")
    if args.plot and rep.align is not None:
        from ..motion_viz import plot_motion

        plot_motion(args.plot, warp=(rep.align.t, rep.align.phi))
        say(f"  plot        {args.plot}")
    return EXIT_OK if rep.converged == rep.frames else EXIT_WARN


def _close_meshes(args, kf, say) -> int:
    from ..animation import mesh_close

    if args.render or args.trim:
        raise ShellsplineError("--render and --trim: BVH clips only")
    Vs, rep = mesh_close(kf.V, kf.F, iterations=args.iterations, c1=args.c1,
                         root_motion=args.root_motion)
    _write_mesh(args, Vs, kf, {"operation": "motion close", "c1": args.c1,
                               "root_motion": args.root_motion,
                               "seam_gap": rep.history, "status": rep.status,
                               "frames": rep.frames, "converged": rep.converged,
                               "descriptor_error": rep.descriptor_error}, rep.times)
    say(f"  seam gap    {rep.history[0]:.3g} -> {rep.history[-1]:.3g} (LΘA) in "
        f"{rep.history.size - 1} iterations ({rep.status}); {rep.converged}/{rep.frames} "
        f"reconstructions converged, descriptor error {rep.descriptor_error:.2g}")
    say(f"  wrote       {args.out}")
    if args.plot:
        from ..motion_viz import plot_motion

        plot_motion(args.plot, seam_history=rep.history)
        say(f"  plot        {args.plot}")
    if rep.status != "converged":
        say(f"  warning: the seam did not close ({rep.status}): more --iterations")
    return EXIT_OK if rep.success else EXIT_WARN


def _close_track(args, track, length, say) -> int:
    from ..animation import track_close
    from ..io.posefiles import write_poses

    if track.t.size < 3:
        raise ShellsplineError(f"{args.a}: {track.t.size} poses; closing needs at least 3")
    out, rep = track_close(track, iterations=args.iterations, c1=args.c1, length=length)
    write_poses(args.out, out.t, out.T, out.format, origin_ns=out.origin_ns,
                time_unit=out.time_unit)
    res = rep.result
    say(f"  seam gap    {np.degrees(rep.rotation_gap[0]):.3g} -> "
        f"{np.degrees(rep.rotation_gap[1]):.3g} deg, {rep.position_gap[0]:.3g} -> "
        f"{rep.position_gap[1]:.3g} units (position scale {rep.length:.6g} units/rad) in "
        f"{res.iterations} iterations ({res.status})")
    if args.c1:
        say(f"  velocity    jump at the seam {res.velocity_jump[0]:.3g} -> "
            f"{res.velocity_jump[-1]:.3g}")
    say(f"  wrote       {args.out} ({out.format})")
    if args.plot:
        from ..motion_viz import plot_motion

        plot_motion(args.plot, seam_history=res.seam_gap)
        say(f"  plot        {args.plot}")
    return _status(res, say)


def _close(args) -> int:
    from ..animation import close
    from ..io.bvh import write_bvh

    if args.iterations < 0:
        raise ShellsplineError(f"--iterations must be >= 0, got {args.iterations}")
    _check_outputs(args, args.out)
    say = _say(args)
    m = _read(args.a, args.topology)
    _pictures_possible(args, m)
    length = _track_options(args, m)
    if _is_track(m):
        return _close_track(args, m, length, say)
    if _is_mesh(m):
        return _close_meshes(args, m, say)
    try:
        out, rep = close(m, iterations=args.iterations, c1=args.c1,
                         root_motion=args.root_motion, plant=not args.no_plant, up=args.up,
                         trim=args.trim)
    except ShellsplineError as e:  # name the file (the message names joint and frame)
        raise ShellsplineError(f"{args.a}: {e}") from None
    write_bvh(out, args.out)
    if args.trim:
        say(f"  trim        frames {rep.frames[0]}..{rep.frames[1]} of {m.n_frames} loop best")
    g0, g1 = rep.gap_before, rep.gap_after
    say(f"  seam gap    {g0['rotation_max']:.3g} -> {g1['rotation_max']:.3g} deg (largest "
        f"joint), {g0['position_max']:.3g} -> {g1['position_max']:.3g} units (largest joint "
        f"jump); energy {g0['energy']:.3g} -> {g1['energy']:.3g} in {rep.iterations} "
        "iterations")
    s0, s1, s2 = rep.skate_before, rep.skate_closed, rep.skate_after
    say(f"  foot skate  {s0['speed']:.3g} (input) -> {s1['speed']:.3g} (closed) -> "
        f"{s2['speed']:.3g} units/s (feet planted) while in contact")
    say(f"  wrote       {args.out}")
    if args.render or args.plot:
        _pictures(args, out, say, seam=rep.history)
    return _status(rep, say)
