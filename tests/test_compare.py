"""``fviz compare``: wins, losses and one-sided failures agree with the runs' CSV."""

import csv
import math
import shutil

import pytest
from cli_util import assert_one_line_error, invoke, run_fviz

from fviz.compare import EXACT_MAX_N, TIE_REL, Side, compare, summary_rows, wilcoxon_signed_rank

pytestmark = pytest.mark.kitti

SMALL = ("--max-keypoints", "400", "--no-progress", "--workers", "1", "--features", "orb")



def values(run, estimator, metric="sed_median"):
    with open(run / "metrics.csv", newline="") as f:
        return {r["name"]: (float(r[metric]) if r[metric] not in ("", "nan") else math.nan, r["error"] or r["pair_error"])
                for r in csv.DictReader(f) if r["estimator"] == estimator}


@pytest.fixture(scope="module")
def runs(kitti_root, tmp_path_factory):
    base = tmp_path_factory.mktemp("compare")
    sel = ("--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "0:10")
    invoke("eval", *sel, "-e", "8point", "-e", "magsac", *SMALL, "--out-dir", base / "a")
    invoke("eval", *sel, "-e", "8point", "-e", "magsac", "--threshold", "3", *SMALL, "--out-dir", base / "b")
    return base / "a", base / "b"


def apart(x, y, rel=TIE_REL):
    """Not a tie under the default tolerance: more than 5 % of the larger value apart."""
    return math.isfinite(x) and math.isfinite(y) and abs(x - y) > rel * max(abs(x), abs(y))


def expected(va, vb, threshold):
    fails = lambda v, e: bool(e) or not math.isfinite(v) or v > threshold  # noqa: E731
    wins = sum(va[n][0] < vb[n][0] and apart(va[n][0], vb[n][0]) for n in va)
    losses = sum(va[n][0] > vb[n][0] and apart(va[n][0], vb[n][0]) for n in va)
    only_a = sum(fails(*va[n]) and not fails(*vb[n]) for n in va)
    only_b = sum(fails(*vb[n]) and not fails(*va[n]) for n in va)
    return wins, losses, only_a, only_b


@pytest.mark.parametrize("threshold", [2.0, 0.3])
def test_two_estimators_of_one_run(runs, threshold):
    a, _ = runs
    c = compare(Side(a, "magsac"), Side(a, "8point"), "sed_median", threshold)
    va, vb = values(a, "magsac"), values(a, "8point")
    assert len(c.values) == 9
    assert (len(c.wins), len(c.losses), len(c.only_a_fails), len(c.only_b_fails)) == expected(va, vb, threshold)
    assert len(c.wins) + len(c.losses) + len(c.ties) == 9


def test_cli_writes_compare_md_and_prints_the_table(runs):
    a, _ = runs
    r = invoke("compare", "--out-dir", a, "--a", "magsac", "--b", "8point")
    c = compare(Side(a, "magsac"), Side(a, "8point"))
    text = (a / "compare.md").read_text()
    assert f"| magsac better (wins) | {len(c.wins)} |" in text
    assert f"| 8point better (losses) | {len(c.losses)} |" in text
    assert "magsac better (wins)" in r.output


def test_one_estimator_across_two_runs(runs, tmp_path):
    a, b = runs
    out = tmp_path / "runs.md"
    invoke("compare", "--run-a", a, "--run-b", b, "--estimator", "magsac", "--metric", "inlier_ratio", "--fail-threshold", "0.5",
           "--out", out)
    c = compare(Side(a, "magsac"), Side(b, "magsac"), "inlier_ratio", 0.5)
    va, vb = values(a, "magsac", "inlier_ratio"), values(b, "magsac", "inlier_ratio")
    # higher is better for inlier_ratio: a wins where its ratio is larger
    assert len(c.wins) == sum(va[n][0] > vb[n][0] and apart(va[n][0], vb[n][0]) for n in va)
    assert len(c.losses) == sum(va[n][0] < vb[n][0] and apart(va[n][0], vb[n][0]) for n in va)
    assert len(c.losses) > 0  # a 3 px threshold keeps more inliers than 1 px
    text = out.read_text()
    assert f"| magsac of a better (wins) | {len(c.wins)} |" in text and f"| magsac of b better (losses) | {len(c.losses)} |" in text
    assert "## Only magsac of a fails" in text and "## Only magsac of b fails" in text
    assert "| magsac better" not in text and "Only magsac fails" not in text


def test_compare_md_holding_another_comparison_is_not_replaced_silently(runs, tmp_path):
    a, b = runs
    shutil.copy(a / "metrics.csv", tmp_path / "metrics.csv")
    first = run_fviz("compare", "--out-dir", tmp_path, "--a", "magsac", "--b", "8point")
    assert first.returncode == 0, first.stderr
    md = tmp_path / "compare.md"
    before = md.read_text()
    r = run_fviz("compare", "--out-dir", tmp_path, "--a", "8point", "--b", "magsac")
    assert_one_line_error(r, 2, f"{md} holds another comparison: add --force to replace it, or write to --out OTHER.md")
    assert md.read_text() == before
    # the same comparison again brings it up to date (and says so); another one needs --force or --out
    r = run_fviz("compare", "--out-dir", tmp_path, "--a", "magsac", "--b", "8point")
    assert r.returncode == 0 and f"{md} (replaced the previous version)" in r.stderr
    r = run_fviz("compare", "--out-dir", tmp_path, "--a", "8point", "--b", "magsac", "--out", tmp_path / "other.md")
    assert r.returncode == 0 and md.read_text() == before and "8point better (wins)" in (tmp_path / "other.md").read_text()
    r = run_fviz("compare", "--out-dir", tmp_path, "--a", "8point", "--b", "magsac", "--force")
    assert r.returncode == 0 and f"{md} (replaced the previous version)" in r.stderr
    assert md.read_text() == (tmp_path / "other.md").read_text()
    # no temporaries left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["compare.md", "compare.rrd", "metrics.csv", "other.md", "other.rrd"]


@pytest.mark.parametrize("args, fragment", [
    (("--fail-threshold", "nan"), "--fail-threshold nan: must be a number"),
    (("--tie", "-1"), "--tie -1.0: must be a number >= 0"),
])
def test_nonsense_thresholds(runs, args, fragment):
    a, _ = runs
    assert_one_line_error(run_fviz("compare", "--out-dir", a, "--a", "magsac", "--b", "8point", *args), 2, fragment)


def test_an_estimator_against_itself_is_refused(runs):
    a, _ = runs
    r = run_fviz("compare", "--run-a", a, "--run-b", a, "-e", "magsac")
    assert_one_line_error(r, 2, f"compare: a and b are both magsac of {a}")


@pytest.mark.parametrize("args, fragment", [
    ((), "compare"),
    (("--out-dir", "X", "--a", "magsac"), "compare"),
    (("--run-a", "X", "--run-b", "Y"), "compare"),
])
def test_bad_input_is_one_line_exit_2(args, fragment):
    assert_one_line_error(run_fviz("compare", *args), 2, fragment)


def test_unknown_estimator_or_metric(runs):
    a, _ = runs
    assert_one_line_error(run_fviz("compare", "--out-dir", a, "--a", "magsac", "--b", "nope"), 2, "nope")
    assert_one_line_error(run_fviz("compare", "--out-dir", a, "--a", "magsac", "--b", "8point", "--metric", "x"), 2, "--metric")


def test_compare_md_lists_every_pair_difference_and_the_paired_test(runs):
    a, _ = runs
    invoke("compare", "--out-dir", a, "--a", "magsac", "--b", "8point", "--force")
    va, vb = values(a, "magsac"), values(a, "8point")
    text = (a / "compare.md").read_text()
    rows = [line for line in text.split("## Per pair")[1].splitlines() if line.startswith("| `")]
    assert len(rows) == sum(math.isfinite(va[n][0]) and math.isfinite(vb[n][0]) for n in va) == 9
    diffs = []
    for line in rows:
        name, x, y, d = [c.strip().strip("`") for c in line.strip("|").split("|")[:4]]
        assert float(x) == pytest.approx(va[name][0], rel=1e-3) and float(y) == pytest.approx(vb[name][0], rel=1e-3)
        assert float(d) == pytest.approx(va[name][0] - vb[name][0], rel=1e-3, abs=1e-4)
        diffs.append(abs(float(d)))
    assert diffs == sorted(diffs, reverse=True)
    # the exact test by enumerating the 2^9 sign patterns of the CSV's differences (distinct magnitudes here)
    import itertools

    d = [va[n][0] - vb[n][0] for n in va]
    ranks = {n: 1 + sorted(map(abs, d)).index(abs(x)) for n, x in zip(va, d)}
    assert len(set(map(abs, d))) == 9
    w_plus = sum(ranks[n] for n, x in zip(va, d) if x > 0)
    sums = [sum(r for r, s in zip(ranks.values(), signs) if s) for signs in itertools.product((0, 1), repeat=9)]
    p = min(1.0, 2 * min(sum(s <= w_plus for s in sums), sum(s >= w_plus for s in sums)) / 512)
    assert f"Wilcoxon signed-rank p (two-sided) | {p:.3g} (exact, n = 9, W+ = {w_plus:g}, W- = {45 - w_plus:g})" in text


@pytest.mark.parametrize("n", [1, 5, 12])
def test_wilcoxon_exact_one_signed_differences(n):
    """Every difference of one sign: W+ = n(n+1)/2 is the largest of the 2^n equally likely sign patterns."""
    w = wilcoxon_signed_rank(list(range(1, n + 1)))
    assert (w.n, w.w_plus, w.w_minus, w.method) == (n, n * (n + 1) / 2, 0.0, "exact")
    assert w.p == pytest.approx(min(1.0, 2 / 2**n))
    assert wilcoxon_signed_rank([-v for v in range(1, n + 1)]).p == pytest.approx(w.p)


def test_wilcoxon_exact_small_cases_by_enumeration():
    """n = 4 with a tie: the two-sided p counts the sign patterns whose rank sum is at least as extreme."""
    import itertools

    d = [0.5, -1.0, 1.0, 2.0, 0.0]  # the zero is dropped; |1.0| tied: ranks 1, 2.5, 2.5, 4
    w = wilcoxon_signed_rank(d)
    ranks = [1, 2.5, 2.5, 4]
    sums = [sum(r for r, s in zip(ranks, signs) if s) for signs in itertools.product((0, 1), repeat=4)]
    lo, hi = sum(s <= w.w_plus for s in sums), sum(s >= w.w_plus for s in sums)
    assert (w.n, w.w_plus, w.w_minus) == (4, 7.5, 2.5)
    assert w.p == pytest.approx(min(1.0, 2 * min(lo, hi) / 16))


def test_wilcoxon_normal_approximation_matches_its_closed_form():
    n = EXACT_MAX_N + 10
    d = [(k if k % 3 else -k) for k in range(1, n + 1)]  # distinct magnitudes: ranks 1..n, every third negative
    w = wilcoxon_signed_rank(d)
    w_plus = sum(k for k in range(1, n + 1) if k % 3)
    z = (abs(w_plus - n * (n + 1) / 4) - 0.5) / math.sqrt(n * (n + 1) * (2 * n + 1) / 24)
    assert (w.method, w.w_plus) == ("normal", w_plus)
    assert w.p == pytest.approx(math.erfc(z / math.sqrt(2)))
    assert wilcoxon_signed_rank([0.0, 0.0]).method == "none"


def test_each_metric_fails_by_its_own_rule_named_in_the_table(runs):
    """One threshold (2.0) for every metric used to say "both fail 49/49" of inlier ratios and never failed NSGD.
    Each metric now has its own rule (fviz.verdicts), named wherever fails are counted; an "error" (no value, eval's
    count) stays apart from "fails" (the metric's verdict)."""
    from fviz import triage
    from fviz.verdicts import FAIL_RULES, fails_label

    a, b = runs
    for metric, label, thr, hb in (("sed_median", "sed_median > 2 px", 2.0, False),
                                   ("inlier_ratio", "inlier_ratio < 0.5", 0.5, True),
                                   ("nsgd", "nsgd > 0.05", 0.05, False),
                                   ("pose_err_deg", "pose_err_deg > 10 deg", 10.0, False)):
        c = compare(Side(a, "magsac"), Side(b, "magsac"), metric)
        assert c.fails_label == fails_label(metric) == label
        va, vb = values(a, "magsac", metric), values(b, "magsac", metric)
        bad = lambda v, e: bool(e) or not math.isfinite(v) or (v < thr if hb else v > thr)  # noqa: E731
        assert len(c.both_fail) == sum(bad(*va[n]) and bad(*vb[n]) for n in va)
        assert len(c.only_a_fails) == sum(bad(*va[n]) and not bad(*vb[n]) for n in va)
        assert c.a_errors == [n for n in va if va[n][1] or not math.isfinite(va[n][0])]
        rows = dict(summary_rows(c))
        assert f"only magsac of a fails ({label})" in rows and f"both fail ({label})" in rows
        assert rows["magsac of a: errors (no F or no value)"] == str(len(c.a_errors))
    # inlier ratios of a working estimator do not all "fail"; the rule is the triage's low-inliers and matcher blame
    assert len(compare(Side(a, "magsac"), Side(b, "magsac"), "inlier_ratio").both_fail) < 9
    assert triage.LOW_INLIER_RATIO == FAIL_RULES["inlier_ratio"].threshold
    assert triage.FAIL_SED_PX == FAIL_RULES["sed_median"].threshold and triage.FAIL_POSE_DEG == FAIL_RULES["pose_err_deg"].threshold
    # --fail-threshold still replaces the rule, and says so; a metric without a rule fails only where it has no value
    r = invoke("compare", "--run-a", a, "--run-b", b, "-e", "magsac", "--metric", "inlier_ratio", "--fail-threshold", "0.99",
               "--out", a / "strict.md")
    assert "inlier_ratio < 0.99 (`--fail-threshold`)" in (a / "strict.md").read_text() and "inlier_ratio < 0.99" in r.output
    assert compare(Side(a, "magsac"), Side(a, "8point"), "epi_abs").fails_label == "no value"


def test_the_run_folder_is_given_one_way_everywhere(runs, tmp_path):
    """`table RUN` and `--out-dir RUN` both work in table, compare and triage; two different ones are
    refused."""
    a, _ = runs
    shutil.copytree(a, tmp_path / "run")
    run = tmp_path / "run"
    invoke("compare", run, "--a", "magsac", "--b", "8point", "--force")  # the fixture's run may hold one already
    assert "magsac better (wins)" in (run / "compare.md").read_text()
    invoke("table", "--out-dir", run)
    first = (run / "table.md").read_text()
    invoke("table", run)
    assert (run / "table.md").read_text() == first
    r = invoke("triage", run, "--by", "magsac", "--top", "1", "--no-progress")
    assert "0 evaluated now" in r.output and (run / "triage.md").is_file()
    r = run_fviz("compare", run, "--out-dir", a, "--a", "magsac", "--b", "8point")
    assert_one_line_error(r, 2, f"{run} and --out-dir {a}: two run folders")
    assert_one_line_error(run_fviz("table"), 2, "table: give the run folder, as RUN or --out-dir RUN")


def index_of(run):
    with open(run / "metrics.csv", newline="") as f:
        return {r["name"]: int(r["index"]) for r in csv.DictReader(f)}


def test_listed_pairs_say_where_they_sit_how_to_reopen_them_and_are_plotted(runs, tmp_path):
    """compare lists each pair where only one side fails with its `fviz inspect pair`
    command, says whether those pairs are one stretch of consecutive frames, and writes compare.rrd beside
    compare.md: both sides' values per pair and the one-sided fails, as the CSV has them."""
    from fviz.record.reader import column, text

    a, _ = runs
    out = tmp_path / "pose.md"
    r = invoke("compare", "--out-dir", a, "--a", "magsac", "--b", "8point", "--metric", "pose_err_deg", "--out", out)
    assert f"{tmp_path / 'pose.rrd'}" in r.output
    va, vb, index = values(a, "magsac", "pose_err_deg"), values(a, "8point", "pose_err_deg"), index_of(a)
    bad = lambda v, e: bool(e) or not v <= 10.0  # noqa: E731 (pose_err_deg's rule)
    only_b = sorted((n for n in va if bad(*vb[n]) and not bad(*va[n])), key=index.get)
    assert only_b, "8-point on ORB matches should fail some pose the robust estimator gets"
    section = out.read_text().split("## Only 8point fails")[1].split("## Per pair")[0]
    rows = [line for line in section.splitlines() if line.startswith("| `")]
    assert [line.split("`")[1] for line in rows] == only_b
    for line, name in zip(rows, only_b):
        frame = int(name.rpartition("/f")[2][:6])  # odometry/00/temporal/f000003c0-f000004c0
        assert ("`fviz inspect pair --kitti-root " in line and f"--sequence 00 --frame {frame} --pair temporal" in line
                and "-e 8point -e magsac" in line), line
    # the stretches of consecutive pairs, from the CSV's indices
    idx = [index[n] for n in only_b]
    breaks = sum(j != i + 1 for i, j in zip(idx, idx[1:]))
    expected = ("consecutive: one stretch of the sequence" if breaks == 0 else f"in {breaks + 1} stretches of consecutive pairs")
    assert len(only_b) < 2 or expected in section, section
    # compare.rrd: the values per pair of the run, in the run's order, and which side alone fails
    rrd = tmp_path / "pose.rrd"
    pairs = column(rrd, "compare/pairs", "pairs")[0]
    assert pairs == sorted(va, key=index.get)
    for side, vals in (("a", va), ("b", vb)):
        got = column(rrd, "compare/pairs", side)[0]
        assert got == pytest.approx([vals[n][0] for n in pairs], rel=1e-6, nan_ok=True)
    assert [n for n, f in zip(pairs, column(rrd, "compare/pairs", "only_b_fails")[0]) if f] == only_b
    assert text(rrd, "compare/text")[0] == out.read_text()
