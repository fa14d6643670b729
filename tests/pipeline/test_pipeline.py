"""End-to-end properties of shellspline.interpolate on synthetic and real keyframes."""
from pathlib import Path

import numpy as np
import pytest

import data_synth
import shellspline as ss
from shellspline.timeline import canonical_frames, linear_blend
from conftest import icosphere, shared_data


@pytest.fixture(scope="module")
def ellipsoids():
    return data_synth.generate("ellipsoids", n_vertices=300)


def _kink(V, f):
    """Relative second difference at frame f: O(1/K) for a smooth curve, O(1) at a corner."""
    return np.linalg.norm(V[f + 1] - 2 * V[f] + V[f - 1]) / np.linalg.norm(V[f + 1] - V[f - 1])


def test_keyframes_exact_and_smooth_at_interior_keyframe(ellipsoids):
    d = ellipsoids
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1)
    lin = ss.interpolate((d["V"], d["F"]), frames=d["frames"], method="linear")
    assert res.V.shape == (13, d["V"].shape[1], 3)
    for j, f in enumerate(d["frames"]):
        assert np.array_equal(res.V[f], d["V"][j]) and np.array_equal(lin.V[f], d["V"][j])
    q = res.report["quality"]
    assert q["keyframes_exact"] and q["flipped_faces"] == 0 and q["degenerate_faces"] == 0
    gn = res.report["gauss_newton"]
    assert gn["converged"] == gn["frames"] == 10
    # the linear blend has a corner at the middle keyframe, the spline does not
    assert _kink(lin.V, 6) > 0.9
    assert _kink(res.V, 6) < 0.5 * _kink(lin.V, 6)
    # the same in descriptor space (velocity continuity of the descriptor trajectories)
    T = ss.topology(d["F"])
    Zs, Zl = ss.lta_descriptors(res.V, T), ss.lta_descriptors(lin.V, T)
    assert _kink(Zs, 6) < 0.5 * _kink(Zl, 6)


def test_reconstruction_follows_the_spline_targets(ellipsoids):
    d = ellipsoids
    # η is relative to the first keyframe's sqrt(area) (D² ≈ 21 here): 0.005 is the thickness
    # this test was written for (an absolute 0.1)
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.005)
    T = ss.topology(d["F"])
    sL, sT, sA = T.descriptor_slices()
    Z = ss.lta_descriptors(res.V, T)
    rel = np.abs(Z[:, sL] - res.Z[:, sL]) / res.Z[:, sL]
    assert rel.max() < 0.05  # lengths realised within 5 % (targets are not exactly realisable)
    assert np.median(rel) < 0.01


def test_rigid_keyframes_give_rigid_frames():
    V, F = data_synth.generate("ellipsoids", n_vertices=200)["V"][0], \
        data_synth.generate("ellipsoids", n_vertices=200)["F"]
    Q, _ = np.linalg.qr(np.random.default_rng(0).standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    Vs = np.stack([V, V @ Q.T + [1.0, 0, 0]])
    res = ss.interpolate((Vs, F), K=6, gn_options={"gtol": 1e-10, "ftol": 1e-14})
    T = ss.topology(F)
    z0 = ss.lta_descriptors(V, T)
    for k in range(7):
        assert np.abs(ss.lta_descriptors(res.V[k], T) - z0).max() < 1e-6


def test_rotating_the_input_rotates_the_output(ellipsoids):
    d = ellipsoids
    Q, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    a = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1)
    b = ss.interpolate((d["V"] @ Q.T, d["F"]), frames=d["frames"], eta=0.1)
    assert np.abs(a.V @ Q.T - b.V).max() < 1e-4


@pytest.mark.parametrize("bc", ["natural", "periodic"])
@pytest.mark.parametrize("reference", ["constant", "keyframe", 1])
def test_boundary_conditions_and_references(ellipsoids, bc, reference):
    d = ellipsoids
    K = 12 if bc == "natural" else 18
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 6, 12], K=K, bc=bc, reference=reference)
    for j, f in enumerate([0, 6, 12]):
        assert np.array_equal(res.V[f], d["V"][j])
    if bc == "periodic":
        assert np.array_equal(res.V[K], d["V"][0])
    q = res.report["quality"]
    assert q["flipped_faces"] == 0 and q["degenerate_faces"] == 0


def test_hermite_uses_the_velocity_poses(ellipsoids):
    d = ellipsoids
    V = d["V"]
    # poses at frames 1 and K-1 from a linear blend: the end velocities point along it
    K = 12
    Vh = np.stack([V[0], V[0] + (V[1] - V[0]) / 6, V[1], V[2] + (V[1] - V[2]) / 6, V[2]])
    res = ss.interpolate((Vh, d["F"]), frames=[0, 1, 6, K - 1, K], K=K, bc="hermite")
    for j, f in enumerate([0, 1, 6, 11, 12]):
        assert np.array_equal(res.V[f], Vh[j])
    with pytest.raises(ValueError, match="hermite"):
        ss.interpolate((V, d["F"]), frames=[0, 6, 12], bc="hermite")


def test_workers_give_the_same_sequence(ellipsoids, monkeypatch):
    import shellspline.pipeline.reconstruction as pl

    monkeypatch.setattr(pl, "SERIAL_RECONSTRUCT_WORK", 0)  # this small case: use the pool
    d = ellipsoids
    a = ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=1)
    b = ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=2)
    assert np.abs(a.V - b.V).max() < 1e-5 * np.abs(a.V).max()


def test_small_work_starts_no_process_pool(ellipsoids, monkeypatch):
    """Below SERIAL_RECONSTRUCT_WORK / SERIAL_DECODE_WORK vertex-frames ``workers=2`` runs in
    process (a pool costs more than the work); above, the pool is used."""
    import shellspline.parallel as par
    import shellspline.pipeline.reconstruction as pl

    started = []

    def pool(workers, *a, **k):
        started.append(workers)
        raise RuntimeError("pool started")

    monkeypatch.setattr(par, "process_pool", pool)
    d = ellipsoids
    assert d["V"].shape[1] * 12 < pl.SERIAL_RECONSTRUCT_WORK
    r = ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=2)
    assert started == [] and r.report["quality"]["keyframes_exact"]
    c = ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=2, coarse=100)
    assert started == [] and c.report["quality"]["flipped_faces"] == 0
    monkeypatch.setattr(pl, "SERIAL_RECONSTRUCT_WORK", 0)
    with pytest.raises(RuntimeError, match="pool started"):
        ss.interpolate((d["V"], d["F"]), frames=d["frames"], workers=2)
    assert started == [2]


