import numpy as np
import pytest

from shellspline import MeshError, topology
from conftest import grid_sheet, icosphere


def test_closed_surface_tables():
    V, F = icosphere(1)
    T = topology(F, len(V))
    assert T.n_edges == 3 * len(F) // 2
    assert T.n_interior == T.n_edges  # closed: every edge interior
    assert len(V) - T.n_edges + len(F) == 2  # Euler characteristic
    assert T.boundary_vertices.size == 0
    # flaps: face (v0,v1,v2) and (v1,v0,v3) are faces of the mesh (as cyclic rotations)
    faces = {tuple(np.roll(f, r)) for f in F.tolist() for r in range(3)}
    for v0, v1, v2, v3 in T.flaps:
        assert (v0, v1, v2) in faces and (v1, v0, v3) in faces
    # face_edges: edge opposite corner c
    for t in range(len(F)):
        for c in range(3):
            e = set(T.E[T.face_edges[t, c]].tolist())
            assert e == set(F[t].tolist()) - {F[t, c]}


def test_open_sheet_boundary():
    V, F = grid_sheet(5, 4)
    T = topology(F)
    n_bnd_edges = int((T.edge_faces[:, 1] < 0).sum())
    assert n_bnd_edges == 2 * (4 + 3)
    assert T.n_interior == T.n_edges - n_bnd_edges
    assert set(T.boundary_vertices.tolist()) == {i for i in range(20) if i // 4 in (0, 4) or i % 4 in (0, 3)}


@pytest.mark.parametrize("F, phrase", [
    (np.array([[0, 1, 2], [0, 1, 3], [1, 0, 4]]), "non-manifold edge"),
    (np.array([[0, 1, 2], [0, 1, 3]]), "consistently oriented"),
    (np.array([[0, 1, 1]]), "repeats a vertex"),
    (np.array([[0, 1]]), "(m,3)"),
    (np.array([[0.0, 1, 2]]), "integers"),
])
def test_invalid_connectivity_raises(F, phrase):
    with pytest.raises(MeshError, match=phrase.replace("(", r"\(").replace(")", r"\)")):
        topology(F, name="bad.obj")


def test_error_names_the_mesh():
    with pytest.raises(MeshError, match="bad.obj"):
        topology(np.array([[0, 1, 5]]), 3, name="bad.obj")


def test_components_are_counted_over_the_faces_only():
    import trimesh
    from shellspline.mesh.topology import topology

    m = trimesh.creation.icosphere(1)
    F = np.asarray(m.faces)
    n = len(m.vertices)
    assert topology(F, n).n_components == 1
    assert topology(np.concatenate([F, F + n]), 2 * n).n_components == 2
    assert topology(F, n + 5).n_components == 1  # isolated vertices are no component
