"""README and API agree: every ```python block of README.md runs, every `shellspline ...`
command line it shows names a subcommand and options the parser has, every `ss.NAME` exists.

The Python blocks run each in a fresh namespace and a fresh temporary working directory
prepared with the files they name (``a.obj``/``b.obj``/``c.obj`` keyframes, the output
directories ``out/...`` the viz examples read, and ``pipelines/batch_obj.toml`` with its
sequences in ``synth/batch``). A block whose first line is ``# readme-test: skip (reason)``
is not run (keep that rare). ``ss.preview`` opens a window, which CI does not have: the call
is recorded instead, and its argument checked; energy plots use the cheap step energy.
"""
from __future__ import annotations

import argparse
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import data_synth
import shellspline as ss
from shellspline.cli.main import _build_parser

REPO = Path(__file__).resolve().parents[1]
README = (REPO / "README.md").read_text(encoding="utf-8")
SKIP = "# readme-test: skip"


def _fenced_blocks(text: str):
    """``(language, first line number, body)`` of every fenced block."""
    blocks = []
    for m in re.finditer(r"^```([\w-]*)\n(.*?)^```", text, flags=re.S | re.M):
        blocks.append((m.group(1), text.count("\n", 0, m.start()) + 1, m.group(2)))
    return blocks


PYTHON_BLOCKS = [(line, body) for lang, line, body in _fenced_blocks(README) if lang == "python"]


def test_readme_has_python_blocks_and_few_skips():
    assert len(PYTHON_BLOCKS) >= 3
    assert sum(body.startswith(SKIP) for _, body in PYTHON_BLOCKS) <= 1


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    """A directory holding every file the README's Python blocks name."""
    d = tmp_path_factory.mktemp("readme")
    poses = data_synth.write("ellipsoids", d / "ell", n_vertices=500)
    for name, p in zip("abc", poses):
        shutil.copy(p, d / f"{name}.obj")
    kf = ss.read_keyframes([d / f"{c}.obj" for c in "abc"], frames=[0, 10, 20])
    res = ss.interpolate(kf, method="linear")
    for name in ("cactus", "a", "b", "spline", "geodesic"):
        ss.write_sequence(d / "out" / name, res.V, res.F, res.report)
    (d / "pipelines").mkdir()
    shutil.copy(REPO / "pipelines" / "batch_obj.toml", d / "pipelines")
    for k in range(2):
        data_synth.write("ellipsoids", d / "synth" / "batch" / f"ell_{k}", n_vertices=200)
    return d


@pytest.mark.parametrize("line,body", PYTHON_BLOCKS, ids=[f"line{l}" for l, _ in PYTHON_BLOCKS])
def test_python_block_runs(line, body, workspace, tmp_path, monkeypatch):
    if body.startswith(SKIP):
        pytest.skip(body.splitlines()[0])
    here = tmp_path / "work"
    # every block starts from the same files; the sample outputs only where a block reads
    # them (the API example writes its own "out")
    shutil.copytree(workspace, here,
                    ignore=None if '"out/' in body else shutil.ignore_patterns("out"))
    monkeypatch.chdir(here)
    shown = []

    def preview(*sources, **kw):  # no window in CI: record what would be shown
        shown.append(sources)

    monkeypatch.setattr(ss, "preview", preview)
    monkeypatch.setattr(ss.viz, "preview", preview)
    # the energy plots' "auto" Discrete Shells energy takes one Newton solve per frame (40 s
    # for the two plots here on a loaded 2-core VM); the cheap W[s_k, s_k+1] keeps CI fast and
    # runs the same plotting code
    monkeypatch.setattr(ss.viz, "AUTO_MIDPOINT_WORK", -1)
    code = compile(body, f"README.md:{line}", "exec")
    exec(code, {"__name__": "__readme__"})
    if "ss.preview(" in body:
        assert shown and all(len(s) >= 1 for s in shown)


def _commands(text: str):
    """Every ``shellspline SUB ...`` command line shown in fenced (non-Python) blocks and in
    inline code, synopsis continuation lines joined; ``(where, tokens)``."""
    found = []
    for lang, line, body in _fenced_blocks(text):
        if lang in ("python", "toml"):
            continue
        current = None
        for i, raw in enumerate(body.splitlines()):
            row = raw.split(" #")[0] if not raw.lstrip().startswith("#") else ""
            if re.match(r"^\s*shellspline\s+\w", row) or " && shellspline " in row:
                current = row[row.index("shellspline"):].split("&&")[0].split()
                found.append((f"README.md:{line + 1 + i}", current))
            elif current is not None and re.match(r"^\s+\[", row):
                current.extend(row.split())  # synopsis continuation
            else:
                current = None
    for m in re.finditer(r"`(shellspline [^`]+)`", text):
        found.append((f"README.md:{text.count(chr(10), 0, m.start()) + 1}", m.group(1).split()))
    return found


COMMANDS = _commands(README)


def _subparsers(parser: argparse.ArgumentParser) -> dict:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return action.choices
    return {}


def test_readme_shows_every_subcommand():
    shown = {tokens[1] for _, tokens in COMMANDS if len(tokens) > 1}
    assert set(_subparsers(_build_parser())) <= shown


@pytest.mark.parametrize("where,tokens", COMMANDS, ids=[w for w, _ in COMMANDS])
def test_readme_command_line_matches_the_parser(where, tokens):
    subs = _subparsers(_build_parser())
    assert tokens[0] == "shellspline" and tokens[1] in subs, f"{where}: {' '.join(tokens)}"
    parser, rest = subs[tokens[1]], tokens[2:]
    inner = _subparsers(parser)
    if inner and rest and rest[0] in inner:  # a subcommand with subcommands (motion align)
        parser, rest = inner[rest[0]], rest[1:]
    options = {s: a for a in parser._actions for s in a.option_strings}
    text = " ".join(rest)
    for m in re.finditer(r"(?<![\w/.-])(--?[A-Za-z][\w-]*)(?:[ =]([\w.|-]+))?", text):
        opt, value = m.group(1), m.group(2)
        assert opt in options, f"{where}: {tokens[1]} has no option {opt}"
        choices = options[opt].choices
        if choices and value and "|" in value:  # a synopsis alternative list
            assert set(value.split("|")) <= set(choices), f"{where}: {opt} {value}"
        elif choices and value and not value.isupper():
            assert value in choices, f"{where}: {opt} {value}"


def test_every_ss_name_in_the_readme_exists():
    names = set(re.findall(r"\bss\.([A-Za-z_]\w*)", README))
    assert names, "the README shows the Python API as ss.NAME"
    missing = sorted(n for n in names if not hasattr(ss, n))
    assert not missing, f"README names ss.{missing} but shellspline has no such attribute"
    exported = set(ss.__all__)
    assert not sorted(n for n in names if n not in exported and not n.startswith("_")
                      and n not in ("viz",)), "README names a non-exported attribute"


def test_quick_start_starts_in_a_virtual_environment_and_keeps_the_ci_command():
    quick = README.split("## Quick start", 1)[1].split("\n## ", 1)[0]
    bash = [body.strip() for lang, _, body in _fenced_blocks(quick) if lang == "bash"]
    assert bash[0] == "python3 -m venv .venv && . .venv/bin/activate"
    ci = (REPO / ".ci" / "run").read_text()
    test_cmd = 'python3 -m pip install ".[test]" && python3 -m pytest -q'
    assert test_cmd in bash and test_cmd in ci
    assert all("\n" not in b for b in bash), "each Quick start command is one line"
