"""GLB export: checked with readers that are not ours (pygltflib, trimesh)."""
from __future__ import annotations

import json
import struct

import numpy as np
import pytest
import trimesh

import shellspline as ss
from shellspline.errors import ShellsplineError
from shellspline.io.gltf import glb_bytes, read_glb, vertex_normals, write_glb

from conftest import icosphere

pygltflib = pytest.importorskip("pygltflib", reason="the GLB tests need pygltflib "
                                                    "(pip install '.[test]')")


def _sequence(K=6):
    V0, F = icosphere(2)
    t = np.linspace(0.0, 1.0, K + 1)[:, None]
    x, y, z = V0[:, 0], V0[:, 1], V0[:, 2]
    # stretch along x, bend in y, squash and lift in z: every frame differs
    V = np.stack([x * (1 + 0.5 * t), y + 0.2 * t * x ** 2, z * (1 - 0.3 * t) + 0.1 * t],
                 axis=-1)
    return V + 3.0, F  # away from the origin: float32 rounding of base + delta matters


def _accessor_array(g, data, i):
    a = g.accessors[i]
    bv = g.bufferViews[a.bufferView]
    dt = {5126: np.float32, 5125: np.uint32}[a.componentType]
    width = {"SCALAR": 1, "VEC3": 3}[a.type]
    off = (bv.byteOffset or 0) + (a.byteOffset or 0)
    arr = np.frombuffer(data, dtype=dt, count=a.count * width, offset=off)
    return arr.reshape(a.count, width) if width > 1 else arr


def test_glb_structure_and_positions_with_pygltflib(tmp_path):
    V, F = _sequence(K=6)
    K = V.shape[0] - 1
    p = tmp_path / "a.glb"
    write_glb(p, V, F, fps=12)
    g = pygltflib.GLTF2().load(str(p))
    data = g.binary_blob()
    assert g.asset.version == "2.0"
    assert len(g.meshes) == 1 and len(g.meshes[0].primitives) == 1
    prim = g.meshes[0].primitives[0]
    # indices: uint32 scalars, 3 per face, equal to F
    ia = g.accessors[prim.indices]
    assert (ia.componentType, ia.type, ia.count) == (5125, "SCALAR", 3 * F.shape[0])
    assert g.bufferViews[ia.bufferView].target == 34963
    np.testing.assert_array_equal(_accessor_array(g, data, prim.indices).reshape(-1, 3), F)
    # base positions = frame 0 in float32, with exact min/max
    pa = g.accessors[prim.attributes.POSITION]
    assert (pa.componentType, pa.type, pa.count) == (5126, "VEC3", V.shape[1])
    base = _accessor_array(g, data, prim.attributes.POSITION)
    np.testing.assert_array_equal(base, V[0].astype(np.float32))
    np.testing.assert_allclose(pa.min, base.min(axis=0))
    np.testing.assert_allclose(pa.max, base.max(axis=0))
    # one morph target per later frame; base + delta = V[k] within float32 precision
    assert len(prim.targets) == K
    eps = np.finfo(np.float32).eps * np.abs(V).max()
    for k, t in enumerate(prim.targets, start=1):
        ta = g.accessors[t["POSITION"]]
        assert (ta.componentType, ta.type, ta.count) == (5126, "VEC3", V.shape[1])
        d = _accessor_array(g, data, t["POSITION"])
        np.testing.assert_allclose(ta.min, d.min(axis=0))
        np.testing.assert_allclose(ta.max, d.max(axis=0))
        assert np.abs((base + d).astype(np.float64) - V[k]).max() <= 2 * eps
        assert np.abs(d).max() >= 0.49 * k / K  # the stretch of x by 0.5 t, not a zero target
    assert g.meshes[0].extras["targetNames"][0] == "frame_0001"
    # one animation: weights of node 0, times k/fps, one-hot weights per frame
    (anim,) = g.animations
    (ch,) = anim.channels
    assert (ch.target.node, ch.target.path) == (0, "weights")
    sampler = anim.samplers[ch.sampler]
    assert sampler.interpolation == "LINEAR"
    times = _accessor_array(g, data, sampler.input)
    np.testing.assert_allclose(times, np.arange(K + 1) / 12.0, rtol=1e-6)
    assert g.accessors[sampler.input].min == [0.0]
    assert g.accessors[sampler.input].max == pytest.approx([K / 12.0])
    W = _accessor_array(g, data, sampler.output).reshape(K + 1, K)
    expected = np.zeros((K + 1, K))
    expected[np.arange(1, K + 1), np.arange(K)] = 1
    np.testing.assert_array_equal(W, expected)
    assert g.nodes[0].mesh == 0 and g.scenes[g.scene].nodes == [0]


