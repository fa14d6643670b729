"""USD as keyframe input (:func:`shellspline.io.read_keyframes` on ``.usd``/``.usda``/``.usdc``):
a stage written by our writer (and by hand, with pxr's text format) reads back as the same
keyframes as the OBJ files of the same poses; every malformed stage is a one-line MeshError
naming the file; without ``pxr`` the error names the extra."""
import sys

import numpy as np
import pytest

from shellspline.errors import MeshError, ShellsplineError
from shellspline.io import read_keyframes


def _pxr():
    return pytest.importorskip("pxr", reason="usd-core (pip install 'shellspline[usd]') is not "
                                             "installed")


def _quad_strip(nx=5, angles=(0.0, 1.2, 0.4)):
    """Poses (J,n,3) of a strip of quads rolled up about the z axis, and its quads (CSR)."""
    x = np.linspace(0, 2, nx + 1)
    V0 = np.array([[xi, 0.0, z] for z in (0.0, 0.5) for xi in x])
    quads = np.array([(i, i + 1, nx + 2 + i, nx + 1 + i) for i in range(nx)])
    poses = []
    for angle in angles:
        V = V0.copy()
        if angle:
            r = 2 / angle
            V[:, 0], V[:, 1] = r * np.sin(V0[:, 0] / r), r * (1 - np.cos(V0[:, 0] / r))
        poses.append(V)
    offsets = np.arange(0, 4 * nx + 1, 4)
    return np.array(poses), offsets, quads.ravel()


def _write_obj(path, V, offsets, indices):
    path.write_text("".join(f"v {a!r} {b!r} {c!r}\n" for a, b, c in V.tolist())
                    + "".join("f" + "".join(f" {i + 1}" for i in indices[a:b]) + "\n"
                              for a, b in zip(offsets[:-1], offsets[1:])))
    return path


def _same_keyframes(a, b):
    np.testing.assert_array_equal(a.V, b.V)
    np.testing.assert_array_equal(a.F, b.F)
    np.testing.assert_array_equal(a.source.poly_offsets, b.source.poly_offsets)
    np.testing.assert_array_equal(a.source.poly_indices, b.source.poly_indices)


def _one_line_error(fn, *phrases, cls=MeshError):
    with pytest.raises(cls) as info:
        fn()
    msg = str(info.value)
    assert "\n" not in msg, msg
    for ph in phrases:
        assert ph in msg, (ph, msg)
    return msg


@pytest.mark.parametrize("ext", ["usda", "usdc", "usd"])
def test_one_usd_file_is_the_keyframe_sequence_of_its_time_samples(tmp_path, ext):
    _pxr()
    from shellspline.io.usd import write_usd

    V, off, idx = _quad_strip()
    V32 = V.astype(np.float32).astype(np.float64)  # USD stores point3f
    p = write_usd(tmp_path / f"keys.{ext}", V, polygons=(off, idx), start=1)  # Blender's start
    kf = read_keyframes(p)
    # the oracle: the same poses (float32-rounded) as OBJ files, read by the OBJ reader
    objs = [_write_obj(tmp_path / f"k{j}.obj", V32[j], off, idx) for j in range(3)]
    _same_keyframes(kf, read_keyframes(objs))
    assert kf.frames.tolist() == [0, 1, 2]  # time codes 1, 2, 3 less the first
    assert kf.names == [f"{p} time {t}" for t in (1, 2, 3)]
    assert read_keyframes([p], frames="0,4,10").frames.tolist() == [0, 4, 10]
    # one pose per file, USD and OBJ mixed: the same keyframes again
    single = [write_usd(tmp_path / f"s{j}.{ext}", V[j:j + 1], polygons=(off, idx), start=7)
              for j in range(3)]
    _same_keyframes(read_keyframes([single[0], objs[1], single[2]], frames=[0, 5, 9]), kf)


def test_time_codes_with_gaps_are_the_frames(tmp_path):
    _pxr()
    from pxr import Usd, UsdGeom

    from shellspline.io.usd import write_usd

    V, off, idx = _quad_strip()
    p = write_usd(tmp_path / "k.usda", V, polygons=(off, idx))
    stage = Usd.Stage.Open(str(p))
    pts = UsdGeom.Mesh(stage.GetDefaultPrim()).GetPointsAttr()
    for t, new in ((2, 10), (1, 4)):  # move the samples at 1, 2 to 4, 10
        pts.Set(pts.Get(t), new)
        pts.ClearAtTime(t)
    stage.GetRootLayer().Save()
    kf = read_keyframes(p)
    assert kf.frames.tolist() == [0, 4, 10]
    np.testing.assert_array_equal(kf.V[2], V[2].astype(np.float32))
    pts.Set(pts.Get(10), 10.5)
    pts.ClearAtTime(10)
    stage.GetRootLayer().Save()
    _one_line_error(lambda: read_keyframes(p), "k.usda", "not whole frames apart")
    assert read_keyframes(p, frames=[0, 4, 11]).frames.tolist() == [0, 4, 11]
    _one_line_error(lambda: read_keyframes(p, frames="0,4"), "k.usda", "holds 3 poses",
                    "2 keyframe frames")


_MESH = 'def Mesh "{name}"\n{{\n{body}}}\n'


def _tri_mesh(name="m", points=None, extra=""):
    """A usda Mesh prim of two triangles over four points; ``points`` the time samples."""
    if points is None:
        points = {0: "(0,0,0), (1,0,0), (0,1,0), (1,1,0.5)", 3: "(0,0,0), (2,0,0), (0,2,0), (2,2,1)"}
    samples = ", ".join(f"{t}: [{p}]" for t, p in points.items())
    body = ("    int[] faceVertexCounts = [3, 3]\n"
            "    int[] faceVertexIndices = [0, 1, 2, 2, 1, 3]\n"
            f"    point3f[] points.timeSamples = {{{samples}}}\n" + extra)
    return _MESH.format(name=name, body=body)


