"""Every docstring example in the package runs (doctest), module by module.

A module whose optional dependency is missing (pyvista, matplotlib, bpy, pxr, ...) is skipped
with the name of what is missing; a module that imports but fails an example fails the test.
"""
from __future__ import annotations

import doctest
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "shellspline"
MODULES = sorted(
    ".".join(("shellspline",) + p.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
    for p in ROOT.rglob("*.py")
    if ">>>" in p.read_text(encoding="utf-8")
)


def test_there_are_examples():
    assert len(MODULES) >= 20, MODULES


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name):
    try:
        mod = importlib.import_module(name)
    except ImportError as exc:  # an optional extra that is not installed
        pytest.skip(f"{name} needs {exc.name or exc}")
    result = doctest.testmod(mod, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=True)
    assert result.attempted > 0, f"{name} has \">>>\" but no example doctest finds"
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
