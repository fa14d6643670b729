"""Files in and out: meshes, keyframe sets, sequences, glTF, BVH motions, pose files.

Everything that touches the file system lives in this package. Inputs are validated here,
once, into canonical values the numerical layers trust; outputs are written atomically.
"""
from .keyframes import Keyframes, keyframes_from_arrays, read_frames, read_indices, read_keyframes
from .meshes import MESH_EXTENSIONS, read_mesh
from .sequences import GLB_NAME, check_output_dir, read_sequence, write_sequence

__all__ = ["Keyframes", "read_mesh", "read_keyframes", "keyframes_from_arrays", "read_indices",
           "read_frames", "write_sequence", "check_output_dir", "read_sequence",
           "MESH_EXTENSIONS", "GLB_NAME"]
