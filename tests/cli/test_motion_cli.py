"""``shellspline motion distance|align|blend|close``: outputs, exit codes, one-line errors."""
from __future__ import annotations

import importlib.util

import numpy as np
import pytest

import data_synth.motion as synth
from shellspline import animation as A
from shellspline.cli.main import main
from shellspline.io.bvh import forward_kinematics, read_bvh, write_bvh

from conftest import shared_data

HAVE_MPL = importlib.util.find_spec("matplotlib") is not None


def walk(name="dataset-1_walk_normal_001.bvh"):
    return str(shared_data("motion", name))


def run(capsys, *argv):
    code = main(["motion", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_distance_prints_the_number(capsys):
    a, b = walk(), walk("dataset-1_walk_tired_001.bvh")
    code, out, err = run(capsys, "distance", a, a, "--align", "none")
    assert code == 0 and float(out) == 0.0
    code, out, _ = run(capsys, "distance", a, b, "--align", "dp", "--features", "contacts", "-q")
    assert code == 0
    d = float(out)
    assert np.isclose(d, A.distance(read_bvh(a), read_bvh(b), features="contacts"), rtol=1e-6)


def test_align_writes_the_warp(capsys, tmp_path):
    a = read_bvh(walk())
    t = np.linspace(0, 1, a.n_frames)
    write_bvh(A.warp_motion(a, t ** 1.5), tmp_path / "slow.bvh")
    out = tmp_path / "warp.csv"
    code, _, err = run(capsys, "align", tmp_path / "slow.bvh", walk(), "-o", out)
    assert code == 0 and "align" in err
    rows = np.loadtxt(out, delimiter=",", skiprows=1)
    dur = (a.n_frames - 1) * a.frame_time
    assert rows.shape[1] == 2 and np.allclose(rows[[0, -1]], [[0, 0], [dur, dur]], atol=1e-9)
    assert np.abs(rows[:, 1] / dur - (rows[:, 0] / dur) ** 1.5).max() <= 0.005
    # a feature file: pairs of times in seconds
    feats = tmp_path / "f.csv"
    feats.write_text("time_a,time_b\n# touch-downs\n1.0, 1.2\n3.0,3.1\n")
    code, _, _ = run(capsys, "align", tmp_path / "slow.bvh", walk(), "-o", out, "--overwrite",
                     "--features", feats)
    assert code == 0
    at = lambda r, x: np.interp(x, r[:, 0], r[:, 1])  # noqa: E731
    # these pairs contradict the true warp (1.0 s -> 0.40 s, 3.0 s -> 2.03 s): the default
    # weight leaves the warp there, a large one forces the features (seed 003's trade-off)
    soft = np.loadtxt(out, delimiter=",", skiprows=1)
    assert abs(at(soft, 1.0) - 0.4) <= 0.05
    code, _, _ = run(capsys, "align", tmp_path / "slow.bvh", walk(), "-o", out, "--overwrite",
                     "--features", feats, "--feature-weight", "1e4", "-q")
    hard = np.loadtxt(out, delimiter=",", skiprows=1)
    assert code in (0, 1) and abs(at(hard, 1.0) - 1.2) <= 0.02 and abs(at(hard, 3.0) - 3.1) <= 0.02
    for bad in (["--feature-weight", "-1", "--features", feats], ["--feature-weight", "10"]):
        code, _, err = run(capsys, "align", walk(), walk(), "-o", out, "--overwrite", *bad)
        assert code == 2 and "--feature-weight" in err


def test_align_and_distance_exit_status_says_whether_the_refinement_converged(capsys,
                                                                              tmp_path):
    """Exit 0 and "converged" when the warp's refinement met its tolerance; exit 1 and
    "limit" when it stopped at --iterations (it exited 0 whatever the refinement did)."""
    out = tmp_path / "warp.csv"
    a, b = walk(), walk("dataset-1_walk_tired_001.bvh")
    code, _, err = run(capsys, "align", a, b, "-o", out)
    assert code == 0 and "(converged in " in err and "warning" not in err
    code, _, err = run(capsys, "align", a, b, "-o", out, "--overwrite", "--iterations", "5")
    assert code == 1 and "(limit in 5 iterations" in err and "warning: did not converge" in err
    assert np.loadtxt(out, delimiter=",", skiprows=1).shape[1] == 2  # the warp is written
    code, d, err = run(capsys, "distance", a, b)
    assert code == 0 and "(converged, " in err and float(d) > 0
    code, d, err = run(capsys, "distance", a, b, "--iterations", "3")
    assert code == 1 and "(limit, 3+3 refinement iterations)" in err and float(d) > 0
    for bad in (["--iterations", "0"], ["--iterations", "3", "--align", "none"]):
        code, _, err = run(capsys, "distance", a, b, *bad)
        assert code == 2 and "--iterations" in err


def test_blend_writes_a_bvh_that_reads_back(capsys, tmp_path):
    out = tmp_path / "blend.bvh"
    code, _, err = run(capsys, "blend", walk(), walk("dataset-1_walk_happy_001.bvh"),
                       "--s", "0.5", "-o", out)
    assert code == 0 and "foot skate" in err
    m = read_bvh(out)
    src = read_bvh(walk())
    assert m.channels == src.channels and m.names == src.names
    # blending a clip with itself gives the clip
    code, _, _ = run(capsys, "blend", walk(), walk(), "-o", out, "--overwrite", "-q")
    assert code == 0 and np.abs(read_bvh(out).values - src.values).max() <= 1e-9


def test_close_writes_a_loop(capsys, tmp_path):
    out = tmp_path / "loop.bvh"
    code, _, err = run(capsys, "close", walk(), "-o", out, "--iterations", "10")
    assert code == 0 and "seam gap" in err and "foot skate" in err
    m = read_bvh(out)
    g = A.seam_gap(m)
    assert g["rotation_max"] <= 1e-6 and A.seam_gap(read_bvh(walk()))["rotation_max"] > 20
    code, _, err = run(capsys, "close", walk(), "-o", out, "--trim", "--overwrite")
    assert code == 0 and "trim" in err and read_bvh(out).n_frames < read_bvh(walk()).n_frames
    # one iteration does not close it: reported, exit status 1
    code, _, err = run(capsys, "close", walk(), "-o", out, "--iterations", "1", "--overwrite",
                       "--c1", "--no-plant")
    assert code == 1 and "warning" in err


def test_other_layouts_through_the_cli(capsys, tmp_path):
    a = synth.motion(fps=120.0, seconds=1.0, channels=3, order="mixed", up="z")
    b = synth.motion(fps=30.0, seconds=1.2, channels=3, order="mixed", up="z", cadence=0.8)
    write_bvh(a, tmp_path / "a.bvh")
    write_bvh(b, tmp_path / "b.bvh")
    code, _, _ = run(capsys, "blend", tmp_path / "a.bvh", tmp_path / "b.bvh", "-o",
                     tmp_path / "ab.bvh", "-q")
    assert code == 0
    m = read_bvh(tmp_path / "ab.bvh")
    assert m.channels == a.channels and m.frame_time == a.frame_time


def test_errors_are_one_line_with_exit_code_2(capsys, tmp_path):
    bad = tmp_path / "bad.bvh"
    bad.write_text("HIERARCHY\nROOT a\n{\n OFFSET 0 0 0\n}\nMOTION\nFrames: 2\n")
    out = tmp_path / "o.bvh"
    cases = [("distance", bad, walk()),
             ("distance", tmp_path / "missing.bvh", walk()),
             ("blend", walk(), walk(), "-o", tmp_path / "nofolder" / "x.bvh"),
             ("close", walk(), "-o", out, "--iterations", "-1"),
             ("align", walk(), walk(), "-o", out, "--features", "nonsense"),
             ("distance", walk(), walk(), "--up", "w")]
    other = synth.motion(seconds=0.5)
    write_bvh(other, tmp_path / "other.bvh")
    cases.append(("distance", walk(), tmp_path / "other.bvh"))
    for argv in cases:
        code, out_s, err = run(capsys, *argv)
        assert code == 2, argv
        assert err.strip() and len(err.strip().splitlines()) == 1, (argv, err)
    err = run(capsys, *cases[-1])[2]
    assert "different skeletons" in err and "other.bvh" in err   # names the files


def test_outputs_are_not_replaced_without_overwrite(capsys, tmp_path):
    out = tmp_path / "x.bvh"
    out.write_text("keep me")
    code, _, err = run(capsys, "blend", walk(), walk(), "-o", out)
    assert code == 2 and "--overwrite" in err and out.read_text() == "keep me"


@pytest.mark.skipif(not HAVE_MPL, reason="matplotlib (the viz extra) is not installed")
def test_render_and_plot(capsys, tmp_path):
    strip, gif, png = tmp_path / "s.png", tmp_path / "a.gif", tmp_path / "p.png"
    code, _, _ = run(capsys, "align", walk(), walk("dataset-1_walk_tired_001.bvh"), "-o",
                     tmp_path / "w.csv", "--render", strip, "--plot", png, "-q")
    assert code == 0 and strip.stat().st_size > 1000 and png.stat().st_size > 1000
    from PIL import Image

    short = tmp_path / "short.bvh"
    write_bvh(read_bvh(walk()).frames(0, 20), short)
    code, _, _ = run(capsys, "blend", short, short, "-o", tmp_path / "b.bvh", "--render", gif,
                     "-q")
    assert code == 0
    with Image.open(gif) as im:
        assert im.n_frames == 20
    code, _, err = run(capsys, "distance", walk(), walk(), "--render", tmp_path / "x.txt")
    assert code == 2 and ".gif" in err


def test_mesh_sequence_folders(capsys, tmp_path):
    """Folders of mesh frames: close writes a sequence folder, align a frame warp, blend and
    distance work on the LΘA curves."""
    from data_synth.skinned import skinned_sequence
    from shellspline.io import read_sequence, write_sequence

    Vs, F, _ = skinned_sequence(walk(), start=10, stop=30, n_vertices=300)
    write_sequence(tmp_path / "a", Vs, F)
    write_sequence(tmp_path / "b", Vs[::-1].copy(), F)
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "loop")
    assert code == 0 and "seam gap" in err
    V, F2, rep = read_sequence(tmp_path / "loop")
    assert V.shape == Vs.shape and rep["operation"] == "motion close"
    assert rep["seam_gap"][-1] <= 1e-9 * rep["seam_gap"][0]
    code, out, _ = run(capsys, "distance", tmp_path / "a", tmp_path / "a", "-q")
    assert code == 0 and float(out) <= 1e-9
    code, _, _ = run(capsys, "align", tmp_path / "a", tmp_path / "b", "-o", tmp_path / "w.csv")
    rows = np.loadtxt(tmp_path / "w.csv", delimiter=",", skiprows=1)
    assert code == 0 and rows.shape == (Vs.shape[0], 2)
    # align's -o is a file (the outputs of close and blend are folders): replaced when asked
    code, _, err = run(capsys, "align", tmp_path / "a", tmp_path / "b", "-o",
                       tmp_path / "w.csv", "--overwrite", "-q")
    assert code == 0, err
    # an input folder is never the output, nor inside it
    before = sorted((p.name, p.read_bytes()) for p in (tmp_path / "a").iterdir())
    code, _, err = run(capsys, "close", tmp_path / "a", "-o", tmp_path / "a", "--overwrite")
    assert code == 2 and "is an input of this command" in err
    code, _, err = run(capsys, "blend", tmp_path / "a", tmp_path / "b", "-o", tmp_path,
                       "--overwrite")
    assert code == 2 and "contains the input" in err
    assert sorted((p.name, p.read_bytes()) for p in (tmp_path / "a").iterdir()) == before
    code, _, _ = run(capsys, "blend", tmp_path / "a", tmp_path / "a", "-o", tmp_path / "mid",
                     "-q")
    assert code == 0 and np.abs(read_sequence(tmp_path / "mid")[0] - Vs).max() <= 1e-8
    code, _, err = run(capsys, "blend", tmp_path / "a", walk(), "-o", tmp_path / "x")
    assert code == 2 and "two BVH files, two mesh sequence folders or two pose" in err


def test_unpadded_frame_numbers_read_in_numeric_order(capsys, tmp_path):
    """Houdini/Maya write ``mesh.1.obj ... mesh.12.obj``: frame 10 comes after frame 9, not
    after frame 1 (the blend of the folder with itself returns its frames in that order)."""
    from data_synth.skinned import skinned_sequence
    from shellspline.io import read_sequence

    Vs, F, _ = skinned_sequence(walk(), start=10, stop=22, n_vertices=200)
    d = tmp_path / "houdini"
    d.mkdir()
    for k, V in enumerate(Vs):
        (d / f"mesh.{k + 1}.obj").write_text(
            "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
            + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist()))
    code, _, err = run(capsys, "blend", d, d, "-o", tmp_path / "mid", "--align", "none", "-q")
    assert code == 0, err
    np.testing.assert_allclose(read_sequence(tmp_path / "mid")[0], Vs, atol=1e-8)


