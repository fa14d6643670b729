import numpy as np
import pytest

import shellspline as ss
from shellspline.metrics import (edge_strain, half_axes, keyframe_kinks, length_scale,
                                 lta_energies, sequence_defects, shell_energies, speed)

from conftest import icosphere


def test_half_axes_of_a_scaled_and_shifted_sphere():
    V, _ = icosphere(2)
    W = V * np.array([2.0, 1.0, 0.5]) + np.array([5.0, -3.0, 1.0])
    np.testing.assert_allclose(half_axes(W), [2.0, 1.0, 0.5], rtol=1e-12)
    assert half_axes(np.stack([V, W])).shape == (2, 3)


def test_kinks_separate_smooth_curves_from_corners():
    V, _ = icosphere(1)
    K = 20
    t = np.linspace(0, 1, K + 1)[:, None, None]
    smooth = V[None] * (1 + t ** 2)                     # C¹ in t: second difference O(1/K)
    a, b = np.array([1.0, 0, 0]), np.array([0, 1.0, 0])   # turn by 90° at frame 10
    corner = V[None] + np.where(t <= 0.5, t * a, 0.5 * a + (t - 0.5) * b)
    assert keyframe_kinks(smooth, [0, 10, 20])[0] < 0.2
    np.testing.assert_allclose(keyframe_kinks(corner, [0, 10, 20]), [1.0], rtol=1e-12)
    assert keyframe_kinks(smooth, [0, 20]).size == 0


def test_edge_strain_of_a_uniform_scaling_and_speed_of_a_translation():
    V, F = icosphere(2)
    T = ss.topology(F)
    np.testing.assert_allclose(edge_strain(np.stack([V, 1.1 * V]), V, T), [0.0, 0.1], atol=1e-12)
    K = 8
    Vs = V[None] + np.linspace(0, 1, K + 1)[:, None, None] * np.array([3.0, 4.0, 0.0])
    np.testing.assert_allclose(speed(Vs), 5.0, rtol=1e-12)


def test_shell_energy_vanishes_at_a_geodesic_midpoint():
    V0, F = icosphere(1)
    T = ss.topology(F)
    A, B = V0, V0 * np.array([1.5, 1.0, 0.9])
    # metrics measure a sequence divided by the first pose's sqrt(area) D, η relative to it
    D = length_scale(A, F)
    a, b = A / D, B / D
    m = ss.discrete_geodesic(a, b, 2, T, eta=0.01, tol=1e-12).V[1]
    e_geo = shell_energies(np.stack([A, D * m, B]), T, eta=0.01)
    e_lin = shell_energies(np.stack([A, 0.5 * (A + B) * 1.02, B]), T, eta=0.01)
    scale = ss.shell_energy(a, b, T, eta=0.01)
    assert e_geo[0] == e_geo[2] == 0.0
    assert e_geo[1] < 1e-10 * scale
    assert e_lin[1] > 1e-4 * scale
    steps = shell_energies(np.stack([A, D * m, B]), T, eta=0.01, midpoints=False)
    np.testing.assert_allclose(steps[:2], [ss.shell_energy(a, m, T, eta=0.01),
                                           ss.shell_energy(m, b, T, eta=0.01)])
    # unit-free: the same sequence in other units has the same energies
    np.testing.assert_allclose(shell_energies(np.stack([A, D * m, B]) * 1e3, T, eta=0.01,
                                              midpoints=False), steps, rtol=1e-9)


def test_lta_energies_concentrate_at_a_kink():
    V, F = icosphere(1)
    T = ss.topology(F)
    t = np.linspace(0, 1, 7)[:, None, None]
    straight = V[None] * (1 + 0.5 * t)                    # descriptors L, A change smoothly
    e = lta_energies(straight, T)
    assert e[0] == e[-1] == 0.0 and e.shape == (7,)
    kinked = V[None] * np.where(t <= 0.5, 1 + t, 2 - t)   # grows, then shrinks back
    ek = lta_energies(kinked, T)
    assert np.argmax(ek) == 3 and ek[3] > 100 * max(ek[1], ek[5], e.max())


def _hinge(phi):
    """Two triangles on the edge 0-1; the flap turned by ``phi`` from lying on the other
    (phi = 0: folded flat, signed dihedral angle ±π; it crosses ±π as phi changes sign)."""
    return np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, np.cos(phi), np.sin(phi)]])


@pytest.mark.parametrize("key_phi, folds", [(1e-12, 0), (0.8, 2)])
def test_a_step_at_a_keyframe_held_at_pi_is_not_a_fold(key_phi, folds):
    # keyframes at frames 0 and 4; the in-betweens sit 0.01-0.02 rad across the touching
    # point. A keyframe within FOLD_BAND of ±π has no trustworthy sign (an angle of exactly π
    # came out +π or −π with round-off), so the steps from and to it are not folds; with
    # keyframes away from ±π the same two crossings are
    F = np.array([[0, 1, 2], [1, 0, 3]])
    T = ss.topology(F)
    V = np.stack([_hinge(p) for p in (key_phi, -0.01, -0.02, -0.01, key_phi + 0.3)])
    from shellspline.shells.descriptors import dihedral_angles

    th = dihedral_angles(V, T)[:, 0]
    assert (np.abs(np.diff(th)) > np.pi).sum() == 2                 # two steps through ±π
    assert sequence_defects(V, T, [0, 4])["folded_edges"] == folds
