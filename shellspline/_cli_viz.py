"""CLI subcommands ``preview``, ``render`` and ``plot`` (see :mod:`shellspline.viz`)."""
from __future__ import annotations


def add_parsers(sub) -> None:
    """Register the visualisation subcommands on the ``shellspline`` subparsers."""