def test_pinned_vertices_stay_put():
    d = data_synth.generate("cactus", n_vertices=600)
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=d["pinned"])
    assert np.array_equal(res.V[:, d["pinned"]], np.broadcast_to(d["V"][0, d["pinned"]],
                                                                 res.V[:, d["pinned"]].shape))
    q = res.report["quality"]
    assert q["flipped_faces"] == 0 and q["degenerate_faces"] == 0


def test_report_contents(ellipsoids):
    d = ellipsoids
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"])
    rep = res.report
    assert set(rep["timings"]) >= {"describe", "solve", "reconstruct", "place", "total"}
    assert len(rep["frames"]) == 10 and all("nit" in r and "success" in r for r in rep["frames"])
    e = rep["energies"]
    assert len(e["lta_spline_energy_per_frame"]) == 13
    import json

    json.dumps(rep)  # JSON-serialisable


@pytest.mark.parametrize("kwargs, phrase", [
    ({"method": "cubic"}, "method"), ({"bc": "clamped"}, "bc"), ({"eta": -1.0}, "eta"),
    ({"reference": "geodesics"}, "reference"), ({"reference": 7}, "reference"),
    ({"frames": [0, 5, 5]}, "strictly increasing"), ({"frames": [0, 5]}, "one entry per"),
    ({"K": 3, "frames": [0, 6, 12]}, "smaller than"), ({"workers": 0}, "workers"),
    ({"pinned": [10**6]}, "pinned"),
])
def test_invalid_arguments_raise(ellipsoids, kwargs, phrase):
    d = ellipsoids
    with pytest.raises(ValueError, match=phrase):
        ss.interpolate((d["V"], d["F"]), **kwargs)


def test_canonical_frames_defaults():
    assert canonical_frames(3)[0].tolist() == [0, 10, 20] and canonical_frames(3)[1] == 20
    assert canonical_frames(3, bc="periodic")[1] == 30
    f, K = canonical_frames(4, K=9)
    assert f.tolist() == [0, 3, 6, 9] and K == 9
    assert canonical_frames(2, frames=[0, 7], bc="periodic")[1] == 14


def test_linear_blend_closed_form():
    V = np.zeros((2, 3, 3))
    V[1] += 1.0
    B = linear_blend(V, np.array([0, 4]), 4)
    assert np.allclose(B[:, 0, 0], [0, 0.25, 0.5, 0.75, 1.0])
    P = linear_blend(V, np.array([0, 2]), 4, bc="periodic")
    assert np.allclose(P[:, 0, 0], [0, 0.5, 1.0, 0.5, 0.0])


@pytest.mark.parametrize("bc", ["natural", "periodic"])
def test_one_linear_blend(bc):
    """The blend, its time weights and the prolongation's weights are one implementation."""
    from shellspline.shells.prolong import linear_time_weights as prolong_weights
    from shellspline.timeline import linear_time_weights

    rng = np.random.default_rng(3)
    V, frames, K = rng.standard_normal((3, 5, 3)), np.array([0, 3, 7]), 10
    W = linear_time_weights(frames, K, bc)
    np.testing.assert_allclose(W.sum(axis=1), 1.0, rtol=1e-15)
    np.testing.assert_allclose(np.einsum("kj,jni->kni", W, V), linear_blend(V, frames, K, bc),
                               rtol=0, atol=1e-14)
    assert np.array_equal(prolong_weights(frames, K, bc), W)
    assert np.array_equal(W[frames], np.eye(3))


@pytest.mark.slow
def test_real_cactus_is_clean():
    D = shared_data("cactus")
    kf = ss.read_keyframes([D / "cactus0.ply", D / "cactus5.ply", D / "cactus13.ply"],
                           frames=[0, 4, 8], pinned=ss.read_indices(D / "cactusBottomMask_indices.txt"))
    res = ss.interpolate(kf, workers=2)
    q = res.report["quality"]
    assert q["keyframes_exact"] and q["flipped_faces"] == 0 and q["degenerate_faces"] == 0
    assert q["min_area_ratio"] > 0.5
    gn = res.report["gauss_newton"]
    assert gn["converged"] == gn["frames"]
    # smooth through the middle keyframe, unlike the blend
    lin = ss.interpolate(kf, method="linear")
    assert _kink(res.V, 4) < 0.6 * _kink(lin.V, 4)


def test_energy_has_no_spike_at_keyframes_unlike_linear_blend(ellipsoids):
    # paper Figs. 11-12: the spline's per-frame energy varies continuously through a keyframe,
    # a piecewise interpolation concentrates energy there
    d = ellipsoids
    # η = 0.005 relative to sqrt(area) (D² ≈ 21): the absolute 0.1 this test was written for
    e = {m: np.array(ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.005, method=m)
                     .report["energies"]["lta_output_energy_per_frame"]) for m in ("lta", "linear")}
    spike = {m: v[6] / max(v[5], v[7]) for m, v in e.items()}
    assert spike["linear"] > 50
    assert spike["lta"] < 2


def test_geodesic_method_is_piecewise_with_a_kink(ellipsoids):
    d = ellipsoids
    g = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1, method="geodesic")
    for j, f in enumerate(d["frames"]):
        assert np.array_equal(g.V[f], d["V"][j])
    assert g.report["geodesic"]["success"]
    q = g.report["quality"]
    assert q["flipped_faces"] == 0 and q["degenerate_faces"] == 0
    s = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.1)
    assert _kink(g.V, 6) > 2 * _kink(s.V, 6)  # the geodesic corners at the keyframe


