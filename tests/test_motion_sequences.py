"""``shellspline motion`` on mesh sequences as users have them: frame folders named and mixed
as exporters write them, UV-seam-split quad frames, point caches and animation folders, and
the loop a mesh closing writes (status, root motion, the input's format)."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from shellspline import animation as A
from shellspline.cli.main import main
from shellspline.io import read_sequence, write_sequence

from conftest import shared_data


def run(capsys, *argv):
    code = main(["motion", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def walk_body():
    """A body of 300 vertices skinned to 20 frames of the real walk (it travels)."""
    from data_synth.skinned import skinned_sequence

    Vs, F, fps = skinned_sequence(shared_data("motion", "dataset-1_walk_normal_001.bvh"),
                                  start=10, stop=30, n_vertices=300)
    return Vs, F, fps


def write_obj(path, V, F):
    path.write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))


def frame_folder(d, Vs, F, name="frame_{:04d}.obj", first=1):
    d.mkdir()
    for k, V in enumerate(Vs):
        write_obj(d / name.format(k + first), V, F)
    return d


# ----------------------------------------------------------------------------------------
# frame folders as exporters write them
# ----------------------------------------------------------------------------------------
def test_a_stray_mesh_or_a_frame_written_twice_is_refused_not_read_as_a_frame(
        capsys, tmp_path, walk_body):
    """Other files are left out and unpadded numbers sort by value; but a mesh named like no
    frame (a rest pose beside the frames) was read as frame 0, and a frame exported twice
    (OBJ and PLY) was read twice, the distance then silently wrong: both are one-line
    errors naming the files."""
    Vs, F, _ = walk_body
    a = frame_folder(tmp_path / "a", Vs, F)
    u = frame_folder(tmp_path / "u", Vs, F, name="frame_{}.obj")  # frame_1, frame_10, frame_2
    (u / "notes.txt").write_text("exported from Maya\n")
    (u / "skin.mtl").write_text("newmtl skin\n")
    code, out, err = run(capsys, "distance", a, u, "--align", "none", "-q")
    assert code == 0 and float(out) == 0.0, err

    write_obj(u / "rest.obj", Vs[5], F)  # same vertex count: was frame 0
    code, _, err = run(capsys, "distance", a, u, "-q")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "not one numbered sequence" in err and "rest.obj" in err and "frame_1.obj" in err

    (u / "rest.obj").unlink()
    import trimesh

    trimesh.Trimesh(Vs[2], F, process=False).export(u / "frame_0003.ply")
    code, _, err = run(capsys, "close", u, "-o", tmp_path / "loop")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "two files of frame 3: frame_3.obj and frame_0003.ply" in err
    assert not (tmp_path / "loop").exists()


def test_a_version_suffix_after_the_frame_number_is_one_sequence(capsys, tmp_path,
                                                                 walk_body):
    """``frame_0001_v2.obj ...`` (a version suffix, as DCC tools export) was refused as one
    sequence per file (the last digits taken for the frame number); the number that varies
    is the frame number (:func:`shellspline.io.sequences.frame_files`)."""
    Vs, F, _ = walk_body
    a = frame_folder(tmp_path / "a", Vs, F)
    v = frame_folder(tmp_path / "v", Vs, F, name="frame_{:04d}_v2.obj")
    code, out, err = run(capsys, "distance", a, v, "--align", "none", "-q")
    assert code == 0 and float(out) == 0.0, err


def test_macos_resource_forks_beside_the_frames_are_left_out(capsys, tmp_path, walk_body):
    """A frame folder copied by macOS to an exFAT drive or a network share holds a binary
    ``._frame_0001.obj`` beside every frame (and a ``.DS_Store``): they were taken for a
    second sequence ("not one numbered sequence", exit 2). Hidden files are not frames."""
    from shellspline.io.sequences import frame_files

    Vs, F, _ = walk_body
    a = frame_folder(tmp_path / "a", Vs, F)
    mac = frame_folder(tmp_path / "mac", Vs, F)
    fork = b"\x00\x05\x16\x07\x00\x02\x00\x00Mac OS X        " + bytes(4050)
    for f in sorted(mac.iterdir()):
        (mac / f"._{f.name}").write_bytes(fork)
    (mac / ".DS_Store").write_bytes(bytes(6148))
    assert [f.name for f in frame_files(mac)] == [f.name for f in frame_files(a)]
    code, out, err = run(capsys, "distance", a, mac, "--align", "none", "-q")
    assert code == 0 and float(out) == 0.0, err


def torus_frames(d, n_frames, *, periods=1.0):
    """OBJ frames of a quad torus split at its UV seams (117 vertices, 96 distinct: the
    seam rows and columns repeated, as game exporters write them) with texture coordinates
    and material lines, a bulge running around it once over the frames (the last frame
    equals the first)."""
    nu, nv = 12, 8
    u, v = np.meshgrid(np.linspace(0, 2 * np.pi, nu + 1), np.linspace(0, 2 * np.pi, nv + 1),
                       indexing="ij")
    idx = np.arange((nu + 1) * (nv + 1)).reshape(nu + 1, nv + 1)
    quads = np.stack([idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]], -1).reshape(-1, 4)
    uv = np.stack([u / (2 * np.pi), v / (2 * np.pi)], -1).reshape(-1, 2)
    d.mkdir()
    Vs = []
    for k in range(n_frames):
        r = 0.5 + 0.15 * np.sin(2 * np.pi * periods * k / (n_frames - 1) + u)
        X = np.stack([(1.5 + r * np.cos(v)) * np.cos(u), (1.5 + r * np.cos(v)) * np.sin(u),
                      r * np.sin(v)], -1).reshape(-1, 3)
        Vs.append(X)
        (d / f"frame_{k + 1:04d}.obj").write_text(
            "mtllib skin.mtl\no torus\n"
            + "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in X.tolist())
            + "".join(f"vt {s!r} {t!r}\n" for s, t in uv.tolist()) + "usemtl skin\n"
            + "".join("f " + " ".join(f"{q + 1}/{q + 1}" for q in quad) + "\n"
                      for quad in quads.tolist()))
    return np.stack(Vs)


def test_uv_seam_split_quad_frames_close_and_blend_on_their_own_polygons(capsys, tmp_path):
    """Welded seams: the output was handed to the writer on the welded (solve) vertices and
    refused ("V must hold the input's 117 vertices", exit 2). Two animations of one quad mesh
    triangulated each by its own frames took other diagonals and were "not frames of one
    mesh". Now both are read as one keyframe set, and the outputs keep the files' vertices,
    quads, UVs and material lines, seams closed."""
    Va = torus_frames(tmp_path / "a", 21)
    Vb = torus_frames(tmp_path / "b", 15)
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "loop")
    assert code == 0, err
    src = (tmp_path / "a" / "frame_0001.obj").read_text().splitlines()
    got = (tmp_path / "loop" / "frame_0000.obj").read_text().splitlines()
    assert [x for x in got if x[0] in "fu"] == [x for x in src if x[0] in "fu"]
    def uvs(lines):
        return [[float(x) for x in ln.split()[1:]] for ln in lines if ln.startswith("vt")]
    assert uvs(got) == uvs(src)
    V, _, rep = read_sequence(tmp_path / "loop")
    assert V.shape == Va.shape and rep["status"] == "converged"
    # already periodic: changed to the reconstruction's tolerance; the split seam stays shut
    assert np.abs(V - Va).max() <= 1e-8
    seam = np.arange(13 * 9).reshape(13, 9)
    assert np.array_equal(V[:, seam[0]], V[:, seam[-1]])
    assert np.array_equal(V[:, seam[:, 0]], V[:, seam[:, -1]])

    for s, want in ((0, Va), (1, Vb)):
        out = tmp_path / f"s{s}"
        code, _, err = run(capsys, "blend", tmp_path / "a", tmp_path / "b", "--s", s, "-o",
                           out, "-q")
        assert code == 0, err
        V = read_sequence(out)[0]
        assert V.shape == want.shape and np.abs(V - want).max() <= 1e-8
    code, out, err = run(capsys, "distance", tmp_path / "a", tmp_path / "a", "-q")
    assert code == 0 and float(out) <= 1e-9, err


# ----------------------------------------------------------------------------------------
# point caches, animation folders, the input's format
# ----------------------------------------------------------------------------------------
def test_point_caches_and_animation_folders_are_mesh_sequences(capsys, tmp_path, walk_body):
    """A .pc2/.mdd cache was read as a pose file ("not a text pose file (binary data)") and
    a folder that shellspline wrote as a cache or a glTF animation as "at least 3 frames,
    found 1". A cache on the mesh --topology names, or such a folder, is a mesh sequence;
    the output is written in the input's format (MDD at the input's frame rate)."""
    from shellspline.io.pointcache import read_mdd, read_pc2, write_pc2

    Vs, F, _ = walk_body
    write_obj(tmp_path / "rest.obj", Vs[0], F)
    write_pc2(tmp_path / "walk.pc2", Vs)
    code, _, err = run(capsys, "close", tmp_path / "walk.pc2", "-o", tmp_path / "x")
    assert code == 2 and "point cache" in err and "--topology MESH" in err
    code, _, err = run(capsys, "close", tmp_path / "walk.pc2", "--topology",
                       tmp_path / "rest.obj", "-o", tmp_path / "loop", "-q")
    assert code == 0, err
    assert sorted(p.name for p in (tmp_path / "loop").iterdir()) == [
        "animation.pc2", "mesh.obj", "report.json"]
    assert read_pc2(tmp_path / "loop" / "animation.pc2")[0].shape == Vs.shape

    write_sequence(tmp_path / "mdd", Vs, F, fmt="mdd", fps=30.0)
    code, out, err = run(capsys, "distance", tmp_path / "mdd", tmp_path / "walk.pc2",
                         "--topology", tmp_path / "rest.obj", "--align", "none", "-q")
    assert code == 0 and float(out) <= 1e-9, err
    code, _, err = run(capsys, "blend", tmp_path / "mdd", tmp_path / "mdd", "-o",
                       tmp_path / "mid", "-q")
    assert code == 0, err
    V, times = read_mdd(tmp_path / "mid" / "animation.mdd")
    assert np.abs(V - Vs).max() <= 1e-4 and np.allclose(np.diff(times), 1 / 30)
    code, _, err = run(capsys, "distance", tmp_path / "mdd", tmp_path / "mdd", "--topology",
                       tmp_path / "rest.obj")
    assert code == 2 and "--topology" in err and "none given" in err


def test_a_z_up_glb_or_usd_animation_is_written_back_z_up(capsys, tmp_path, walk_body):
    """A GLB says its data are z-up by its node's rotation, a USD stage by its upAxis (as
    ``interpolate`` writes them for PLY keyframes); the loop of such an animation was written
    y-up, so a viewer showed it lying on its side. Now it is written back in the input's
    frame: the same up axis, frame 0 where the input's is."""
    from shellspline.io.usd import conventional_up_axis

    Vs, F, _ = walk_body
    Vz = Vs[:, :, [0, 2, 1]] * [1.0, -1.0, 1.0]  # the walk with z up (rotation about x)
    formats = ["glb"] + (["usd"] if importlib.util.find_spec("pxr") else [])
    for fmt in formats:
        src = write_sequence(tmp_path / f"in_{fmt}", Vz, F, fmt=fmt, fps=30.0, up_axis="z")
        out = tmp_path / f"loop_{fmt}"
        code, _, err = run(capsys, "close", src, "-o", out, "-q")
        assert code == 0, err
        anim = next(out.glob("animation.*"))
        assert conventional_up_axis(anim) == "z", fmt
        V = read_sequence(out)[0]
        size = np.ptp(Vz[0], axis=0).max()
        assert V.shape == Vz.shape and np.abs(V[0] - Vz[0]).max() <= 1e-2 * size, fmt


