"""Prolongation by detail transfer: exact keyframes, no folds, details kept, equivariance."""
import numpy as np
import pytest

import data_synth
from shellspline.mesh.decimate import decimate
from shellspline.shells.lta_spline import lta_spline
from shellspline.pipeline.interpolation import linear_blend
from shellspline.shells.prolong import (Prolongation, linear_time_weights, prolong,
                                 spline_time_weights)


def _normals(V, F):
    return np.cross(V[..., F[:, 1], :] - V[..., F[:, 0], :], V[..., F[:, 2], :] - V[..., F[:, 0], :])


@pytest.fixture(scope="module")
def bumpy():
    d = data_synth.generate("bumpy", n_vertices=2500)
    dec = decimate(d["V"], d["F"], 400)
    return d, dec, Prolongation.encode(d["V"], d["F"], dec, d["frames"])


@pytest.mark.parametrize("tw", ["linear", "spline"])
def test_keyframes_come_back_bit_for_bit(bumpy, tw):
    d, dec, P = bumpy
    K = int(d["frames"][-1])
    Vc = linear_blend(dec.V, d["frames"], K)
    V = P.decode(Vc, d["frames"], K, time_weights=tw)
    assert V.shape == (K + 1,) + d["V"].shape[1:]
    for j, f in enumerate(d["frames"]):
        assert np.array_equal(V[f], d["V"][j])


def test_encoding_reproduces_keyframes_without_the_shortcut(bumpy):
    """The displacement transfer's formula itself returns the keyframe from its own coarse
    pose (the coefficients are encoded whatever the transfer)."""
    d, dec, P = bumpy
    S = P.base(dec.V)
    R = P.frames_of(S)
    V = S + np.einsum("jnab,jnb->jna", R, P.coeffs)
    assert np.abs(V - d["V"]).max() < 1e-12


def test_base_interpolates_coarse_vertices_and_kept_vertices_follow(bumpy):
    d, dec, P = bumpy
    K = int(d["frames"][-1])
    Vc = linear_blend(dec.V, d["frames"], K)
    S = P.base(Vc[3])
    assert np.array_equal(S[dec.kept], Vc[3])
    V = P.decode(Vc)
    assert np.abs(V[:, dec.kept] - Vc).max() < 1e-12


def test_linear_coarse_sequence_has_no_folded_triangles(bumpy):
    d, dec, P = bumpy
    F, fr = d["F"], d["frames"]
    K = int(fr[-1])
    V = P.decode(linear_blend(dec.V, fr, K))
    N = _normals(V, F)
    Nk = _normals(d["V"], F)
    for k in range(K + 1):
        j0 = min(np.searchsorted(fr, k, side="right") - 1, len(fr) - 2)
        for j in (j0, j0 + 1):
            cos = np.einsum("mi,mi->m", N[k], Nk[j]) / (
                np.linalg.norm(N[k], axis=1) * np.linalg.norm(Nk[j], axis=1))
            assert cos.min() > 0.5
    area = 0.5 * np.linalg.norm(N, axis=-1)
    assert area.min() > 0.1 * (0.5 * np.linalg.norm(Nk, axis=-1)).min()


def test_in_between_keeps_the_bumps(bumpy):
    """bumpy keyframes are the bumped unit sphere scaled per axis: divide a frame by the
    linearly interpolated axes and the bump amplitude must match the keyframes' (10 %)."""
    d, dec, P = bumpy
    fr, A = d["frames"], d["axes"]
    K = int(fr[-1])
    V = P.decode(linear_blend(dec.V, fr, K))
    W = linear_time_weights(fr, K)
    amp = np.array([np.linalg.norm(V[k] / (W[k] @ A), axis=1).std() for k in range(K + 1)])
    key_amp = amp[fr].mean()
    assert np.abs(amp / key_amp - 1).max() < 0.10
    # and the detail is not simply copied: the coarse-only surface has much smaller bumps
    S = P.base(linear_blend(dec.V, fr, K)[3])
    assert np.linalg.norm(S / (W[3] @ A), axis=1).std() < 0.8 * key_amp


def test_rigid_motion_of_the_coarse_path_moves_the_detail_rigidly():
    d = data_synth.generate("cactus", n_vertices=1200)
    V0 = d["V"][1]
    K = 4
    th = np.linspace(0, np.pi / 2, K + 1)

    def rot(t):
        c, s = np.cos(t), np.sin(t)
        return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])

    key = np.stack([V0, V0 @ rot(th[-1]).T])
    dec = decimate(key, d["F"], 150)
    P = Prolongation.encode(key, d["F"], dec, [0, K])
    Vc = np.stack([dec.V[0] @ rot(t).T for t in th])
    V = P.decode(Vc)
    for k in range(K + 1):
        assert np.abs(V[k] - V0 @ rot(th[k]).T).max() < 1e-10