def test_held_out_layouts_through_the_cli(tmp_path, capsys):
    one, cmu, simple = tmp_path / "one.bvh", tmp_path / "cmu.bvh", tmp_path / "simple.bvh"
    write_bvh(synth.motion(frames=1), one)
    write_bvh(synth.motion(skeleton="cmu", names="mixamo", channels=6, fps=30.0,
                           seconds=1.3), cmu)
    write_bvh(synth.motion(fps=30.0, seconds=1.3), simple)
    for cmd in (["distance", one, one], ["blend", one, one, "-o", tmp_path / "b.bvh"],
                ["align", one, one, "-o", tmp_path / "w.csv"]):
        code, _, err = run(capsys, *cmd)
        assert code == 2 and "one.bvh: 1 frame" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "close", one, "-o", tmp_path / "c.bvh")
    assert code == 2 and "at least 3 frames" in err
    code, _, err = run(capsys, "distance", cmu, simple)
    assert code == 2 and "different skeletons" in err and len(err.strip().splitlines()) == 1
    code, out, _ = run(capsys, "distance", cmu, cmu, "--features", "contacts")
    assert code == 0 and float(out) <= 1e-12
    code, _, err = run(capsys, "close", cmu, "-o", tmp_path / "loop.bvh", "--trim")
    assert code == 0, err
    loop = read_bvh(tmp_path / "loop.bvh")
    assert loop.names[0] == "mixamorig:Hips"
    c = A.motion_curve(loop)
    assert np.abs(c.R[-1] - c.R[0]).max() <= 1e-6


