"""BVH reading/writing and forward kinematics (shellspline.io.bvh)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from shellspline import ShellsplineError
from shellspline.io.bvh import Motion, euler_matrices, forward_kinematics, read_bvh, write_bvh

from conftest import shared_data

# A 2-joint, 3-channel skeleton with a non-XYZ rotation order, an End Site, tabs and CRLF.
TWO_JOINTS = (
    "HIERARCHY\r\n"
    "ROOT hip\r\n"
    "{\r\n"
    "\tOFFSET 1 2 3\r\n"
    "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation\r\n"
    "\tJOINT knee\r\n"
    "\t{\r\n"
    "\t\tOFFSET 0 -2 0\r\n"
    "\t\tCHANNELS 3 Xrotation Zrotation Yrotation\r\n"
    "\t\tEnd Site\r\n"
    "\t\t{\r\n"
    "\t\t\tOFFSET 0 -3 0\r\n"
    "\t\t}\r\n"
    "\t}\r\n"
    "}\r\n"
    "MOTION\r\n"
    "Frames:\t3\r\n"
    "Frame Time:\t0.008333333\r\n"
    "0 0 0 0 0 0 0 0 0\r\n"
    "10 20 30 90 0 0 0 0 0\r\n"
    "0 0 0 0 0 0 90 0 0\r\n"
)


def _write(tmp_path, text, name="m.bvh"):
    p = tmp_path / name
    p.write_bytes(text.encode())
    return p


def test_two_joint_file_known_positions(tmp_path):
    m = read_bvh(_write(tmp_path, TWO_JOINTS))
    assert m.names == ("hip", "knee")
    assert m.parents.tolist() == [-1, 0]
    assert m.channels[1] == ("Xrotation", "Zrotation", "Yrotation")
    assert m.n_frames == 3 and m.frame_time == 0.008333333
    assert m.fps == pytest.approx(120.0, rel=1e-6)
    assert len(m.end_sites) == 1 and m.end_sites[0][0] == 1
    np.testing.assert_array_equal(m.end_sites[0][1], [0, -3, 0])
    P, R = forward_kinematics(m)
    assert P.shape == (3, 2, 3) and R.shape == (3, 2, 3, 3)
    # frame 0: root position channels (0,0,0) replace the OFFSET (1,2,3)
    np.testing.assert_allclose(P[0], [[0, 0, 0], [0, -2, 0]], atol=1e-12)
    # frame 1: root at (10,20,30) rotated 90 deg about z: the knee offset (0,-2,0) -> (2,0,0)
    np.testing.assert_allclose(P[1], [[10, 20, 30], [12, 20, 30]], atol=1e-12)
    np.testing.assert_allclose(R[1, 1] @ [0, -3, 0], [3, 0, 0], atol=1e-12)
    # frame 2: the knee rotates 90 deg about x: its own position stays, its End Site moves
    np.testing.assert_allclose(P[2, 1], [0, -2, 0], atol=1e-12)
    np.testing.assert_allclose(P[2, 1] + R[2, 1] @ [0, -3, 0], [0, -2, -3], atol=1e-12)


@pytest.mark.parametrize("axes", ["XYZ", "ZXY", "ZYX", "YXZ", "XZY", "YZX", "XY", "Z"])
def test_euler_matrices_match_scipy_intrinsic(axes):
    rng = np.random.default_rng(len(axes))
    a = rng.uniform(-180, 180, size=(7, len(axes)))
    R = euler_matrices(a, axes)
    np.testing.assert_allclose(R, Rotation.from_euler(axes, a, degrees=True).as_matrix(),
                               atol=1e-13)


def _fk_oracle(m: Motion):
    """Per-frame, per-joint forward kinematics with scipy Rotation (independent of the
    vectorised implementation)."""
    T, J = m.n_frames, m.n_joints
    P = np.zeros((T, J, 3))
    R = np.zeros((T, J, 3, 3))
    for f in range(T):
        col = 0
        for j in range(J):
            t = m.offsets[j].copy()
            axes, angles = "", []
            for c in m.channels[j]:
                v = m.values[f, col]
                col += 1
                if c.endswith("position"):
                    t["XYZ".index(c[0])] = v
                else:
                    axes += c[0]
                    angles.append(v)
            loc = (Rotation.from_euler(axes, angles, degrees=True) if axes
                   else Rotation.identity())
            p = m.parents[j]
            if p < 0:
                P[f, j], R[f, j] = t, loc.as_matrix()
            else:
                P[f, j] = P[f, p] + R[f, p] @ t
                R[f, j] = R[f, p] @ loc.as_matrix()
    return P, R


def test_fk_matches_per_frame_scipy_oracle_real_file():
    m = read_bvh(shared_data("motion", "dataset-1_walk_normal_001.bvh")).frames(0, 40)
    P, R = forward_kinematics(m)
    P0, R0 = _fk_oracle(m)
    np.testing.assert_allclose(P, P0, atol=1e-9)
    np.testing.assert_allclose(R, R0, atol=1e-12)
    # the hips travel: root motion is in the data
    assert np.linalg.norm(P[-1, 1] - P[0, 1]) > 30


def test_fk_matches_oracle_mixed_orders_and_partial_positions():
    # 3 joints: XYZ root with 6 channels, a YZX joint with only Yposition, a 1-channel joint
    rng = np.random.default_rng(3)
    chans = (("Zposition", "Xrotation", "Yrotation", "Zrotation", "Xposition", "Yposition"),
             ("Yposition", "Yrotation", "Zrotation", "Xrotation"),
             ("Zrotation",))
    m = Motion(("a", "b", "c"), [-1, 0, 1], rng.normal(size=(3, 3)), chans, 1 / 24,
               rng.uniform(-170, 170, size=(5, 11)))
    P, R = forward_kinematics(m)
    P0, R0 = _fk_oracle(m)
    np.testing.assert_allclose(P, P0, atol=1e-10)
    np.testing.assert_allclose(R, R0, atol=1e-12)
    # the offset's x and z of joint b survive, its y is replaced by the channel
    R_loc, t_loc = m.local_transforms()
    np.testing.assert_array_equal(t_loc[:, 1, [0, 2]], np.broadcast_to(m.offsets[1, [0, 2]],
                                                                         (5, 2)))
    np.testing.assert_array_equal(t_loc[:, 1, 1], m.values[:, 6])


def test_sinusoidal_other_skeleton():
    m = read_bvh(shared_data("motion", "sinusoidal.bvh"))
    assert m.n_joints == 4 and [len(c) for c in m.channels] == [6, 3, 3, 3]
    assert m.fps == pytest.approx(60.0)
    P, R = forward_kinematics(m)
    np.testing.assert_allclose(P, _fk_oracle(m)[0], atol=1e-10)


@pytest.mark.parametrize("name", ["dataset-1_run_normal_001.bvh", "sinusoidal.bvh"])
def test_round_trip_bit_exact_real_files(tmp_path, name):
    m = read_bvh(shared_data("motion", name))
    m2 = read_bvh(write_bvh(m, tmp_path / "out.bvh"))
    assert m2.names == m.names and m2.channels == m.channels
    np.testing.assert_array_equal(m2.parents, m.parents)
    np.testing.assert_array_equal(m2.offsets, m.offsets)
    np.testing.assert_array_equal(m2.values, m.values)
    assert m2.frame_time == m.frame_time
    assert len(m2.end_sites) == len(m.end_sites)


def test_round_trip_bit_exact_random_doubles(tmp_path):
    rng = np.random.default_rng(0)
    vals = rng.normal(size=(4, 9)) * 10.0 ** rng.integers(-20, 20, size=(4, 9))
    vals[0, 0] = -0.0
    m = read_bvh(_write(tmp_path, TWO_JOINTS))
    m = Motion(m.names, m.parents, m.offsets + 1 / 3, m.channels, 1 / 120, vals, m.end_sites)
    m2 = read_bvh(write_bvh(m, tmp_path / "r.bvh"))
    assert m2.values.tobytes() == m.values.tobytes()  # bit for bit, -0.0 included
    assert m2.offsets.tobytes() == m.offsets.tobytes()
    assert m2.frame_time == 1 / 120


def test_frames_window_scales_frame_time(tmp_path):
    m = read_bvh(_write(tmp_path, TWO_JOINTS))
    w = m.frames(0, None, 2)
    assert w.n_frames == 2 and w.frame_time == pytest.approx(2 * 0.008333333)
    np.testing.assert_array_equal(w.values, m.values[::2])


@pytest.mark.parametrize("edit, fragment", [
    (lambda s: s.replace("0 0 0 0 0 0 90 0 0", "0 0 0 0 0 0 90 0"),
     "m.bvh:21: frame 2 has 8 values, the HIERARCHY declares 9 channels"),
    (lambda s: s.split("MOTION")[0], "no MOTION section"),
    (lambda s: s.replace("Frame Time:\t0.008333333", "Frame Time: abc"), "m.bvh:18: Frame Time"),
    (lambda s: s.replace("Zrotation Yrotation", "Wrotation Yrotation"),
     "m.bvh:9: CHANNELS of knee: unknown channel 'Wrotation'"),
    (lambda s: s.replace("10 20 30", "10 x 30"), "m.bvh:20: frame 1: expected numbers, got 'x'"),
    (lambda s: s.replace("\t}\r\n}\r\n", "\t}\r\n"), "closing hip"),
    (lambda s: s.replace("HIERARCHY", "HIERARCH"), "expected 'HIERARCHY'"),
    (lambda s: s.replace("OFFSET 0 -2 0", "OFFSET 0 -2"), "m.bvh:9: OFFSET of knee: expected a "
                                                         "number, got 'CHANNELS'"),
])
def test_malformed_files_raise_one_line(tmp_path, edit, fragment):
    p = _write(tmp_path, edit(TWO_JOINTS))
    with pytest.raises(ShellsplineError) as exc:
        read_bvh(p)
    msg = str(exc.value)
    assert fragment in msg and "\n" not in msg
    assert str(p) in msg


def test_motion_validates_shapes():
    with pytest.raises(ShellsplineError, match=r"values must be a \(frames, 3\) array"):
        Motion(("a",), [-1], np.zeros((1, 3)), (("Xrotation", "Yrotation", "Zrotation"),),
               0.1, np.zeros((2, 4)))
    with pytest.raises(ShellsplineError, match="parent must come before"):
        Motion(("a", "b"), [1, -1], np.zeros((2, 3)), ((), ()), 0.1, np.zeros((1, 0)))


def test_zero_frames_and_rotation_only_root(tmp_path):
    text = ("HIERARCHY\nROOT r\n{\n OFFSET 1 2 3\n CHANNELS 3 Yrotation Xrotation Zrotation\n"
            " JOINT c\n {\n  OFFSET 0 1 0\n }\n}\nMOTION\nFrames: 0\nFrame Time: 0.04\n")
    m = read_bvh(_write(tmp_path, text))
    assert m.n_frames == 0 and m.values.shape == (0, 3) and m.channels[1] == ()
    P, R = forward_kinematics(m)
    assert P.shape == (0, 2, 3) and R.shape == (0, 2, 3, 3)
    one = read_bvh(_write(tmp_path, text.replace("Frames: 0", "Frames: 1") + "0 90 0\n", "b.bvh"))
    P, R = forward_kinematics(one)
    # no position channels: the root sits at its OFFSET; Xrotation 90 turns +y into +z
    np.testing.assert_allclose(P[0], [[1, 2, 3], [1, 2, 4]], atol=1e-12)


def test_real_clip_rewritten_in_another_layout_has_the_same_kinematics(tmp_path):
    """The 6-channel ZXY walk rewritten CMU-style (one 6-channel root, 3-channel ZYX joints,
    End Sites kept) through write_bvh/read_bvh: the same joint positions and rotations."""
    m = read_bvh(shared_data("motion", "dataset-1_walk_normal_001.bvh")).frames(0, 20)
    P, R = forward_kinematics(m)
    keep = np.arange(1, m.n_joints)  # drop the ground-reference joint_Root: Hips is the root
    R_loc, t_loc = m.local_transforms()
    # non-root translations are constant over time (bone vectors) in this data set
    assert np.ptp(t_loc[:, 2:], axis=0).max() < 1e-9
    cols = [np.concatenate([P[:, 1], Rotation.from_matrix(R[:, 1]).as_euler(
        "ZYX", degrees=True)], axis=1)]
    for j in keep[1:]:
        loc = np.einsum("fba,fbc->fac", R[:, m.parents[j]], R[:, j])
        cols.append(Rotation.from_matrix(loc).as_euler("ZYX", degrees=True))
    chans = (("Xposition", "Yposition", "Zposition", "Zrotation", "Yrotation", "Xrotation"),) \
        + (("Zrotation", "Yrotation", "Xrotation"),) * (len(keep) - 1)
    ends = tuple((p - 1, o) for p, o in m.end_sites)
    cmu = Motion(m.names[1:], m.parents[1:] - 1, t_loc[0, 1:], chans, 1 / 120,
                 np.concatenate(cols, axis=1), ends)
    back = read_bvh(write_bvh(cmu, tmp_path / "cmu.bvh"))
    assert back.fps == pytest.approx(120.0)
    assert [len(c) for c in back.channels] == [6] + [3] * (len(keep) - 1)
    P2, R2 = forward_kinematics(back)
    np.testing.assert_allclose(P2, P[:, keep], atol=1e-9 * np.abs(P).max())
    np.testing.assert_allclose(R2, R[:, keep], atol=1e-10)


def _biped_text(brace_same_line: bool, bom: bool) -> str:
    """A 3ds Max Biped-style file: joint names with spaces, ZXY rotations, CRLF."""
    def head(kw, name):
        return [f"{kw} {name} {{"] if brace_same_line else [f"{kw} {name}", "{"]
    lines = (["HIERARCHY"] + head("ROOT", "Bip01") + [
        "OFFSET 0 0 0",
        "CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"]
        + head("JOINT", "Bip01  L Thigh") + [  # two spaces: read as one
            "OFFSET 10 -5 0", "CHANNELS 3 Zrotation Xrotation Yrotation"]
        + head("JOINT", "Bip01 L Calf") + [
            "OFFSET 0 -40 0", "CHANNELS 3 Zrotation Xrotation Yrotation",
            "End Site", "{", "OFFSET 0 -42 0", "}", "}", "}", "}",
            "MOTION", "Frames: 2", "Frame Time: 0.0333333",
            "1 90 3 10 20 30 40 50 60 -70 80 -90",
            "0 0 0 0 0 0 0 0 0 0 0 0"])
    return ("\ufeff" if bom else "") + "\r\n".join(lines) + "\r\n"


@pytest.mark.parametrize("brace_same_line, bom", [(False, False), (True, True)])
def test_names_with_spaces_and_bom(tmp_path, brace_same_line, bom):
    m = read_bvh(_write(tmp_path, _biped_text(brace_same_line, bom)))
    assert m.names == ("Bip01", "Bip01 L Thigh", "Bip01 L Calf")
    assert m.parents.tolist() == [-1, 0, 1]
    P, _ = forward_kinematics(m)
    # independent oracle: scipy intrinsic Euler angles composed by hand
    R0 = Rotation.from_euler("ZXY", [10, 20, 30], degrees=True)
    R1 = R0 * Rotation.from_euler("ZXY", [40, 50, 60], degrees=True)
    thigh = np.array([1, 90, 3]) + R0.apply([10, -5, 0])
    np.testing.assert_allclose(P[0, 1], thigh, atol=1e-12)
    np.testing.assert_allclose(P[0, 2], thigh + R1.apply([0, -40, 0]), atol=1e-12)
    # written back with the spaces, read back identical
    back = read_bvh(write_bvh(m, tmp_path / "back.bvh"))
    assert back.names == m.names
    np.testing.assert_array_equal(back.values, m.values)


@pytest.mark.parametrize("declared", [2, 4, 0])
def test_frame_count_that_disagrees_is_warned_and_every_line_read(tmp_path, declared):
    """Blender's importer reads every frame line whatever ``Frames:`` says; so do we, with a
    warning (the CLI shows it as a note). The values are those of the lines."""
    p = _write(tmp_path, TWO_JOINTS.replace("Frames:\t3", f"Frames:\t{declared}"))
    with pytest.warns(UserWarning, match=f"declares {declared} frames, the file has 3"):
        m = read_bvh(p)
    assert m.n_frames == 3
    np.testing.assert_array_equal(m.values[1], [10, 20, 30, 90, 0, 0, 0, 0, 0])
    # a truncated last line is still an error (the download stopped mid-line)
    cut = TWO_JOINTS.replace("Frames:\t3", "Frames:\t4") + "1 2 3 4\r\n"
    with pytest.raises(ShellsplineError, match="frame 3 has 4 values"):
        read_bvh(_write(tmp_path, cut, "cut.bvh"))


def test_joint_names_in_a_windows_code_page(tmp_path):
    text = TWO_JOINTS.replace("knee", "genou_épaule")
    p = tmp_path / "cp.bvh"
    p.write_bytes(text.encode("cp1252"))
    m = read_bvh(p)
    assert m.names == ("hip", "genou_épaule")
    assert read_bvh(write_bvh(m, tmp_path / "utf8.bvh")).names == m.names