def test_pinned_vertices_stay_put():
    d = data_synth.generate("cactus", n_vertices=1200)
    fr = d["frames"]
    K = int(fr[-1])
    dec = decimate(d["V"], d["F"], 0.1, pinned=d["pinned"])
    Vc = linear_blend(dec.V, fr, K)
    Vc = Vc + 1e-3 * np.sin(np.arange(K + 1))[:, None, None]   # a coarse path that moves
    V = prolong(Vc, d["V"], d["F"], dec, fr, pinned=d["pinned"])
    assert np.array_equal(V[:, d["pinned"]], np.broadcast_to(d["V"][0, d["pinned"]],
                                                              (K + 1, len(d["pinned"]), 3)))


def test_flat_sheet_base_stays_flat():
    from conftest import grid_sheet

    V, F = grid_sheet(12, 10)
    Vs = np.stack([V, V + [0.0, 0.0, 0.0]])
    Vs[1, :, 2] = 0.05 * np.sin(6 * V[:, 0])
    dec = decimate(Vs, F, 40)
    P = Prolongation.encode(Vs, F, dec)
    S = P.base(dec.V[0])
    assert np.abs(S[:, 2]).max() == 0.0


def test_time_weights():
    fr = np.array([0, 3, 7])
    W = linear_time_weights(fr, 9)
    assert W.shape == (10, 3)
    assert np.allclose(W.sum(1), 1.0)
    assert np.array_equal(W[fr], np.eye(3))
    assert np.allclose(W[5], [0, 0.5, 0.5])
    assert np.array_equal(W[9], [0, 0, 1])
    Wp = linear_time_weights(fr, 9, "periodic")
    assert np.allclose(Wp[8], [0.5, 0, 0.5])
    Z = np.random.default_rng(0).normal(size=(3, 4))
    Ws = spline_time_weights(fr, 9)
    assert np.allclose(Ws @ Z, lta_spline(Z, fr, 9), atol=1e-12)
    assert np.array_equal(Ws[fr], np.eye(3))


def test_invalid_inputs_raise(bumpy):
    d, dec, P = bumpy
    K = int(d["frames"][-1])
    Vc = linear_blend(dec.V, d["frames"], K)
    with pytest.raises(ValueError, match="Vc"):
        P.decode(Vc[:, :-1])
    with pytest.raises(ValueError, match="frames"):
        P.decode(Vc, [0, 5, 12])
    with pytest.raises(ValueError, match="time_weights"):
        P.decode(Vc, time_weights=np.ones((K, 3)))
    with pytest.raises(ValueError, match="time_weights"):
        P.decode(Vc, time_weights="cubic")
    with pytest.raises(ValueError, match="K"):
        P.decode(Vc[:5], K=4)
    with pytest.raises(ValueError, match="Vs_fine"):
        Prolongation.encode(d["V"][:, :-1], d["F"], dec)
    with pytest.raises(ValueError, match="frames"):
        Prolongation.encode(d["V"], d["F"], dec, [0, 0, 1])
    with pytest.raises(ValueError, match="pinned"):
        Prolongation.encode(d["V"], d["F"], dec, pinned=[0])
    with pytest.raises(ValueError, match="frames"):
        linear_time_weights([0, 5, 3], 9)
    with pytest.raises(ValueError, match="K"):
        linear_time_weights([0, 5], 0)


def test_encode_accepts_a_prebuilt_topology(bumpy):
    from shellspline import topology

    d, dec, P = bumpy
    T = topology(d["F"], d["V"].shape[1])
    P2 = Prolongation.encode(d["V"], T, dec, d["frames"])
    assert np.array_equal(P2.coeffs, P.coeffs)
    K = int(d["frames"][-1])
    Vc = linear_blend(dec.V, d["frames"], K)
    assert np.array_equal(P2.decode(Vc), P.decode(Vc))


def _shaken_coarse(d, dec):
    K = int(d["frames"][-1])
    Vc = linear_blend(dec.V, d["frames"], K)
    Vc[1:-1] += 0.01 * np.sin(np.arange(K - 1))[:, None, None]   # not a blend any more
    Vc[d["frames"]] = dec.V
    return Vc, K