def test_same_joints_other_rotation_order_is_one_skeleton_other_channels_name_the_joint(
        tmp_path, capsys):
    """Two exports of one skeleton that differ only in a joint's Euler order are one skeleton
    (the rotations are converted); a joint with other channels is refused in one line that
    says which joint and how (the joint counts alone are equal)."""
    a = read_bvh(walk())
    chans = list(a.channels)
    j = 3
    chans[j] = chans[j][:3] + ("Xrotation", "Yrotation", "Zrotation")
    b = type(a)(a.names, a.parents, a.offsets, tuple(chans), a.frame_time, a.values,
                a.end_sites)
    write_bvh(b, tmp_path / "xyz.bvh")
    code, out, _ = run(capsys, "distance", walk(), tmp_path / "xyz.bvh", "--align", "none")
    assert code == 0 and float(out.split()[0]) > 0
    chans[j] = ("Xrotation", "Yrotation")
    cols = a.channel_columns(j)[:-2]
    c = type(a)(a.names, a.parents, a.offsets, tuple(chans), a.frame_time,
                np.delete(a.values, cols, axis=1), a.end_sites)
    write_bvh(c, tmp_path / "xy.bvh")
    code, _, err = run(capsys, "distance", walk(), tmp_path / "xy.bvh")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"joint {j} ({a.names[j]})" in err and "Xrotation Yrotation" in err
    assert "xy.bvh" in err


