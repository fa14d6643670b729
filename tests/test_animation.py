"""Skeletal animations as curves: BVH <-> SO(3)^d x R^m, resampling, up axis, feet, contacts,
foot skate, seam gap, and the SRV operations (distance, align, blend, close) on real and
synthetic clips of several channel layouts."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import data_synth.motion as synth
from shellspline import animation as A
from shellspline.errors import ShellsplineError
from shellspline.groups import so3
from shellspline.io.bvh import Motion, euler_matrices, forward_kinematics, read_bvh, write_bvh

from conftest import shared_data

REAL = ["dataset-1_walk_normal_001.bvh", "dataset-1_walk_tired_001.bvh",
        "dataset-1_walk_happy_001.bvh", "dataset-1_run_normal_001.bvh", "sinusoidal.bvh"]


def real(name="dataset-1_walk_normal_001.bvh") -> Motion:
    return read_bvh(shared_data("motion", name))


LAYOUTS = [dict(channels=3, order="ZYX", up="y", fps=120.0),
           dict(channels=3, order="XYZ", up="z", fps=120.0, scale=0.01),
           dict(channels=6, order="mixed", up="y", fps=30.0),
           dict(channels=6, order="ZXY", up="z", fps=60.0, names="numbered")]


# ----------------------------------------------------------------------------------------
# Motion <-> curve
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", REAL)
def test_round_trip_real_files(name):
    m = real(name)
    c = A.motion_curve(m)
    assert c.R.shape == (m.n_frames, m.n_joints, 3, 3)
    back = c.to_motion()
    assert back.channels == m.channels and back.frame_time == m.frame_time
    assert np.abs(back.values - m.values).max() <= 1e-9
    # the rotations are the file's: forward kinematics agrees
    assert np.allclose(forward_kinematics(back)[0], forward_kinematics(m)[0], atol=1e-9)


@pytest.mark.parametrize("layout", LAYOUTS)
def test_round_trip_synthetic_layouts_through_files(layout, tmp_path):
    m = synth.motion(seconds=1.0, **layout)
    p = write_bvh(m, tmp_path / "w.bvh")
    r = read_bvh(p)
    back = A.motion_curve(r).to_motion()
    assert np.abs(back.values - r.values).max() <= 1e-9
    write_bvh(back, tmp_path / "back.bvh")
    assert np.array_equal(read_bvh(tmp_path / "back.bvh").values, back.values)


def test_layouts_describe_one_motion():
    """The same walk in two layouts has the same world joint positions (up axis turned)."""
    a = synth.motion(seconds=0.5, fps=30, channels=3, order="ZYX", up="y")
    b = synth.motion(seconds=0.5, fps=30, channels=6, order="mixed", up="z")
    Pa, Pb = forward_kinematics(a)[0], forward_kinematics(b)[0]
    Q = Rotation.from_euler("x", 90, degrees=True).as_matrix()
    assert np.allclose(Pa @ Q.T, Pb, atol=1e-9)


@pytest.mark.parametrize("axes", ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "ZXZ", "YXY"])
def test_euler_angles_invert_euler_matrices(axes):
    rng = np.random.default_rng(1)
    R = Rotation.random(200, random_state=rng).as_matrix()
    ang = A.euler_angles(R, axes)
    assert np.allclose(euler_matrices(ang, axes), R, atol=1e-12)
    # a reference a few turns away: the same rotations, angles within 180 deg of it
    ref = ang + 720.0 + rng.uniform(-60, 60, ang.shape)
    near = A.euler_angles(R, axes, reference=ref)
    assert np.allclose(euler_matrices(near, axes), R, atol=1e-12)
    assert np.all(np.abs(near - ref) <= 180.0 + 1e-9)


def test_euler_angles_pick_the_second_solution_near_the_reference():
    a = np.array([[30.0, 120.0, -20.0]])  # beyond 90 deg: not scipy's principal solution
    R = euler_matrices(a, "ZXY")
    assert not np.allclose(A.euler_angles(R, "ZXY"), a)
    assert np.allclose(A.euler_angles(R, "ZXY", reference=a + 1.0), a, atol=1e-9)


def test_round_trip_at_gimbal_lock_is_bit_exact():
    vals = np.array([[10.0, 90.0, 30.0], [-45.0, -90.0, 170.0], [0.0, 89.9999999, 0.0],
                     [400.0, 720.0 + 90.0, -500.0]])
    m = Motion(("r",), [-1], np.zeros((1, 3)), (("Zrotation", "Xrotation", "Yrotation"),), 0.01,
               vals)
    assert np.array_equal(A.motion_curve(m).to_motion().values, vals)
    # and the second and following frames of a changed clip still follow the branches
    c = A.motion_curve(m)
    R = c.R.copy()
    R[0] = R[0] @ so3.exp(np.array([[0.0, 1e-3, 0.0]]))
    back = c.with_samples(R, c.X).to_motion()
    assert np.array_equal(back.values[1:], vals[1:])
    assert np.allclose(euler_matrices(back.values[0], "ZXY"), R[0, 0], atol=1e-12)


def test_one_and_two_axis_joints():
    m = Motion(("r", "c"), [-1, 0], np.zeros((2, 3)),
               (("Xposition", "Yrotation"), ("Zrotation", "Xrotation")), 0.05,
               [[0.0, 10.0, 20.0, -30.0], [1.0, 200.0, 25.0, -35.0]])
    back = A.motion_curve(m).to_motion()
    assert np.abs(back.values - m.values).max() <= 1e-9


# ----------------------------------------------------------------------------------------
# Resampling
# ----------------------------------------------------------------------------------------
def test_resample_keeps_frames_and_interpolates_geodesically():
    m = real()
    up = A.resample(m, frame_time=m.frame_time / 4)
    assert up.n_frames == 4 * (m.n_frames - 1) + 1
    assert np.abs(up.values[::4] - m.values).max() <= 1e-9
    Ra, Rm, Rb = (A.motion_curve(up).R[k] for k in (0, 2, 4))
    half = so3.angle(np.swapaxes(Ra, -1, -2) @ Rb) / 2
    assert np.allclose(so3.angle(np.swapaxes(Ra, -1, -2) @ Rm), half, atol=1e-9)
    assert np.allclose(so3.angle(np.swapaxes(Rm, -1, -2) @ Rb), half, atol=1e-9)


def test_resample_120hz_to_30hz_gives_the_30hz_clip():
    hi = synth.motion(fps=120.0, seconds=1.0, channels=3, order="XYZ")
    lo = synth.motion(fps=30.0, seconds=1.0, channels=3, order="XYZ")
    r = A.resample(hi, frame_time=1 / 30)
    assert r.n_frames == lo.n_frames
    assert np.abs(r.values - lo.values).max() <= 1e-9


def test_common_grid_rejects_other_skeletons():
    a = synth.motion(seconds=0.5, channels=3)
    b = synth.motion(seconds=0.5, channels=6)
    with pytest.raises(ShellsplineError, match="different skeletons"):
        A.common_grid(a, b)


def test_clips_of_one_rig_in_other_euler_orders_are_one_skeleton():
    # the same rig exported with ZXY (CMU) and YXZ/XYZ (another tool) rotation channels was
    # refused as "different skeletons"; the rotations are the same, so distance, alignment and
    # blend must be those of the clip written in the first clip's order
    a = synth.motion(fps=60, seconds=1.2, channels=3, order="ZXY")
    b_same = synth.motion(fps=30, seconds=1.4, channels=3, order="ZXY", cadence=0.9)
    b_other = synth.motion(fps=30, seconds=1.4, channels=3, order="YXZ", cadence=0.9)
    assert A.skeleton_mismatch(a, b_other) is None
    conv = A.with_channel_layout(b_other, a)
    assert conv.channels == a.channels
    np.testing.assert_allclose(A.motion_curve(conv).R, A.motion_curve(b_other).R, atol=1e-12)
    np.testing.assert_allclose(conv.values, b_same.values, atol=1e-9)  # same angles as ZXY
    assert A.distance(a, b_other, align="none") == pytest.approx(
        A.distance(a, b_same, align="none"), rel=1e-12)
    # the DP warp's refinement ends apart from rounding-level differences (README: to 0.1 %)
    assert A.distance(a, b_other) == pytest.approx(A.distance(a, b_same), rel=5e-3)
    m_other, _ = A.blend(a, b_other, 0.5, align="none")
    m_same, _ = A.blend(a, b_same, 0.5, align="none")
    assert m_other.channels == a.channels
    np.testing.assert_allclose(A.motion_curve(m_other).R, A.motion_curve(m_same).R, atol=1e-9)
    # fewer rotation channels, or other position channels, stay another skeleton
    two = Motion(("r",), [-1], np.zeros((1, 3)), (("Zrotation", "Xrotation"),), 0.1,
                 np.zeros((2, 2)))
    two_b = Motion(("r",), [-1], np.zeros((1, 3)), (("Xrotation", "Zrotation"),), 0.1,
                   np.zeros((2, 2)))
    assert "channels Zrotation Xrotation against Xrotation Zrotation" in \
        A.skeleton_mismatch(two, two_b)
    with pytest.raises(ShellsplineError, match="different skeletons"):
        A.with_channel_layout(two_b, two)


# ----------------------------------------------------------------------------------------
# Up axis, feet, contacts, skate
# ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("layout", LAYOUTS)
def test_up_axis_and_feet_of_synthetic_layouts(layout):
    m = synth.motion(seconds=1.0, **layout)
    assert A.up_axis(m) == ((1 if layout["up"] == "y" else 2), 1.0)
    toes = {14, 18}  # toe_l, toe_r (the names are not used: "numbered" layouts too)
    assert set(A.find_feet(m)) == toes


def test_up_override_and_bad_up():
    m = synth.motion(seconds=0.5)
    assert A.foot_contacts(m, up="+y").up == (1, 1.0)
    with pytest.raises(ShellsplineError, match="up axis"):
        A.foot_contacts(m, up="w")


def test_real_walk_feet_and_periodic_contacts():
    m = real()
    assert A.up_axis(m) == (1, 1.0)
    c = A.foot_contacts(m)
    assert sorted(m.names[f] for f in c.feet) == ["Toes_L", "Toes_R"]
    on = [c.onsets(i) for i in range(2)]
    assert all(o.size >= 5 for o in on)
    steps = np.concatenate([np.diff(o) for o in on])
    period = np.median(steps)
    assert np.ptp(steps) <= 0.15 * period  # regular gait
    # the feet alternate: every touch-down of one foot lies between two of the other's
    merged = np.sort(np.concatenate([on[0], on[1]]))
    owner = np.isin(merged, on[1]).astype(int)
    assert np.all(np.diff(owner) != 0)
    # independent oracle: the period of the toe height from its autocorrelation
    h = c.heights[:, 0, 0] - c.heights[:, 0, 0].mean()
    ac = np.correlate(h, h, "full")[h.size - 1:]
    lag = 10 + np.argmax(ac[10:60])
    assert abs(lag - period) <= 0.1 * period
    # every step's lowest foot height is reached while the foot is planted
    for i in range(2):
        H = c.heights[:, i].min(axis=1)
        for a, b in zip(on[i][:-1], on[i][1:]):
            f = a + np.argmin(H[a:b])
            assert c.contact[f, i]


def test_foot_skate_is_translation_invariant_and_fixed_by_planting():
    m = real()
    c = A.foot_contacts(m)
    s0 = A.foot_skate(m, c)
    assert s0["contact_frames"] > 100 and s0["drift"] > 0
    # a constant shift of the whole clip changes nothing
    v = m.values.copy()
    v[:, A.motion_curve(m).pos_cols[:3]] += [5.0, 0.0, -7.0]
    shifted = Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)
    assert np.isclose(A.foot_skate(shifted, c)["drift"], s0["drift"], rtol=1e-9)
    # a root drift of 1 unit per frame adds sliding; planting removes it and more
    v = m.values.copy()
    root_x = m.channel_columns(0)[0]
    v[:, root_x] += np.arange(m.n_frames) * 1.0
    slid = Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)
    s1 = A.foot_skate(slid, c)
    assert s1["drift"] > s0["drift"] + 0.5 * s0["contact_frames"] * 0.5
    fixed = A.plant_feet(slid, c)
    s2 = A.foot_skate(fixed, c)
    assert s2["drift"] < 0.25 * s0["drift"]
    # single support is exact: the planted point of the one planted foot does not move
    both = c.joint_contact[1:] & c.joint_contact[:-1]  # (T-1, feet, joints)
    single = both.any(axis=2).sum(axis=1) == 1
    P = forward_kinematics(fixed)[0][:, np.array(c.joints)][..., [0, 2]]
    step = np.where(both, np.linalg.norm(np.diff(P, axis=0), axis=-1), np.inf)
    assert single.sum() > 50
    assert step[single].min(axis=2).min(axis=1).max() <= 1e-9


def test_seam_gap_of_a_periodic_clip_is_zero():
    m = real()
    v = np.vstack([m.values[:100], m.values[:1]])
    loop = Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)
    g = A.seam_gap(loop)
    assert g["rotation_max"] <= 1e-9 and g["position_max"] <= 1e-9 and g["energy"] <= 1e-20
    g = A.seam_gap(m)
    assert g["rotation_max"] > 5 and g["energy"] > 0.01


# ----------------------------------------------------------------------------------------
# Distance, alignment, blending
# ----------------------------------------------------------------------------------------
def test_distance_zero_and_symmetric():
    a = real()
    b = real("dataset-1_walk_tired_001.bvh")
    assert A.distance(a, a, align="none") == 0.0
    assert A.distance(a, a) <= 1e-9
    for how in ("none", "dp"):
        dab, dba = A.distance(a, b, align=how), A.distance(b, a, align=how)
        assert dab > 0.1 and np.isclose(dab, dba, rtol=1e-9)
    assert A.distance(a, b) < A.distance(a, b, align="none")


def test_distance_between_frame_rates():
    """A 120 Hz clip and the same walk at 30 Hz are at distance ~0; another cadence is not."""
    hi = synth.motion(fps=120.0, seconds=1.0, channels=3, order="ZYX")
    lo = synth.motion(fps=30.0, seconds=1.0, channels=3, order="ZYX")
    other = synth.motion(fps=120.0, seconds=1.0, channels=3, order="ZYX", cadence=1.3)
    d_same = A.distance(hi, lo, align="none")  # on the 120 Hz grid: chords against arcs
    assert d_same < 0.2 * A.distance(hi, other, align="none")
    assert A.distance(A.resample(hi, frame_time=1 / 30), lo, align="none") <= 1e-9


def test_align_recovers_a_known_warp():
    a = real()
    t = np.linspace(0, 1, a.n_frames)
    b = A.warp_motion(a, t ** 1.5)  # b(u) = a(u^1.5)
    r = A.align(b, a)  # a(phi(t)) = b(t): phi = t^1.5
    assert np.abs(r.phi - r.t ** 1.5).max() <= 0.005
    assert r.distance_after < 0.2 * r.distance_before
    assert np.allclose(r.seconds[:, 1], r.phi * (a.n_frames - 1) * a.frame_time)


def test_contact_features_pair_touchdowns():
    a = real()
    b = real("dataset-1_walk_tired_001.bvh")
    F = A.contact_features(a, b)
    assert F.shape[0] >= 8 and np.all(np.diff(F[:, 0]) > 0) and np.all(np.diff(F[:, 1]) > 0)
    r = A.align(a, b, features="contacts", lam=50.0)
    free = A.align(a, b)

    def miss(rep, F=F, n=b.n_frames):  # mean distance of paired touch-downs, in frames
        return np.abs(np.interp(F[:, 0], rep.t, rep.phi) - F[:, 1]).mean() * (n - 1)
    # both within 0.7 frames here: the features may not pull it farther (0.05 frame: the
    # refinement's rounding-level ends, e.g. with or without a 0.5 degree heading turn)
    assert miss(r) <= miss(free) + 0.05
    # seed 003 Fig. 3 on real data: without features the DP matches a step of walk_happy
    # with the next one; the touch-downs (default weight) pull it back to within ~1 frame
    h = real("dataset-1_walk_happy_001.bvh")
    Fh = A.contact_features(a, h)
    free, pulled = A.align(a, h), A.align(a, h, features="contacts")
    assert miss(free, Fh, h.n_frames) > 5 and miss(pulled, Fh, h.n_frames) < 2
    assert pulled.distance_after < 1.05 * free.distance_after
    with pytest.raises(ShellsplineError, match="features"):
        A.align(a, b, features="feet")
    with pytest.raises(ShellsplineError, match="within the clips"):
        A.align(a, b, features=[[0.0, 100.0]])


def test_blend_of_a_motion_with_itself_is_the_motion():
    a = real()
    for how in ("none", "dp"):
        m, _ = A.blend(a, a, 0.5, align=how)
        assert m.n_frames == a.n_frames and m.frame_time == a.frame_time
        assert np.abs(m.values - a.values).max() <= 1e-9


def test_blend_ends_and_timing():
    a = real()
    b = real("dataset-1_walk_happy_001.bvh")
    m0, _ = A.blend(a, b, 0.0, align="none")
    assert m0.n_frames == a.n_frames
    # s = 0 is a (it was a resampled to the common grid and back: 5 degrees off)
    Pa, P0 = forward_kinematics(a)[0], forward_kinematics(m0)[0]
    assert np.abs(Pa - P0).max() < 1e-9 * A.body_height(a)
    for heading in ("align", "keep"):
        m1, _ = A.blend(a, b, 1.0, align="dp", heading=heading)
        assert m1.n_frames == b.n_frames
        # s = 1 plays b where it was recorded (where the DP warp is steep, blending on a's
        # grid alone skipped frames of b: 8 % of the body height, 1.7 degrees on the grid)
        assert np.abs(forward_kinematics(m1)[0] - forward_kinematics(b)[0]).max() \
            <= 1e-9 * A.body_height(b)
    mh, rep = A.blend(a, b, 0.5)
    dur = (mh.n_frames - 1) * mh.frame_time
    da, db = ((x.n_frames - 1) * x.frame_time for x in (a, b))
    assert abs(dur - 0.5 * (da + db)) <= mh.frame_time
    assert rep.distance_after < rep.distance_before


def test_blend_with_planted_feet_slides_less():
    a = real()
    b = real("dataset-1_walk_tired_001.bvh")
    m, _ = A.blend(a, b, 0.5)
    p, _ = A.blend(a, b, 0.5, plant=True)
    assert A.foot_skate(p)["speed"] < 0.3 * A.foot_skate(m)["speed"]
    # only the hips' horizontal channels changed (the static joint_Root above stays put)
    changed = np.flatnonzero(np.abs(p.values - m.values).max(axis=0) > 0)
    assert set(changed) <= {6, 8}


def test_blend_across_frame_rates_and_layouts():
    a = synth.motion(fps=120.0, seconds=1.0, channels=3, order="mixed", up="z")
    b = synth.motion(fps=30.0, seconds=1.5, channels=3, order="mixed", up="z", cadence=0.7)
    m, _ = A.blend(a, b, 0.5)
    assert m.frame_time == a.frame_time and m.channels == a.channels
    assert abs((m.n_frames - 1) * m.frame_time - 1.25) <= m.frame_time
    with pytest.raises(ShellsplineError, match="align must be"):
        A.blend(a, b, 0.5, align="dtw")
    # the same walk at 120 and 30 Hz blends into itself (at 120 Hz): world joints within
    # 0.5 % of the body height (chords of the 30 Hz clip against arcs)
    lo = synth.motion(fps=30.0, seconds=1.0, channels=3, order="mixed", up="z")
    m, _ = A.blend(a, lo, 0.5)
    assert m.n_frames == a.n_frames
    err = np.abs(forward_kinematics(m)[0] - forward_kinematics(a)[0]).max()
    assert err <= 0.005 * A.body_height(a)
    # s = 1 without alignment is the second clip; s = 0 is the first at the finer rate:
    # its own frames every fourth frame, the geodesics between them in between
    m1, _ = A.blend(lo, a, 1.0, align="none")
    assert np.abs(forward_kinematics(m1)[0] - forward_kinematics(a)[0]).max() <= 1e-9
    for how in ("none", "dp"):
        m0, _ = A.blend(lo, a, 0.0, align=how)
        assert m0.n_frames == 4 * (lo.n_frames - 1) + 1 and m0.frame_time == a.frame_time
        assert max(pose_gap(m0.frames(0, m0.n_frames, 4), lo)) <= 1e-9
        assert max(pose_gap(m0, A.resample(lo, frame_time=a.frame_time))) <= 1e-9


def pose_gap(m: Motion, ref: Motion) -> tuple[float, float]:
    """Largest joint rotation between two clips of one skeleton (degrees, frame by frame)
    and largest difference of their position channels (file units)."""
    cm, cr = A.motion_curve(m), A.motion_curve(ref)
    assert cm.R.shape == cr.R.shape
    ang = np.degrees(so3.angle(np.swapaxes(cm.R, -1, -2) @ cr.R)).max()
    return float(ang), float(np.abs(cm.X - cr.X).max())


BLENDS = [("none", "keep"), ("none", "align"), ("dp", "align")]


@pytest.mark.parametrize("first,second", [
    ("dataset-1_walk_normal_001.bvh", "dataset-1_walk_happy_001.bvh"),
    ("dataset-1_walk_happy_001.bvh", "dataset-1_walk_normal_001.bvh")])
def test_blend_at_0_and_1_is_each_real_clip(first, second):
    """s = 0 is a and s = 1 is b (README) for clips of different lengths at one frame rate:
    walk_normal (195 frames) blended with walk_happy (213) at s = 0 was walk_normal resampled
    to 213 frames and back, 5.0 degrees off at Toes_R and 0.15 units at the hips; s = 1 with
    the DP warp 1.7 degrees off b. Oracle: the clips' own frames (b where it was recorded)."""
    a, b = real(first), real(second)
    assert a.frame_time == b.frame_time and a.n_frames != b.n_frames
    for how, heading in BLENDS:
        m0, _ = A.blend(a, b, 0.0, align=how, heading=heading)
        m1, _ = A.blend(a, b, 1.0, align=how, heading=heading)
        assert (m0.n_frames, m0.frame_time) == (a.n_frames, a.frame_time)
        assert (m1.n_frames, m1.frame_time) == (b.n_frames, b.frame_time)
        assert max(pose_gap(m0, a)) <= 1e-9, (how, heading)
        assert max(pose_gap(m1, b)) <= 1e-9, (how, heading)