def test_chunked_decode_equals_one_frame_at_a_time(bumpy):
    d, dec, _ = bumpy
    P = Prolongation.encode(d["V"], d["F"], dec, d["frames"], transfer="displacement")
    Vc, K = _shaken_coarse(d, dec)
    a, b = P.decode(Vc, chunk=1), P.decode(Vc, chunk=7)
    assert np.abs(a - b).max() < 1e-12
    # frame by frame through the public pieces: base, frames_of, coefficients
    W = linear_time_weights(d["frames"], K)
    k = 3
    S = P.base(Vc[k])
    R = P.frames_of(S)
    ref = S + np.einsum("nab,nb->na", R, np.einsum("j,jna->na", W[k], P.coeffs))
    assert np.abs(a[k] - ref).max() < 1e-12


def test_gradient_transfer_is_the_least_squares_fit_of_the_carried_edges(bumpy):
    """transfer="gradient": a frame is the weighted least-squares fit of the keyframe edge
    vectors carried on the base frames of their two vertices, the coarse vertices anchored
    with weight ε = ANCHOR × mean diagonal of the edge Laplacian; the misfit left at the
    coarse vertices is then spread by the base surface's bi-Laplacian interpolation.
    Oracle: the fit written out edge by edge and solved by scipy's LSQR, from the public
    pieces (base, frames_of, the keyframes)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import lsqr
    from shellspline.mesh.topology import topology
    from shellspline.shells.prolong import ANCHOR, _edge_weights

    d, dec, P = bumpy
    assert P.transfer == "gradient"
    Vc, K = _shaken_coarse(d, dec)
    a, b = P.decode(Vc, chunk=1), P.decode(Vc, chunk=5)
    assert np.abs(a - b).max() < 1e-12
    E = topology(d["F"]).E
    w = _edge_weights(d["V"], E)
    W = linear_time_weights(d["frames"], K)
    Rkey = P.frames_of(P.base(dec.V))                          # (J, n, 3, 3)
    g = d["V"][:, E[:, 1]] - d["V"][:, E[:, 0]]
    k = 3
    R = P.frames_of(P.base(Vc[k]))
    h = np.zeros((E.shape[0], 3))
    for end in (E[:, 0], E[:, 1]):  # keyframe coordinates in each end's frame, interpolated
        c = np.einsum("j,jeb->eb", W[k], np.einsum("jeab,jea->jeb", Rkey[:, end], g))
        h += 0.5 * np.einsum("eab,eb->ea", R[end], c)
    n, ne, nc = d["V"].shape[1], E.shape[0], dec.kept.shape[0]
    degree = np.bincount(E.ravel(), weights=np.r_[w, w], minlength=n)
    eps = ANCHOR * degree.mean()
    # rows √w_e (x_b − x_a) = √w_e h_e and √ε x_c = √ε Vc_c
    rows = np.r_[np.arange(ne), np.arange(ne), ne + np.arange(nc)]
    cols = np.r_[E[:, 1], E[:, 0], dec.kept]
    vals = np.r_[np.sqrt(w), -np.sqrt(w), np.full(nc, np.sqrt(eps))]
    A = sp.csr_matrix((vals, (rows, cols)), shape=(ne + nc, n))
    rhs = np.vstack([np.sqrt(w)[:, None] * h, np.sqrt(eps) * Vc[k]])
    fit = np.stack([lsqr(A, rhs[:, i], atol=1e-15, btol=1e-15, iter_lim=50000)[0]
                    for i in range(3)], axis=1)
    x = fit + P.base(Vc[k] - fit[dec.kept])
    assert np.abs(a[k] - x).max() < 1e-8
    assert np.abs(a[k, dec.kept] - Vc[k]).max() == 0


def test_gradient_transfer_with_pins_that_are_not_coarse_vertices():
    """Pinned fine vertices that decimation merged away stay at their keyframe position in
    the fit, and the misfit at the coarse vertices is spread with them held (its own
    bi-Laplacian factorization). Oracle: the anchored fit and the spread solved densely
    (numpy lstsq, scipy spsolve) from the public pieces."""
    import data_synth.stress as stress
    import scipy.sparse as sp
    from scipy.sparse.linalg import spsolve
    from shellspline.mesh.topology import topology
    from shellspline.shells.prolong import ANCHOR, _edge_weights

    c = stress.joint(rings=12, segments=8)
    T, fr = topology(c["F"]), c["frames"]
    dec = decimate(c["V"], T, 0.3, pinned=c["pinned"])
    loose = np.setdiff1d(c["pinned"], dec.kept)
    assert loose.size > 0                                       # the case under test
    P = Prolongation.encode(c["V"], T, dec, fr, pinned=c["pinned"])
    K = int(fr[-1])
    Vc = linear_blend(dec.V, fr, K)
    Vc[1:-1] += 0.01 * np.cos(np.arange(K - 1))[:, None, None]
    Vc[fr] = dec.V
    Vc[:, dec.pinned] = dec.V[0, dec.pinned]                    # coarse pins stay too
    k = 4
    got = P.decode(Vc)[k]
    E = T.E
    w = _edge_weights(c["V"], E)
    W = linear_time_weights(fr, K)
    Rkey = P.frames_of(P.base(dec.V))
    R = P.frames_of(P.base(Vc[k]))
    g = c["V"][:, E[:, 1]] - c["V"][:, E[:, 0]]
    h = sum(0.5 * np.einsum("eab,eb->ea", R[end], np.einsum(
        "j,jeb->eb", W[k], np.einsum("jeab,jea->jeb", Rkey[:, end], g))) for end in E.T)
    n, ne = T.n_vertices, E.shape[0]
    pinned_pos = c["V"][0, loose]
    free = np.setdiff1d(np.arange(n), loose)
    degree = np.bincount(E.ravel(), weights=np.r_[w, w], minlength=n)
    eps = ANCHOR * degree.mean()
    A = np.zeros((ne + dec.kept.size, n))
    A[np.arange(ne), E[:, 1]] = np.sqrt(w)
    A[np.arange(ne), E[:, 0]] = -np.sqrt(w)
    A[ne + np.arange(dec.kept.size), dec.kept] = np.sqrt(eps)
    rhs = np.vstack([np.sqrt(w)[:, None] * h, np.sqrt(eps) * Vc[k]])
    rhs -= A[:, loose] @ pinned_pos
    x = np.zeros((n, 3))
    x[loose] = pinned_pos
    x[free] = np.linalg.lstsq(A[:, free], rhs, rcond=None)[0]
    # spread the misfit: min ‖L c‖², c = misfit at the coarse vertices, 0 at the pins
    Lw = sp.coo_matrix((np.r_[w, w], (np.r_[E[:, 0], E[:, 1]], np.r_[E[:, 1], E[:, 0]])),
                       shape=(n, n)).tocsr()
    L = sp.diags(np.asarray(Lw.sum(axis=1)).ravel()) - Lw
    B = (L.T @ L).tocsr()
    held = np.union1d(dec.kept, loose)
    rest = np.setdiff1d(np.arange(n), held)
    corr = np.zeros((n, 3))
    corr[dec.kept] = Vc[k] - x[dec.kept]
    corr[rest] = -spsolve(B[rest][:, rest].tocsc(), B[rest][:, held] @ corr[held])
    assert np.abs(got - (x + corr)).max() < 1e-9
    assert np.array_equal(got[c["pinned"]], c["V"][0, c["pinned"]])


def test_gradient_transfer_reproduces_the_keyframes_from_its_own_formula(bumpy):
    """At a keyframe the carried edge vectors are the keyframe's own, so the fit returns the
    keyframe itself (decode's shortcut of copying keyframes is not needed)."""
    d, dec, P = bumpy
    W = np.eye(len(d["frames"]))
    S = P._base_vm(dec.V)
    x = P._grad.solve(P._frames_vm(S), W, dec.V, P.keyframes[0])
    assert np.abs(x.transpose(1, 0, 2) - d["V"]).max() < 1e-10


def test_unknown_transfer_is_refused(bumpy):
    d, dec, _ = bumpy
    with pytest.raises(ValueError, match="transfer"):
        Prolongation.encode(d["V"], d["F"], dec, d["frames"], transfer="offsets")


def _graded_tube(rng, nt=24, nz=60):
    """A tube (radius 0.2, z in [-1, 1]) whose rings crowd towards z = 0 (spacing ∝ |z|) and
    whose vertices are jittered around the rings: an irregular mesh, dense at the joint."""
    z = np.linspace(-1, 1, nz)
    z = np.sign(z) * z ** 2
    th = np.linspace(0, 2 * np.pi, nt, endpoint=False)
    Z, TH = np.meshgrid(z, th, indexing="ij")
    TH = TH + rng.uniform(-0.3, 0.3, TH.shape) * (2 * np.pi / nt)
    V = np.stack([0.2 * np.cos(TH).ravel(), 0.2 * np.sin(TH).ravel(), Z.ravel()], 1)
    idx = np.arange(nz * nt).reshape(nz, nt)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1].ravel(), nxt[:-1].ravel(), nxt[1:].ravel(), idx[1:].ravel()
    return V, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def _flex(V, angle, half_width=0.15):
    """The tube's upper half rotated about the x axis by ``angle``, blended smoothly across
    ``|z| < half_width`` (a joint)."""
    s = np.clip((V[:, 2] + half_width) / (2 * half_width), 0, 1)
    a = angle * s * s * (3 - 2 * s)
    y, z = V[:, 1], V[:, 2]
    return np.stack([V[:, 0], np.cos(a) * y - np.sin(a) * z, np.sin(a) * y + np.cos(a) * z], 1)


