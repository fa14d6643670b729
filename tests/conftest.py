"""Shared fixtures: small meshes built in code, and the location of ../shared/data."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


def shared_data(*parts) -> Path:
    """Path under ../shared/data, or skip the test with a clear reason when it is absent."""
    p = SHARED_DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"{p} not present: the real keyframe sets live in ../shared/data beside the "
                    "repository (a user's clone has none)")
    return p


def icosphere(subdivisions: int = 1):
    import trimesh

    m = trimesh.creation.icosphere(subdivisions=subdivisions)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def cactus_sequence_problem(n_vertices: int = 700, K: int = 8):
    """Synthetic cactus keyframes (base pinned) at frames 0, K/2, K and their LΘA spline
    targets: ``(Vs, T, pinned, Z (K+1, d), weights, frames)``."""
    import data_synth
    from shellspline.shells.descriptors import lta_descriptors, lta_weights, unwrap_angles
    from shellspline.shells.lta_spline import lta_spline
    from shellspline.mesh.topology import topology

    d = data_synth.generate("cactus", n_vertices=n_vertices)
    Vs, F, pinned = d["V"], d["F"], d["pinned"]
    T = topology(F, Vs.shape[1])
    Z = lta_descriptors(Vs, T)
    sT = T.descriptor_slices()[1]
    Z[:, sT] = unwrap_angles(Z[:, sT])
    frames = [0, K // 2, K]
    return Vs, T, pinned, lta_spline(Z, frames, K), lta_weights(Vs[0], T), frames


def grid_sheet(nx: int = 5, ny: int = 4):
    """A flat rectangular sheet with boundary, triangulated regularly."""
    x, y = np.meshgrid(np.linspace(0, 1, nx), np.linspace(0, 0.8, ny), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    idx = np.arange(nx * ny).reshape(nx, ny)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def raises_mesh_error(fn, *phrases):
    """Call ``fn`` and check it raises a one-line MeshError containing every phrase; returns
    the message."""
    from shellspline import MeshError

    with pytest.raises(MeshError) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg
    for p in phrases:
        assert p in msg, (p, msg)
    return msg


@pytest.fixture(scope="module")
def tube():
    """data_synth.dcc.dcc_tube (its n-gon cap needs the 'dcc' extra)."""
    pytest.importorskip("mapbox_earcut", reason="the tube's n-gon cap needs the 'dcc' extra")
    from data_synth.dcc import dcc_tube

    return dcc_tube()


@pytest.fixture
def sphere():
    return icosphere(1)


@pytest.fixture
def sheet():
    return grid_sheet()


@pytest.fixture
def gated_run():
    """``run(**kw)``: :func:`~shellspline.pipeline.reconstruction.solve_run` over frames 1–7
    of a joint flexing 90° between keyframes 0 and 8 (frames started from the vertex blend,
    targets the descriptors blended linearly: not those of a mesh, so every frame has an
    energy); the keyword arguments go to ``solve_run`` (``worse_than``, ``gate``, ``work``)."""
    import shellspline as ss
    from data_synth import stress
    from shellspline.shells.descriptors import lta_descriptors, lta_weights
    from shellspline.pipeline.reconstruction import solve_run
    from shellspline.shells.reconstruct import GaussNewton

    d = stress.joint(angles=(0.0, 90.0), frames=(0, 8), rings=8, segments=8)
    V0, V1 = d["V"]
    T = ss.topology(d["F"])
    t = np.linspace(0.0, 1.0, 9)[:, None, None]
    blend = (1 - t) * V0 + t * V1
    Z = (1 - t[:, :, 0]) * lta_descriptors(V0, T) + t[:, :, 0] * lta_descriptors(V1, T)
    w = lta_weights(V0, T)
    gn = GaussNewton(T)
    ks = np.arange(1, 8)

    def run(**kw):
        return solve_run(gn, ks, Z[ks], [w] * len(ks), blend[ks], V0, "extrapolate", **kw)
    return run