def test_nonlinear_method_starts_from_lta_and_decreases_the_energy():
    d = data_synth.generate("ellipsoids", n_vertices=100)
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, eta=0.1, method="nonlinear",
                         solver_options={"max_iter": 5})
    nl = res.report["nonlinear"]
    assert nl["nit"] <= 5 and nl["energy_final"] <= nl["energy_initial"]
    assert np.all(np.diff(nl["energy_history"]) <= 1e-12 * nl["energy_initial"])
    # per-iteration records: one step length and Hessian kind per outer iteration
    assert len(nl["step_lengths"]) == len(nl["hessian"]) == nl["nit"]
    assert len(nl["grad_norm_history"]) == len(nl["energy_history"])
    assert set(nl["hessian"]) <= {"gauss-newton", "exact"}
    for j, f in enumerate([0, 2, 4]):
        assert np.array_equal(res.V[f], d["V"][j])


def test_nonlinear_auto_coarse_solves_on_the_coarse_mesh(monkeypatch):
    """``coarse="auto"`` with the nonlinear model decimates above AUTO_NONLINEAR_ABOVE (here
    lowered to fit a test mesh), says so, and prolongs with keyframes exact."""
    from shellspline.pipeline import options as pipeline

    monkeypatch.setattr(pipeline, "AUTO_NONLINEAR_ABOVE", 80)
    monkeypatch.setattr(pipeline, "AUTO_COARSE_VERTICES", 60)
    d = data_synth.generate("ellipsoids", n_vertices=100)
    n = d["V"].shape[1]
    events = []
    res = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, eta=0.1, method="nonlinear",
                         solver_options={"max_iter": 3}, progress=events.append)
    assert 55 <= res.report["multires"]["coarse_vertices"] <= 60 < n
    assert res.report["nonlinear"]["resolution"] == "coarse"
    assert res.report["nonlinear"]["vertices"] == res.report["multires"]["coarse_vertices"]
    msgs = [e["text"] for e in events if e["kind"] == "message"]
    assert any("coarse vertices" in m and "--coarse none" in m for m in msgs), msgs
    for j, f in enumerate([0, 2, 4]):
        assert np.array_equal(res.V[f], d["V"][j])
    # the LΘA default is unchanged at this size
    lta = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, eta=0.1)
    assert "multires" not in lta.report


def test_multiresolution_path_keeps_keyframes_and_detail():
    d = data_synth.generate("bumpy", n_vertices=2500)
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.01, coarse=400)
    mr = res.report["multires"]
    assert 380 <= mr["coarse_vertices"] <= 400
    for j, f in enumerate(d["frames"]):
        assert np.array_equal(res.V[f], d["V"][j])
    q = res.report["quality"]
    assert q["flipped_faces"] == 0 and q["degenerate_faces"] == 0
    assert res.report["energies"]["resolution"] == "coarse"
    # the prolonged in-betweens are close to a full-resolution LΘA solve
    full = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.01, coarse="none")
    size = np.ptp(d["V"][0], axis=0).max()
    assert np.abs(res.V - full.V).max() < 0.05 * size
    # and the bumps survive: vertex-wise deviation from a smooth blend stays keyframe-sized
    fine = ss.interpolate((d["V"], d["F"]), frames=d["frames"], eta=0.01, coarse=400, fine=True)
    assert fine.report["parameters"]["fine"] and fine.report["energies"]["resolution"] == "full"
    assert np.abs(fine.V - full.V).max() < 0.01 * size


def test_coarse_option_canonicalisation(monkeypatch):
    from shellspline.pipeline import options as pipeline

    assert pipeline.coarse_target("none", 5000) is None
    assert pipeline.coarse_target(0.1, 5000) == 500
    assert pipeline.coarse_target("0.1", 5000) == 500
    assert pipeline.coarse_target("700", 5000) == 700
    assert pipeline.coarse_target(6000, 5000) is None  # no coarsening above the mesh size
    assert pipeline.coarse_target("auto", 5000) is None
    assert pipeline.coarse_target("auto", 50_000) == pipeline.AUTO_COARSE_VERTICES
    # the nonlinear model decimates by default far earlier (its cost grows faster than n)
    assert pipeline.coarse_target("auto", 5000, "nonlinear") == pipeline.AUTO_COARSE_VERTICES
    assert pipeline.coarse_target("auto", pipeline.AUTO_NONLINEAR_ABOVE, "nonlinear") is None
    assert pipeline.coarse_target("none", 5000, "nonlinear") is None
    for bad in ("many", 0, 1.5, True, -3):
        with pytest.raises(ValueError, match="coarse"):
            pipeline.coarse_target(bad, 5000)


def test_hermite_follows_the_velocity_poses(ellipsoids):
    # different poses at frames 1 and K-1 (different end velocities) change the in-betweens
    d = ellipsoids
    V = d["V"]
    K = 12
    res = []
    for a in (1 / 6, 1 / 3):
        Vh = np.stack([V[0], V[0] + a * (V[1] - V[0]), V[1], V[2] + a * (V[1] - V[2]), V[2]])
        res.append(ss.interpolate((Vh, d["F"]), frames=[0, 1, 6, K - 1, K], K=K,
                                  bc="hermite").V)
    size = np.ptp(V[0], axis=0).max()
    assert np.abs(res[0][3] - res[1][3]).max() > 1e-3 * size


def test_keyframe_reference_changes_the_weights(ellipsoids):
    d = ellipsoids
    a = ss.interpolate((d["V"], d["F"]), frames=d["frames"], reference="constant")
    b = ss.interpolate((d["V"], d["F"]), frames=d["frames"], reference="keyframe")
    c = ss.interpolate((d["V"], d["F"]), frames=d["frames"], reference=2)
    assert np.abs(a.V - b.V).max() > 1e-4 and np.abs(a.V - c.V).max() > 1e-4


def test_paths_tuple_half_turn_and_strict_json(ellipsoids, tmp_path, monkeypatch):
    import shellspline.pipeline.reconstruction as pl

    monkeypatch.setattr(pl, "SERIAL_RECONSTRUCT_WORK", 0)  # the half-turn through the pool
    import json

    d = ellipsoids
    paths = data_synth.write("ellipsoids", tmp_path / "e", n_vertices=300)
    r = ss.interpolate(tuple(paths), frames=d["frames"], reference=np.int64(1),
                       eta=np.float32(0.1))
    json.dumps(r.report, allow_nan=False)
    # a half-turn between keyframes collapses the blend: no crash, a finite sequence
    V = d["V"][0]
    h = ss.interpolate((np.stack([V, V * [-1, -1, 1]]), d["F"]), K=6, workers=2)
    assert np.all(np.isfinite(h.V)) and h.report["quality"]["degenerate_faces"] == 0


