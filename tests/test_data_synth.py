"""Tests of the synthetic keyframe generators in ``data_synth`` and their command line."""
from __future__ import annotations

import math
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

import data_synth as ds

REPO = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- helpers
def edges_of(F):
    """Unique undirected edges (e,2) and the number of faces on each."""
    n = np.int64(F.max() + 1)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    key, count = np.unique(E[:, 0] * n + E[:, 1], return_counts=True)
    return np.stack([key // n, key % n], axis=1), count


def edge_lengths(V, E):
    return np.linalg.norm(V[E[:, 0]] - V[E[:, 1]], axis=1)


def face_areas(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)


def signed_volume(V, F):
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def check_keyframes(data, *, closed, euler):
    """Shared checks: shapes, dtypes, manifold + orientation, non-degenerate faces."""
    Vs, F, frames = data["V"], data["F"], data["frames"]
    assert Vs.ndim == 3 and Vs.shape[2] == 3 and Vs.dtype == np.float64
    J, n, _ = Vs.shape
    assert F.ndim == 2 and F.shape[1] == 3 and F.dtype == np.int64
    assert frames.shape == (J,) and frames.dtype == np.int64
    assert frames[0] >= 0 and np.all(np.diff(frames) > 0)
    assert np.all(np.isfinite(Vs))
    assert F.min() == 0 and F.max() == n - 1
    assert np.all(np.bincount(F.ravel(), minlength=n) > 0)  # every vertex is used
    # no repeated vertex within a face
    assert np.all((F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0]))
    # each directed halfedge once -> consistent orientation, no duplicate faces
    he = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(he[:, 0] * np.int64(n) + he[:, 1])
    assert np.all(key[1:] != key[:-1])
    E, count = edges_of(F)
    assert count.max() <= 2
    if closed:
        assert count.min() == 2
    chi = n - E.shape[0] + F.shape[0]
    assert chi == euler
    for V in Vs:
        E_len = edge_lengths(V, E)
        assert face_areas(V, F).min() > 1e-8 * E_len.mean() ** 2
        if closed:
            assert signed_volume(V, F) > 0
    if data["pinned"] is not None:
        p = data["pinned"]
        assert p.dtype == np.int64 and p.ndim == 1 and p.size > 0
        assert np.all(np.diff(p) > 0) and p[0] >= 0 and p[-1] < n
    return E


# --------------------------------------------------------------------------- ellipsoids
def test_ellipsoids_defaults():
    d = ds.ellipsoids()
    E = check_keyframes(d, closed=True, euler=2)
    assert d["V"].shape == (3, 492, 3)
    assert d["frames"].tolist() == [0, 6, 12]
    assert d["pinned"] is None
    A = np.asarray(ds.DEFAULT_ELLIPSOID_AXES)
    np.testing.assert_array_equal(d["axes"], A)
    for V, a in zip(d["V"], A):
        # every vertex lies on the ellipsoid and the extent matches the half-axes
        np.testing.assert_allclose(np.linalg.norm(V / a, axis=1), 1.0, atol=1e-12)
        np.testing.assert_allclose(np.abs(V).max(axis=0), a, rtol=0.01)
    # well-shaped triangles on the sphere
    L = edge_lengths(d["V"][1], E)
    assert L.max() / L.min() < 1.5


def test_ellipsoids_custom_axes_and_frames():
    axes = [(1.0, 1.0, 1.0), (3.0, 0.5, 1.0)]
    d = ds.ellipsoids(200, axes=axes, frames=[0, 5])
    check_keyframes(d, closed=True, euler=2)
    assert d["V"].shape[0] == 2 and d["frames"].tolist() == [0, 5]
    np.testing.assert_allclose(np.abs(d["V"][1]).max(axis=0), axes[1], rtol=0.02)
    # same unit-sphere parameter point in every pose
    np.testing.assert_allclose(d["V"][1] / axes[1], d["V"][0], atol=1e-14)


def test_geodesic_sphere_counts():
    for nu in (1, 2, 5):
        V, F = ds.geodesic_sphere(nu)
        assert V.shape == (10 * nu**2 + 2, 3) and F.shape == (20 * nu**2, 3)
        np.testing.assert_allclose(np.linalg.norm(V, axis=1), 1.0, atol=1e-14)


# --------------------------------------------------------------------------- cactus
def test_cactus_defaults():
    d = ds.cactus()
    E = check_keyframes(d, closed=True, euler=2)
    Vx, V0, Vy = d["V"]
    assert d["frames"].tolist() == [0, 10, 20]
    np.testing.assert_array_equal(V0, d["rest"])
    # straight rest pose standing on z = 0
    assert V0[:, 2].min() == 0.0
    np.testing.assert_allclose(V0[-1], (0.0, 0.0, 1.08), atol=1e-15)
    # base vertices pinned and identical across poses; everything above it moves
    p = d["pinned"]
    base = V0[:, 2] <= 0.05
    np.testing.assert_array_equal(p, np.flatnonzero(base))
    for V in (Vx, Vy):
        np.testing.assert_array_equal(V[p], V0[p])
        assert np.all(np.linalg.norm(V[~base] - V0[~base], axis=1) > 0)
    # bend directions: +x keeps y, +y keeps x; the tip leans the right way
    np.testing.assert_array_equal(Vx[:, 1], V0[:, 1])
    np.testing.assert_array_equal(Vy[:, 0], V0[:, 0])
    assert Vx[-1, 0] > 0.3 and Vy[-1, 1] > 0.3
    # the tip lies on the centre arc: total turn pi/4 over the trunk length above the base
    kappa = d["curvature"]
    R = 1.0 / kappa
    phi = math.pi / 4
    np.testing.assert_allclose(Vx[-1], (R * (1 - math.cos(phi)), 0.0, 0.05 + R * math.sin(phi)),
                               atol=1e-12)
    # near-isometric: a few percent at most, bounded by curvature * max radius
    L0 = edge_lengths(V0, E)
    r_max = np.linalg.norm(V0[:, :2], axis=1).max()
    for V in (Vx, Vy):
        rel = np.abs(edge_lengths(V, E) / L0 - 1.0)
        assert rel.max() <= 1.02 * kappa * r_max
        assert rel.max() < 0.07 and rel.mean() < 0.025
        # horizontal cross sections move rigidly: edges within a ring keep their length
        same_ring = V0[E[:, 0], 2] == V0[E[:, 1], 2]
        np.testing.assert_allclose(edge_lengths(V, E)[same_ring], L0[same_ring], rtol=1e-12)


def test_cactus_options():
    d = ds.cactus(800, n_ribs=0, rib_depth=0.0, bend_angle=0.0, base_height=0.0)
    check_keyframes(d, closed=True, euler=2)
    np.testing.assert_array_equal(d["V"][0], d["V"][1])
    np.testing.assert_array_equal(d["V"][2], d["V"][1])
    assert np.all(d["rest"][d["pinned"], 2] == 0.0)
    d = ds.cactus(3000, bend_angle=math.pi / 2, n_ribs=5, radius=0.05)
    check_keyframes(d, closed=True, euler=2)


def test_cactus_150k_fast():
    t = time.perf_counter()
    d = ds.cactus(150_000)
    elapsed = time.perf_counter() - t
    assert elapsed < 2.0
    n = d["V"].shape[1]
    assert 0.8 * 150_000 <= n <= 1.2 * 150_000
    check_keyframes(d, closed=True, euler=2)


# --------------------------------------------------------------------------- hexagon
def _rotz(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def test_hexagon_crease_folds_are_isometric():
    d = ds.hexagon()
    E = check_keyframes(d, closed=False, euler=1)
    H = d["rest"]
    k = 18
    assert H.shape == (3 * k * k + 3 * k + 1, 3) and d["F"].shape == (6 * k * k, 3)
    assert d["frames"].tolist() == [0, 4, 8] and d["periodic"] is True
    # flat, regular: z == 0, all edges equal, corners at unit distance, normals +z
    assert np.all(H[:, 2] == 0.0)
    L0 = edge_lengths(H, E)
    np.testing.assert_allclose(L0, 1.0 / k, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(H, axis=1).max(), 1.0, rtol=1e-12)
    a, b, c = H[d["F"][:, 0]], H[d["F"][:, 1]], H[d["F"][:, 2]]
    assert np.all(np.cross(b - a, c - a)[:, 2] > 0)
    # single boundary loop of 6k edges
    _, count = edges_of(d["F"])
    assert (count == 1).sum() == 6 * k
    for V in d["V"]:
        np.testing.assert_allclose(edge_lengths(V, E), L0, atol=1e-9)
        # two planar wings whose normals make the fold angle (pi/2)
        a, b, c = V[d["F"][:, 0]], V[d["F"][:, 1]], V[d["F"][:, 2]]
        nrm = np.cross(b - a, c - a)
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        wings = np.unique(np.round(nrm, 9), axis=0)
        assert wings.shape[0] == 2
        assert math.isclose(math.acos(float(wings[0] @ wings[1])), math.pi / 2, abs_tol=1e-9)
        assert V[:, 2].min() >= -1e-15
    # D -> E -> F are 120-degree rotations of one another (as point sets)
    for j in range(2):
        rotated = d["V"][j] @ _rotz(120).T
        dist, _ = cKDTree(d["V"][j + 1]).query(rotated)
        assert dist.max() < 1e-9


def test_hexagon_roll_is_nearly_isometric():
    d = ds.hexagon(600, mode="roll", fold_angle=2.0)
    E = check_keyframes(d, closed=False, euler=1)
    L0 = edge_lengths(d["rest"], E)
    for V in d["V"]:
        rel = np.abs(edge_lengths(V, E) / L0 - 1.0)
        assert rel.max() < 1e-3
        assert V[:, 2].max() > 0.1  # actually bent


# --------------------------------------------------------------------------- bumpy
def test_bumpy():
    d = ds.bumpy()
    check_keyframes(d, closed=True, euler=2)
    r = np.linalg.norm(d["V"][1], axis=1)  # pose 1 has unit half-axes
    assert r.std() > 0.005 and np.all(np.abs(r - 1) <= 0.03 + 1e-12)


# --------------------------------------------------------------------------- counts, API
@pytest.mark.parametrize("name,n", [("ellipsoids", 500), ("ellipsoids", 3000),
                                    ("cactus", 5000), ("cactus", 20000),
                                    ("hexagon", 1000), ("hexagon", 4000),
                                    ("bumpy", 2500), ("bumpy", 10000)])
def test_vertex_count_close_to_request(name, n):
    d = ds.generate(name, n)
    assert 0.8 * n <= d["V"].shape[1] <= 1.2 * n


def test_generate_dispatch_and_validation():
    assert set(ds.NAMES) == {"ellipsoids", "cactus", "hexagon", "bumpy"}
    d = ds.generate("cactus", 1000, bend_angle=0.3)
    assert math.isclose(d["curvature"] * (1.0 + 0.08 - 0.05), 0.3)
    assert ds.generate("hexagon")["V"].shape[1] == 1027
    with pytest.raises(ValueError, match="name"):
        ds.generate("teapot")
    with pytest.raises(ValueError, match="n_vertices"):
        ds.generate("ellipsoids", 5)
    with pytest.raises(ValueError, match="n_vertices"):
        ds.cactus(1000.5)
    with pytest.raises(ValueError, match="axes"):
        ds.ellipsoids(axes=[(1, 1, -1)])
    with pytest.raises(ValueError, match="fold_angle"):
        ds.hexagon(fold_angle=4.0)
    with pytest.raises(ValueError, match="mode"):
        ds.hexagon(mode="origami")
    with pytest.raises(ValueError, match="bend_angle"):
        ds.cactus(bend_angle=5.0)
    with pytest.raises(ValueError, match="base_height"):
        ds.cactus(base_height=2.0)
    with pytest.raises(ValueError, match="frames"):
        ds.cactus(frames=(0, 10, 5))
    with pytest.raises(ValueError, match="fmt"):
        ds.write("cactus", "unused", fmt="stl")


# --------------------------------------------------------------------------- writing
@pytest.mark.parametrize("fmt", ["obj", "ply", "off"])
def test_write_roundtrip(tmp_path, fmt):
    paths = ds.write("ellipsoids", tmp_path, n_vertices=200, fmt=fmt)
    assert [p.name for p in paths] == [f"pose_0{j}.{fmt}" for j in range(3)]
    d = ds.generate("ellipsoids", 200)
    for p, V in zip(paths, d["V"]):
        m = trimesh.load(p, process=False)
        np.testing.assert_array_equal(m.vertices, V)
        np.testing.assert_array_equal(m.faces, d["F"])
    assert np.loadtxt(tmp_path / "frames.txt", dtype=np.int64).tolist() == [0, 6, 12]
    assert not (tmp_path / "pinned.txt").exists()


def test_write_removes_stale_layout_files(tmp_path):
    (tmp_path / "pose_07.obj").write_text("stale")
    (tmp_path / "pinned.txt").write_text("0\n")
    (tmp_path / "notes.txt").write_text("keep")
    ds.write("hexagon", tmp_path, n_vertices=100)
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "frames.txt", "notes.txt", "pose_00.obj", "pose_01.obj", "pose_02.obj"]


def test_pose_filenames_sort_in_order():
    names = ds.pose_filenames(120)
    assert names[:2] == ["pose_000.obj", "pose_001.obj"] and sorted(names) == names


def test_cli_writes_cactus(tmp_path):
    out = tmp_path / "cactus"
    env = dict(os.environ, PYTHONPATH=str(REPO) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    res = subprocess.run([sys.executable, "-m", "data_synth", "cactus", str(out),
                          "--vertices", "2000"], capture_output=True, text=True, cwd=REPO,
                         env=env, timeout=60)
    assert res.returncode == 0, res.stderr
    assert len(res.stdout.strip().splitlines()) == 1 and "cactus" in res.stdout
    assert sorted(p.name for p in out.iterdir()) == [
        "frames.txt", "pinned.txt", "pose_00.obj", "pose_01.obj", "pose_02.obj"]
    d = ds.generate("cactus", 2000)
    files = sorted(out.glob("pose_*.obj"))
    for p, V in zip(files, d["V"]):
        m = trimesh.load(p, process=False)
        np.testing.assert_array_equal(m.vertices, V)
        np.testing.assert_array_equal(m.faces, d["F"])
    np.testing.assert_array_equal(np.loadtxt(out / "pinned.txt", dtype=np.int64), d["pinned"])
    assert np.loadtxt(out / "frames.txt", dtype=np.int64).tolist() == [0, 10, 20]
    with open(files[0]) as fh:
        faces = [line for line in fh if line.startswith("f ")]
    assert min(int(t) for line in faces for t in line.split()[1:]) == 1  # 1-based

    bad = subprocess.run([sys.executable, "-m", "data_synth", "cactus", str(out),
                          "--vertices", "3"], capture_output=True, text=True, cwd=REPO,
                         env=env, timeout=60)
    assert bad.returncode == 2 and "n_vertices" in bad.stderr