def test_side_view_follows_the_body_not_the_root_marker():
    """A Bandai walk whose root (a ground marker) drifts a little sideways while the hips
    carry the travel (as closing wrote it when it planted the feet through the marker): the
    side view and the strip/GIF camera follow the body's centroid (the view was along the
    marker's small drift before). Closing now leaves the marker static."""
    from shellspline import motion_viz as V

    out, _ = A.close(read_bvh(walk("dataset-1_walk_tired_001.bvh")), trim=True)
    assert np.ptp(out.values[:, out.channel_columns(0)[:3]], axis=0).max() == 0  # static
    v = out.values.copy()
    v[:, 0] += np.linspace(0.0, 20.0, out.n_frames)  # the marker drifts 20 units along X
    out = type(out)(out.names, out.parents, out.offsets, out.channels, out.frame_time, v,
                    out.end_sites)
    P = forward_kinematics(out)[0]
    S = V._view(out, P, 1, 1.0)
    hips = P[:, 1, [0, 2]]
    travel = np.linalg.norm(hips[-1] - hips[0])
    assert travel > 300
    c = V._centre(out, S)
    assert c[-1] - c[0] >= 0.99 * travel  # the view is along the travel, forward


# ----------------------------------------------------------------------------------------
# rigid pose tracks
# ----------------------------------------------------------------------------------------
def camera_window(tmp_path, lo, hi, name, fmt="tum"):
    """A window of the real TUM camera trajectory written to ``tmp_path / name``."""
    from shellspline.io.posefiles import read_poses, write_poses

    tr = read_poses(shared_data("camera", "freiburg1_xyz-groundtruth.txt"))
    t = np.arange(hi - lo, dtype=np.float64) if fmt == "kitti" else tr.t[lo:hi]
    write_poses(tmp_path / name, t, tr.T[lo:hi], fmt)
    return tmp_path / name


def test_close_a_camera_track(capsys, tmp_path):
    from shellspline.io.posefiles import read_poses

    a = camera_window(tmp_path, 500, 900, "cam.txt")
    out = tmp_path / "loop.txt"
    code, _, err = run(capsys, "close", a, "-o", out, "--c1")
    assert code == 0 and "seam gap" in err and "velocity" in err
    track, loop = read_poses(a), read_poses(out)
    assert loop.format == "tum" and np.array_equal(loop.t, track.t)
    gap = lambda T: np.abs(T[-1] - T[0]).max()  # noqa: E731
    assert gap(loop.T) <= gap(track.T) / 100
    code, _, err = run(capsys, "close", a, "-o", out)
    assert code == 2 and "exists" in err and len(err.strip().splitlines()) == 1
    # an explicit position scale (file units per radian) is used and reported
    code, _, err = run(capsys, "close", a, "-o", out, "--overwrite", "--position-scale", "0.5")
    assert code == 0 and "position scale 0.5 units/rad" in err