def test_moving_pins_work_with_multiresolution():
    d = data_synth.generate("hexagon", n_vertices=400)
    T = ss.topology(d["F"])
    pins = T.boundary_vertices
    res = ss.interpolate((d["V"], d["F"]), frames=d["frames"], pinned=pins, coarse=120)
    blend = linear_blend(d["V"], np.asarray(d["frames"]), res.K)
    assert np.array_equal(res.V[:, pins], blend[:, pins])


# -- scale invariance (issue 14 item 3) --------------------------------------------------------
#: Gauss–Newton run to convergence: the model is unit-free exactly, but a frame stopped at the
#: default tolerances sits anywhere within them (measured: 3e-9 relative at s = 1e-6 with the
#: defaults, 5e-12 with these).
_TIGHT = {"gtol": 1e-12, "ftol": 1e-15, "dtol": 1e-15, "max_iter": 200}


@pytest.fixture(scope="module")
def unit_sequences():
    d = data_synth.generate("ellipsoids", n_vertices=100)
    kw = {"lta": {}, "linear": {}, "geodesic": {},
          "nonlinear": {"solver_options": {"max_iter": 3}}}
    out = {}
    for m, extra in kw.items():
        out[m] = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, method=m, eta=0.01,
                                gn_options=_TIGHT, **extra)
    return d, kw, out


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@pytest.mark.parametrize("method", ["lta", "linear", "geodesic", "nonlinear"])
@pytest.mark.parametrize("s", [1e-6, 1e-3, 1.0, 1e3, 1e6])
def test_scaled_keyframes_give_the_scaled_sequence(unit_sequences, method, s):
    d, kw, unit = unit_sequences
    r = ss.interpolate((s * d["V"], d["F"]), frames=[0, 2, 4], K=4, method=method, eta=0.01,
                       gn_options=_TIGHT, **kw[method])
    ref = unit[method].V
    assert np.abs(r.V - s * ref).max() <= 1e-9 * s * np.abs(ref).max()
    assert r.report["quality"]["keyframes_exact"]
    for j, f in enumerate([0, 2, 4]):
        assert np.array_equal(r.V[f], s * d["V"][j])
    # energies are those of the unit-free problem
    e, e1 = (np.asarray(x.report["energies"]["lta_output_energy_per_frame"]) for x in (r, unit[method]))
    np.testing.assert_allclose(e, e1, rtol=1e-6, atol=1e-12 * e1.max())
    D = r.report["parameters"]["length_scale"]
    assert D == pytest.approx(s * ss.metrics.length_scale(d["V"][0], d["F"]), rel=1e-12)


def test_eta_is_relative_to_the_keyframes_size():
    """The same relative η gives the same shape at any size; the same absolute thickness
    (η·D²) does not: bending is measured against sqrt(area) of keyframe 0."""
    d = data_synth.generate("ellipsoids", n_vertices=100)
    D = ss.metrics.length_scale(d["V"][0], d["F"])
    a = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, eta=0.01)
    b = ss.interpolate((d["V"] / D, d["F"]), frames=[0, 2, 4], K=4, eta=0.01)
    assert np.abs(a.V - D * b.V).max() < 1e-6 * D
    c = ss.interpolate((d["V"], d["F"]), frames=[0, 2, 4], K=4, eta=0.01 * D ** 2)
    assert np.abs(a.V - c.V).max() > 1e-4 * D


def test_pins_stay_exact_after_scaling_back():
    d = data_synth.generate("cactus", n_vertices=300)
    V = d["V"] * 1e-3  # a unit where dividing by D and multiplying back is not exact
    res = ss.interpolate((V, d["F"]), frames=d["frames"], pinned=d["pinned"])
    assert res.report["parameters"]["length_scale"] != 1.0
    assert np.array_equal(res.V[:, d["pinned"]],
                          np.broadcast_to(V[0, d["pinned"]], res.V[:, d["pinned"]].shape))


# -- rigid subset (issue 16 item 3) ------------------------------------------------------------
def _tube(n_rings=17, sections=12, length=3.0, radius=0.3):
    """A closed tube along x (rings of ``sections`` vertices, capped by fans)."""
    x = np.linspace(-length / 2, length / 2, n_rings)
    th = np.linspace(0, 2 * np.pi, sections, endpoint=False)
    V = np.stack([np.repeat(x, sections), radius * np.tile(np.cos(th), n_rings),
                  radius * np.tile(np.sin(th), n_rings)], axis=1)
    r, s = np.meshgrid(np.arange(n_rings - 1), np.arange(sections), indexing="ij")
    a, b = r * sections + s, r * sections + (s + 1) % sections
    F = np.concatenate([np.stack([a, b, b + sections], -1).reshape(-1, 3),
                        np.stack([a, b + sections, a + sections], -1).reshape(-1, 3)])
    n, o, s = len(V), (n_rings - 1) * sections, np.arange(sections)
    caps = np.concatenate([np.stack([np.full(sections, n), (s + 1) % sections, s], -1),
                           np.stack([np.full(sections, n + 1), o + s, o + (s + 1) % sections],
                                    -1)])
    return np.vstack([V, [[x[0], 0, 0], [x[-1], 0, 0]]]), np.concatenate([F, caps])


def _rot(axis, a):
    c, s = np.cos(a), np.sin(a)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


@pytest.fixture(scope="module")
def circling_body():
    """A tube whose torso (x <= 0) turns on a circle of radius 4 about the z axis, 60° per
    keyframe gap of 6 frames, while its limb (x > 0) swings about the joint at x = 0."""
    V, F = _tube()
    torso = np.flatnonzero(V[:, 0] <= 1e-9)
    limb = V[:, 0] > 1e-9
    keys = []
    for j, swing in enumerate([0.0, 0.9, -0.6, 0.7]):
        B = V.copy()
        B[limb] = B[limb] @ _rot(1, swing).T
        keys.append((B + [4.0, 0, 0]) @ _rot(2, j * np.pi / 3).T)
    return V, F, np.stack(keys), torso