@pytest.mark.parametrize("transfer", ["gradient", "displacement"])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_joint_flexing_150_degrees_prolongs_without_flipping_the_fine_faces(seed, transfer):
    """Issue 13 item 3: a joint flexing to 150° on an irregular mesh, the coarse sequence
    being the exact analytic motion restricted to the coarse vertices. The prolonged fine
    frames are compared with the analytic fine motion (the oracle): with the uniform
    bi-Laplacian base the encoded details were long (the base drifts along the graded
    rings) and their frames' rotation flipped 16-59 fine faces and moved vertices by up to
    0.0076; the edge-length weights give at most 9 and 0.0047 (displacement transfer; the
    gradient transfer 7, 8 and 7 faces)."""
    V, F = _graded_tube(np.random.default_rng(seed))
    frames, K = [0, 8, 16], 16
    angles = np.radians([0.0, 75.0, 150.0])
    Vs = np.stack([_flex(V, a) for a in angles])
    dec = decimate(Vs, F, 0.1)
    truth = np.stack([_flex(V, a) for a in np.interp(np.arange(K + 1), frames, angles)])
    Vp = Prolongation.encode(Vs, F, dec, frames, transfer=transfer).decode(
        truth[:, dec.kept], frames, K)
    agree = np.einsum("kmi,kmi->km", _normals(Vp, F), _normals(truth, F)) > 0
    assert (~agree).sum() <= 12
    assert np.abs(Vp - truth).max() <= 0.006
    assert np.array_equal(Vp[frames], Vs)


