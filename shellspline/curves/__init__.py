"""Curves on Lie groups: geodesic de Casteljau Bézier curves, geodesic de Boor B-splines with
knot insertion, and interpolating splines through poses (C¹ quadratic, C² cubic) with
natural, clamped and periodic ends; shape analysis of curves in SO(3)^d x R^m (seeds 000,
003): the square-root-velocity transform, distances and blends (:mod:`.srv`), elastic time
alignment with feature points (:mod:`.align`) and closing (:mod:`.closing`).

Layer rule: imports only numpy, scipy, :mod:`shellspline.groups` and
:mod:`shellspline.errors` (never the shell modules).
"""
from .bezier import bezier, bezier_ckl, bezier_velocity, de_casteljau, geodesic
from .bspline import BSpline, clamped_knots
from .interp import (PiecewiseBezier, SplineSolve, cubic_spline, geodesic_interpolant,
                     hermite_spline, quadratic_spline)
from .srv import ProductCurve, blend, reparametrize, srv, srv_distance, srv_inverse
from .align import AlignResult, align, project_closed, shape_distance
from .closing import CloseResult, close, seam_gap

__all__ = ["geodesic", "de_casteljau", "bezier", "bezier_velocity", "bezier_ckl", "BSpline",
           "clamped_knots", "PiecewiseBezier", "SplineSolve", "cubic_spline", "quadratic_spline",
           "hermite_spline", "geodesic_interpolant",
           "ProductCurve", "srv", "srv_inverse", "srv_distance", "reparametrize", "blend",
           "AlignResult", "align", "shape_distance", "project_closed",
           "CloseResult", "close", "seam_gap"]