def test_glb_normals_are_unit_vertex_normals(tmp_path):
    V, F = _sequence(K=3)
    p = tmp_path / "n.glb"
    write_glb(p, V, F)
    g = pygltflib.GLTF2().load(str(p))
    data = g.binary_blob()
    prim = g.meshes[0].primitives[0]
    N0 = _accessor_array(g, data, prim.attributes.NORMAL)
    np.testing.assert_allclose(np.linalg.norm(N0, axis=1), 1.0, atol=1e-6)
    # on a sphere about its centre the normals point outwards: normal ≈ (V - c)/|V - c|
    R = V[0] - V[0].mean(axis=0)
    assert (np.einsum("ij,ij->i", N0, R / np.linalg.norm(R, axis=1, keepdims=True)) > 0.98).all()
    N3 = N0 + _accessor_array(g, data, prim.targets[2]["NORMAL"])
    np.testing.assert_allclose(N3, vertex_normals(V[3], F), atol=1e-6)


def test_vertex_normals_batched_matches_single():
    V, F = _sequence(K=2)
    NB = vertex_normals(V, F)
    for k in range(3):
        np.testing.assert_allclose(NB[k], vertex_normals(V[k], F), atol=1e-15)


def test_glb_loads_in_trimesh(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    V, F = _sequence(K=4)
    p = tmp_path / "t.glb"
    write_glb(p, V, F, normals=False)
    scene = trimesh.load(str(p), process=False)
    (mesh,) = scene.geometry.values()
    assert mesh.faces.shape == F.shape
    np.testing.assert_allclose(mesh.vertices, V[0], atol=1e-5)


def test_glb_header_and_chunks_are_aligned():
    V, F = _sequence(K=2)
    b = glb_bytes(V, F, interpolation="step")
    magic, version, total = struct.unpack_from("<III", b, 0)
    assert (magic, version, total) == (0x46546C67, 2, len(b))
    jlen, jtype = struct.unpack_from("<II", b, 12)
    assert jtype == 0x4E4F534A and jlen % 4 == 0
    doc = json.loads(b[20:20 + jlen])
    blen, btype = struct.unpack_from("<II", b, 20 + jlen)
    assert btype == 0x004E4942 and blen % 4 == 0 and 28 + jlen + blen == len(b)
    assert doc["buffers"][0]["byteLength"] <= blen
    assert doc["animations"][0]["samplers"][0]["interpolation"] == "STEP"
    for v in doc["bufferViews"]:
        assert v["byteOffset"] % 4 == 0


def test_read_glb_roundtrip_and_single_frame(tmp_path):
    V, F = _sequence(K=5)
    p = tmp_path / "r.glb"
    write_glb(p, V, F, fps=30)
    V2, F2, fps = read_glb(p)
    assert fps == 30.0
    np.testing.assert_array_equal(F2, F)
    np.testing.assert_allclose(V2, V, atol=2 * np.finfo(np.float32).eps * np.abs(V).max())
    # a single pose: no targets, no animation, still a valid file
    write_glb(p, V[:1], F)
    g = pygltflib.GLTF2().load(str(p))
    assert not g.animations and not g.meshes[0].primitives[0].targets
    assert read_glb(p)[0].shape == (1,) + V.shape[1:]


@pytest.mark.parametrize("kwargs, match", [
    ({"fps": 0}, "fps"), ({"fps": float("nan")}, "fps"), ({"interpolation": "cubic"},
                                                          "interpolation")])
def test_glb_bad_arguments(kwargs, match):
    V, F = _sequence(K=1)
    with pytest.raises(ShellsplineError, match=match):
        glb_bytes(V, F, **kwargs)


def test_glb_bad_input():
    V, F = _sequence(K=1)
    with pytest.raises(ShellsplineError, match="NaN"):
        glb_bytes(np.where(V > 3.5, np.nan, V), F)
    with pytest.raises(ShellsplineError, match="outside"):
        glb_bytes(V, F + V.shape[1])
    with pytest.raises(ShellsplineError, match=r"\(K\+1,n,3\)"):
        glb_bytes(V[0], F)


def test_read_glb_rejects_other_files(tmp_path):
    p = tmp_path / "x.glb"
    p.write_bytes(b"not a glb file at all")
    with pytest.raises(ShellsplineError, match="cannot read"):
        read_glb(p)


def test_write_sequence_glb_and_read_back(tmp_path):
    V, F = _sequence(K=4)
    out = ss.write_sequence(tmp_path / "out", V, F, {"K": 4}, fmt="glb", fps=10)
    assert sorted(p.name for p in out.iterdir()) == ["animation.glb", "report.json"]
    V2, F2, rep = ss.read_sequence(out)
    assert rep == {"K": 4}
    np.testing.assert_array_equal(F2, F)
    np.testing.assert_allclose(V2, V, atol=2 * np.finfo(np.float32).eps * np.abs(V).max())
    g = pygltflib.GLTF2().load(str(out / "animation.glb"))
    assert len(g.meshes[0].primitives[0].targets) == 4
    with pytest.raises(ShellsplineError, match="fps"):
        ss.write_sequence(tmp_path / "bad", V, F, fmt="glb", fps=-1)
    assert not (tmp_path / "bad").exists()


def test_cli_interpolate_format_glb(tmp_path):
    from shellspline.cli.main import main

    V0, F = icosphere(1)
    paths = []
    for j, s in enumerate([1.0, 1.3, 1.0]):
        p = tmp_path / f"k{j}.obj"
        X = V0 * np.array([s, 1.0, 1.0])
        p.write_text("".join("v %.17g %.17g %.17g\n" % tuple(r) for r in X)
                     + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
        paths.append(str(p))
    out = tmp_path / "out"
    rc = main(["interpolate", *paths, "--frames", "0,3,6", "-o", str(out), "--format", "glb",
               "--fps", "8", "-q"])
    assert rc == 0
    assert sorted(p.name for p in out.iterdir()) == ["animation.glb", "report.json"]
    g = pygltflib.GLTF2().load(str(out / "animation.glb"))
    prim = g.meshes[0].primitives[0]
    assert len(prim.targets) == 6
    times = _accessor_array(g, g.binary_blob(), g.animations[0].samplers[0].input)
    np.testing.assert_allclose(times, np.arange(7) / 8.0, rtol=1e-6)
    # keyframe 1 sits at frame 3: base + target 3 reproduces it in float32
    d = _accessor_array(g, g.binary_blob(), prim.targets[2]["POSITION"])
    base = _accessor_array(g, g.binary_blob(), prim.attributes.POSITION)
    np.testing.assert_allclose(base + d, V0 * np.array([1.3, 1.0, 1.0]), atol=1e-6)
    assert main(["interpolate", *paths, "-o", str(tmp_path / "o2"), "--fps", "0", "-q"]) == 2


def test_glb_normals_are_unit_where_vertex_normals_vanish():
    # vertex 4 is used by no face: its vertex normal is zero, which glTF forbids
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]], dtype=float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    Vs = np.stack([V, 1.5 * V, 2.0 * V])
    assert not vertex_normals(Vs, F)[:, 4].any()
    g = pygltflib.GLTF2().load_from_bytes(glb_bytes(Vs, F))
    prim = g.meshes[0].primitives[0]
    N0 = _accessor_array(g, g.binary_blob(), prim.attributes.NORMAL)
    for N in [N0] + [N0 + _accessor_array(g, g.binary_blob(), t["NORMAL"])
                     for t in prim.targets]:
        np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-6)
    np.testing.assert_array_equal(N0[4], [0, 0, 1])
    np.testing.assert_allclose(N0[:4], vertex_normals(V, F)[:4], atol=1e-7)


