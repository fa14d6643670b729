"""BVH files as other tools write them: the real walk re-expressed in other conventions (CMU
layout, 120 Hz, other Euler orders and joint orders, namespaced names, CRLF, scientific
notation), deep hierarchies, and what must be refused in one line."""
from __future__ import annotations

import numpy as np
import pytest

from shellspline import ShellsplineError
from shellspline import animation as A
from shellspline.cli.main import main
from shellspline.io.bvh import Motion, forward_kinematics, read_bvh, write_bvh

from conftest import shared_data


def _walk(frames=100):
    """The first ``frames`` frames of the real walk (Bandai Namco layout: a static
    ``joint_Root`` above the hips, 6 channels ``ZXY`` on every joint, 30 fps)."""
    return read_bvh(shared_data("motion", "dataset-1_walk_normal_001.bvh")).frames(0, frames)


def _re_expressed(m, orders=("ZYX",), root_rotation_first=False, prefix=""):
    """``m`` in the CMU layout: the static root with ``CHANNELS 0``, the hips with 3 position
    and 3 rotation channels, every other joint 3 rotation channels (Euler order
    ``orders[j % len(orders)]``), the constant bone vectors as offsets; names prefixed."""
    R, t = m.local_transforms()
    assert np.all(m.values[:, m.channel_columns(0)] == 0)  # the static root
    offsets, chans, cols = t[0].copy(), [()], [np.zeros((m.n_frames, 0))]
    for j in range(1, m.n_joints):
        order = orders[j % len(orders)]
        ang = np.unwrap(A.euler_angles(R[:, j], order), period=360.0, axis=0)
        rot = tuple(f"{a}rotation" for a in order)
        if j == 1:
            pos = ("Xposition", "Yposition", "Zposition")
            chans.append(rot + pos if root_rotation_first else pos + rot)
            cols.append(np.hstack([ang, t[:, j]] if root_rotation_first else [t[:, j], ang]))
        else:
            chans.append(rot)
            cols.append(ang)
    return Motion(tuple(prefix + n for n in m.names), m.parents, offsets, tuple(chans),
                  m.frame_time, np.hstack(cols), m.end_sites)


def _reordered(m, order):
    """``m`` with its joints listed in ``order`` (old indices, parents first)."""
    new = {j: i for i, j in enumerate(order)}
    cols = np.concatenate([m.channel_columns(j) for j in order])
    return Motion(tuple(m.names[j] for j in order),
                  [-1 if m.parents[j] < 0 else new[int(m.parents[j])] for j in order],
                  m.offsets[order], tuple(m.channels[j] for j in order), m.frame_time,
                  m.values[:, cols], tuple(sorted(((new[p], o) for p, o in m.end_sites),
                                                  key=lambda e: e[0])))


def _tool_text(m, frame_time: str) -> str:
    """``m`` as a tool writes it: CRLF, two-space and tab indentation, ``%.12e`` numbers
    with a trailing space, the given ``Frame Time`` text, trailing blank lines."""
    children = [[k for k in range(m.n_joints) if m.parents[k] == j] for j in range(m.n_joints)]
    ends = {}
    for p, o in m.end_sites:
        ends.setdefault(p, []).append(o)
    out = ["HIERARCHY"]

    def num(xs):
        return "\t".join(f"{x:.12e}" for x in xs)

    def joint(j, ind):
        out.append(f"{ind}{'ROOT' if m.parents[j] < 0 else 'JOINT'} {m.names[j]}")
        out.extend([ind + "{", f"{ind}  OFFSET\t{num(m.offsets[j])}",
                    f"{ind}  CHANNELS {len(m.channels[j])} {' '.join(m.channels[j])}"])
        for k in children[j]:
            joint(k, ind + "  ")
        for o in ends.get(j, []):
            out.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET {num(o)}",
                        f"{ind}  }}"])
        out.append(ind + "}")

    for r in np.flatnonzero(m.parents < 0):
        joint(int(r), "")
    out += ["MOTION", f"Frames:\t{m.n_frames}", f"Frame Time:\t{frame_time}"]
    out += [" ".join(f"{x:.12e}" for x in row) + " " for row in m.values]
    return "\r\n".join(out) + "\r\n\r\n\r\n"


