"""shellspline: splines in the space of thin shells.

Turn a handful of keyframe poses of one triangle mesh into a smooth in-between sequence
(Heeren, Rumpf, Schröder, Wardetzky, Wirth, "Splines in the Space of Shells", SGP 2016).
"""
from __future__ import annotations

__version__ = "0.1.0"

# Public names, imported lazily (PEP 562) so that ``import shellspline`` stays light and the
# CLI can configure the BLAS thread pools before numpy is first imported.
_EXPORTS = {
    "MeshError": "_errors", "ShellsplineError": "_errors",
    "dihedral_angles": "descriptors", "edge_lengths": "descriptors", "face_areas": "descriptors",
    "lta_descriptors": "descriptors", "lta_jacobian": "descriptors", "lta_weights": "descriptors",
    "Keyframes": "io", "keyframes_from_arrays": "io", "read_frames": "io", "read_indices": "io",
    "read_keyframes": "io", "read_mesh": "io", "read_sequence": "io", "write_sequence": "io",
    "lta_spline": "lta_spline",
    "InterpolationResult": "pipeline", "interpolate": "pipeline", "linear_blend": "pipeline",
    "GaussNewton": "reconstruct", "ReconstructionResult": "reconstruct",
    "reconstruct": "reconstruct", "rigid_placement": "reconstruct",
    "Topology": "topology", "topology": "topology",
}

__all__ = ["__version__", *_EXPORTS]


def __getattr__(name):
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'shellspline' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(f".{mod}", __name__), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(list(globals()) + list(_EXPORTS))