def _circle_distance(P, P0):
    """Distance of points ``P (..., s, 3)`` to the circles about the z axis through ``P0``."""
    r = np.linalg.norm(P[..., :2], axis=-1) - np.linalg.norm(P0[..., :2], axis=-1)
    return np.sqrt(r ** 2 + (P[..., 2] - P0[..., 2]) ** 2)


def test_rigid_subset_keeps_the_torso_on_its_circle(circling_body):
    V, F, keys, torso = circling_body
    frames = [0, 6, 12, 18]
    inb = np.setdiff1d(np.arange(19), frames)
    core = np.flatnonzero(V[:, 0] <= -0.5)                # the torso away from the joint
    P0 = V + [4.0, 0, 0]
    res = {}
    for name, sub in (("subset", torso), ("all", None)):
        r = ss.interpolate((keys, F), frames=frames, rigid_track="spline", rigid_subset=sub)
        for j, f in enumerate(frames):
            assert np.array_equal(r.V[f], keys[j])
        res[name] = r
    assert res["subset"].report["parameters"]["rigid_subset_vertices"] == len(torso)
    # the torso's centroid rides the screw spline through the torso poses: the true circle,
    # at the true constant rate
    c = res["subset"].V[:, torso].mean(axis=1)
    c0 = P0[torso].mean(axis=0)
    assert _circle_distance(c, c0).max() < 1e-9
    angle = np.unwrap(np.arctan2(c[:, 1], c[:, 0]))
    np.testing.assert_allclose(angle - angle[0], np.arange(19) * np.pi / 18, atol=1e-9)
    # without the subset the swinging limb drags the pose off the circle
    c_all = res["all"].V[:, torso].mean(axis=1)
    assert _circle_distance(c_all, c0).max() > 0.02
    # every torso vertex away from the joint: near its circle with the subset, not without
    d_sub = _circle_distance(res["subset"].V[inb][:, core], P0[core]).max()
    d_all = _circle_distance(res["all"].V[inb][:, core], P0[core]).max()
    assert d_sub < 0.05 < 0.1 < d_all


def test_rigid_subset_with_the_fit_track_and_pins(circling_body):
    V, F, keys, torso = circling_body
    frames = [0, 6, 12, 18]
    r = ss.interpolate((keys, F), frames=frames, rigid_subset=torso)       # rigid_track="fit"
    a = ss.interpolate((keys, F), frames=frames)
    # placed by the torso: its vertices sit closer to their own per-vertex cubic track
    track = ss.pipeline.placement_track(keys, frames, 18)
    err = {n: np.abs(x.V[:, torso] - track[:, torso]).max() for n, x in (("sub", r), ("all", a))}
    assert err["sub"] < 0.8 * err["all"]
    for j, f in enumerate(frames):
        assert np.array_equal(r.V[f], keys[j])


@pytest.mark.parametrize("sub, phrase", [([0, 1], "at least 3"), ([0, 12, 24], "on a line"),
                                         ([0, 1, 10**6], "rigid_subset")])
def test_rigid_subset_invalid(circling_body, sub, phrase):
    V, F, keys, torso = circling_body
    with pytest.raises(ss.ShellsplineError, match=phrase):
        ss.interpolate((keys, F), frames=[0, 6, 12, 18], rigid_subset=sub)
    with pytest.raises(ss.ShellsplineError, match="linear"):
        ss.interpolate((keys, F), frames=[0, 6, 12, 18], rigid_subset=torso, method="linear")


def test_rigid_subset_from_the_command_line(circling_body, tmp_path):
    from shellspline.cli.main import main

    V, F, keys, torso = circling_body
    paths = []
    for j, K in enumerate(keys):
        paths.append(tmp_path / f"pose_{j}.obj")
        ss.write_sequence(tmp_path / f"k{j}", K[None], F)
        (tmp_path / f"k{j}" / "frame_0000.obj").rename(paths[-1])
    (tmp_path / "torso.txt").write_text("\n".join(map(str, torso)) + "\n")
    out = tmp_path / "out"
    rc = main(["interpolate", *map(str, paths), "--frames", "0,6,12,18", "--rigid-track",
               "spline", "--rigid-subset", str(tmp_path / "torso.txt"), "-o", str(out), "-q"])
    assert rc in (0, 1)
    Vs, _, rep = ss.read_sequence(out)
    assert rep["parameters"]["rigid_subset_vertices"] == len(torso)
    c = Vs[:, torso].mean(axis=1)
    assert _circle_distance(c, (V[torso] + [4.0, 0, 0]).mean(axis=0)).max() < 1e-9
    (tmp_path / "bad.txt").write_text("0\n5000\n")
    rc = main(["interpolate", *map(str, paths), "--rigid-subset", str(tmp_path / "bad.txt"),
               "-o", str(tmp_path / "o2"), "-q"])
    assert rc == 2 and not (tmp_path / "o2").exists()


def test_geodesic_method_honours_coarse_and_starts_from_lta(ellipsoids):
    """Issue 13 item 7: ``--coarse`` was ignored by ``method="geodesic"`` (the 8.4k-vertex
    horse ran one Newton solve with 480k unknowns: >4 min and 4 GB for its first step). Now
    it solves on the decimated keyframes and prolongs like the LΘA spline; ``"auto"``
    decimates above 2000 vertices as for the nonlinear spline; each segment starts from the
    LΘA spline, not the keyframe blend."""
    from shellspline.pipeline.options import coarse_target

    d = ellipsoids
    kw = dict(frames=d["frames"], eta=0.1, method="geodesic")
    full = ss.interpolate((d["V"], d["F"]), **kw)
    assert "multires" not in full.report and full.report["geodesic"]["start"] == "lta"
    coarse = ss.interpolate((d["V"], d["F"]), coarse=60, **kw)
    rep = coarse.report
    assert rep["multires"]["coarse_vertices"] == 60 and rep["geodesic"]["resolution"] == "coarse"
    assert "coarse geodesic" in rep["timings"] and "prolong" in rep["timings"]
    assert rep["geodesic"]["success"]
    for j, f in enumerate(d["frames"]):
        assert np.array_equal(coarse.V[f], d["V"][j])
    q = rep["quality"]
    assert q["flipped_faces"] == 0 and q["collapsed_faces"] == 0
    # the prolonged coarse geodesic is near the full one (detail transfer of smooth shapes)
    diag = np.linalg.norm(np.ptp(d["V"][0], axis=0))
    assert np.abs(coarse.V - full.V).max() < 0.05 * diag
    assert coarse_target("auto", 3000, "geodesic") == 1000
    assert coarse_target("auto", 3000, "lta") is None
    with pytest.raises(ValueError, match="fine=True.*geodesic"):
        ss.interpolate((d["V"], d["F"]), coarse=60, fine=True, **kw)


