"""Files replaced only when complete (:mod:`fviz.atomic`): temporaries that cannot be planted, new and
unpredictable beside the target; permissions kept on replace, the umask's for a new file."""

from __future__ import annotations

import os
import stat

import pytest

from fviz import atomic


def test_a_symlink_planted_at_the_old_temporary_name_is_not_written_through(tmp_path):
    victim, out = tmp_path / "victim", tmp_path / "report.csv"
    victim.write_text("precious\n")
    (tmp_path / f".report.csv.tmp{os.getpid()}").symlink_to(victim)  # the name fviz used to write to
    atomic.write_text(out, "a,b\n")
    assert out.read_text() == "a,b\n" and victim.read_text() == "precious\n"
    assert not out.is_symlink()


def test_temporaries_are_new_unpredictable_files_beside_the_target(tmp_path):
    out = tmp_path / "report.csv"
    with atomic.replacing(out) as a, atomic.replacing(out) as b:
        assert a != b and a.parent == b.parent == tmp_path
        assert a.is_file() and not a.is_symlink() and stat.S_IMODE(a.stat().st_mode) == 0o600
        a.write_text("1")
        b.write_text("2")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report.csv"]


@pytest.mark.parametrize("mode", [0o600, 0o640, 0o664])
def test_replacing_a_file_keeps_its_mode(tmp_path, mode):
    out = tmp_path / "report.csv"
    out.write_text("old\n")
    os.chmod(out, mode)
    atomic.write_text(out, "new\n")
    assert out.read_text() == "new\n" and stat.S_IMODE(out.stat().st_mode) == mode


def test_a_new_file_gets_the_umask_mode(tmp_path):
    old = os.umask(0o027)
    try:
        atomic.write_text(tmp_path / "new.csv", "x\n")
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "new.csv").stat().st_mode) == 0o640