@pytest.mark.parametrize("up", ["z", "x"])
def test_z_and_x_up_data_stand_in_gltf_viewers(tmp_path, up):
    """glTF is y-up: data whose up axis is z (PLY scans, CAD) or x get a node rotation that
    turns their up onto +y, checked with trimesh's scene graph (an independent reader that
    applies node transforms); the vertex data, read back by pygltflib and by read_glb, stay in
    the input's coordinates, and glb_up_axis reads the axis back."""
    from shellspline.io.gltf import glb_up_axis
    from shellspline.io.usd import conventional_up_axis

    V, F = _sequence(3)
    a = "xyz".index(up)
    V = V * np.where(np.arange(3) == a, 3.0, 1.0)  # long along its up axis, like a standing body
    p = tmp_path / f"{up}.glb"
    write_glb(p, V, F, up_axis=up)
    assert glb_up_axis(p) == up and conventional_up_axis(p) == up
    write_glb(tmp_path / "y.glb", V, F)  # the same data, y-up: no rotation, as before
    np.testing.assert_array_equal(read_glb(p)[0], read_glb(tmp_path / "y.glb")[0])
    g = pygltflib.GLTF2().load(str(p))
    pos = g.meshes[0].primitives[0].attributes.POSITION
    np.testing.assert_allclose(_accessor_array(g, g.binary_blob(), pos), V[0], rtol=1e-6)
    scene = trimesh.load(p, force="scene", process=False)
    world = scene.to_geometry().vertices                     # the base mesh, node applied
    ext = world.max(axis=0) - world.min(axis=0)
    assert np.argmax(ext) == 1                                # the long (up) axis is glTF's y
    top_in, top_out = np.argmax(V[0][:, a]), np.argmax(world[:, 1])
    np.testing.assert_allclose(world[top_out, 1], V[0][top_in, a], rtol=1e-6)  # up, not down
    q = glb_up_axis(tmp_path / "none.glb")
    assert q == "y"
    assert glb_up_axis(tmp_path / "y.glb") == "y"
    assert pygltflib.GLTF2().load(str(tmp_path / "y.glb")).nodes[0].rotation is None
    with pytest.raises(ShellsplineError, match="up_axis"):
        glb_bytes(V, F, up_axis="w")


def test_interpolate_glb_output_of_z_up_input_stands(tmp_path):
    """The CLI writes a GLB of PLY keyframes (z-up by convention) with the z-up rotation."""
    from shellspline.cli.main import main
    from shellspline.io.gltf import glb_up_axis

    V, F = _sequence(2)
    paths = []
    for i in (0, 2):
        paths.append(tmp_path / f"k{i}.ply")
        trimesh.Trimesh(V[i], F, process=False).export(paths[-1])
    out = tmp_path / "out"
    assert main(["interpolate", *map(str, paths), "--frames", "0,4", "-o", str(out),
                 "--format", "glb", "--method", "linear", "-q"]) == 0
    assert glb_up_axis(out / "animation.glb") == "z"