def test_length_and_area_targets_stay_positive_between_keyframes():
    """A face that shrinks hard at the middle keyframe and grows back: the cubic through its
    area dips below zero between the keyframes (the horse 0/02/04/06/08: −0.017 of the median
    area at frame 41, the face got no weight, collapsed, and Gauss–Newton stalled). Targets
    are held at POSITIVE_FLOOR of the smaller keyframe value of their gap; keyframes exact."""
    from scipy.interpolate import CubicSpline

    from shellspline.pipeline.describe import POSITIVE_FLOOR
    from shellspline.shells.descriptors import lta_descriptors

    V, F = icosphere(2)
    t = 0  # the face that shrinks: its first vertex moves to the middle of the other two
    a, b, c = F[t]
    Vmid = V.copy()
    Vmid[a] = 0.98 * (0.5 * (V[b] + V[c])) + 0.02 * V[a]
    frames = [0, 2, 12]
    Vkey = np.stack([V, Vmid, V])
    T = ss.topology(F)
    sL, _, sA = T.descriptor_slices()
    Zkey = lta_descriptors(Vkey, T)
    k = np.arange(13)
    raw = CubicSpline(frames, Zkey[:, sA][:, t])(k)
    assert raw.min() < 0  # the oracle: the cubic itself overshoots below zero
    res = ss.interpolate((Vkey, F), frames=frames, eta=0.1)
    Z = np.asarray(res.Z)
    for j, f in enumerate(frames):
        assert np.array_equal(res.V[f], Vkey[j])
    gap = np.searchsorted(frames, k, side="right") - 1
    gap = np.minimum(gap, len(frames) - 2)
    for s in (sL, sA):
        P = Zkey[:, s]
        floor = POSITIVE_FLOOR * np.minimum(P[gap], P[gap + 1])
        assert np.all(Z[:, s] >= floor - 1e-15)
    assert Z[:, sA][:, t].min() > 0
    assert res.report["gauss_newton"]["converged"] == res.report["gauss_newton"]["frames"]


def test_coarse_frames_get_more_gauss_newton_iterations_unless_the_user_says(monkeypatch):
    """Coarse iterations are cheap: the coarse mesh of a multiresolution run allows
    COARSE_MAX_ITER per frame, the full-resolution refinement the solver's default, and a
    user's max_iter holds for both."""
    from shellspline.pipeline import stages
    from shellspline.shells import reconstruct

    seen = []
    init = reconstruct.GaussNewton.__init__

    def spy(self, T, **kw):
        init(self, T, **kw)
        seen.append((T.n_vertices, self.max_iter))

    monkeypatch.setattr(reconstruct.GaussNewton, "__init__", spy)
    d = data_synth.generate("cactus", n_vertices=600)
    kw = dict(frames=d["frames"], pinned=d["pinned"], coarse=200, fine=True)
    ss.interpolate((d["V"], d["F"]), **kw)
    n = d["V"].shape[1]
    assert {m for v, m in seen if v < n} == {stages.COARSE_MAX_ITER}
    default = reconstruct.GaussNewton(ss.topology(d["F"])).max_iter
    assert {m for v, m in seen if v == n} == {default}
    seen.clear()
    ss.interpolate((d["V"], d["F"]), gn_options={"max_iter": 7}, **kw)
    assert {m for _, m in seen} == {7}


