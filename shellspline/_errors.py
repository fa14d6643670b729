"""Exceptions and the library-wide numerical tolerances."""
from __future__ import annotations

from dataclasses import dataclass


class ShellsplineError(ValueError):
    """Base class for errors raised on bad input (a ``ValueError``)."""


class MeshError(ShellsplineError):
    """A mesh (or a set of keyframe meshes) is invalid.

    The message is one line and names the offending file when there is one.
    """


@dataclass(frozen=True)
class Tolerances:
    """One tolerance object for the whole library.

    Attributes
    ----------
    degenerate_area : float
        A face whose area is below ``degenerate_area * mean_edge_length**2`` is degenerate.
    zero : float
        Generic floating-point zero used for guarded divisions.
    """

    degenerate_area: float = 1e-12
    zero: float = 1e-300


tol = Tolerances()