# -- the guard: no defect that the coarse frames do not have (issue 13 item 7) -------------------

@pytest.fixture(scope="module")
def sliver_run():
    """data_synth.stress.slivers (half the triangles 1 % of the median area) decimated to a
    quarter, its coarse LΘA solution, and the prolongation of it."""
    import data_synth.stress as stress
    from shellspline import interpolate, topology

    c = stress.slivers()
    T = topology(c["F"])
    dec = decimate(c["V"], T, 0.25, pinned=c["pinned"])
    Vc = interpolate((dec.V, dec.F), frames=c["frames"], pinned=dec.pinned, coarse="none").V
    # the paper's displacement transfer: the guard's tests need the defects it makes
    P = Prolongation.encode(c["V"], T, dec, c["frames"], pinned=c["pinned"],
                            transfer="displacement")
    return c, T, dec, Vc, P, P.decode(Vc)


def test_gradient_transfer_adds_no_defect_to_the_sliver_run(sliver_run):
    """The sliver tube's coarse LΘA solution prolonged by the two transfers. Displacements
    carried on the base frames turn slivers (1 % of the median area) over: 184 new flipped
    faces and 76 folded edges when this was written. The carried edge vectors keep each
    sliver's shape up to the rotation of its vertices' frames: no new defect, before any
    guard (one folded edge, whose flap has three coarse vertices)."""
    c, T, dec, Vc, Pd, Vd = sliver_run
    P = Prolongation.encode(c["V"], T, dec, c["frames"], pinned=c["pinned"])
    V = P.decode(Vc)
    _, rd = Pd.guard(Vd, Vc, max_rounds=0)
    _, rg = P.guard(V, Vc, max_rounds=0)
    assert rd["new_defects_before"]["flipped"] > 20
    assert rg["new_defects_before"]["flipped"] == 0
    assert rg["new_defects_before"]["folded"] <= 1
    assert rg["new_defects_before"]["collapsed"] == 0
    for j, f in enumerate(c["frames"]):
        assert np.array_equal(V[f], c["V"][j])
    assert np.array_equal(V[:, c["pinned"]],
                          np.broadcast_to(c["V"][0, c["pinned"]], (V.shape[0],
                                                                   len(c["pinned"]), 3)))
    assert np.abs(V[:, dec.kept] - Vc).max() < 1e-12


def _defective_steps(V, T, frames):
    from shellspline.metrics import sequence_defects

    d = sequence_defects(V, T, frames)["per_frame"]
    return np.array(d["flipped"]) + np.array(d["folded"]) + np.array(d["collapsed"])


def test_step_defects_are_what_sequence_defects_counts(sliver_run):
    from shellspline.metrics import sequence_defects
    from shellspline.shells.prolong import step_defects

    c, T, dec, Vc, P, V = sliver_run
    d = step_defects(V, T, c["frames"])
    m = sequence_defects(V, T, c["frames"])
    assert m["flipped_faces"] > 20 and m["folded_edges"] > 10      # a sequence with defects
    assert d["flipped"].sum(axis=1).tolist() == m["per_frame"]["flipped"][1:]
    assert d["folded"].sum(axis=1).tolist() == m["per_frame"]["folded"][1:]
    assert d["collapsed"].sum(axis=1).tolist() == m["per_frame"]["collapsed"]


