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


def one_line(exc: BaseException, *, limit: int = 200, bare: tuple = ()) -> str:
    """The message of ``exc`` on one line, at most ``limit`` characters.

    The exception's type name is prefixed unless ``exc`` is an instance of one of the
    classes in ``bare`` (messages of our own errors already say what went wrong).
    """
    text = " ".join(str(exc).split())
    if len(text) > limit:
        text = text[:limit - 3] + "..."
    if text and bare and isinstance(exc, bare):
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
