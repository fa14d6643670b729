"""shellspline.io.atomic: the one recipe for atomic writes, and the writers that use it."""
from __future__ import annotations

import errno
import os
import stat

import numpy as np
import pytest

from shellspline.batch.outroot import cleanup_leftovers
from shellspline.io import atomic
from shellspline.io.bvh import read_bvh, write_bvh
from shellspline.io.pointcache import read_pc2, write_mdd, write_pc2
from shellspline.io.posefiles import read_poses, write_poses


@pytest.fixture
def umask():
    """Set the process umask for one test and put the old one back."""
    old = os.umask(0o022)
    os.umask(old)
    yield lambda m: os.umask(m)
    os.umask(old)


def _mode(p):
    return stat.S_IMODE(os.stat(p).st_mode)


def test_write_replaces_whole_and_leaves_nothing(tmp_path):
    p = tmp_path / "a.txt"
    p.write_text("old")
    assert atomic.write_text_atomic(p, "new\n") == p
    assert p.read_text() == "new\n"
    assert sorted(os.listdir(tmp_path)) == ["a.txt"]
    atomic.write_bytes_atomic(p, b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"


def test_failed_write_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    p = tmp_path / "a.json"
    p.write_text("old")
    seen = []

    def boom(tmp):
        seen.append(tmp)
        tmp.write_text("partial")
        raise KeyError("stop")

    with pytest.raises(KeyError):  # not an OSError: propagates unchanged
        atomic.write_atomically(p, boom)
    assert p.read_text() == "old" and sorted(os.listdir(tmp_path)) == ["a.json"]
    assert seen[0].parent == tmp_path and seen[0].suffix == ".json"


def test_oserror_names_the_users_path_not_the_temporary(tmp_path):
    missing = tmp_path / "no" / "such" / "f.txt"
    with pytest.raises(FileNotFoundError) as e:
        atomic.write_text_atomic(missing, "x", shown="no/such/f.txt")
    assert str(e.value).endswith("writing 'no/such/f.txt'") and ".tmp-" not in str(e.value)

    def full(tmp):
        tmp.write_text("x")
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp))

    with pytest.raises(OSError) as e:
        atomic.write_atomically(tmp_path / "g.bin", full)
    assert e.value.errno == errno.ENOSPC
    assert str(e.value) == f"[Errno 28] no space left on device writing '{tmp_path / 'g.bin'}'"
    assert os.listdir(tmp_path) == []


@pytest.mark.parametrize("mask", [0o022, 0o027, 0o002])
def test_outputs_follow_the_umask(tmp_path, umask, mask):
    umask(mask)
    want = 0o666 & ~mask
    p = atomic.write_text_atomic(tmp_path / "a.txt", "x")
    assert _mode(p) == want
    T = np.tile(np.eye(4), (3, 1, 1))
    T[:, 0, 3] = [0.0, 1.0, 2.0]
    write_poses(tmp_path / "p.txt", np.arange(3.0), T, "tum")
    assert _mode(tmp_path / "p.txt") == want
    write_pc2(tmp_path / "a.pc2", np.zeros((2, 3, 3)))
    assert _mode(tmp_path / "a.pc2") == want


def test_temporary_names_are_what_cleanup_leftovers_removes(tmp_path):
    target = tmp_path / "out"
    d = atomic.temporary_directory(target)
    f = atomic.temporary_sibling(tmp_path / "x.png")
    f.write_bytes(b"half")
    assert d.is_dir() and d.name.startswith(".out.tmp-") and f.name.endswith(".png")
    kept = tmp_path / "keep.png"
    kept.write_bytes(b"done")
    removed = cleanup_leftovers(tmp_path)
    assert sorted(removed) == sorted([d.name, f.name])
    assert os.listdir(tmp_path) == ["keep.png"]


def test_move_into_place(tmp_path):
    target = tmp_path / "out"
    tmp = atomic.temporary_directory(target)
    (tmp / "a").write_text("1")
    atomic.move_into_place(tmp, target, overwrite=False)
    assert (target / "a").read_text() == "1" and os.listdir(tmp_path) == ["out"]
    tmp = atomic.temporary_directory(target)
    (tmp / "b").write_text("2")
    with pytest.raises(FileExistsError, match="'.*out' already exists"):
        atomic.move_into_place(tmp, target, overwrite=False)
    atomic.move_into_place(tmp, target, overwrite=True)  # the old one set aside, then removed
    assert os.listdir(target) == ["b"] and os.listdir(tmp_path) == ["out"]


def test_writers_round_trip_and_leave_no_temporaries(tmp_path):
    V = np.random.default_rng(0).normal(size=(3, 5, 3))
    write_mdd(tmp_path / "a.mdd", V)
    write_pc2(tmp_path / "a.pc2", V)
    assert np.allclose(read_pc2(tmp_path / "a.pc2")[0], V, atol=1e-6)
    T = np.tile(np.eye(4), (2, 1, 1))
    write_poses(tmp_path / "p.txt", np.array([0.0, 1.0]), T, "tum")
    assert np.allclose(read_poses(tmp_path / "p.txt").T, T)
    from data_synth.motion import motion

    m = motion(fps=30.0, seconds=0.2)
    write_bvh(m, tmp_path / "w.bvh")
    assert np.array_equal(read_bvh(tmp_path / "w.bvh").values, m.values)
    assert sorted(os.listdir(tmp_path)) == ["a.mdd", "a.pc2", "p.txt", "w.bvh"]
