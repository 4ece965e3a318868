"""A suspect ground truth's reference on screen: ``fviz inspect pair`` draws the best robust estimator's epipolar
lines (``layout.REFERENCE``) on the overview only when the pair is gt-suspect, labelled as the reference.

Sample pairs of odometry 00 (the README): 6->7 has a ground truth that looks right, 7->8 does not (its ground
truth's own inlier ratio is 0.12 against 0.94 for MAGSAC). Checked against the JSON's F with numpy's SVD."""

import json

import numpy as np
import pytest
from cli_util import run_fviz

from fviz.record import layout as L
from fviz.record import reader as R
from fviz.record.placement import offset_b

pytestmark = pytest.mark.kitti

ROBUST = ("ransac", "magsac")


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    """{frame: (its --json, its recording)} for the pairs 6->7 (ground truth right) and 7->8 (suspect)."""
    out = {}
    for frame in (6, 7):
        rrd = tmp_path_factory.mktemp("ref") / f"{frame}.rrd"
        r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal",
                     "--frame", frame, "--out", rrd, "--json")
        assert r.returncode == 0, r.stderr
        out[frame] = json.loads(r.stdout), rrd
    return out


def null_vectors(F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(e_a, e_b): F e_a = 0 and F^T e_b = 0, by SVD."""
    u, _, vt = np.linalg.svd(F)
    return vt[-1], u[:, -1]


def through(strips: np.ndarray, e: np.ndarray) -> np.ndarray:
    """For each segment (N, 2, 2): the epipole's distance to its line, normalized as in test_cli_inspect."""
    lines = np.cross(np.c_[strips[:, 0], np.ones(len(strips))], np.c_[strips[:, 1], np.ones(len(strips))])
    return np.abs(lines @ e) / (np.linalg.norm(lines[:, :2], axis=1) * np.linalg.norm(e))


def test_reference_lines_only_where_the_ground_truth_is_suspect(inspected):
    doc, rrd = inspected[6]
    assert not any(n.startswith("gt-suspect: ") for n in doc["notes"]), doc["notes"]
    assert L.REFERENCE not in {p.lstrip("/") for p in R.entity_paths(rrd)}
    doc, rrd = inspected[7]
    assert any(n.startswith("gt-suspect: ") for n in doc["notes"]), doc["notes"]
    assert L.REFERENCE in {p.lstrip("/") for p in R.entity_paths(rrd)}


def test_reference_lines_are_the_best_robust_fs_labelled_as_the_reference(inspected):
    """The reference is the robust estimator with the most inliers; its strips are epipolar lines of that F
    (through its epipoles, not the ground truth's), the same segments as its own tab's lines, thick, in its colour,
    and one label per image names it as the REFERENCE (not the ground truth)."""
    doc, rrd = inspected[7]
    rows = {e["name"]: e for e in doc["estimators"]}
    best = max(ROBUST, key=lambda n: rows[n]["metrics"]["n_inliers"])
    assert any(n.endswith(f"(reference: {best})") for n in doc["notes"]), doc["notes"]
    strips = [np.asarray(s, float) for s in R.column(rrd, L.REFERENCE, "LineStrips2D:strips")[0]]
    labels = R.column(rrd, L.REFERENCE, "LineStrips2D:labels")[0]
    radii = R.column(rrd, L.REFERENCE, "LineStrips2D:radii")[0]
    colors = R.column(rrd, L.REFERENCE, "LineStrips2D:colors")[0]
    lines = np.array([s for s, lab in zip(strips, labels) if not lab])
    named = [lab for lab in labels if lab]
    assert len(named) == 2 and all("REFERENCE" in lab and best in lab and "ground truth" not in lab.split("REFERENCE")[1].split("(")[0]
                                   for lab in named), named
    assert {float(r) for r, lab in zip(radii, labels) if not lab} == {L.REFERENCE_RADIUS} and L.REFERENCE_RADIUS > 0.9
    rgb = {((c >> 24) & 255, (c >> 16) & 255, (c >> 8) & 255) for c, lab in zip(colors, labels) if not lab}
    assert rgb == {L.estimator_colors(list(rows))[best]}
    (_, h), offset = doc["pair"]["size_a"], offset_b(tuple(doc["pair"]["size_a"]))
    in_b = lines[..., 1].min(axis=1) > h
    a, b = lines[~in_b], lines[in_b] - offset
    assert len(a) == len(b) and 5 <= len(a) <= L.REFERENCE_LINES, (len(a), len(b))
    e_a, e_b = null_vectors(np.array(rows[best]["F"]))
    assert through(a, e_a).max() < 1e-4 and through(b, e_b).max() < 1e-4
    g_a, _ = null_vectors(np.array(doc["F_gt"]))
    assert through(a, g_a).max() > 1e-3  # the ground truth's lines would fail the check above
    # the same segments as the reference's own lines (its tab): the first of them
    own = [np.asarray(s, float) for s, lab in zip(R.column(rrd, L.est("a", best, "epilines"), "LineStrips2D:strips")[0],
                                                  R.column(rrd, L.est("a", best, "epilines"), "LineStrips2D:labels")[0])
           if not lab and len(s) == 2]
    for seg in a:
        assert min(np.abs(seg - o).max() for o in own) < 1e-3


def test_triage_draws_the_reference_on_suspect_ranks_only(kitti_root, tmp_path):
    """triage.rrd (pairs 5->6 .. 8->9: 7->8 and 8->9 suspect, 5->6 and 6->7 not): at every rank the reference lines are
    there exactly when its banner tags the pair gt-suspect (empty otherwise: none linger from the rank before)."""
    out = tmp_path / "run"
    small = ("--max-keypoints", "400", "--no-progress", "--workers", "1")
    r = run_fviz("eval", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", "5:10",
                 "-e", "ransac", "-e", "magsac", *small, "--out-dir", out, timeout=600)
    assert r.returncode == 0, r.stderr
    r = run_fviz("triage", "--out-dir", out, "--top", "5", "--by", "ransac", "--no-progress", timeout=600)
    assert r.returncode == 0, r.stderr
    rrd = out / "triage.rrd"
    banners = [t for t in R.column(rrd, L.TRIAGE_TAGS, "TextDocument:text", timeline=L.RANK_TIMELINE)]
    strips = R.column(rrd, L.REFERENCE, "LineStrips2D:strips", timeline=L.RANK_TIMELINE)
    suspect = ["**gt-suspect**" in (b[0] if isinstance(b, list) else b) for b in banners]
    drawn = [len(s) > 0 for s in strips]
    print(f"ranks: gt-suspect {suspect}, reference lines {drawn}")
    assert len(banners) == len(strips) == 4 and any(suspect) and not all(suspect)
    assert drawn == suspect
