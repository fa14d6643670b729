"""shellspline: splines in the space of thin shells.

Turn a handful of keyframe poses of one triangle mesh into a smooth in-between sequence
(Heeren, Rumpf, Schröder, Wardetzky, Wirth, "Splines in the Space of Shells", SGP 2016).
"""
from __future__ import annotations

# first: a Ctrl-C while the command line imports the rest is one line, exit 130
from .cli import startup as _startup

_startup.guard()

from .version import __version__

from .batch import BatchSummary, Job, load_job, run_batch
from .errors import MeshError, ShellsplineError
from .io import (Keyframes, check_output_dir, keyframes_from_arrays, read_frames, read_indices,
                 read_keyframes, read_mesh, read_sequence, write_sequence)
from .mesh.decimate import Decimation, decimate
from .mesh.topology import Topology, topology
from .pipeline import InterpolationResult, interpolate, linear_blend
from .shells.descriptors import (dihedral_angles, edge_lengths, face_areas, lta_descriptors,
                                 lta_jacobian, lta_weights)
from .shells.energy import DiscreteShells, shell_energy
from .shells.geodesic import discrete_geodesic, geodesic_interpolation
from .shells.lta_spline import LTASpline, lta_spline
from .shells.nonlinear import nonlinear_spline
from .shells.prolong import Prolongation
from .shells.reconstruct import GaussNewton, ReconstructionResult, reconstruct, rigid_placement
from .viz import (SequenceViewer, export_glb, plot, plot_half_axes, preview, render_animation,
                  render_strip)

__all__ = [
    "__version__", "MeshError", "ShellsplineError", "Keyframes", "read_keyframes",
    "keyframes_from_arrays", "read_mesh", "read_frames", "read_indices", "read_sequence",
    "write_sequence", "check_output_dir", "interpolate", "InterpolationResult", "linear_blend",
    "lta_spline", "LTASpline",
    "lta_descriptors", "lta_jacobian", "lta_weights", "edge_lengths", "face_areas",
    "dihedral_angles", "GaussNewton", "ReconstructionResult", "reconstruct", "rigid_placement",
    "Topology", "topology", "decimate", "Decimation", "Prolongation", "discrete_geodesic",
    "geodesic_interpolation", "nonlinear_spline", "DiscreteShells", "shell_energy",
    "load_job", "run_batch", "Job", "BatchSummary",
    "preview", "SequenceViewer", "render_animation", "render_strip", "plot", "plot_half_axes",
    "export_glb",
]