def test_malformed_stages_are_one_line_errors_naming_the_file(tmp_path):
    _pxr()
    cases = {
        "two_meshes": (_tri_mesh("a") + _tri_mesh("b"), ["2 Mesh prims", "/a, /b"]),
        "no_mesh": ('def Xform "x"\n{\n}\n', ["holds no Mesh prim"]),
        "points_vary": (_tri_mesh(points={0: "(0,0,0), (1,0,0), (0,1,0), (1,1,0)",
                                          1: "(0,0,0), (1,0,0), (0,1,0), (1,1,0), (2,2,2)"}),
                        ["topology", "changes over time", "4..5"]),
        "faces_vary": (_tri_mesh(extra="    int[] faceVertexIndices.timeSamples = "
                                       "{0: [0, 1, 2, 2, 1, 3], 3: [0, 1, 3, 0, 3, 2]}\n"),
                       ["topology", "changes over time", "faceVertexIndices"]),
        "one_pose": (_tri_mesh(points={0: "(0,0,0), (1,0,0), (0,1,0), (1,1,0.5)"}),
                     ["need at least 2 keyframes", "1 time samples"]),
    }
    for name, (text, phrases) in cases.items():
        p = tmp_path / f"{name}.usda"
        p.write_text("#usda 1.0\n" + text)
        _one_line_error(lambda: read_keyframes(p), f"{name}.usda", *phrases)
        if name != "one_pose":  # a file of a list fails alike
            _one_line_error(lambda: read_keyframes([p, p]), f"{name}.usda", *phrases)
    # a time-sampled file in a list of one-pose files
    ok = tmp_path / "faces_same.usda"
    ok.write_text("#usda 1.0\n" + _tri_mesh())
    assert read_keyframes(ok).V.shape == (2, 4, 3)
    _one_line_error(lambda: read_keyframes([ok, tmp_path / "one_pose.usda"]), "faces_same.usda",
                    "holds 2 poses", "give it alone")
    _one_line_error(lambda: read_keyframes([tmp_path / "one_pose.usda", tmp_path / "x.abc"]),
                    "x.abc", "unknown extension", ".usdc")


def test_transforms_and_left_handed_meshes_are_read_in_world_space(tmp_path):
    _pxr()
    mesh = _tri_mesh(extra='    uniform token orientation = "leftHanded"\n')
    p = tmp_path / "xf.usda"
    p.write_text('#usda 1.0\ndef Xform "rig"\n{\n    double3 xformOp:translate = (1, 2, 3)\n'
                 '    float3 xformOp:scale = (2, 2, 2)\n'
                 '    uniform token[] xformOpOrder = ["xformOp:translate", "xformOp:scale"]\n'
                 + mesh.replace("\n", "\n    ").rstrip() + "\n}\n")
    kf = read_keyframes(p)
    local = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.5]],
                      [[0, 0, 0], [2, 0, 0], [0, 2, 0], [2, 2, 1]]], dtype=float)
    np.testing.assert_allclose(kf.V, 2 * local + [1, 2, 3], rtol=0, atol=1e-12)
    # left-handed corners reversed: the normals point the other way from the authored order
    assert kf.frames.tolist() == [0, 3]
    assert sorted(map(tuple, kf.F.tolist())) == sorted([(2, 1, 0), (3, 1, 2)])


def test_without_pxr_a_usd_keyframe_file_names_the_extra(tmp_path, monkeypatch, capsys):
    from shellspline.cli.main import main

    p = tmp_path / "keys.usda"
    p.write_text("#usda 1.0\n" + _tri_mesh())
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr now raises ImportError
    msg = _one_line_error(lambda: read_keyframes(p), r"shellspline[usd]", cls=ShellsplineError)
    assert isinstance(msg, str)
    with pytest.raises(ImportError):
        read_keyframes([p, p])
    capsys.readouterr()
    assert main(["interpolate", str(p), "-o", str(tmp_path / "out"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "usd-core" in err[0] and "internal error" not in err[0]
    assert not (tmp_path / "out").exists()


def test_interpolate_a_usd_keyframe_file_end_to_end(tmp_path, capsys):
    _pxr()
    from shellspline.cli.main import main
    from shellspline.io import read_sequence
    from shellspline.io.usd import conventional_up_axis, write_usd

    V, off, idx = _quad_strip()
    p = write_usd(tmp_path / "keys.usdc", V, polygons=(off, idx), up_axis="z", start=1)
    out = tmp_path / "out"
    assert main(["interpolate", str(p), "--frames", "0,4,10", "-o", str(out), "--format",
                 "usd"]) == 0
    assert "3 keyframes" in capsys.readouterr().err
    W, F, report = read_sequence(out)
    assert W.shape == (11, V.shape[1], 3)
    V32 = V.astype(np.float32)
    for j, k in enumerate((0, 4, 10)):  # the keyframes are hit (float32 on both ends)
        np.testing.assert_allclose(W[k], V32[j], rtol=0, atol=1e-5)
    assert conventional_up_axis(out / "animation.usdc") == "z"  # the input stage's up axis
    capsys.readouterr()
    assert main(["interpolate", str(p), "-o", str(p), "--overwrite", "-q"]) == 2
    assert "keys.usdc" in capsys.readouterr().err  # the input is protected
    assert p.is_file()