def test_distance_align_blend_of_camera_tracks(capsys, tmp_path):
    from shellspline.io.posefiles import read_poses

    a = camera_window(tmp_path, 500, 900, "a.txt")
    b = camera_window(tmp_path, 1000, 1300, "b.txt")
    code, out, _ = run(capsys, "distance", a, a, "--align", "none", "-q")
    assert code == 0 and float(out) == 0.0
    code, out, _ = run(capsys, "distance", a, b, "-q")
    d = float(out)
    assert code == 0 and np.isclose(d, A.track_distance(read_poses(a), read_poses(b)),
                                    rtol=1e-8)
    code, out, _ = run(capsys, "distance", b, a, "-q")
    assert np.isclose(float(out), d, rtol=1e-8)
    warp = tmp_path / "warp.csv"
    code, _, err = run(capsys, "align", a, b, "-o", warp)
    assert code == 0 and "align" in err
    rows = np.loadtxt(warp, delimiter=",", skiprows=1)
    ta, tb = read_poses(a).t, read_poses(b).t
    assert rows.shape == (400, 2) and np.all(np.diff(rows[:, 1]) >= 0)
    assert np.allclose(rows[[0, -1]], [[ta[0], tb[0]], [ta[-1], tb[-1]]], atol=1e-6)
    # blend: written in A's format (KITTI here); its pose count blended too (399 and 299
    # intervals: 349 at s = 0.5; it was A's 400 times)
    k = camera_window(tmp_path, 500, 900, "a.kitti", fmt="kitti")
    code, _, err = run(capsys, "blend", k, b, "--s", "0.5", "-o", tmp_path / "mid.txt")
    assert code in (0, 1) and "blend" in err, err
    mid = read_poses(tmp_path / "mid.txt")
    assert mid.format == "kitti" and mid.t.size == 350
    # s = 1 writes B itself: its times and poses (it was B resampled onto A's times)
    code, _, err = run(capsys, "blend", a, b, "--s", "1", "-o", tmp_path / "one.txt")
    assert code in (0, 1), err
    one, tb = read_poses(tmp_path / "one.txt"), read_poses(b)
    assert np.array_equal(one.t, tb.t) and np.abs(one.T - tb.T).max() <= 1e-9
    code, _, _ = run(capsys, "blend", a, a, "--s", "0.7", "--align", "none",
                     "-o", tmp_path / "same.txt")
    assert code == 0
    assert np.abs(read_poses(tmp_path / "same.txt").T - read_poses(a).T).max() <= 1e-9


def test_camera_track_errors_exit_2(capsys, tmp_path):
    a = camera_window(tmp_path, 500, 600, "a.txt")
    lines = a.read_text().splitlines()
    one = tmp_path / "one.txt"
    one.write_text("\n".join(lines[:2]) + "\n")
    unsorted = tmp_path / "unsorted.txt"
    unsorted.write_text("\n".join([lines[0], lines[3], lines[2]] + lines[4:]) + "\n")
    feats = tmp_path / "f.csv"
    feats.write_text("time_a,time_b\n1305031104.0,1305031104.1\n")
    cases = [
        (("distance", one, a), "one.txt: 1 pose"),
        (("close", one, "-o", tmp_path / "x.txt"), "at least 3"),
        (("distance", unsorted, a), "times must increase strictly"),
        (("distance", a, walk()), "two pose files (got a pose file and a BVH clip)"),
        (("close", a, "-o", tmp_path / "x.txt", "--trim"), "--trim: BVH clips only"),
        (("distance", a, a, "--features", "contacts"), "BVH clips only"),
        (("distance", a, a, "--position-scale", "0"), "--position-scale must be a positive"),
        (("distance", walk(), walk(), "--position-scale", "2"), "pose tracks only"),
        (("blend", a, a, "--align", "none", "--features", feats, "-o", tmp_path / "x.txt"),
         "--features needs --align dp"),
    ]
    for argv, msg in cases:
        code, _, err = run(capsys, *argv)
        assert code == 2 and msg in err, (argv, err)
        assert len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.txt").exists()