def test_ply_frames_give_ply_frames_and_the_invariances_hold(capsys, tmp_path, walk_body):
    """A folder of PLY frames is written back as PLY frames (it was always OBJ); on it, the
    LΘA distance ignores a rigid move, and align recovers a known re-timing."""
    Vs, F, _ = walk_body
    write_sequence(tmp_path / "a", Vs, F, fmt="ply")
    from shellspline.groups import so3

    R = so3.exp(np.array([0.3, -1.2, 0.5]))
    write_sequence(tmp_path / "moved", Vs @ R.T + [50.0, -3.0, 2.0], F, fmt="ply")
    code, out, err = run(capsys, "distance", tmp_path / "a", tmp_path / "moved", "--align",
                         "none", "-q")
    assert code == 0 and float(out) <= 1e-9, err
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "loop", "-q")
    assert code == 0, err
    names = sorted(p.name for p in (tmp_path / "loop").iterdir())
    assert names[0] == "frame_0000.ply" and len(names) == Vs.shape[0] + 1

    t = np.linspace(0.0, 1.0, 15)
    write_sequence(tmp_path / "slow", A.reparametrize_vertices(Vs, t ** 1.5), F, fmt="ply")
    code, _, err = run(capsys, "align", tmp_path / "a", tmp_path / "slow", "-o",
                       tmp_path / "w.csv", "-q")
    assert code == 0, err
    rows = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)
    ta, tb = rows[:, 0] / (Vs.shape[0] - 1), rows[:, 1] / 14
    # b(phi(t)) = a(t): phi = t^(2/3), within half a frame of b
    assert np.abs(tb - ta ** (1 / 1.5)).max() <= 0.5 / 14