def test_blend_at_0_and_1_is_each_synthetic_clip():
    """The same on synthetic walks of different lengths at one rate, b another walk (slower
    cadence) turned 90 degrees and moved elsewhere on the ground: s = 0 is a, s = 1 is b
    where it was recorded, both ways round; an output frame sits exactly on each source
    frame. Before, the blend ran on a grid of the longer clip's frame count over each
    clip's span, which does not contain the shorter clip's frame times."""
    a = synth.motion(fps=30.0, seconds=2.0, channels=3, order="ZXY")
    b = turned_on_ground(synth.motion(fps=30.0, seconds=2.7, channels=3, order="ZXY",
                                      cadence=0.8, speed=100.0), 90.0, [250.0, 0.0, -80.0])
    assert (a.n_frames, b.n_frames) == (61, 82)
    for x, y in ((a, b), (b, a)):
        for how, heading in BLENDS:
            m0, _ = A.blend(x, y, 0.0, align=how, heading=heading)
            m1, _ = A.blend(x, y, 1.0, align=how, heading=heading)
            assert m0.n_frames == x.n_frames and m1.n_frames == y.n_frames
            assert max(pose_gap(m0, x)) <= 1e-9, (how, heading)
            assert max(pose_gap(m1, y)) <= 1e-9, (how, heading)
            H = A.body_height(x)
            assert np.abs(forward_kinematics(m1)[0] - forward_kinematics(y)[0]).max() \
                <= 1e-9 * H


