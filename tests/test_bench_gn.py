"""benchmarks/bench_gn.py: its ``--variant`` options reach the Gauss–Newton solver."""
from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import icosphere

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def bench():
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        spec = importlib.util.spec_from_file_location("bench_gn",
                                                      REPO / "benchmarks" / "bench_gn.py")
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))
    return mod


def test_variant_text_is_parsed_into_solver_options(bench):
    assert bench.gn_variant("dtol=2e-5, cg_tol=1e-3,subspace=False") == {
        "dtol": 2e-5, "cg_tol": 1e-3, "subspace": False}
    assert bench.gn_variant("") == {}
    for bad in ("dtol", "=1", "dtol=fast"):
        with pytest.raises(SystemExit, match="--variant"):
            bench.gn_variant(bad)
    args = argparse.Namespace(data="d", poses="a,b", frames="0,4", workers=1, pinned=None)
    argv = bench._child_argv(args, True, "dtol=2e-5")
    assert argv[argv.index("--variant-options") + 1] == "dtol=2e-5"
    assert "--variant-options" not in bench._child_argv(args, True)


def test_a_variant_changes_the_measured_run(bench, tmp_path):
    # a sphere squashed into an ellipsoid and back: the loose stopping tolerance of the
    # variant must take fewer Gauss–Newton iterations than the default (same frames)
    V, F = icosphere(2)
    names = []
    for j, s in enumerate(([1.0, 1.0, 1.0], [1.6, 0.8, 0.7], [1.0, 1.3, 0.9])):
        lines = [f"v {x:.17g} {y:.17g} {z:.17g}" for x, y, z in V * s]
        lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in F]
        (tmp_path / f"k{j}.obj").write_text("\n".join(lines) + "\n")
        names.append(f"k{j}")
    args = argparse.Namespace(data=str(tmp_path), poses=",".join(names), frames="0,4,8",
                              workers=1, pinned=None, variant_options=None)
    tight = bench.measure(args, subspace=True)
    args.variant_options = "dtol=1e-1,gtol=1e-1"
    loose = bench.measure(args, subspace=True)
    assert tight["frames"] == loose["frames"] == 6
    assert loose["iterations"] < tight["iterations"]
    assert np.isfinite(loose["cpu"]) and loose["cpu"] > 0