def test_guard_fades_the_detail_that_turns_slivers_over(sliver_run):
    """The detail of slivers (1 % of an edge high) carried on a coarse LΘA solution turns
    them over and folds them in steps where the coarse frames have no defect at all (11 such
    steps, 184 new flipped faces and 76 folded edges when this was written); the guard leaves
    no new flipped face and at most one folded edge, keyframes and pins exact, and keeps
    the detail elsewhere."""
    c, T, dec, Vc, P, V = sliver_run
    fr = c["frames"]
    from shellspline import topology

    clean = _defective_steps(Vc, topology(dec.F), fr) == 0
    raw = _defective_steps(V, T, fr)
    assert (raw[clean] > 0).sum() >= 3
    Vg, rec = P.guard(V, Vc)
    assert rec["new_defects_before"]["flipped"] > 20
    assert rec["new_defects_after"]["flipped"] == 0
    assert rec["new_defects_after"]["folded"] <= 1
    assert rec["new_defects_after"]["collapsed"] == 0
    assert (_defective_steps(Vg, T, fr)[clean] > 0).sum() <= 1
    for j, f in enumerate(fr):
        assert np.array_equal(Vg[f], c["V"][j])
    assert np.array_equal(Vg[:, c["pinned"]], V[:, c["pinned"]])
    same = np.all(Vg == V, axis=-1)
    assert same.mean() > 0.25                                   # the detail stays elsewhere
    # where the detail is faded completely the vertex lies on the base surface
    moved = ~same
    S = P.base(Vc)
    on_base = np.linalg.norm(Vg - S, axis=-1) < 1e-12
    assert on_base[moved].any()


def test_guard_stops_when_fading_only_adds_defects(sliver_run, monkeypatch):
    """A fallback with defects everywhere (the prolonged frames mirrored through z = 0: every
    faded face turns over): fading only adds defects, and the guard gives up after
    GUARD_PATIENCE rounds without a better one, returning its input (its best round) instead
    of running all max_rounds (the horse subdivided twice: 528 → 10 383 new defects after
    five rounds, 66 s of guard for nothing)."""
    from shellspline.shells import prolong as PR

    c, T, dec, Vc, P, V = sliver_run
    counts = []
    count = PR._new_defects

    def counted(*args):
        out = count(*args)
        counts.append(sum(out[0].values()))
        return out

    monkeypatch.setattr(PR, "_new_defects", counted)
    Vg, rec = P.guard(V, Vc, fallback=V * np.array([1.0, 1.0, -1.0]), max_rounds=20)
    assert len(counts) == PR.GUARD_PATIENCE + 1
    assert min(counts[1:]) > counts[0] > 0                 # every round was worse
    assert rec["rounds"] == 0 and rec["new_defects_after"] == rec["new_defects_before"]
    assert np.array_equal(Vg, V)


def test_guard_rescanning_only_the_changed_steps_is_the_full_rescan(sliver_run, monkeypatch):
    """After a round of fading, the guard scans again only the steps next to the frames it
    changed: the sequence and record are those of scanning every step every round (17
    rounds on the sliver tube when this was written), towards the base and towards an
    explicit fallback."""
    from shellspline.shells.defects import DefectRules

    c, T, dec, Vc, P, V = sliver_run
    rng = np.random.default_rng(1)
    shaken = V + 0.02 * rng.normal(size=V.shape)
    shaken[P.frames] = V[P.frames]
    scans = []
    scan = DefectRules.scan

    def counted(self, V, steps=None):
        scans.append(self.K if steps is None else len(np.unique(steps)))
        return scan(self, V, steps)

    monkeypatch.setattr(DefectRules, "scan", counted)
    fast = [P.guard(V, Vc), P.guard(shaken, Vc, fallback=V)]
    assert fast[0][1]["rounds"] > 5 and fast[1][1]["rounds"] > 1
    assert min(scans) < P.frames[-1] // 2                         # some rounds scan a few

    def full(self, V, steps=None):
        return scan(self, V)                                      # every step, every round

    monkeypatch.setattr(DefectRules, "scan", full)
    slow = [P.guard(V, Vc), P.guard(shaken, Vc, fallback=V)]
    for (a, ra), (b, rb) in zip(fast, slow):
        assert ra == rb
        assert np.array_equal(a, b)