def test_a_linear_blend_through_a_half_turn_is_written_and_flagged_not_refused():
    """A cube turned 180° about z: the per-vertex blend passes every vertex through the
    axis, and the middle frame collapses every face to a segment. That is a result to
    report (collapsed faces, energies undefined), not bad input or a crash."""
    V0 = np.array([[-1, -1, -1], [1, -1, -1], [1, 1, -1], [-1, 1, -1],
                   [-1, -1, 1], [1, -1, 1], [1, 1, 1], [-1, 1, 1]], dtype=np.float64)
    F = np.array([[0, 3, 2], [0, 2, 1], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    V1 = V0 * np.array([-1.0, -1.0, 1.0])
    res = ss.interpolate((np.stack([V0, V1]), F), K=10, method="linear")
    assert "degenerate triangles" in res.report["energies"]["error"]
    assert "[5]" in res.report["energies"]["error"]
    q = res.report["quality"]
    assert q["collapsed_faces"] >= 12 and q["per_frame"]["collapsed"][5] == 12
    np.testing.assert_array_equal(res.V[5], np.zeros_like(V0) + V0 * [0, 0, 1])


def test_reference_geodesic_status_is_recorded_and_decides_success(monkeypatch):
    """`reference="geodesic"`: the reference path's solve was reported in one mid-run note
    only; an unconverged one left a run that said it succeeded (exit 0). Its record is in
    the report, and an unconverged reference is a convergence problem."""
    from shellspline.pipeline.report import convergence_problems
    from shellspline.shells import geodesic

    V0, F = icosphere(1)
    Vs = np.stack([V0, V0 * np.array([1.3, 1.0, 0.8]), V0 * np.array([0.9, 1.2, 1.0])])
    res = ss.interpolate((Vs, F), frames=[0, 3, 6], reference="geodesic", eta=0.1)
    ref = res.report["reference_geodesic"]
    assert ref["success"] and ref["status"] == "converged"
    assert "reference geodesic" not in " ".join(convergence_problems(res.report))
    real = geodesic.geodesic_interpolation
    monkeypatch.setattr(geodesic, "geodesic_interpolation",
                        lambda *a, **kw: real(*a, **{**kw, "max_iter": 1}))
    res = ss.interpolate((Vs, F), frames=[0, 3, 6], reference="geodesic", eta=0.1)
    ref = res.report["reference_geodesic"]
    assert not ref["success"] and ref["status"] == "limit"
    assert any("reference geodesic did not converge" in p
               for p in convergence_problems(res.report))


def test_max_time_bounds_the_reference_geodesic_solve():
    """`reference="geodesic"` solved its geodesic with no time limit (``max_time_s`` was
    ignored with ``method="lta"``, ``--max-time`` refused): on a big mesh it ran unbounded.
    ``max_time_s`` now bounds it on its own clock; a solve it stops keeps its paths so far
    and the run is not a success. A limit that is not reached changes nothing."""
    from shellspline.pipeline.report import convergence_problems

    V0, F = icosphere(1)
    Vs = np.stack([V0, V0 * np.array([1.3, 1.0, 0.8]), V0 * np.array([0.9, 1.2, 1.0])])
    kw = dict(frames=[0, 3, 6], reference="geodesic", eta=0.1)
    free = ss.interpolate((Vs, F), **kw)
    roomy = ss.interpolate((Vs, F), solver_options={"max_time_s": 600}, **kw)
    ref = roomy.report["reference_geodesic"]
    assert ref["success"] and ref["max_time_s"] == 600 and not ref["time_limit_reached"]
    assert ref["nit"] == free.report["reference_geodesic"]["nit"] >= 2
    assert ref["grad_norm_final"] < 1e-6 * ref["grad_norm_initial"]
    np.testing.assert_array_equal(roomy.V, free.V)
    tight = ss.interpolate((Vs, F), solver_options={"max_time_s": 1e-9}, **kw)
    ref = tight.report["reference_geodesic"]
    assert not ref["success"] and ref["status"] == "limit" and ref["time_limit_reached"]
    assert "time limit reached" in ref["message"] and ref["nit"] == 0
    assert ref["grad_norm_final"] == ref["grad_norm_initial"] > 0
    assert "reference geodesic did not converge (time limit reached; weights from its last " \
           "iterate)" in convergence_problems(tight.report)
    assert np.abs(tight.V - free.V).max() > 1e-6  # other weights: the blend's
    np.testing.assert_array_equal(tight.V[[0, 3, 6]], Vs)


def test_cli_max_time_stops_the_reference_geodesic_and_exits_1(tmp_path, capsys):
    """`--max-time` with `--reference geodesic` was refused for `--method lta`; now it bounds
    the reference solve, and a solve it stops is in the report, in the summary and exits 1."""
    import json
    from pathlib import Path

    from shellspline.cli.main import main

    d = tmp_path / "ell"
    data_synth.write("ellipsoids", d, n_vertices=150)
    poses = sorted(str(p) for p in Path(d).glob("pose_*.obj"))
    args = ["interpolate", *poses, "--frames", str(d / "frames.txt"), "--eta", "0.1",
            "--reference", "geodesic"]
    rc = main([*args, "--max-time", "1e-9", "-o", str(tmp_path / "tight")])
    err = capsys.readouterr().err
    assert rc == 1, err
    ref = json.loads((tmp_path / "tight" / "report.json").read_text())["reference_geodesic"]
    assert ref["status"] == "limit" and ref["time_limit_reached"] and ref["max_time_s"] == 1e-9
    line = [ln for ln in err.splitlines() if ln.startswith("reference geodesic: ")]
    assert len(line) == 1 and "NOT converged" in line[0] and "time limit reached" in line[0]
    rc = main([*args, "--max-time", "600", "-o", str(tmp_path / "roomy")])
    err = capsys.readouterr().err
    assert rc == 0, err
    ref = json.loads((tmp_path / "roomy" / "report.json").read_text())["reference_geodesic"]
    assert ref["success"] and ref["max_time_s"] == 600
    assert "reference geodesic: converged after" in err
    # linear blending has no reference: the limit would bound nothing
    rc = main([*args, "--method", "linear", "--max-time", "5", "-o", str(tmp_path / "lin")])
    err = capsys.readouterr().err
    assert rc == 2 and "--max-time" in err and not (tmp_path / "lin").exists()


def test_geodesic_method_extrapolates_frames_after_the_last_keyframe():
    """`--method geodesic --K` past the last keyframe said it extrapolates but held those
    frames at the keyframe (steps 0, then a pop); they are the LΘA start's extrapolation,
    which keeps moving at the sequence's pace."""
    V0, F = icosphere(1)
    Vs = np.stack([V0, V0 * np.array([1.3, 1.0, 0.8])])
    res = ss.interpolate((Vs, F), frames=[0, 3], K=5, method="geodesic", eta=0.1)
    step = np.abs(np.diff(res.V, axis=0)).max(axis=(1, 2))
    assert step.min() > 0.5 * step.max()
    np.testing.assert_array_equal(res.V[[0, 3]], Vs)
    lta = ss.interpolate((Vs, F), frames=[0, 3], K=5, eta=0.1)
    np.testing.assert_allclose(res.V[4:], lta.V[4:], atol=1e-6)


def test_periodic_loop_refuses_a_last_keyframe_that_repeats_the_first(tmp_path, capsys):
    """Closing a loop as a DCC tool does, the first pose repeated as the last keyframe, ran
    with ``bc="periodic"`` as a loop one gap longer: frame K (frame 0 again) came a gap after
    the repeated pose, and the frames between wandered off that pose and back (horse, frames
    0/6/12/18: up to 0.1 of its 1.4 diagonal). Refused, saying what to give instead; the loop
    it asks for runs, and an explicit K keeps the repeated pose as an interior keyframe."""
    V0, F = icosphere(1)
    V1, V2 = V0 * np.array([1.3, 1.0, 0.8]), V0 * np.array([0.9, 1.2, 1.0])
    Vs = np.stack([V0, V1, V2, V0.copy()])
    with pytest.raises(ss.ShellsplineError, match=r"repeats the first.*K=12.*K=9"):
        ss.interpolate((Vs, F), frames=[0, 3, 6, 9], bc="periodic", method="linear")
    closed = ss.interpolate((Vs[:3], F), frames=[0, 3, 6], K=9, bc="periodic",
                            method="linear")
    assert np.array_equal(closed.V[9], V0) and closed.V.shape[0] == 10
    held = ss.interpolate((Vs, F), frames=[0, 3, 6, 9], K=12, bc="periodic", method="linear")
    assert held.V.shape[0] == 13
    # files: the message names the repeated file; the CLI exits 2 and writes nothing
    from shellspline.cli.main import main

    paths = []
    for j, V in enumerate(Vs):
        paths.append(str(tmp_path / f"p{j}.obj"))
        Path(paths[-1]).write_text("".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in V)
                                   + "".join(f"f {a} {b} {c}\n" for a, b, c in F + 1))
    rc = main(["interpolate", *paths, "--frames", "0,3,6,9", "--bc", "periodic",
               "--method", "linear", "-q", "-o", str(tmp_path / "out")])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and not (tmp_path / "out").exists()
    assert len(err) == 1 and "p3.obj" in err[0] and "repeats the first" in err[0], err


def test_a_keyframe_in_other_units_is_noted():
    """A keyframe exported in centimetres among metre keyframes (100 times the size) ran
    without a word: the in-betweens grew 100 times and shrank back, thousands of flipped
    faces (horse, --coarse 1000: 2413). A note names it; poses of one size get none."""
    V0, F = icosphere(1)
    c, s = np.cos(0.5), np.sin(0.5)
    turned = V0 @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]).T
    Vs = np.stack([V0, 100 * turned, V0])
    events = []
    ss.interpolate((Vs, F), frames=[0, 3, 6], method="linear", progress=events.append)
    notes = [e["text"] for e in events if e.get("kind") == "message"]
    assert any("keyframe 1 is 100 times the size of keyframe 0" in t and "units" in t
               for t in notes), notes
    events.clear()
    ss.interpolate((Vs[[0, 2]] * [[[1.0]], [[1.5]]], F), frames=[0, 3], method="linear",
                   progress=events.append)
    assert not [e for e in events if e.get("kind") == "message"]
    events.clear()
    ss.interpolate((np.stack([V0, V0 / 100]), F), frames=[0, 3], method="linear",
                   progress=events.append)
    assert any("keyframe 1 is 1/100 of the size of keyframe 0" in e["text"]
               for e in events if e.get("kind") == "message")


