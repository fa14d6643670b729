"""CLI subcommand ``batch`` (see :mod:`shellspline.batch`)."""
from __future__ import annotations


def add_parsers(sub) -> None:
    """Register the ``batch`` subcommand on the ``shellspline`` subparsers."""
