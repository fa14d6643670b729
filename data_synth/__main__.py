"""Command line: ``python -m data_synth NAME OUT [--vertices N] [--format obj|ply|off]
[--count C]``, and ``python -m data_synth skinned BVH OUT ...`` (a body skinned to a BVH clip,
every frame written: see :mod:`data_synth.skinned`), and ``python -m data_synth motion OUT.bvh
...`` (a synthetic walk in any BVH channel layout: see :mod:`data_synth.motion`)."""
from __future__ import annotations

import argparse
import sys

from . import FORMATS, NAMES, generate, write_batch, write_keyframes
from .dcc import DCC_NAMES, write_dcc


def main(argv=None) -> int:
    """Parse arguments, write the data set and print a one-line summary.

    Parameters
    ----------
    argv : list of str, optional
        Arguments (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status (0 on success; invalid arguments exit with status 2).
    """
    parser = argparse.ArgumentParser(
        prog="python -m data_synth",
        description="Write synthetic keyframe meshes (one mesh, shared connectivity): "
                    "OUT/pose_00.<fmt>, pose_01.<fmt>, ..., OUT/frames.txt and, when the data "
                    "set pins vertices, OUT/pinned.txt. `python -m data_synth skinned BVH OUT` "
                    "writes a body skinned to a BVH clip instead (see its --help).")
    parser.add_argument("name", choices=NAMES + DCC_NAMES,
                        help="data set (dcc_tube: polygons, UV seam, fin, isolated vertex and "
                             "two components, as a DCC tool exports them)")
    parser.add_argument("out", help="output directory (created if missing)")
    parser.add_argument("--vertices", type=int, default=None, metavar="N",
                        help="approximate vertex count (default: the data set's default)")
    parser.add_argument("--format", choices=FORMATS, default="obj", help="mesh file format")
    parser.add_argument("--count", type=int, default=None, metavar="C",
                        help="write C varied sequences OUT/NAME_00/, OUT/NAME_01/, ... (for "
                             "batch jobs) instead of one")
    parser.add_argument("--seed", type=int, default=0, help="seed of the --count variation")
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["skinned"]:  # its own arguments (a BVH file, a window of frames)
        from .skinned import main as skinned_main
        return skinned_main(argv[1:])
    if argv[:1] == ["motion"]:  # a synthetic BVH walk in a chosen channel layout
        from .motion import main as motion_main
        return motion_main(argv[1:])
    args = parser.parse_args(argv)
    if args.name in DCC_NAMES:
        if args.count is not None or args.vertices is not None:
            parser.error(f"{args.name} takes neither --count nor --vertices")
        paths = write_dcc(args.name, args.out, args.format)
        print(f"{args.name}: wrote {len(paths)} poses {paths[0].name}..{paths[-1].name} to "
              f"{paths[0].parent}, frames.txt")
        return 0
    if args.count is not None:
        try:
            dirs = write_batch(args.name, args.out, args.count, args.vertices, args.format,
                               args.seed)
        except ValueError as exc:
            parser.error(str(exc))  # exits with status 2
        print(f"{args.name}: wrote {len(dirs)} sequences {dirs[0].name}..{dirs[-1].name} "
              f"to {dirs[0].parent}")
        return 0
    try:
        data = generate(args.name, args.vertices)
        paths = write_keyframes(data, args.out, args.format)
    except ValueError as exc:
        parser.error(str(exc))  # exits with status 2
    J, n, _ = data["V"].shape
    pinned = "" if data["pinned"] is None else f", pinned.txt ({data['pinned'].size} vertices)"
    print(f"{args.name}: wrote {J} poses ({n} vertices, {data['F'].shape[0]} faces) "
          f"{paths[0].name}..{paths[-1].name} to {paths[0].parent}, frames.txt "
          f"({' '.join(str(int(f)) for f in data['frames'])}){pinned}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