# ----------------------------------------------------------------------------------------
# the loop
# ----------------------------------------------------------------------------------------
def test_an_unclosed_seam_is_not_reported_as_success(capsys, tmp_path, walk_body):
    """``--iterations 1`` leaves the seam open: exit 1 with a warning (it was exit 0), and
    the report says so; in Python ``MeshReport.status`` / ``success``."""
    Vs, F, _ = walk_body
    _, rep = A.mesh_close(Vs, F, iterations=1)
    assert rep.status == "limit" and not rep.success
    _, rep = A.mesh_close(Vs, F)
    assert rep.status == "converged" and rep.success
    frame_folder(tmp_path / "a", Vs, F)
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "loop",
                       "--iterations", "1")
    assert code == 1 and "did not close (limit)" in err
    assert read_sequence(tmp_path / "loop")[2]["status"] == "limit"


def test_root_motion_close_makes_a_walking_body_loop_in_place(capsys, tmp_path, walk_body):
    """A closed walk keeps its travel (the last frame is the first's shape where the walk
    ended, 100+ units on); ``--root-motion close`` (it was silently ignored, as were ``--up``
    and ``--no-plant``, now refused) moves the last frame onto the first, the step across
    the seam no larger than the others, no face flipped or collapsed."""
    from shellspline.mesh.topology import topology
    from shellspline.metrics import sequence_defects

    Vs, F, _ = walk_body
    frame_folder(tmp_path / "a", Vs, F)
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "keep", "-q")
    assert code == 0, err
    V = read_sequence(tmp_path / "keep")[0]
    steps = np.linalg.norm(np.diff(V, axis=0), axis=2).max(axis=1)
    assert np.linalg.norm(V[-1] - V[0], axis=1).max() > 5 * steps.max()  # travels
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "loop", "-q",
                       "--root-motion", "close")
    assert code == 0, err
    V = read_sequence(tmp_path / "loop")[0]
    steps = np.linalg.norm(np.diff(V, axis=0), axis=2).max(axis=1)
    assert np.linalg.norm(V[-1] - V[0], axis=1).max() <= 1e-3 * steps.min()
    looped = np.concatenate([V, V[1:2]])  # played in a loop: ..., last = first, second
    d = sequence_defects(looped, topology(F, V.shape[1]), [0, V.shape[0] - 1])
    assert d["flipped_faces"] == 0 and d["collapsed_faces"] == 0
    for opt in (["--up", "y"], ["--no-plant"]):
        code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "x", *opt)
        assert code == 2 and f"{opt[0]}: BVH clips only, not mesh sequences" in err
