import numpy as np

import shellspline as ss
from shellspline.metrics import (edge_strain, half_axes, keyframe_kinks, length_scale,
                                 lta_energies, shell_energies, speed)

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