def _max_pose_difference(a, b):
    """Largest difference of joint positions and of world rotation matrices."""
    (Pa, Ra), (Pb, Rb) = forward_kinematics(a), forward_kinematics(b)
    return float(np.abs(Pa - Pb).max()), float(np.abs(Ra - Rb).max())


def run(capsys, *argv):
    code = main(["motion", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


# ----------------------------------------------------------------------------------------
# Joints matched by name, in any file order
# ----------------------------------------------------------------------------------------
def test_joints_listed_in_another_order_are_matched_by_name(tmp_path, capsys):
    """One rig from two tools: A in the CMU layout at 120 Hz (static root with CHANNELS 0,
    ZYX, CRLF, scientific notation, 'Frame Time: .0083333'); B at 30 fps with the legs listed
    before the spine and the right leg before the left, ``mixamorig:`` names, mixed Euler
    orders and the root's rotations before its positions. Matched by position in the file,
    B's legs were A's spine (refused as other skeletons) or, with only the legs swapped (the
    same parent indices), A's left leg was blended with B's right one (distance 7.3 for one
    motion). Matched by name they are one motion."""
    walk = _walk()
    cmu = A.resample(_re_expressed(walk), frame_time=1 / 120)
    (tmp_path / "a.bvh").write_bytes(_tool_text(cmu, ".0083333").encode())
    a = read_bvh(tmp_path / "a.bvh")
    assert a.channels[0] == () and a.channels[2] == ("Zrotation", "Yrotation", "Xrotation")
    # Hips' children: Spine (2..13), UpperLeg_L (14..17), UpperLeg_R (18..21)
    assert [a.names[j] for j in (2, 14, 18)] == ["Spine", "UpperLeg_L", "UpperLeg_R"]
    other = _re_expressed(walk, ("XYZ", "YXZ", "ZXY"), True, "mixamorig:")
    legs_first = _reordered(other, [0, 1, *range(18, 22), *range(14, 18), *range(2, 14)])
    swapped = _reordered(_re_expressed(walk), [*range(14), *range(18, 22), *range(14, 18)])
    assert np.array_equal(swapped.parents, a.parents)  # only the names tell the legs apart
    write_bvh(legs_first, tmp_path / "b.bvh")
    write_bvh(swapped, tmp_path / "swapped.bvh")
    assert _max_pose_difference(legs_first, walk)[0] > 10  # joint j is another joint

    assert A.skeleton_mismatch(a, legs_first) is None
    assert A.distance(a, swapped, align="none") <= 1e-6
    for b in ("b.bvh", "swapped.bvh"):
        for align in ("none", "dp"):
            code, out, err = run(capsys, "distance", tmp_path / "a.bvh", tmp_path / b,
                                 "--align", align, "-q")
            assert code == 0 and float(out) <= 1e-6, (b, align, out, err)
    code, out, _ = run(capsys, "distance", tmp_path / "a.bvh", tmp_path / "b.bvh",
                       "--features", "contacts", "-q")
    assert code == 0 and float(out) <= 1e-6
    # blends are written in A's layout (its joint order and channels) and play the motion
    for s in ("0", "1", "0.5"):
        out_path = tmp_path / f"blend{s}.bvh"
        code, _, err = run(capsys, "blend", tmp_path / "a.bvh", tmp_path / "b.bvh", "--s", s,
                           "-o", out_path, "-q")
        assert code == 0, err
        m = read_bvh(out_path)
        assert m.names == a.names and m.channels == a.channels
        assert m.n_frames == a.n_frames and m.frame_time == a.frame_time
        dp, dr = _max_pose_difference(m, a)
        assert dp <= 1e-5 and dr <= 1e-7, (s, dp, dr)
    # B's own layout survives a round trip through close: joint order and channels kept
    code, _, err = run(capsys, "close", tmp_path / "b.bvh", "-o", tmp_path / "loop.bvh", "-q")
    assert code in (0, 1), err
    loop = read_bvh(tmp_path / "loop.bvh")
    assert loop.names == legs_first.names and loop.channels == legs_first.channels
    # a joint under another parent (by name) is refused, naming it and both parents
    bad = Motion(swapped.names, [4 if n == "Shoulder_L" else p
                                 for n, p in zip(swapped.names, swapped.parents)],
                 swapped.offsets, swapped.channels, swapped.frame_time, swapped.values,
                 swapped.end_sites)
    write_bvh(bad, tmp_path / "bad.bvh")
    code, _, err = run(capsys, "distance", tmp_path / "a.bvh", tmp_path / "bad.bvh")
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "joint Shoulder_L: parent Chest against Neck" in err and "bad.bvh" in err


def test_different_skeletons_name_the_first_difference(tmp_path, capsys):
    """Refusals say what differs: the joints one clip lacks (one naming), the first joint
    that differs (another naming), a joint without channels ('none', not an empty word)."""
    walk = _walk(20)
    cmu = _re_expressed(walk)
    keep = list(range(cmu.n_joints - 1))  # without Toes_R (the last joint, a leaf)
    cols = np.concatenate([cmu.channel_columns(j) for j in keep])
    short = Motion(cmu.names[:-1], cmu.parents[:-1], cmu.offsets[:-1], cmu.channels[:-1],
                   cmu.frame_time, cmu.values[:, cols],
                   tuple(e for e in cmu.end_sites if e[0] < len(keep)))
    renamed = Motion(tuple(f"bone{j}" for j in keep), short.parents, short.offsets,
                     short.channels, short.frame_time, short.values, short.end_sites)
    assert "; only in the first: Toes_R" in A.skeleton_mismatch(cmu, short)
    assert "; only in the second: Toes_R" in A.skeleton_mismatch(short, cmu)
    assert "; joint 21: Toes_R (parent Foot_R) against no joint" in \
        A.skeleton_mismatch(cmu, renamed)
    write_bvh(cmu, tmp_path / "cmu.bvh")
    code, _, err = run(capsys, "distance", tmp_path / "cmu.bvh",
                       shared_data("motion", "dataset-1_walk_normal_001.bvh"))
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "joint 0 (joint_Root): channels none against Xposition" in err


# ----------------------------------------------------------------------------------------
# Reading and writing
# ----------------------------------------------------------------------------------------
def test_deep_chain_is_read_and_written(tmp_path):
    """A chain of 1,500 joints (a rope): read, written and read back (the reader and the
    writer recursed once per joint: RecursionError, a traceback, past ~1,000)."""
    n = 1500
    text = ["HIERARCHY"]
    for i in range(n):
        text += [f"{'ROOT' if i == 0 else 'JOINT'} link{i}", "{", "\tOFFSET 0 1 0",
                 "\tCHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation"
                 if i == 0 else "\tCHANNELS 3 Zrotation Xrotation Yrotation"]
    text += ["End Site", "{", "OFFSET 0 1 0", "}"] + ["}"] * n
    C = 6 + 3 * (n - 1)
    rows = [np.zeros(C), np.zeros(C)]
    rows[1][3] = 90.0  # the root turned 90 degrees about z: the chain lies along -x
    text += ["MOTION", "Frames: 2", "Frame Time: 8.3333e-3"]
    text += [" ".join(map(str, r)) for r in rows]
    (tmp_path / "rope.bvh").write_text("\r\n".join(text) + "\r\n")
    m = read_bvh(tmp_path / "rope.bvh")
    assert m.n_joints == n and m.parents[-1] == n - 2 and m.end_sites[0][0] == n - 1
    P, _ = forward_kinematics(m)
    np.testing.assert_allclose(P[1, -1], [-(n - 1), 0, 0], atol=1e-9)
    write_bvh(m, tmp_path / "out.bvh")
    r = read_bvh(tmp_path / "out.bvh")
    assert r.names == m.names and np.array_equal(r.parents, m.parents)
    assert np.array_equal(r.values, m.values) and r.channels == m.channels


TWO = """HIERARCHY
ROOT hip
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Yrotation Xrotation
  JOINT knee
  {
    OFFSET 0 -2 0
    CHANNELS 3 Zrotation Yrotation Xrotation
    End Site
    {
      OFFSET 0 -3 0
    }
  }
}
MOTION
Frames: 2
Frame Time: 0.0083333
0 0 0 0 0 0 10 20 30
1 0 0 5 0 0 15 25 35
"""


@pytest.mark.parametrize("channels, line, fragment", [
    ("CHANNELS 3 Xrotation Xrotation Yrotation", 9, "two rotations about one axis in a row"),
    ("CHANNELS 4 Zrotation Yrotation Xrotation Zrotation", 9, "4 rotation channels"),
    ("CHANNELS 3 Xposition Xposition Zrotation", 9, "Xposition appears twice"),
])
def test_channel_lists_without_one_transform_are_refused(tmp_path, capsys, channels, line,
                                                         fragment):
    """Two rotations about one axis in a row have no Euler order, a position channel twice
    has no one value, 4 rotation channels are no Euler angles: they were read, and blend /
    close then stopped with an internal error (scipy's ValueError, a KeyError: exit 3)."""
    text = TWO.replace("CHANNELS 3 Zrotation Yrotation Xrotation", channels)
    if channels.startswith("CHANNELS 4"):
        text = text.replace(" 10 20 30", " 10 20 30 0").replace(" 15 25 35", " 15 25 35 0")
    p = tmp_path / "bad.bvh"
    p.write_text(text)
    with pytest.raises(ShellsplineError) as e:
        read_bvh(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}:{line}: CHANNELS of knee: ") and fragment in msg
    assert "\n" not in msg
    names = channels.split()[2:]
    with pytest.raises(ShellsplineError, match=f"joint 'knee': .*{fragment}"):
        Motion(("hip", "knee"), [-1, 0], np.zeros((2, 3)),
               (("Xposition",), tuple(names)), 0.1, np.zeros((2, 1 + len(names))))
    code, _, err = run(capsys, "blend", p, p, "-o", tmp_path / "b.bvh")
    assert code == 2 and len(err.strip().splitlines()) == 1 and fragment in err


@pytest.mark.parametrize("old, new, line, what", [
    ("OFFSET 0 -2 0", "OFFSET 0 nan 0", 8, "OFFSET of knee"),
    ("OFFSET 0 -3 0", "OFFSET 0 -inf 0", 12, "End Site OFFSET of knee"),
])
def test_non_finite_offsets_are_refused(tmp_path, old, new, line, what):
    """A NaN or infinite OFFSET was read and turned every position below it into NaN."""
    p = tmp_path / "m.bvh"
    p.write_text(TWO.replace(old, new))
    with pytest.raises(ShellsplineError, match=f"^{p}:{line}: {what}: expected a finite "
                                               "number"):
        read_bvh(p)
    with pytest.raises(ShellsplineError, match="OFFSET of joint 'knee' is not finite"):
        Motion(("hip", "knee"), [-1, 0], [[0, 0, 0], [0, np.nan, 0]], ((), ()), 0.1,
               np.zeros((1, 0)))


def test_write_refuses_what_would_not_read_back(tmp_path):
    """A non-finite channel value or a joint name with a line break was written, and the
    file then could not be read (or read as another skeleton); nothing is written now."""
    p = tmp_path / "two.bvh"
    p.write_text(TWO)
    m = read_bvh(p)
    values = m.values.copy()
    values[1, 7] = np.nan
    bad = Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, values, m.end_sites)
    with pytest.raises(ShellsplineError, match="frame 1 has a non-finite value .* joint 'knee'"):
        write_bvh(bad, tmp_path / "nan.bvh")
    assert not (tmp_path / "nan.bvh").exists()
    for name in ("kn\nee", "", "knee {"):
        bad = Motion(("hip", name), m.parents, m.offsets, m.channels, m.frame_time,
                     m.values, m.end_sites)
        with pytest.raises(ShellsplineError, match="cannot be written"):
            write_bvh(bad, tmp_path / "name.bvh")
        assert not (tmp_path / "name.bvh").exists()

