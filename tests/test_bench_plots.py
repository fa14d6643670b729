"""The reproduction figures of benchmarks/bench_nonlinear.py (paper Figs. 3 and 10) draw the
numbers of the benchmark's records."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("matplotlib", reason="the figures need the viz extra (pip install '.[test]')")

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    spec = importlib.util.spec_from_file_location("bench_nonlinear",
                                                  REPO / "benchmarks" / "bench_nonlinear.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _record(name, K=4, seed=0):
    rng = np.random.default_rng(seed)
    r = {"name": name, "K": K, "n_vertices": 4, "eta": 0.1, "frames": [0, K // 2, K],
         "radius": 1.0, "eta_unit": 0.1}
    for tag in ("geodesic", "lta", "nonlinear"):
        strain = rng.uniform(0, 0.1, K + 1)
        r[tag] = {"half_axes_x": (1 + rng.uniform(0, 1, K + 1)).tolist(),
                  "half_axes_y": (1 + rng.uniform(0, 1, K + 1)).tolist(),
                  "edge_strain_per_frame": strain.tolist(), "max_edge_strain": strain.max()}
    return r


def test_fig3_draws_the_half_axes_and_their_differences(bench):
    r = _record("ellipsoids")
    fig = bench.half_axes_figure(r)
    left, right = fig.axes
    drawn = {ln.get_label(): ln.get_ydata() for ln in left.get_lines() if
             not ln.get_label().startswith("_")}
    for tag, label in bench.METHODS:
        assert np.array_equal(drawn[f"{label} x"], r[tag]["half_axes_x"])
        assert np.array_equal(drawn[f"{label} y"], r[tag]["half_axes_y"])
    nl = r["nonlinear"]
    for line, other in zip(right.get_lines(), ("lta", "geodesic")):
        ref = np.max([np.abs(np.subtract(nl[a], r[other][a]))
                      for a in ("half_axes_x", "half_axes_y")], axis=0)
        assert np.allclose(line.get_ydata(), ref, rtol=0, atol=0)
        assert f"{ref.max():.2e}" in line.get_label()


def test_fig10_and_written_files(bench, tmp_path):
    hexagon = [_record("hex a", seed=1), _record("hex b", seed=2)]
    fig = bench.strain_figure(hexagon)
    assert len(fig.axes) == 2
    for ax, r in zip(fig.axes, hexagon):
        lines = [ln for ln in ax.get_lines() if not ln.get_label().startswith("_")]
        for ln, (tag, _) in zip(lines, bench.METHODS):
            assert np.array_equal(ln.get_ydata(), r[tag]["edge_strain_per_frame"])
    # files: two half-axes figures and the strain figure (filmstrips need off-screen OpenGL:
    # without it the function says so and writes the rest)
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]])
    F = np.array([[0, 1, 2], [0, 2, 3]])
    for r in hexagon:
        r["_V"] = {"nonlinear": np.stack([V + [0, 0, 0.1 * k] for k in range(r["K"] + 1)])}
    written = bench.write_plots([_record("ellipsoids"), _record("unit_sphere")], hexagon, F,
                                tmp_path / "plots")
    names = {p.name for p in written}
    assert {"fig3_ellipsoids.png", "unit_sphere.png", "fig10_hexagon_strain.png"} <= names
    for p in written:
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 1000
    assert not list((tmp_path / "plots").glob("*.tmp.png"))