def test_blend_varies_continuously_with_s():
    """Near the ends the blend is near the clips (a Lipschitz bound in s), and the frame
    count follows the blended duration (61 frames of a at s = 0 to 82 of b at s = 1)."""
    a = synth.motion(fps=30.0, seconds=2.0, channels=3, order="ZXY")
    b = synth.motion(fps=30.0, seconds=2.7, channels=3, order="ZXY", cadence=0.8,
                     speed=100.0)
    for how in ("none", "dp"):
        near0, _ = A.blend(a, b, 1e-7, align=how)
        near1, _ = A.blend(a, b, 1 - 1e-7, align=how)
        assert near0.n_frames == a.n_frames and near1.n_frames == b.n_frames
        ang0, x0 = pose_gap(near0, a)
        ang1, x1 = pose_gap(near1, b)
        assert ang0 < 1e-4 and ang1 < 1e-4, (how, ang0, ang1)
        assert x0 < 1e-4 * A.body_height(a) and x1 < 1e-4 * A.body_height(b)
    frames = [A.blend(a, b, s, align="none")[0].n_frames for s in np.linspace(0, 1, 11)]
    assert frames == [int(round(60 + 21 * s)) + 1 for s in np.linspace(0, 1, 11)]


# ----------------------------------------------------------------------------------------
# Closing
# ----------------------------------------------------------------------------------------
def test_closing_a_real_walk():
    m = real()
    out, r = A.close(m, iterations=10)
    assert r.iterations <= 10 and r.history[0] >= 100 * r.history[-1]
    assert r.gap_before["rotation_max"] > 20 and r.gap_after["rotation_max"] <= 1e-6
    assert r.gap_after["position_max"] <= 1e-6 * A.body_height(m)
    assert out.n_frames == m.n_frames and out.channels == m.channels
    # the rest of the motion is kept: the middle frame moves little
    Pm, Po = forward_kinematics(m)[0], forward_kinematics(out)[0]
    mid = m.n_frames // 2
    rel = lambda P: P[mid, 1:] - P[mid, 1:2]  # noqa: E731  (pose relative to the hips)
    assert np.abs(rel(Pm) - rel(Po)).max() < 0.1 * A.body_height(m)
    # the walk still travels (root motion kept), the planted feet slide less than before
    hips = lambda P: P[-1, 1, [0, 2]] - P[0, 1, [0, 2]]  # noqa: E731
    assert np.linalg.norm(hips(Po) - hips(Pm)) < 0.05 * np.linalg.norm(hips(Pm))
    assert r.skate_after["speed"] < 0.1 * r.skate_before["speed"]
    assert r.skate_after["speed"] < 0.1 * r.skate_closed["speed"]
    # without planting, the closed clip is returned as closed
    out2, r2 = A.close(m, iterations=10, plant=False)
    assert r2.skate_after == r2.skate_closed


def test_trimmed_closing_changes_the_walk_less():
    m = real()
    start, stop = A.loop_range(m)
    assert stop - start >= 0.5 * (m.n_frames - 1)
    # the chosen ends are closer than the clip's own ends (pose and next pose)
    R = A.motion_curve(m).R
    d = lambda i, j: np.sum((R[i] - R[j]) ** 2) + np.sum((R[i + 1] - R[j + 1]) ** 2)  # noqa
    assert d(start, stop) < 0.1 * d(0, m.n_frames - 2)

    def change(out, r):
        src = m.frames(r.frames[0], r.frames[1] + 1)
        P0, P1 = forward_kinematics(src)[0], forward_kinematics(out)[0]
        return np.linalg.norm((P0[:, 1:] - P0[:, 1:2]) - (P1[:, 1:] - P1[:, 1:2]), axis=2).mean()
    full, rf = A.close(m, plant=False)
    cut, rc = A.close(m, plant=False, trim=True)
    assert rc.frames == (start, stop) and cut.n_frames == stop - start + 1
    assert rc.gap_after["rotation_max"] <= 1e-6
    assert change(cut, rc) < 0.5 * change(full, rf)
    with pytest.raises(ShellsplineError, match="min_fraction"):
        A.loop_range(m, min_fraction=0.0)