def test_guard_changes_nothing_where_the_prolongation_adds_no_defect(bumpy):
    d, dec, P = bumpy
    fr = d["frames"]
    K = int(fr[-1])
    Vc = linear_blend(dec.V, fr, K)
    V = P.decode(Vc)
    Vg, rec = P.guard(V, Vc)
    assert rec["new_defects_before"] == {"flipped": 0, "folded": 0, "collapsed": 0}
    assert rec["faded"] == 0 and rec["rounds"] == 0
    assert np.array_equal(Vg, V)
    with pytest.raises(ValueError, match="`V`"):
        P.guard(V[:-1], Vc)


def test_coarse_interpolation_reports_the_guard():
    import data_synth.stress as stress
    from shellspline import interpolate

    c = stress.slivers()
    res = interpolate((c["V"], c["F"]), frames=c["frames"], pinned=c["pinned"], coarse=0.25)
    g = res.report["multires"]["guard"]
    assert g["new_defects_after"]["flipped"] <= g["new_defects_before"]["flipped"]
    assert g["new_defects_after"]["flipped"] == 0
    for j, f in enumerate(c["frames"]):
        assert np.array_equal(res.V[f], c["V"][j])


def test_guard_towards_the_base_given_as_fallback_is_the_default_guard(sliver_run):
    """``fallback`` fades positions linearly: with the base surface as fallback,
    ``V0 + f (S − V0) = S + (1 − f) R c`` is the default guard (the detail scaled)."""
    c, T, dec, Vc, P, V = sliver_run
    a, ra = P.guard(V, Vc)
    b, rb = P.guard(V, Vc, fallback=P.base(Vc))
    assert ra == rb and ra["faded"] > 0
    assert np.abs(a - b).max() < 1e-12
    with pytest.raises(ValueError, match="fallback"):
        P.guard(V, Vc, fallback=V[:-1])


def test_fine_refinement_adds_no_defect_either():
    """``fine=True`` on a sliver tube: the full-resolution Gauss–Newton started from the
    guarded prolongation turned 10 faces over and folded 3 edges that no coarse element near
    them has (when this was written); the refinement's guard fades them back to the
    prolonged start."""
    import data_synth.stress as stress
    from shellspline import interpolate

    c = stress.slivers(rings=20, segments=12)
    res = interpolate((c["V"], c["F"]), frames=c["frames"], pinned=c["pinned"], coarse=0.25,
                      fine=True)
    g = res.report["multires"]["fine_guard"]
    assert g["new_defects_after"] == {"flipped": 0, "folded": 0, "collapsed": 0}
    for j, f in enumerate(c["frames"]):
        assert np.array_equal(res.V[f], c["V"][j])
    assert np.array_equal(res.V[:, c["pinned"]],
                          np.broadcast_to(c["V"][0, c["pinned"]], (res.V.shape[0],
                                                                   len(c["pinned"]), 3)))


def test_fine_runs_start_from_the_prolonged_frame_or_the_blend_whichever_is_lower(monkeypatch):
    """``fine=True`` starts each run of frames from a keyframe at the prolonged frame or at
    the keyframe blend, whichever has the lower reconstruction energy. On the sliver tube at
    15 % of its vertices the prolonged frames are the worse starts at all four run starts
    (244 Gauss–Newton iterations from them, 222 from the blend when this was written): the
    fine pass then reconstructs every frame as full resolution does."""
    import data_synth.stress as stress
    from shellspline import interpolate
    from shellspline.pipeline import reconstruction, stages

    c = stress.slivers()
    # the displacement transfer's prolonged frames are the worse starts here (the gradient
    # transfer's are the better ones)
    kw = dict(frames=c["frames"], pinned=c["pinned"], transfer="displacement")
    full = interpolate((c["V"], c["F"]), coarse="none", **kw).report
    fine = interpolate((c["V"], c["F"]), coarse=0.15, fine=True, **kw).report
    monkeypatch.setattr(stages, "given_starts", lambda V, *args: (V, {}))
    # and no other start either (warm_start would otherwise find the lower start itself)
    monkeypatch.setattr(reconstruction, "START_PREFERENCE", 0.0)
    given = interpolate((c["V"], c["F"]), coarse=0.15, fine=True, **kw).report
    starts = fine["multires"]["fine_starts"]
    firsts = sorted(starts["prolonged"] + starts["blend"])
    assert firsts == [1, 9, 11, 19]
    e_full, e_fine, e_given = ({r["frame"]: r["energy_initial"] for r in rep["frames"]}
                               for rep in (full, fine, given))
    for k in firsts:  # the lower of the two starts
        assert e_fine[k] == pytest.approx(min(e_full[k], e_given[k]), rel=1e-9)
    assert starts["blend"]
    its = [rep["gauss_newton"]["iterations_total"] for rep in (full, fine, given)]
    assert fine["gauss_newton"]["converged"] == fine["gauss_newton"]["frames"]
    if starts["blend"] == firsts:
        assert its[1] == its[0]
    assert its[1] < its[2]