@pytest.mark.parametrize("method", ["geodesic", "nonlinear"])
def test_time_limit_is_a_limit_status_in_the_method_record(method):
    """``report["geodesic"]`` and ``report["nonlinear"]`` had ``success`` and a message only:
    a run stopped by ``max_time_s`` could not be told from one that failed or stalled but by
    parsing the message, while ``reference_geodesic`` says ``status`` "limit" and
    ``time_limit_reached``. Both records now say it too."""
    V0, F = icosphere(1)
    Vs = np.stack([V0, V0 * np.array([1.3, 1.0, 0.8])])
    res = ss.interpolate((Vs, F), frames=[0, 3], method=method, eta=0.1,
                         solver_options={"max_time_s": 1e-9})
    rec = res.report[method]
    assert not rec["success"] and rec["status"] == "limit" and rec["time_limit_reached"] is True
    assert "time limit" in rec["message"]
    np.testing.assert_array_equal(res.V[[0, 3]], Vs)


def test_shapes_do_not_depend_on_where_the_keyframes_sit():
    # shell energies ignore rigid motions, and so does the whole method: the horse with one
    # keyframe turned by a quarter turn and moved far away gives the same shapes. The
    # frames' starts came from the blend of the keyframes as given: frames up to 0.10 of the
    # diagonal apart, 36 flipped faces against 25 (and in place, where horse-03 and 07 sit
    # 0.4 of the diagonal away from the reference, 25 against 7 now)
    from conftest import shared_data
    from shellspline.shells.reconstruct import rigid_placement

    kf = ss.read_keyframes([shared_data("horse", f"horse-{p}.obj")
                            for p in ("reference", "03", "07")])
    V = np.array(kf.V, dtype=np.float64)
    th = np.pi / 2
    R = np.array([[np.cos(th), 0.0, np.sin(th)], [0.0, 1.0, 0.0],
                  [-np.sin(th), 0.0, np.cos(th)]])
    moved = V.copy()
    moved[1] = V[1] @ R.T + np.array([54.0, 3.0, -7.0])
    runs = [ss.interpolate((X, kf.F), frames=[0, 6, 12], coarse=1000, workers=2)
            for X in (V, moved)]
    assert np.array_equal(runs[1].V[[0, 6, 12]], moved)          # keyframes as given
    diag = np.linalg.norm(V[0].max(axis=0) - V[0].min(axis=0))
    for a, b in zip(runs[0].V, runs[1].V):
        assert np.abs(rigid_placement(b, a) - a).max() < 1e-5 * diag
    assert runs[1].report["keyframe_alignment"]["max_shift"] > 1.0


def test_keyframes_of_a_loop_are_aligned_onto_the_first():
    # a loop blends its last keyframe with its first: a chain of fits (each keyframe onto
    # the one before) would carry the turns it picks up from swinging limbs into that gap;
    # an open sequence chains (a body that turns a corner stays aligned pair by pair)
    from data_synth import stress
    from shellspline.pipeline.stages import aligned_keyframes
    from shellspline.shells.reconstruct import rigid_placement

    d = stress.joint(angles=(0.0, 90.0, 150.0, 60.0), frames=(0, 4, 8, 12), rings=8,
                     segments=8)
    V = np.asarray(d["V"], dtype=np.float64)
    loop, _ = aligned_keyframes(V, d["F"], periodic=True)
    chain, _ = aligned_keyframes(V, d["F"])
    for j in range(1, len(V)):
        np.testing.assert_allclose(loop[j], rigid_placement(V[j], V[0]), atol=1e-12)
        np.testing.assert_allclose(chain[j], rigid_placement(V[j], chain[j - 1]), atol=1e-12)
    # the gap that closes the loop: its keyframes sit closer than the chain leaves them
    gap = [np.abs(X[-1] - X[0]).max() for X in (loop, chain)]
    assert gap[0] < gap[1]