def test_closing_c1_removes_the_velocity_jump():
    m = real().frames(0, 120)
    _, r0 = A.close(m, iterations=10)
    _, r1 = A.close(m, iterations=10, c1=True)
    assert r1.history[-1] <= 1e-9 * r1.history[0]
    assert r1.velocity_jump[-1] < 1e-6 * r1.velocity_jump[0]
    assert r0.velocity_jump[-1] > 100 * r1.velocity_jump[-1]


def test_closing_with_the_root_closed_and_other_layouts():
    m = synth.motion(fps=120.0, seconds=1.3, channels=3, order="mixed", up="z")
    out, r = A.close(m, root_motion="close")
    g = A.seam_gap(out, root_motion="close")
    assert g["position_max"] <= 1e-6 * A.body_height(m) and g["rotation_max"] <= 1e-6
    with pytest.raises(ShellsplineError, match="root_motion"):
        A.close(m, root_motion="open")
    with pytest.raises(ShellsplineError, match="3 frames"):
        A.close(m.frames(0, 2))


# ----------------------------------------------------------------------------------------
# Mesh animations (LΘA descriptor curves)
# ----------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def skinned_walk():
    """One gait cycle of a body skinned to the real walk (frames 10..43)."""
    from data_synth.skinned import skinned_sequence

    Vs, F, _ = skinned_sequence(shared_data("motion", "dataset-1_walk_normal_001.bvh"),
                                start=10, stop=44, n_vertices=400)
    return Vs, F


def test_close_euclidean_matches_the_generic_closing():
    from shellspline.curves.closing import close
    from shellspline.curves.srv import ProductCurve

    t = np.linspace(0, 1, 40)
    rng = np.random.default_rng(0)
    X = np.c_[np.cos(5 * t), np.sin(4 * t), t ** 2, rng.normal(size=(40, 3)).cumsum(0) * 0.05]
    Xc, hist = A.close_euclidean(X)
    ref = close(ProductCurve(X=X))
    assert hist[-1] <= 1e-12 * hist[0] and np.allclose(Xc[0], X[0])
    assert np.abs(Xc - ref.curve.X).max() <= 1e-9


def test_mesh_close_makes_a_loop(skinned_walk):
    from shellspline.shells.reconstruct import rigid_placement

    Vs, F = skinned_walk
    out, rep = A.mesh_close(Vs, F)
    assert rep.converged == rep.frames == Vs.shape[0]
    assert rep.history[-1] <= 1e-9 * rep.history[0] and rep.descriptor_error < 1e-2
    gap = lambda V: np.abs(rigid_placement(V[-1], V[0]) - V[0]).max()  # noqa: E731
    assert gap(out) < 1e-3 * gap(Vs)
    assert np.abs(out - Vs).max() < 0.05 * np.ptp(Vs[0], axis=0).max()
    # the closing is close_euclidean's: the generic closing takes the same steps
    mc = A.mesh_curve(Vs, F)
    assert np.array_equal(rep.history, A.close_euclidean(mc.Z * mc.sqrt_w)[1])
    assert mc.Z.shape[1] > A.MESH_C1_MAX_DIMS
    with pytest.raises(ShellsplineError, match="c1 closing of .* descriptors"):
        A.mesh_close(Vs, F, c1=True)


def test_mesh_c1_close_of_a_small_mesh():
    from shellspline.curves.closing import close
    from data_synth.skinned import skinned_sequence

    Vs, F, _ = skinned_sequence(shared_data("motion", "dataset-1_walk_normal_001.bvh"),
                                start=10, stop=30, n_vertices=100)
    mc = A.mesh_curve(Vs, F)
    assert mc.Z.shape[1] <= A.MESH_C1_MAX_DIMS
    out, rep = A.mesh_close(Vs, F, c1=True)
    ref = close(mc.product_curve(), c1=True)
    assert np.array_equal(rep.history, ref.seam_gap)
    assert rep.history[-1] <= 1e-9 * rep.history[0] and rep.descriptor_error < 1e-2


def test_mesh_blend_and_align(skinned_walk):
    Vs, F = skinned_walk
    same, rep = A.mesh_blend(Vs, Vs, F, 0.5)
    assert np.abs(same - Vs).max() <= 1e-8 and rep.converged == Vs.shape[0]
    t = np.linspace(0, 1, Vs.shape[0])
    W = A.reparametrize_vertices(Vs, t ** 1.5)  # W(u) = Vs(u^1.5), linear between frames
    r = A.mesh_align(W, Vs, F)
    assert np.abs(r.phi - t ** 1.5).max() <= 0.03
    with pytest.raises(ShellsplineError, match="one mesh"):
        A.mesh_blend(Vs, Vs[:, :-1], F)


@pytest.mark.parametrize("how", ["none", "dp"])
def test_mesh_blend_ends_are_the_clips_themselves(skinned_walk, how):
    """Oracle: the clips. Of two clips of other lengths and rates (20 frames, and 13 at half
    the rate), s = 0 is the first and s = 1 the second, frame for frame; 1e-6 from s = 1 the
    blend is within 1e-6 of the second (continuous in s). It ran on the first clip's frames:
    s = 1 was the second resampled onto them (20 frames)."""
    Vs, F = skinned_walk
    a, b = Vs[:20], Vs[8:34:2]
    size = np.ptp(Vs.reshape(-1, 3), axis=0).max()
    for s, ref in ((0.0, a), (1.0, b)):
        out, rep = A.mesh_blend(a, b, F, s, align=how)
        assert out.shape == ref.shape and rep.converged == ref.shape[0]
        assert np.abs(out - ref).max() <= 1e-9 * size
    near, _ = A.mesh_blend(a, b, F, 1 - 1e-6, align=how)
    assert near.shape == b.shape and np.abs(near - b).max() <= 1e-5 * size
    mid, rep = A.mesh_blend(a, b, F, 0.5, align=how)   # (19 + 12) / 2 intervals, rounded
    assert mid.shape == (17,) + Vs.shape[1:] and rep.converged == 17


def test_data_synth_motion_command(tmp_path, capsys):
    from data_synth.__main__ import main as synth_main

    out = tmp_path / "w.bvh"
    assert synth_main(["motion", str(out), "--fps", "120", "--order", "mixed", "--up", "z",
                       "--names", "numbered", "--seconds", "0.5"]) == 0
    m = read_bvh(out)
    assert m.n_frames == 61 and m.frame_time == 1 / 120 and m.names[0] == "j00"
    assert A.up_axis(m) == (2, 1.0)
    with pytest.raises(SystemExit):
        synth_main(["motion", str(out), "--order", "XXY"])
    capsys.readouterr()


def test_plant_feet_moves_a_carrier_below_a_rotated_root():
    """A root without position channels, turned 90 degrees about the up axis, above a hips
    joint that carries the travel: the correction goes through the root's rotation."""
    m = synth.motion(fps=60.0, seconds=1.5, channels=3, order="ZYX")
    J = m.n_joints
    names = ("ground",) + m.names
    parents = np.r_[-1, m.parents + 1]
    parents[1] = 0
    offsets = np.vstack([np.zeros(3), m.offsets])
    chans = (("Yrotation",),) + m.channels
    values = np.hstack([np.full((m.n_frames, 1), 90.0), m.values])
    v = values.copy()
    v[:, 3] += np.arange(m.n_frames) * 0.8  # hips Z drifts: planted feet slide
    turned = Motion(names, parents, offsets, chans, m.frame_time, v, tuple(
        (p + 1, o) for p, o in m.end_sites))
    c = A.foot_contacts(turned)
    assert c.contact.any() and J + 1 == turned.n_joints
    fixed = A.plant_feet(turned, c)
    assert A.foot_skate(fixed, c)["drift"] < 0.2 * A.foot_skate(turned, c)["drift"]
    assert np.array_equal(fixed.values[:, 0], turned.values[:, 0])  # the root is not moved


def test_contacts_do_not_depend_on_frame_rate_or_units():
    m = real()
    hi = A.resample(m, frame_time=m.frame_time / 4)  # 120 Hz
    c, ch = A.foot_contacts(m), A.foot_contacts(hi)
    for i in range(2):
        a, b = c.onsets(i) * 4, ch.onsets(i)
        assert a.size == b.size and np.abs(a - b).max() <= 4  # within one 30 Hz frame
    cm = synth.motion(fps=60.0, seconds=2.0, channels=3, order="ZXY")
    metres = synth.motion(fps=60.0, seconds=2.0, channels=3, order="ZXY", scale=0.01)
    assert np.array_equal(A.foot_contacts(cm).contact, A.foot_contacts(metres).contact)
    assert np.isclose(A.foot_contacts(metres).leg_length, 0.01 * A.foot_contacts(cm).leg_length)


# ----------------------------------------------------------------------------------------
# Held-out layouts (CMU, Mixamo-like, game rigs with fingers, short clips): the generator's
# own stance phase is the oracle for the contacts
# ----------------------------------------------------------------------------------------
HELD_OUT = {"cmu": dict(skeleton="cmu", fps=120.0, channels=3),
            "mixamo": dict(skeleton="cmu", names="mixamo", channels=6, fps=30.0),
            "fingers_zup": dict(skeleton="fingers", up="z", order="mixed", fps=30.0),
            "metres_lifted": dict(scale=0.01, lift=40.0, fps=60.0),
            "tpose_first": dict(skeleton="cmu", tpose_first=True, fps=30.0)}


