"""The house rules of ARCHITECTURE.md, enforced on the source tree.

* imports only go down the layers (a module may import its own unit and lower layers);
* `shells` and `groups` never import each other, `curves` never imports `shells`;
* nothing inside the package imports the package face (`shellspline/__init__.py`);
* no private name crosses a module boundary: neither ``from x import _y`` nor ``x._y`` where
  ``x`` is another module of the package.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1] / "shellspline"

# unit (first name under shellspline/) -> layer rank; a unit may import units of lower or
# equal rank, except the pairs in FORBIDDEN.
LAYERS = {
    "errors": 0, "progress": 0, "timeline": 0, "parallel": 0, "version": 0,
    "numerics": 1,
    "mesh": 2,
    "shells": 3, "groups": 3,
    "curves": 4,
    "io": 5, "metrics": 5,
    "animation": 6, "pipeline": 6,
    "viz": 7, "motion_viz": 7, "batch": 8,
    "integrations": 8,  # the Blender add-on (pipeline + io); `shellspline blender-addon` zips it
    "cli": 9,
}
FORBIDDEN = {("shells", "groups"), ("groups", "shells"), ("curves", "shells"),
             ("io", "metrics"), ("metrics", "io")}


def _modules():
    for f in sorted(ROOT.rglob("*.py")):
        rel = f.relative_to(ROOT).with_suffix("")
        parts = list(rel.parts)
        if parts == ["__init__"] or parts == ["__main__"]:
            continue
        yield f, parts


def _imports(f, parts):
    """(line, absolute module parts, imported names) of every import of the package."""
    pkg = ["shellspline"] + parts[:-1]
    if parts[-1] == "__init__":
        pkg = ["shellspline"] + parts[:-1]
    tree = ast.parse(f.read_text(encoding="utf-8"))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "shellspline":
                    yield node.lineno, a.name.split("."), [], a.asname
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg[:len(pkg) - node.level + 1]
                mod = base + (node.module.split(".") if node.module else [])
            elif node.module and node.module.split(".")[0] == "shellspline":
                mod = node.module.split(".")
            else:
                continue
            yield node.lineno, mod, [(a.name, a.asname) for a in node.names], None


def _unit(modparts):
    return modparts[1] if len(modparts) > 1 else None


def test_every_unit_has_a_layer():
    units = {parts[0] for _, parts in _modules()}
    assert units <= set(LAYERS), f"units without a layer: {sorted(units - set(LAYERS))}"


def test_imports_only_go_down():
    bad = []
    for f, parts in _modules():
        me = parts[0]
        for line, mod, names, _ in _imports(f, parts):
            targets = [mod]
            if len(mod) == 1:  # `from . import x` at the top: x is the unit
                targets = [mod + [n] for n, _ in names]
            for t in targets:
                u = _unit(t)
                if u is None or u == "__version__":
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports the package face")
                    continue
                if u == me:
                    continue
                if u not in LAYERS:
                    continue  # a name re-exported by the face, reported above
                if LAYERS[u] > LAYERS.get(me, 99) or (me, u) in FORBIDDEN:
                    bad.append(f"{f.relative_to(ROOT)}:{line} ({me}, layer {LAYERS[me]}) imports "
                               f"{'.'.join(t)} (layer {LAYERS[u]})")
    assert not bad, "upward or forbidden imports:\n" + "\n".join(bad)


def test_no_private_name_crosses_a_module_boundary():
    bad = []
    for f, parts in _modules():
        this = ["shellspline"] + parts
        aliases = {}
        for line, mod, names, asname in _imports(f, parts):
            if mod == this:
                continue
            for n, a in names:
                if n.startswith("_") and not n.startswith("__"):
                    bad.append(f"{f.relative_to(ROOT)}:{line} imports {n} from {'.'.join(mod)}")
                full = mod + [n]
                if (ROOT.joinpath(*full[1:]).with_suffix(".py").exists()
                        or ROOT.joinpath(*full[1:]).is_dir()):
                    aliases[a or n] = full  # an imported module
            if asname:
                aliases[asname] = mod
        tree = ast.parse(f.read_text(encoding="utf-8"))
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and node.attr.startswith("_")
                    and not node.attr.startswith("__")):
                bad.append(f"{f.relative_to(ROOT)}:{node.lineno} uses {node.value.id}.{node.attr}")
    assert not bad, "private names used across modules:\n" + "\n".join(bad)


@pytest.mark.parametrize("rule", ["down", "private"])
def test_the_checks_catch_a_violation(tmp_path, monkeypatch, rule):
    """The checks above fail on a tree that breaks the rule (they are not vacuous)."""
    pkg = tmp_path / "shellspline"
    (pkg / "mesh").mkdir(parents=True)
    (pkg / "shells").mkdir()
    (pkg / "mesh" / "a.py").write_text(
        "from ..shells.b import g\n" if rule == "down" else "from .c import _h\n")
    (pkg / "mesh" / "c.py").write_text("def _h():\n    pass\n")
    (pkg / "shells" / "b.py").write_text("def g():\n    pass\n")
    monkeypatch.setattr(__import__(__name__), "ROOT", pkg) if False else None
    globals()["ROOT"], old = pkg, ROOT
    try:
        with pytest.raises(AssertionError):
            (test_imports_only_go_down if rule == "down"
             else test_no_private_name_crosses_a_module_boundary)()
    finally:
        globals()["ROOT"] = old