def test_close_a_clip_with_a_joint_flip_and_refuse_a_half_turn(capsys, tmp_path):
    """A 178 degree turn of the arm in one frame closes (it exited 2 with "srv_inverse: ...
    sample t more finely"); an exact half turn has no direction and is refused in one line
    that names the file, the joint and the frame."""
    from shellspline.io.bvh import euler_matrices

    m = read_bvh(walk())
    cols = m.channel_columns(m.joint_index("UpperArm_L"))[3:]
    v = m.values.copy()
    v[100:, cols[2]] += 178.0
    write_bvh(type(m)(m.names, m.parents, m.offsets, m.channels, m.frame_time, v,
                      m.end_sites), tmp_path / "flip.bvh")
    code, _, err = run(capsys, "close", tmp_path / "flip.bvh", "-o", tmp_path / "loop.bvh",
                       "--c1")
    assert code == 0
    loop = A.motion_curve(read_bvh(tmp_path / "loop.bvh"))
    assert np.abs(loop.R[-1] - loop.R[0]).max() < 1e-6
    v = m.values.copy()
    R = euler_matrices(v[99, cols], "ZXY") @ euler_matrices([0.0, 0.0, 180.0], "ZXY")
    v[100, cols] = A.euler_angles(R, "ZXY")
    write_bvh(type(m)(m.names, m.parents, m.offsets, m.channels, m.frame_time, v,
                      m.end_sites), tmp_path / "half.bvh")
    code, _, err = run(capsys, "close", tmp_path / "half.bvh", "-o", tmp_path / "h.bvh")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "half.bvh" in err and "'UpperArm_L'" in err and "frames 99 and 100" in err
    # distance, align and blend name the file too (they said "clip a"/"clip b")
    code, _, err = run(capsys, "distance", tmp_path / "half.bvh", walk())
    assert code == 2 and f"{tmp_path / 'half.bvh'}: joint 'UpperArm_L'" in err
    assert "clip a" not in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "distance", walk(), tmp_path / "half.bvh")
    assert code == 2 and f"{tmp_path / 'half.bvh'}: joint 'UpperArm_L'" in err
    assert "clip b" not in err
    code, _, err = run(capsys, "blend", walk(), tmp_path / "half.bvh", "-o", tmp_path / "b.bvh")
    assert code == 2 and f"{tmp_path / 'half.bvh'}: joint 'UpperArm_L'" in err
    assert not (tmp_path / "b.bvh").exists()


def test_heading_option(capsys, tmp_path):
    """--heading align (default) compares takes recorded facing other ways as one motion;
    keep compares them as recorded; pose tracks refuse it in one line."""
    from shellspline.io.bvh import Motion, euler_matrices

    a = synth.motion(fps=30, seconds=1.5, channels=3, order="ZXY")
    write_bvh(a, tmp_path / "a.bvh")
    v = a.values.copy()                      # the take facing the other way, elsewhere
    G = np.diag([-1.0, 1.0, -1.0])           # 180 degrees about Y
    v[:, :3] = v[:, :3] @ G.T + [50.0, 0.0, 20.0]
    v[:, 3:6] = A.euler_angles(G @ euler_matrices(v[:, 3:6], "ZXY"), "ZXY")
    assert a.channels[0][3:] == ("Zrotation", "Xrotation", "Yrotation")
    write_bvh(Motion(a.names, a.parents, a.offsets, a.channels, a.frame_time, v, a.end_sites),
              tmp_path / "b.bvh")
    code, out, _ = run(capsys, "distance", tmp_path / "a.bvh", tmp_path / "b.bvh", "--align",
                       "none", "-q")
    assert code == 0 and float(out) < 1e-9
    code, out, _ = run(capsys, "distance", tmp_path / "a.bvh", tmp_path / "b.bvh", "--align",
                       "none", "--heading", "keep", "-q")
    assert code == 0 and float(out) > 0.1
    travel = []
    for how in ("align", "keep"):
        code, _, _ = run(capsys, "blend", tmp_path / "a.bvh", tmp_path / "b.bvh", "-o",
                         tmp_path / f"{how}.bvh", "--align", "none", "--heading", how, "-q")
        P = forward_kinematics(read_bvh(tmp_path / f"{how}.bvh"))[0][:, 0, [0, 2]]
        travel.append(np.linalg.norm(P[-1] - P[0]))
    Pa = forward_kinematics(a)[0][:, 0, [0, 2]]
    assert travel[0] == pytest.approx(np.linalg.norm(Pa[-1] - Pa[0]), rel=1e-6)  # a walk
    assert travel[1] < 0.05 * travel[0]                      # as recorded: on the spot
    track = tmp_path / "t.txt"
    track.write_text("0 0 0 0 0 0 0 1\n1 1 0 0 0 0 0 1\n2 2 0 0 0 0 0 1\n")
    code, _, err = run(capsys, "distance", track, track, "--heading", "keep")
    assert code == 2 and "--heading: BVH clips only" in err


