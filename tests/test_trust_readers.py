"""Readers of a user's files (issue "Trust nothing, round two"): pairs-file lines of every documented length and
none other, a byte-order mark, a translation too large to compute with, an --F-gt of subnormal entries."""

from __future__ import annotations

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from sources_util import fountain

from fviz.data.images import parse_F
from fviz.data.pairsfile import parse_line, read_pairs
from fviz.errors import FvizError
from fviz.geometry import normalize

K = "1000 0 500 0 1000 400 0 0 1"
T12 = "1 0 0 0.5 0 1 0 0 0 0 1 0.1"


@pytest.mark.parametrize("n_numbers", [28, 32])  # T of 10 or 14 numbers: neither 12 nor 16
def test_a_line_of_32_or_36_fields_is_named_not_a_traceback(n_numbers):
    fields = ["a.png", "b.png", "0", "0", *(["1"] * n_numbers)]
    with pytest.raises(FvizError, match=rf"^f:3: {len(fields)} fields; expected .*34 with T as 12 numbers"):
        parse_line(fields, "f:3", 3)


def test_a_34_field_line_is_a_pose_of_12_numbers():
    short = parse_line(f"a.png b.png 0 0 {K} {K} {T12}".split(), "f:1", 1)
    full = parse_line(f"a.png b.png 0 0 {K} {K} {T12} 0 0 0 1".split(), "f:1", 1)
    np.testing.assert_array_equal(short.T, full.T)
    assert short.T[0, 3] == 0.5 and short.T[2, 3] == 0.1


def test_a_byte_order_mark_is_not_part_of_the_first_name(tmp_path):
    path = tmp_path / "pairs.txt"
    path.write_bytes("\ufeff0000.jpg 0001.jpg\n".encode())
    assert [(p.name0, p.name1) for p in read_pairs(path)] == [("0000.jpg", "0001.jpg")]
    d = fountain()  # and the run finds the image
    proc = run_fviz("inspect", "pair", "--pairs", path, "--images", d / "images", "--index", "0", "--max-keypoints", "300",
                    "--out", tmp_path / "p.rrd", timeout=300)
    assert proc.returncode == 0, proc.stderr


def test_a_translation_too_large_to_compute_with_is_refused(tmp_path):
    big = "1 0 0 1e300 0 1 0 1e300 0 0 1 1e300"
    with pytest.raises(FvizError, match="f:2: T_0to1: its translation is not a finite number"):
        parse_line(f"a.png b.png 0 0 {K} {K} {big}".split(), "f:2", 2)
    path = tmp_path / "pairs.txt"
    path.write_text(f"0000.jpg 0001.jpg 0 0 {K} {K} {big}\n")
    proc = run_fviz("eval", "--pairs", path, "--images", fountain() / "images", "--out-dir", tmp_path / "r", "--no-progress")
    assert_one_line_error(proc, 2, f"{path}:1", "not a finite number")


def test_an_f_of_subnormal_entries_is_the_same_f():
    F = np.array([[0.0, -1.0, 0.3], [1.0, 0.0, -0.2], [-0.3, 0.2, 0.0]])
    got = parse_F(" ".join(repr(float(v * 1e-320)) for v in F.ravel()))
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, normalize(F, "fbn"), atol=1e-3)  # subnormals keep ~3 digits