@pytest.mark.parametrize("name", sorted(HELD_OUT))
def test_contacts_follow_the_true_stance_on_held_out_layouts(name):
    m = synth.motion(seconds=3.0, **HELD_OUT[name])
    fc = A.foot_contacts(m)
    names = [m.names[f].split(":")[-1] for f in fc.feet]  # "mixamorig:" prefix dropped
    cmu = HELD_OUT[name].get("skeleton") == "cmu"
    assert names == (["LeftToeBase", "RightToeBase"] if cmu else ["toe_l", "toe_r"])
    w = 2 * np.pi * np.arange(m.n_frames) * m.frame_time  # one gait cycle per second
    stance = np.stack([np.cos(w) <= 0, np.cos(w + np.pi) <= 0], axis=1)  # left, right
    agree = (fc.contact == stance).mean(axis=0)
    assert agree.min() >= 0.85, agree
    for i in range(2):  # one touch-down per foot and cycle, where the stance starts
        true_on = np.flatnonzero(stance[1:, i] & ~stance[:-1, i]) + 1
        on = fc.onsets(i)
        assert on.size == true_on.size == 3
        assert np.abs(on - true_on).max() * m.frame_time <= 0.1
    # the generator's planted foot does not slide: measured skate ~ 0 (FK, not the detector)
    P = forward_kinematics(m)[0]
    ax = 2 if HELD_OUT[name].get("up") == "z" else 1
    hor = [a for a in range(3) if a != ax]
    toe = P[:, list(fc.feet)][..., hor]
    mid = stance[1:] & stance[:-1]
    assert np.abs(np.diff(toe, axis=0)[mid[:, :]]).max() <= 1e-9 * fc.leg_length
    assert A.foot_skate(m, fc)["speed_per_leg"] <= 0.02


def test_contacts_drop_a_one_frame_brush():
    c = np.zeros((40, 1, 2), dtype=bool)
    c[5:20] = True
    c[11, 0, 0] = False  # one-frame gap inside a stance
    c[26] = True  # a one-frame brush of the ground after lift-off
    c[38:] = True  # a contact cut by the clip's end
    out = A._debounce(c, 3)
    want = np.zeros_like(c)
    want[5:20] = True
    want[38:] = True
    assert np.array_equal(out, want)


@pytest.mark.parametrize("name", ["cmu", "fingers_zup"])
def test_operations_on_held_out_layouts(name):
    m = synth.motion(seconds=1.3, **HELD_OUT[name])
    assert A.distance(m, m, align="none") == 0.0
    assert A.distance(m, m) <= 1e-12
    b, _ = A.blend(m, m, 0.5, features="contacts")
    assert b.n_frames == m.n_frames and np.abs(b.values - m.values).max() <= 1e-9
    out, rep = A.close(m)
    assert rep.success and rep.history[-1] <= 1e-2 * rep.history[0]
    g0, g1 = rep.gap_before, rep.gap_after
    assert g1["rotation_max"] <= 1e-2 * g0["rotation_max"]
    assert g1["position_max"] <= 1e-2 * g0["position_max"]
    # what the report says is what the file shows: last frame's rotations = first frame's
    c = A.motion_curve(out)
    assert so3.angle(c.R[-1] @ np.swapaxes(c.R[0], -1, -2)).max() <= 1e-6


def test_short_and_single_frame_clips():
    one = synth.motion(frames=1)
    assert one.n_frames == 1
    for f in (lambda: A.distance(one, one), lambda: A.blend(one, one),
              lambda: A.align(one, one), lambda: A.close(one)):
        with pytest.raises(ShellsplineError, match="frame"):
            f()
    three = synth.motion(frames=3, fps=30.0)
    assert A.loop_range(three) == (0, 2)  # too short to trim: the whole clip
    out, rep = A.close(three, trim=True)
    assert rep.frames == (0, 2) and out.n_frames == 3 and rep.success


def test_root_only_and_tpose_first_clips():
    statue = synth.motion(root_only=True, fps=30.0, seconds=1.3)
    fc = A.foot_contacts(statue)
    assert not fc.contact.any()  # the feet slide with the root: never planted
    out, rep = A.close(statue)  # nothing but travel: already a loop, kept as root motion
    assert rep.success and np.abs(out.values - statue.values).max() <= 1e-9
    assert A.distance(statue, statue) <= 1e-12
    # a rest-pose first frame (as many exports start) is cut off by the trimmed closing
    tp = synth.motion(skeleton="cmu", tpose_first=True, fps=30.0, seconds=2.3)
    start, stop = A.loop_range(tp)
    assert start >= 1 and stop - start >= 0.5 * (tp.n_frames - 1)
    assert A.up_axis(tp) == (1, 1.0)


# ----------------------------------------------------------------------------------------
# Rigid pose tracks: curves in SO(3) x R^3
# ----------------------------------------------------------------------------------------
def camera(lo=500, hi=900):
    """A window of the real TUM camera trajectory (100 Hz, jittered clock)."""
    from shellspline.io.posefiles import PoseTrack, read_poses

    tr = read_poses(shared_data("camera", "freiburg1_xyz-groundtruth.txt"))
    return PoseTrack(tr.t[lo:hi].copy(), tr.T[lo:hi].copy(), tr.format)


def moved(track, R=np.eye(3), x=np.zeros(3), scale=1.0, t=None):
    """``track`` with its rotations right-multiplied by ``R``, positions ``scale * p + x``."""
    from shellspline.io.posefiles import PoseTrack

    T = track.T.copy()
    T[:, :3, :3] = T[:, :3, :3] @ R
    T[:, :3, 3] = scale * T[:, :3, 3] + x
    return PoseTrack(track.t.copy() if t is None else t, T, track.format)


def test_track_curve_srv_against_scipy():
    """The track's SRV: rotation vectors of R_{i+1} R_i^T (scipy) and position steps / length,
    over dt, divided by the square root of their joint norm."""
    from shellspline.curves.srv import srv

    a = camera(500, 560)
    L = A.track_length(a)
    p = a.T[:, :3, 3]
    assert np.isclose(L, np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, axis=1))), rtol=1e-12)
    R = a.T[:, :3, :3]
    w = Rotation.from_matrix(R[1:] @ np.swapaxes(R[:-1], 1, 2)).as_rotvec()
    eta = np.c_[w, np.diff(p, axis=0) / L] / np.diff(a.t)[:, None]
    q = eta / np.sqrt(np.linalg.norm(eta, axis=1))[:, None]
    assert np.allclose(srv(A.track_curve(a, L)), q, rtol=1e-9, atol=1e-12)


def test_track_close_reduces_the_seam_gap_of_a_real_camera_track():
    a = camera()
    out, rep = A.track_close(a)
    g = rep.result.seam_gap
    assert g[-1] <= g[0] / 100 and rep.result.status == "converged"
    assert rep.rotation_gap[1] <= rep.rotation_gap[0] / 100
    assert rep.position_gap[1] <= rep.position_gap[0] / 100
    assert rep.rotation_gap[0] > 0.1 and rep.position_gap[0] > 0.1  # a real gap to close
    # the seam measured independently of the closing code
    assert np.abs(out.T[-1] - out.T[0]).max() <= 1e-9
    assert np.array_equal(out.t, a.t) and np.allclose(out.T[0], a.T[0], atol=1e-14)
    assert out.format == "tum" and rep.length == A.track_length(a)
    # C1: the velocity jump at the seam goes too
    out1, rep1 = A.track_close(a, c1=True)
    v = rep1.result.velocity_jump
    assert v[-1] <= v[0] / 100 and np.abs(out1.T[-1] - out1.T[0]).max() <= 1e-9


@pytest.mark.parametrize("fmt", ["tum", "kitti", "euroc", "csv", "json"])
def test_closed_track_reads_back_in_every_format(fmt, tmp_path):
    from shellspline.io.posefiles import PoseTrack, read_poses, write_poses

    a = camera(500, 700)
    if fmt == "kitti":
        a = PoseTrack(np.arange(a.t.size, dtype=np.float64), a.T, "kitti")
    elif fmt == "euroc":
        a = PoseTrack(a.t - a.t[0], a.T, "euroc", origin_ns=1403636579758555392)
    else:
        a = PoseTrack(a.t, a.T, fmt)
    out, _ = A.track_close(a)
    assert out.format == fmt and out.origin_ns == a.origin_ns
    path = tmp_path / f"loop.{'json' if fmt == 'json' else 'txt'}"
    write_poses(path, out.t, out.T, out.format, origin_ns=out.origin_ns)
    back = read_poses(path)
    assert back.format == fmt and back.origin_ns == a.origin_ns
    assert np.allclose(back.t, a.t, rtol=0, atol=1e-9)
    assert np.allclose(back.T, out.T, atol=1e-9)


def test_track_distance_zero_symmetric_and_invariant():
    a, b = camera(500, 900), camera(1000, 1300)
    assert A.track_distance(a, a, align="none") == 0.0
    assert A.track_distance(a, a) <= 1e-9
    for how in ("none", "dp"):
        dab, dba = A.track_distance(a, b, align=how), A.track_distance(b, a, align=how)
        assert dab > 0.1 and np.isclose(dab, dba, rtol=1e-9)
    assert A.track_distance(a, b) < A.track_distance(a, b, align="none")
    # the default position scale makes the distance independent of the unit (mm) and of a
    # common right translation (SO(3) x R^3: body frame turned, origin moved; Lemma 3.6)
    g = Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix()
    x = np.array([2.0, -1.0, 0.5])
    d = A.track_distance(a, b, align="none")
    assert np.isclose(A.track_distance(moved(a, scale=1000.0), moved(b, scale=1000.0),
                                       align="none"), d, rtol=1e-9)
    assert np.isclose(A.track_distance(moved(a, g, x), moved(b, g, x), align="none"), d,
                      rtol=1e-9)
    # a given scale is used as given: positions weigh 1/length
    assert A.track_distance(a, b, align="none", length=1e3) < d
    with pytest.raises(ShellsplineError, match="length must be a positive"):
        A.track_distance(a, b, length=0.0)


