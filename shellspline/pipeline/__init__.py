"""Orchestration: keyframes in, an interpolated sequence and its report out.

The only layer that knows the order of the stages (decimate, describe, solve, reconstruct,
prolong, place) and which numerical layers each method uses: options (:mod:`.options`), one
stage function per method (:mod:`.stages`), the shared stages (:mod:`.describe`,
:mod:`.reconstruction`, :mod:`.placement`) and the report (:mod:`.report`).
"""
from .interpolation import InterpolationResult, interpolate
from .options import (BOUNDARY_CONDITIONS, METHODS, REFERENCES, RIGID_TRACKS,
                      InterpolationOptions)
from .placement import placement_track
from .report import quality_ok
from ..timeline import linear_blend

__all__ = ["interpolate", "InterpolationResult", "InterpolationOptions", "linear_blend",
           "placement_track", "quality_ok", "METHODS", "BOUNDARY_CONDITIONS", "REFERENCES",
           "RIGID_TRACKS"]
