"""Curves on Lie groups: geodesic de Casteljau Bézier curves, geodesic de Boor B-splines with
knot insertion, and interpolating splines through poses (C¹ quadratic, C² cubic) with
natural, clamped and periodic ends.

Layer rule: imports only numpy, scipy, :mod:`shellspline.groups` and
:mod:`shellspline.errors` (never the shell modules).
"""
from .bezier import bezier, bezier_ckl, bezier_velocity, de_casteljau, geodesic
from .bspline import BSpline, clamped_knots
from .interp import (PiecewiseBezier, SplineSolve, cubic_spline, geodesic_interpolant,
                     hermite_spline, quadratic_spline)

__all__ = ["geodesic", "de_casteljau", "bezier", "bezier_velocity", "bezier_ckl", "BSpline",
           "clamped_knots", "PiecewiseBezier", "SplineSolve", "cubic_spline", "quadratic_spline",
           "hermite_spline", "geodesic_interpolant"]