def test_track_blend_of_a_track_with_itself_and_ends():
    a, b = camera(500, 900), camera(1000, 1400)
    for how in ("none", "dp"):
        out, rep = A.track_blend(a, a, 0.3, align=how)
        assert np.abs(out.T - a.T).max() <= 1e-9 and np.array_equal(out.t, a.t)
        assert (rep.result is None) == (how == "none")
    # b on a's times (same spacing): s = 0 is a, s = 1 (no alignment) is b, exactly
    b = moved(b, t=a.t.copy())
    assert np.abs(A.track_blend(a, b, 0.0, align="none")[0].T - a.T).max() <= 1e-9
    assert np.abs(A.track_blend(a, b, 1.0, align="none")[0].T - b.T).max() <= 1e-9
    mid, _ = A.track_blend(a, b, 0.5, align="none")
    # the start is the geodesic midpoint of the start poses
    assert np.allclose(mid.T[0, :3, 3], 0.5 * (a.T[0, :3, 3] + b.T[0, :3, 3]), atol=1e-12)
    R0 = a.T[0, :3, :3] @ so3.exp(0.5 * so3.log(a.T[0, :3, :3].T @ b.T[0, :3, :3]))
    assert np.allclose(mid.T[0, :3, :3], R0, atol=1e-12)


@pytest.mark.parametrize("how", ["none", "dp"])
def test_track_blend_ends_are_the_tracks_themselves(how):
    """Oracle: the tracks. Of tracks of other lengths and rates (400 poses at 100 Hz; 134 at
    33 Hz, later), s = 0 is a (its times and poses) and s = 1 is b; 1e-6 from the ends the
    blend is within 1e-6 of them (continuous in s). It ran on a's times: s = 1 was b
    resampled onto them (400 poses at a's times)."""
    from shellspline.io.posefiles import PoseTrack

    a, full = camera(500, 900), camera(1000, 1400)
    b = PoseTrack(full.t[::3].copy(), full.T[::3].copy(), "tum")
    for s, ref in ((0.0, a), (1.0, b)):
        out, _ = A.track_blend(a, b, s, align=how)
        assert np.array_equal(out.t, ref.t) and np.abs(out.T - ref.T).max() <= 1e-12
    for s, ref in ((1e-6, a), (1 - 1e-6, b)):
        out, _ = A.track_blend(a, b, s, align=how)
        assert out.t.size == ref.t.size and np.abs(out.t - ref.t).max() <= 1e-4
        assert np.abs(out.T - ref.T).max() <= 1e-5
    mid, _ = A.track_blend(a, b, 0.5, align=how)        # (399 + 133) / 2 intervals
    assert mid.t.size == 267 and np.all(np.diff(mid.t) > 0)
    assert np.allclose(mid.t[[0, -1]], 0.5 * (a.t[[0, -1]] + b.t[[0, -1]]), rtol=0, atol=1e-6)
    # b's times are read in a's origin: EuRoC tracks, each counted from its own first stamp
    ea = PoseTrack(a.t - a.t[0], a.T, "euroc", origin_ns=10 ** 18)
    eb = PoseTrack(b.t - b.t[0], b.T, "euroc", origin_ns=10 ** 18 + 7 * 10 ** 9)
    out, _ = A.track_blend(ea, eb, 1.0, align=how)
    assert out.origin_ns == 10 ** 18 and np.allclose(out.t, eb.t + 7.0, rtol=0, atol=1e-12)
    assert np.abs(out.T - b.T).max() <= 1e-12


@pytest.mark.parametrize("how", ["none", "dp"])
def test_track_blend_with_a_kitti_track_keeps_one_clock(how):
    """A KITTI file has no times (``t`` is the pose index): blended with a TUM track (Unix
    seconds), the times were a blend of seconds and pose indices (s = 0.5 wrote stamps at
    half the epoch; s = 1 the indices 0..N-1 as seconds). The KITTI track takes the timed
    one's span: the times stay in it, s = 1 is b's poses evenly over a's span, and a KITTI
    result is numbered by pose index."""
    from shellspline.io.posefiles import PoseTrack

    a, full = camera(500, 900), camera(1000, 1300)
    k = PoseTrack(np.arange(300.0), full.T.copy(), "kitti")
    for s in (0.0, 0.5, 1.0):
        out, _ = A.track_blend(a, k, s, align=how)
        assert out.format == "tum" and np.all(np.diff(out.t) > 0)
        assert a.t[0] - 1e-6 <= out.t[0] and out.t[-1] <= a.t[-1] + 1e-6
    assert np.array_equal(A.track_blend(a, k, 0.0, align=how)[0].t, a.t)
    one, _ = A.track_blend(a, k, 1.0, align=how)
    assert np.allclose(one.t, np.linspace(a.t[0], a.t[-1], 300), rtol=0, atol=1e-6)
    assert np.abs(one.T - k.T).max() <= 1e-9
    back, _ = A.track_blend(k, a, 0.5, align=how)
    assert back.format == "kitti" and np.array_equal(back.t, np.arange(350.0))


def test_track_align_recovers_a_known_warp():
    """b(t) = a(phi0(t)) with phi0 = u^1.5 on a's own (jittered) times: aligned back."""
    from shellspline.curves.srv import reparametrize
    from shellspline.groups import se3
    from shellspline.io.posefiles import PoseTrack

    a = camera(500, 900)
    L = A.track_length(a)
    c = A.track_curve(a, L)
    span = a.t[-1] - a.t[0]
    u = (a.t - a.t[0]) / span
    cw = reparametrize(c, a.t[0] + u ** 1.5 * span, a.t)
    b = PoseTrack(a.t.copy(), se3.from_rt(cw.R[:, 0], cw.X * L), "tum")
    r = A.track_align(b, a)  # a(phi(t)) = b(t): phi = t^1.5
    un, pn = (r.t - a.t[0]) / span, (r.phi - a.t[0]) / span
    assert np.abs(pn - un ** 1.5).max() <= 0.005
    assert r.distance < 0.2 * np.sqrt(r.energy_identity)
    # feature pairs in the files' times pull the warp (weight lam)
    tf = a.t[0] + 0.5 * span
    r2 = A.track_align(b, a, features=[[tf, a.t[0] + 0.8 * span]], lam=1e5)
    assert abs(np.interp(tf, r2.t, r2.phi) - (a.t[0] + 0.8 * span)) <= 0.01 * span


def turned_on_ground(m: Motion, deg: float, shift) -> Motion:
    """``m`` (root with 6 channels, Y up) turned by ``deg`` about Y and moved by ``shift`` on
    the ground: the same take recorded facing another way elsewhere in the volume."""
    G = Rotation.from_euler("y", deg, degrees=True).as_matrix()
    v = m.values.copy()
    cols = m.channel_columns(0)
    axes = "".join(c[0] for c in m.channels[0][3:])
    v[:, cols[:3]] = v[:, cols[:3]] @ G.T + np.asarray(shift, dtype=float)
    v[:, cols[3:]] = A.euler_angles(G @ euler_matrices(v[:, cols[3:]], axes), axes)
    return Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)


@pytest.mark.parametrize("deg", [90.0, 180.0])
def test_takes_recorded_facing_other_ways_are_one_motion(deg):
    """Oracle: the clip itself. Blended as recorded, a walk and the same walk facing the other
    way cancelled their travel (the blend walked on the spot, turned 90 degrees from both);
    by default the motions are blended facing alike, and the blend is placed between the
    takes: here the walk itself, turned by half the turn about a's start and moved by half
    the step between the starts."""
    a = synth.motion(fps=60, seconds=2.0, channels=3, order="ZXY")
    shift = np.array([300.0, 0.0, -120.0])
    b = turned_on_ground(a, deg, shift)
    assert A.distance(a, b, align="none") < 1e-9
    assert A.distance(a, b) < 1e-6
    b2, turn = A.heading_aligned(b, a)
    assert abs((turn + deg + 180.0) % 360.0 - 180.0) < 1e-9          # b turned back by deg
    c2, ca = A.motion_curve(b2), A.motion_curve(a)      # (angles may differ by 360)
    assert np.abs(c2.R - ca.R).max() < 1e-12 and np.abs(c2.X - ca.X).max() < 1e-9
    Pa = forward_kinematics(a)[0]
    p0, pb0 = Pa[0, 0] * [1, 0, 1], forward_kinematics(b)[0][0, 0] * [1, 0, 1]
    for s in (0.0, 0.5, 1.0):
        m, _ = A.blend(a, b, s, align="none")
        G = Rotation.from_euler("y", -s * turn, degrees=True).as_matrix()
        expect = (Pa - p0) @ G.T + p0 + s * (pb0 - p0)
        assert np.abs(forward_kinematics(m)[0] - expect).max() < 1e-6 * A.body_height(a)
    # as recorded (heading="keep"): the travel of the 180 degree blend cancels
    k, _ = A.blend(a, b, 0.5, align="none", heading="keep")
    travel = np.linalg.norm(np.ptp(forward_kinematics(k)[0][:, 0, [0, 2]], axis=0))
    if deg == 180.0:
        assert travel < 0.05 * np.linalg.norm(np.ptp(Pa[:, 0, [0, 2]], axis=0))
    with pytest.raises(ShellsplineError, match="heading must be"):
        A.distance(a, b, heading="north")


