"""Lie groups for rigid motions: SO(3), SE(3) with two metrics, SO(3)^d x R^3.

Layer rule: imports only numpy and :mod:`shellspline.errors` (never the shell modules).
"""
from . import se3, so3
from .lie import SE3, SO3, LieGroup, SO3dR3, SO3xR3, group, karcher_mean

__all__ = ["so3", "se3", "LieGroup", "SO3", "SE3", "SO3xR3", "SO3dR3", "group",
           "karcher_mean"]