def test_track_warp_and_features_are_in_the_files_times(capsys, tmp_path):
    """EuRoC's integer nanoseconds stay nanoseconds in the warp CSV (the rows were seconds
    since the first stamp) and --features pairs are read in them; a TUM track's column is
    its seconds."""
    from shellspline.groups import se3, so3
    from shellspline.io.posefiles import write_poses

    t = np.linspace(0.0, 4.0, 81)
    T = se3.from_rt(so3.exp(np.c_[0.1 * np.sin(t), 0.3 * t, 0 * t]),
                    np.c_[np.cos(t), np.sin(t), 0.1 * t])
    origin = 1_403_636_579_758_555_392
    write_poses(tmp_path / "e.csv", t, T, "euroc", origin_ns=origin)
    write_poses(tmp_path / "p.txt", t + 1305031098.5, T, "tum")
    feats = tmp_path / "f.csv"
    feats.write_text(f"{origin + 2_000_000_000},{1305031098.5 + 2.5!r}\n")
    code, _, _ = run(capsys, "align", tmp_path / "e.csv", tmp_path / "p.txt", "-o",
                     tmp_path / "w.csv", "--features", feats, "--feature-weight", "1e5", "-q")
    rows = [ln.split(",") for ln in (tmp_path / "w.csv").read_text().splitlines()[1:]]
    assert code in (0, 1) and rows[0] == [str(origin), repr(1305031098.5)]
    assert int(rows[-1][0]) == origin + 4_000_000_000
    ta = (np.array([int(r[0]) for r in rows]) - origin) * 1e-9
    tb = np.array([float(r[1]) for r in rows]) - 1305031098.5
    assert abs(np.interp(2.0, ta, tb) - 2.5) < 0.1      # the feature pair pulled the warp


# ----------------------------------------------------------------------------------------
# outputs checked up front: never an input, never two in one file, nothing replaced unasked
# ----------------------------------------------------------------------------------------
def _one_line(err):
    return len(err.strip().splitlines()) == 1 and "Traceback" not in err


def test_an_input_is_never_an_output_even_with_overwrite(capsys, tmp_path):
    """`close IN -o IN --overwrite` replaced the clip it read (rc 0), as did a --features CSV
    named as `align -o` and a pose track; now the check `path` has (one for both families):
    one line, exit 2, the input's bytes unchanged."""
    import os
    import shutil

    clip = tmp_path / "wcopy.bvh"
    shutil.copy(walk(), clip)
    before = clip.read_bytes()
    feats = tmp_path / "f.csv"
    feats.write_text("time_a,time_b\n1.0,1.1\n")
    os.symlink(clip, tmp_path / "link.bvh")
    os.link(clip, tmp_path / "hard.bvh")
    cam = camera_window(tmp_path, 500, 600, "cam.txt")
    cam_before = cam.read_bytes()
    cases = [("close", clip, "-o", clip), ("blend", walk(), clip, "-o", clip),
             ("close", clip, "-o", tmp_path / "link.bvh"),
             ("close", clip, "-o", tmp_path / "hard.bvh"),
             ("align", clip, walk(), "-o", feats, "--features", feats),
             ("close", cam, "-o", cam), ("blend", cam, cam, "-o", cam)]
    for argv in cases:
        code, _, err = run(capsys, *argv, "--overwrite", "-q")
        assert code == 2 and _one_line(err), (argv, err)
        assert "is an input of this command" in err and str(argv[-1]) in err, err
    assert clip.read_bytes() == before and cam.read_bytes() == cam_before
    assert feats.read_text() == "time_a,time_b\n1.0,1.1\n"


def test_pictures_are_not_replaced_without_overwrite(capsys, tmp_path):
    """--plot/--render replaced an existing file without --overwrite (only -o was checked)."""
    for name in ("keep.png", "keep2.png", "keep.gif"):
        (tmp_path / name).write_text("precious\n")
    out = tmp_path / "c.bvh"
    cases = [("close", walk(), "-o", out, "--plot", tmp_path / "keep.png"),
             ("distance", walk(), walk(), "--plot", tmp_path / "keep2.png"),
             ("blend", walk(), walk(), "-o", out, "--render", tmp_path / "keep.gif")]
    for argv in cases:
        code, _, err = run(capsys, *argv, "-q")
        assert code == 2 and _one_line(err), (argv, err)
        assert f"{argv[-1]} exists (use --overwrite" in err
    for name in ("keep.png", "keep2.png", "keep.gif"):
        assert (tmp_path / name).read_text() == "precious\n"
    assert not out.exists()  # refused before any work


def test_two_outputs_in_one_file_are_refused(capsys, tmp_path):
    """`-o X --render X`: the picture silently replaced the result (exit 0)."""
    same = tmp_path / "same.png"
    cases = [("blend", walk(), walk(), "-o", same, "--render", same),
             ("align", walk(), walk(), "-o", tmp_path / "w.csv", "--render", same, "--plot",
              tmp_path / "." / "same.png")]
    for argv in cases:
        code, _, err = run(capsys, *argv, "-q")
        assert code == 2 and _one_line(err), (argv, err)
        assert "are the same file" in err and "same.png" in err
    assert not same.exists() and not (tmp_path / "w.csv").exists()


