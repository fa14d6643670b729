"""CLI subcommand ``blender-addon``: write the installable Blender add-on zip."""
from __future__ import annotations

import sys


def add_parsers(sub) -> None:
    """Register ``blender-addon`` on the ``shellspline`` subparsers."""
    p = sub.add_parser("blender-addon", help="write the Blender add-on zip (Blender 4.2+)",
                       description="Write the shellspline add-on for Blender 4.2 LTS and later "
                                   "as a zip to install with Edit > Preferences > Add-ons > "
                                   "Install from Disk (see the README, 'Blender add-on').")
    p.add_argument("-o", "--out", default="shellspline_addon.zip",
                   help="zip file to write (default shellspline_addon.zip)")
    p.add_argument("--overwrite", action="store_true", help="replace the file if it exists")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing")
    p.set_defaults(func=_blender_addon)


def _blender_addon(args) -> int:
    from ..integrations.blender import write_addon_zip

    try:
        out = write_addon_zip(args.out, overwrite=args.overwrite)
    except FileExistsError:
        raise FileExistsError(f"'{args.out}' already exists (--overwrite replaces it)") from None
    if not args.quiet:
        print(f"wrote {out}: in Blender, Edit > Preferences > Add-ons > Install from Disk",
              file=sys.stderr)
    return 0
