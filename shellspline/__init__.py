"""shellspline: splines in the space of thin shells.

Turn a handful of keyframe poses of one triangle mesh into a smooth in-between sequence
(Heeren, Rumpf, Schröder, Wardetzky, Wirth, "Splines in the Space of Shells", SGP 2016).
"""
from __future__ import annotations

__version__ = "0.1.0"
