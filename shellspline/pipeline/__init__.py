"""Orchestration: keyframes in, an interpolated sequence and its report out.

The only layer that knows the order of the stages (decimate, describe, solve, reconstruct,
prolong, place) and which numerical layers each method uses.
"""
from .interpolation import (BOUNDARY_CONDITIONS, METHODS, REFERENCES, RIGID_TRACKS,
                            InterpolationResult, interpolate, linear_blend)

__all__ = ["interpolate", "InterpolationResult", "linear_blend", "METHODS", "BOUNDARY_CONDITIONS",
           "REFERENCES", "RIGID_TRACKS"]