def test_long_clips_are_aligned_on_a_capped_grid(monkeypatch):
    """The DP costs O(N^2): two 5-minute clips at 120 Hz would take hours. Clips whose common
    grid is longer than MOTION_DP_FRAMES are aligned on that many frames; a known re-timing
    is still recovered, and blend interpolates the warp onto its full grid."""
    monkeypatch.setattr(A, "MOTION_DP_FRAMES", 61)
    a = synth.motion(fps=60, seconds=3.0, channels=3)         # 181 frames
    b = A.warp_motion(a, np.linspace(0.0, 1.0, 181) ** 1.3)   # b(t) = a(t^1.3)
    r = A.align(a, b)
    assert r.t.size == 61
    # b(phi(t)) = a(t): phi = t^(1/1.3)
    assert np.abs(r.phi - r.t ** (1 / 1.3)).max() < 0.03
    assert r.distance_after < 0.3 * r.distance_before
    m, rep = A.blend(a, b, 0.0)                               # s = 0: a, on the full grid
    assert rep.t.size == 61 and m.n_frames == a.n_frames
    assert np.abs(A.motion_curve(m).R - A.motion_curve(a).R).max() < 1e-9


def test_long_tracks_are_aligned_on_a_capped_lattice(monkeypatch):
    """The DP costs O(N^2): a 50,000-pose track ran for more than 10 minutes at 2.3 GB. Tracks
    longer than TRACK_DP_SAMPLES are aligned on that many evenly spaced times; the known
    warp u^1.5 of a smooth track is still recovered (here: 3,000 poses on 300 samples)."""
    from shellspline.groups import se3
    from shellspline.io.posefiles import PoseTrack

    monkeypatch.setattr(A, "TRACK_DP_SAMPLES", 300)
    n = 3000

    def poses(u):  # a camera on a wavy helix, turning as it goes
        R = Rotation.from_rotvec(np.c_[0.4 * np.sin(7 * u), 2.0 * u, 0.3 * np.cos(5 * u)])
        p = np.c_[np.cos(6 * u), np.sin(6 * u), u + 0.2 * np.sin(11 * u)]
        return se3.from_rt(R.as_matrix(), p)

    u = np.linspace(0.0, 1.0, n)
    t = 100.0 + 30.0 * u
    a = PoseTrack(t, poses(u), "tum")
    b = PoseTrack(t.copy(), poses(u ** 1.5), "tum")      # b(t) = a(phi0(t)), phi0 = u^1.5
    r = A.track_align(b, a)
    assert r.t.size == 300
    un, pn = (r.t - t[0]) / 30.0, (r.phi - t[0]) / 30.0
    assert np.abs(pn - un ** 1.5).max() <= 0.01
    assert A.track_distance(a, b) < 0.2 * A.track_distance(a, b, align="none")
    out, rep = A.track_blend(a, b, 0.5)                   # the warp carried to a's own times
    assert out.t.size == n and rep.result.t.size == 300


def test_track_errors_are_one_line():
    from shellspline.io.posefiles import PoseTrack

    a = camera(500, 600)
    one = PoseTrack(a.t[:1], a.T[:1], "tum")
    with pytest.raises(ShellsplineError, match="at least 2 poses, got 1"):
        A.track_distance(one, a)
    with pytest.raises(ShellsplineError, match="at least 3 poses, got 2"):
        A.track_close(PoseTrack(a.t[:2], a.T[:2], "tum"))
    with pytest.raises(ShellsplineError, match="expected a PoseTrack"):
        A.track_blend(a, a.T)
    with pytest.raises(ShellsplineError, match="align must be"):
        A.track_blend(a, a, align="dtw")
    # a track that does not move: positions are not scaled (length 1)
    still = PoseTrack(a.t, np.broadcast_to(a.T[0], a.T.shape).copy(), "tum")
    assert A.track_length(still) == 1.0


def _blend_pair(which):
    """Two small valid inputs of ``blend``, ``mesh_blend`` or ``track_blend`` (synthetic)."""
    from shellspline.io.posefiles import PoseTrack

    if which == "blend":
        return synth.motion(seconds=0.3, fps=30, channels=3), \
            synth.motion(seconds=0.4, fps=30, channels=3, cadence=0.9)
    if which == "mesh_blend":
        m = trimesh.creation.icosphere(subdivisions=1)
        Vs = np.stack([m.vertices * [1 + 0.1 * k, 1, 1] for k in range(4)])
        return Vs, Vs[::-1].copy(), m.faces
    t = np.linspace(0.0, 1.0, 12)
    T = np.broadcast_to(np.eye(4), (12, 4, 4)).copy()
    T[:, :3, :3] = Rotation.from_rotvec(np.outer(t, [0.0, 0.0, 0.5])).as_matrix()
    T[:, :3, 3] = np.outer(t, [1.0, 0.5, 0.0])
    return PoseTrack(t, T, "tum"), PoseTrack(t.copy(), T[::-1].copy(), "tum")


@pytest.mark.parametrize("which", ["blend", "mesh_blend", "track_blend"])
def test_blend_weight_must_be_a_finite_number(which):
    """Before, track_blend ran np.isfinite(s) first (a raw numpy TypeError for a string or
    None) and blend and mesh_blend float(s) (a raw ValueError or TypeError for "abc", None or
    a list, while "0.5" and True were read as numbers). Now each is one line naming s; a
    string is refused like one for the API's other numeric arguments (eta, K); a numpy
    scalar is a number."""
    args = _blend_pair(which)
    for s in ("0.5", "abc", None, True, [0.5], np.nan):
        with pytest.raises(ShellsplineError) as e:
            getattr(A, which)(*args, s, align="none")
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith("s must be a finite number"), msg
        assert msg.endswith(f"got {s!r}"), msg
    out, _ = getattr(A, which)(*args, np.float32(0.0), align="none")
    frames = {"blend": lambda x: x.n_frames, "mesh_blend": len,
              "track_blend": lambda x: len(x.T)}[which]
    assert frames(out) == frames(args[0])  # s = 0: the first one's frames


# ----------------------------------------------------------------------------------------
# A static root turned or moved (a file converted to Z-up by its root): the same results
# ----------------------------------------------------------------------------------------
STAGES = [((0.0, 90.0, 0.0), (0.0, 0.0, 0.0)),        # Y-up turned to Z-up by the root
          ((37.0, -80.0, 20.0), (100.0, -5.0, 40.0))]  # any turn and shift


def on_stage(m: Motion, zxy, pos) -> Motion:
    """The clip with its static root (Bandai ``joint_Root``: Xpos Ypos Zpos Zrot Xrot Yrot)
    set to a constant pose."""
    v = m.values.copy()
    v[:, :3], v[:, 3:6] = pos, zxy
    return Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)


def stage_pose(zxy, pos):
    return euler_matrices(np.array(zxy), "ZXY"), np.array(pos)


@pytest.mark.parametrize("zxy,pos", STAGES)
def test_close_does_not_depend_on_a_static_root_pose(zxy, pos):
    """Oracle: the closed clip of the turned file is the closed clip of the original, turned
    (the root's channels are the file's, every other channel equal; world positions
    S p + s)."""
    m = real()
    turned = on_stage(m, zxy, pos)
    assert A.stage_joint(m) == 0 == A.stage_joint(turned)
    S, s = stage_pose(zxy, pos)
    for kw in (dict(c1=True), dict(root_motion="close"), dict(trim=True)):
        out, rep = A.close(m, **kw)
        out_t, rep_t = A.close(turned, **kw)
        assert rep_t.frames == rep.frames
        assert np.abs(out_t.values[:, 6:] - out.values[:, 6:]).max() < 1e-8
        assert np.array_equal(out_t.values[:, :6], turned.values[: out_t.n_frames, :6])
        P, P_t = forward_kinematics(out)[0], forward_kinematics(out_t)[0]
        assert np.abs(P_t - (P @ S.T + s)).max() < 1e-8
        assert rep_t.gap_after["position_max"] < 1e-9  # was 0.661 units for the Z-up file
        assert rep_t.skate_after["drift"] == pytest.approx(rep.skate_after["drift"], abs=1e-8)