def test_gradient_transfer_keeps_dense_slivers_without_spikes_or_stretch():
    """data_synth.stress.dense_slivers (6 080 vertices, slivers 1 % of the median area)
    decimated 24 times, its coarse LΘA solution prolonged by both transfers and guarded.
    Displacements carried on the base frames turned 4 711 faces over and folded 1 614 edges
    (when this was written); the guard faded 68 % of all vertex-frames onto the base
    surface, which does not keep the slivers' ring spacing: edges 100 times their keyframe
    length (99th percentile of the strain against the keyframe lengths blended in time:
    124). The gradient transfer: 7 flipped faces and 3 folded edges, nothing faded, strain
    (99th percentile) 0.17 (linear blending: 0.74)."""
    import data_synth.stress as stress
    from shellspline import interpolate, topology

    c = stress.dense_slivers(subdivisions=1)
    T, fr = topology(c["F"]), c["frames"]
    dec = decimate(c["V"], T, 250, pinned=c["pinned"])
    Vc = interpolate((dec.V, dec.F), frames=fr, pinned=dec.pinned, coarse="none").V
    K = Vc.shape[0] - 1
    E = T.E

    def lengths(V):
        return np.linalg.norm(V[..., E[:, 1], :] - V[..., E[:, 0], :], axis=-1)

    blended = linear_time_weights(fr, K) @ lengths(c["V"])
    out = {}
    for tr in ("gradient", "displacement"):
        P = Prolongation.encode(c["V"], T, dec, fr, pinned=c["pinned"], transfer=tr)
        V, rec = P.guard(P.decode(Vc), Vc)
        strain = np.abs(lengths(V) / blended - 1)
        out[tr] = rec, np.quantile(strain, 0.99)
        for j, f in enumerate(fr):
            assert np.array_equal(V[f], c["V"][j])
    (rg, sg), (rd, sd) = out["gradient"], out["displacement"]
    assert rd["new_defects_before"]["flipped"] > 1000
    assert rg["new_defects_before"]["flipped"] <= 15
    assert rg["new_defects_before"]["folded"] <= 10
    assert rg["new_defects_after"]["collapsed"] == 0
    assert sg < 0.3 and sd > 10


@pytest.mark.parametrize("transfer", ["gradient", "displacement"])
def test_decoding_only_some_frames_fills_only_those(sliver_run, transfer):
    """``decode(only=...)`` (how parallel_decode splits the frames) gives the full decode's
    rows for the frames asked for, keyframes and pins included, and zeros elsewhere."""
    c, T, dec, Vc, _, _ = sliver_run
    P = Prolongation.encode(c["V"], T, dec, c["frames"], pinned=c["pinned"], transfer=transfer)
    full = P.decode(Vc)
    ask = np.array([3, int(c["frames"][1]), 15])
    part = P.decode(Vc, only=ask)
    assert np.array_equal(part[ask], full[ask])
    others = np.setdiff1d(np.arange(full.shape[0]), ask)
    assert not part[others].any()


def test_fine_starts_that_are_close_are_both_solved_and_the_lower_minimum_kept(monkeypatch):
    """Where the prolonged and the blended start of a run's first frame are within
    START_AMBIGUITY in energy, given_starts solves from both and starts the run at the lower
    minimum (a lower start is no promise of a lower minimum: the horse's frame 39 ended at
    the iteration limit at 0.006 from the lower start, at 0.0015 from the other)."""
    import data_synth.stress as stress
    from shellspline import interpolate
    from shellspline.pipeline import stages

    monkeypatch.setattr(stages, "START_AMBIGUITY", np.inf)   # every pair counts as close
    c = stress.slivers()
    kw = dict(frames=c["frames"], pinned=c["pinned"], transfer="displacement")
    rep = interpolate((c["V"], c["F"]), coarse=0.15, fine=True, **kw).report
    starts = rep["multires"]["fine_starts"]
    both = {s["frame"]: s for s in starts["solved_both"]}
    assert sorted(both) == [1, 9, 11, 19]
    recs = {r["frame"]: r for r in rep["frames"]}
    for k, s in both.items():
        lower = "blend" if s["blend"] < s["prolonged"] else "prolonged"
        assert k in starts[lower]
        # the run starts at that minimum: its first solve has little left to do (a few
        # steps: the trial solve stopped at its own decrement test, with its own factor)
        assert recs[k]["energy_initial"] == pytest.approx(min(s["blend"], s["prolonged"]),
                                                          rel=1e-9)
        assert recs[k]["nit"] <= 5 and recs[k]["energy_final"] <= recs[k]["energy_initial"]