def test_every_output_path_is_checked_before_any_work(capsys, tmp_path):
    """A --plot into a missing folder was refused only after -o was written."""
    out = tmp_path / "c2.bvh"
    code, _, err = run(capsys, "close", walk(), "-o", out, "--plot",
                       tmp_path / "nonexist" / "p.png", "-q")
    assert code == 2 and _one_line(err) and "nonexist" in err and "does not exist" in err
    assert not out.exists()
    code, _, err = run(capsys, "close", walk(), "-o", out, "--plot", tmp_path / "p.xyz", "-q")
    assert code == 2 and _one_line(err) and "p.xyz: expected one of .png" in err
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_blend_weight_outside_0_and_1_is_refused(capsys, tmp_path):
    """--s 1.5 wrote a degenerate 2-frame clip with exit 0 (the README documents s from 0
    to 1, no extrapolation)."""
    cam = camera_window(tmp_path, 500, 600, "cam.txt")
    out = tmp_path / "b.bvh"
    for a, s in ((walk(), "1.5"), (walk(), "-0.25"), (walk(), "nan"), (cam, "2")):
        code, _, err = run(capsys, "blend", a, a, "--s", s, "-o", out, "-q")
        assert code == 2 and _one_line(err) and "--s must be between 0 (A) and 1 (B)" in err
        assert not out.exists()
    code, _, _ = run(capsys, "blend", walk(), walk(), "--s", "1", "--align", "none", "-o", out,
                     "-q")
    assert code == 0 and out.exists()  # the ends are allowed


def test_feature_file_errors_name_the_file_and_line(capsys, tmp_path):
    """A NaN said "expected (k,2) pairs ... got shape (1, 2)", times outside the clips
    "features: times must lie within the clips" (no file)."""
    bad = {"nan.csv": "time_a,time_b\n1.0,1.1\nnan,2.0\n",
           "inf.csv": "1.0,inf\n",
           "far.csv": "time_a,time_b\n1.0,1.1\n2.0,99\n",
           "neg.csv": "# pairs\n-1.0,1.1\n"}
    for name, text in bad.items():
        (tmp_path / name).write_text(text)
    dur = (read_bvh(walk()).n_frames - 1) * read_bvh(walk()).frame_time
    cases = [("nan.csv", "nan.csv:3: a time is not a finite number"),
             ("inf.csv", "inf.csv:1: a time is not a finite number"),
             ("far.csv", f"far.csv:3: time 99 is outside B ({walk()}: 0..{dur:.10g} s)"),
             ("neg.csv", f"neg.csv:2: time -1.0 is outside A ({walk()}: 0..")]
    for name, msg in cases:
        for sub in (("align", "-o", tmp_path / "w.csv"), ("distance",)):
            code, _, err = run(capsys, sub[0], walk(), walk(), *sub[1:], "--features",
                               tmp_path / name, "-q")
            assert code == 2 and _one_line(err) and msg in err, (name, err)
    assert not (tmp_path / "w.csv").exists()
    # pose tracks: in the files' times
    a = camera_window(tmp_path, 500, 600, "a.txt")
    (tmp_path / "t.csv").write_text("1305031000.5,1305031104.0\n")
    code, _, err = run(capsys, "align", a, a, "-o", tmp_path / "w.csv", "--features",
                       tmp_path / "t.csv", "-q")
    assert code == 2 and _one_line(err) and "t.csv:1: time 1305031000.5 is outside A" in err
    assert not (tmp_path / "w.csv").exists()


def test_pictures_the_command_cannot_draw_for_tracks_are_refused_up_front(capsys, tmp_path):
    """For pose tracks, `distance --plot`, `blend --align none --plot` and any `--render`
    were silently not drawn (exit 0); they are refused before any work, nothing written."""
    from shellspline.groups import se3, so3
    from shellspline.io.posefiles import write_poses

    t = np.linspace(0.0, 2.0, 21)
    for name, w in (("a.txt", 0.3), ("b.txt", 0.35)):
        T = se3.from_rt(so3.exp(np.c_[0 * t, w * t, 0 * t]), np.c_[np.cos(t), np.sin(t), t])
        write_poses(tmp_path / name, t, T, "tum")
    a, b, png = tmp_path / "a.txt", tmp_path / "b.txt", tmp_path / "p.png"
    for argv, says in ((("distance", a, b, "--plot", png), "has no picture"),
                       (("blend", a, b, "--align", "none", "-o", tmp_path / "o.txt",
                         "--plot", png), "--align dp"),
                       (("close", a, "-o", tmp_path / "c.txt", "--render", tmp_path / "r.gif"),
                        "stick figures")):
        code, out, err = run(capsys, *argv)
        assert code == 2 and _one_line(err) and says in err and "pose tracks" in err
        assert out == ""
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt"]
    # what can be drawn still is: the warp of an alignment
    if HAVE_MPL:
        code, _, _ = run(capsys, "blend", a, b, "-o", tmp_path / "o.txt", "--plot", png, "-q")
        assert code in (0, 1) and png.is_file()