@pytest.mark.parametrize("zxy,pos", STAGES)
def test_distance_align_blend_do_not_depend_on_a_static_root_pose(zxy, pos):
    """Without alignment to rounding; with DP the lattice optimum is the same to rounding,
    and the refinement (which stopped at its iteration limit on these walks before its
    tolerance was tied to the sample grid) ends within
    0.5 % of the distance (0.1 % before the heading alignment turned b by its -0.5 degrees
    of travel direction: another rounding-level start of the refinement)."""
    a, b = real(), real("dataset-1_walk_tired_001.bvh")
    at, bt = on_stage(a, zxy, pos), on_stage(b, zxy, pos)
    assert A.distance(at, bt, align="none") == pytest.approx(A.distance(a, b, align="none"),
                                                             rel=1e-12)
    assert A.distance(at, bt, features="contacts") == pytest.approx(
        A.distance(a, b, features="contacts"), rel=5e-3)
    r, rt = A.align(a, b, features="contacts"), A.align(at, bt, features="contacts")
    assert np.array_equal(r.features, rt.features)
    assert rt.result.energy_dp == pytest.approx(r.result.energy_dp, rel=1e-12)
    assert np.abs(rt.phi - r.phi).max() < 0.01
    m, _ = A.blend(a, b, 0.4, align="none", plant=True)
    mt, _ = A.blend(at, bt, 0.4, align="none", plant=True)
    assert np.abs(mt.values[:, 6:] - m.values[:, 6:]).max() < 1e-7
    assert np.abs(mt.values[:, :6] - at.values[0, :6]).max() < 1e-9  # the root stays put
    S, s = stage_pose(zxy, pos)
    m, _ = A.blend(a, b, 0.4, features="contacts")
    mt, _ = A.blend(at, bt, 0.4, features="contacts")
    P, P_t = forward_kinematics(m)[0], forward_kinematics(mt)[0]
    assert np.abs(P_t - (P @ S.T + s)).max() < 0.01 * A.body_height(m)


def test_alignment_of_a_time_warped_copy_converges_to_the_known_warp():
    """The walk against itself played at the times ``gam``: the warp is ``gam^-1`` (to the
    resampling's sub-frame error), and the refinement converges (it stopped "stalled" after
    200 iterations above the DP energy, and at its limit on walk_tired, with a tolerance of
    1e-9 that the kinked energy never meets)."""
    a = real()
    s = np.linspace(0, 1, a.n_frames)
    gam = s + 0.04 * np.sin(2 * np.pi * s)
    rep = A.align(a, A.warp_motion(a, gam))
    assert rep.result.status == "converged" and rep.result.success
    assert np.abs(rep.phi - np.interp(s, gam, s)).max() * (a.n_frames - 1) <= 1.0
    for name in ("dataset-1_walk_tired_001.bvh", "dataset-1_walk_happy_001.bvh"):
        r = A.align(a, real(name)).result
        assert r.status == "converged" and r.energy < r.energy_dp
    res = []
    A.distance(a, real("dataset-1_walk_tired_001.bvh"), results=res)
    assert [r.status for r in res] == ["converged", "converged"]


def test_alignment_stopped_at_its_iteration_limit_says_so():
    r = A.align(real(), real("dataset-1_walk_tired_001.bvh"), max_iter=5).result
    assert r.status == "limit" and not r.success and r.iterations == 5
    assert "iteration limit (5)" in r.message
    with pytest.raises(ShellsplineError, match="max_iter must be an integer >= 1"):
        A.align(real(), real(), max_iter=0)


def test_up_override_is_a_world_axis_turned_into_the_stage():
    m = real()
    zup = on_stage(m, *STAGES[0])
    assert A.foot_contacts(zup, up="z").up == A.foot_contacts(m, up="y").up == (1, 1.0)
    assert A.up_axis(zup) == A.up_axis(m)
    with pytest.raises(ShellsplineError, match="joint_Root"):
        A.foot_contacts(on_stage(m, *STAGES[1]), up="z")


# ----------------------------------------------------------------------------------------
# A joint that flips between two frames (gimbal flips of the data, marker swaps, fast spins)
# ----------------------------------------------------------------------------------------
def flipped(deg, frame=100, joint="UpperArm_L") -> Motion:
    """The real walk with one joint's last Euler angle (Yrotation) turned by ``deg`` from
    ``frame`` on: a step of about ``deg`` between ``frame - 1`` and ``frame``."""
    m = real()
    v = m.values.copy()
    v[frame:, m.channel_columns(m.joint_index(joint))[5]] += deg
    return Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)


def test_subdivision_keeps_the_curve_and_its_srv():
    """Oracle: the inserted samples are scipy's Slerp between the two frames, and the SRV
    of the split curve is the original SRV on every piece (piecewise constant)."""
    from scipy.spatial.transform import Slerp

    from shellspline.curves.srv import srv

    c = A.motion_curve(flipped(178.0))
    pc = A._product_curve(c, 100.0, cols=A._varying(c.X))
    fine, keep = A._subdivided(pc)
    assert np.array_equal(fine.R[keep], pc.R) and np.allclose(fine.t[keep], pc.t)
    b = A.motion_curve(real()).rot_joints.tolist().index(real().joint_index("UpperArm_L"))
    lo, hi = keep[99], keep[100]
    assert hi - lo == 4  # a 178 degree step in pieces of at most CLOSE_MAX_STEP = 45
    sl = Slerp([0.0, 1.0], Rotation.from_matrix(pc.R[99:101, b]))
    ref = sl((fine.t[lo:hi + 1] - pc.t[99]) / (pc.t[100] - pc.t[99])).as_matrix()
    assert np.abs(fine.R[lo:hi + 1, b] - ref).max() < 1e-12
    q, qf = srv(pc), srv(fine)
    piece = np.repeat(np.arange(keep.size - 1), np.diff(keep))
    assert np.abs(qf - q[piece]).max() < 1e-9 * np.abs(q).max()


@pytest.mark.parametrize("deg", [178.0, 200.0])
def test_closing_a_clip_with_a_joint_flip(deg):
    """A walk whose arm turns by 178 degrees (or 200: the short way, 160) in one frame
    closed like any walk (it stopped with "srv_inverse: ... sample t more finely", or at
    a 143 degree seam after 10 iterations)."""
    m = flipped(deg)
    for c1 in (False, True):
        out, rep = A.close(m, c1=c1)
        assert rep.status == "converged" and rep.iterations <= 4
        assert rep.gap_before["rotation_max"] > 140 and rep.gap_after["rotation_max"] < 1e-6
        c = A.motion_curve(out)
        assert np.abs(c.R[-1] - c.R[0]).max() < 1e-8 and out.n_frames == m.n_frames


def test_a_half_turn_in_one_frame_is_refused_in_one_line():
    m = real()
    v = m.values.copy()
    j = m.joint_index("LowerArm_R")
    cols = m.channel_columns(j)[3:]
    R = euler_matrices(v[99, cols], "ZXY") @ euler_matrices([0.0, 0.0, 180.0], "ZXY")
    v[100, cols] = A.euler_angles(R, "ZXY")
    m = Motion(m.names, m.parents, m.offsets, m.channels, m.frame_time, v, m.end_sites)
    with pytest.raises(ShellsplineError, match=r"close: joint 'LowerArm_R' turns by 180\.0000 "
                       r"degrees between frames 99 and 100 \(3\.300 s\).*cut out") as e:
        A.close(m)
    assert "\n" not in str(e.value)


def test_curve_closing_backtracks_where_a_trial_step_would_turn_a_joint_past_pi(monkeypatch):
    """Without the split, the Gauss-Newton step of the flip clip's curve would turn the arm
    past pi in one step (srv_inverse refuses such a trial); the line search now shortens
    the step instead of stopping the run, and reports honestly that it did not close."""
    from shellspline.curves import closing
    from shellspline.curves.srv import srv, srv_inverse

    c = A.motion_curve(flipped(178.0))
    X = A._detrend(c, 1)
    pc = A._product_curve(c, A.body_height(c.template), X, A._varying(X))
    refused = []
    inverse = closing.srv_inverse

    def spy(*a, **k):
        try:
            return inverse(*a, **k)
        except ShellsplineError:
            refused.append(1)
            raise
    monkeypatch.setattr(closing, "srv_inverse", spy)
    r = closing.close(pc)
    assert refused and r.status == "limit"
    assert np.all(np.diff(r.seam_gap) < 0)
    back = srv_inverse(srv(r.curve), r.curve.t, R0=r.curve.R[0], X0=r.curve.X[0])
    assert np.abs(back.R - r.curve.R).max() < 1e-9  # a valid piecewise-geodesic curve


def with_world(m: Motion, xyz=(90.0, 0.0, 30.0), offset=(5.0, 0.0, -3.0)) -> Motion:
    """``m`` below an extra static root "World" (rotation channels only, turned and moved)."""
    parents = np.r_[-1, m.parents + 1]
    parents[1] = 0
    v = np.hstack([np.tile(xyz, (m.n_frames, 1)), m.values])
    return Motion(("World",) + m.names, parents, np.vstack([offset, m.offsets]),
                  (("Xrotation", "Yrotation", "Zrotation"),) + m.channels, m.frame_time, v,
                  tuple((p + 1, o) for p, o in m.end_sites))


def test_an_extra_static_root_changes_nothing():
    """Above the walk's static joint_Root, and above the run's joint_Root that carries the
    travel (its hips move in place): the stage, the body, the travel channels and every
    result are those of the file without it."""
    walk, run = real(), real("dataset-1_run_normal_001.bvh")
    assert (A.stage_joint(walk), A.stage_joint(run)) == (0, -1)
    ww, wr = with_world(walk), with_world(run)
    assert (A.stage_joint(ww), A.stage_joint(wr)) == (1, 0)
    for m, w in ((walk, ww), (run, wr)):
        assert np.array_equal(A.body_joints(w)[1:], A.body_joints(m))
        assert A.body_height(w) == pytest.approx(A.body_height(m), rel=1e-12)
        out, rep = A.close(m, c1=True)
        out_w, rep_w = A.close(w, c1=True)
        assert np.abs(out_w.values[:, 3:] - out.values).max() < 1e-8
        assert rep_w.gap_after["position_max"] < 1e-9
    assert A.distance(ww, wr, align="none") == pytest.approx(
        A.distance(walk, run, align="none"), rel=1e-12)
