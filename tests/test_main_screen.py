"""The main screen read back from real recordings (``rerun.chunk.RrdReader``): the stored tabs and what
each shows, one colour per estimator wherever it appears, the probe timeline's geometry, the residual
classes of the keypoints and the motion tracks of an eval run, each against an independent computation
(OpenCV's epipolar lines and SVD)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from browser import eval_run as run_eval, inspect_recording
from cli_util import run_fviz

from fviz.record import layout as L
from fviz.record import reader as R
from fviz.record.placement import offset_b, screen_unit
from fviz.record.rebuild import match_classes

pytestmark = pytest.mark.kitti
ESTIMATORS = ("8point", "ransac", "magsac")  # inspect's defaults, in order


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    """(recording of odometry 00, temporal 3 -> 4, and the --json of the same run)."""
    return inspect_recording(kitti_root, tmp_path_factory.mktemp("main") / "pair.rrd")


@pytest.fixture(scope="module")
def eval_run(kitti_root, tmp_path_factory):
    return run_eval(kitti_root, tmp_path_factory.mktemp("main-eval") / "run", "0:7", ESTIMATORS)


def rows(path, entity: str, column: str, timeline: str | None = None) -> list:
    """The values of a column of an entity, one per row (static first, then in time order)."""
    return R.column(path, entity, column, timeline)


def line_through(strip) -> np.ndarray:
    """Homogeneous unit line through the two ends of a segment."""
    p, q = np.append(strip[0], 1.0), np.append(strip[-1], 1.0)
    ell = np.cross(p, q)
    return ell / np.linalg.norm(ell[:2])


def opencv_line(F: np.ndarray, x: np.ndarray, which_image: int) -> np.ndarray:
    """OpenCV's epipolar line (a, b, c) with a^2 + b^2 = 1: in image b of a point of a (which_image=1), or in a of
    a point of b (2)."""
    return cv2.computeCorrespondEpilines(x.reshape(1, 1, 2).astype(np.float64), which_image, F).reshape(3)


def same_line(l1: np.ndarray, l2: np.ndarray, tol: float = 1e-6) -> bool:
    return min(np.abs(l1 - l2).max(), np.abs(l1 + l2).max()) < tol * max(1.0, abs(l2[2]))


def sed(F: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> float:
    """Symmetric epipolar distance from OpenCV's lines."""
    lb, la = opencv_line(F, xa, 1), opencv_line(F, xb, 2)
    return (abs(lb @ np.append(xb, 1.0)) + abs(la @ np.append(xa, 1.0))) / 2


def F_of(doc: dict, name: str) -> np.ndarray:
    return np.array(next(e["F"] for e in doc["estimators"] if e["name"] == name))


# ---------------------------------------------------------------------------------------------- tabs


def test_tabs_overview_one_per_estimator_and_probe(inspected):
    path, _ = inspected
    tabs = R.blueprint_tabs(path)
    assert list(tabs) == ["overview", *ESTIMATORS, "probe"]
    for name in ESTIMATORS:
        # both images, the matches (in its classes: the override below), its lines and epipole, the ground
        # truth's lines, a click's marks and the matches an edit excluded (drawn live by the viewers that send
        # clicks and edits): nothing else
        assert sorted(tabs[name]) == sorted(["+ a/image", "+ b/image", f"+ {L.matches('gt')}", f"+ a/est/{name}/epilines",
                                             f"+ b/est/{name}/epilines", "+ a/est/gt/epilines", "+ b/est/gt/epilines",
                                             f"+ {L.click('a')}/**", f"+ {L.click('b')}/**", f"+ {L.EXCLUDED}"])
        assert not any(other in q for q in tabs[name] for other in ESTIMATORS if other != name)
    assert {f"+ {L.matches('gt')}", "+ a/est/gt/**", "+ a/epipoles", "+ b/epipoles"} <= set(tabs["overview"])
    assert not any(f"/est/{e}" in q for q in tabs["overview"] for e in ESTIMATORS)
    assert {"+ a/probe", "+ b/probe"} <= set(tabs["probe"])


def test_recording_stays_small(inspected):
    """An inspect recording with three estimators <= 250 KB (match positions stored
    once, no footer, JPEG 50), plus the verdict above the tabs (~5 KB of blueprint) and the probe's two zoomed views
    (12 KB: each view of the blueprint costs ~5 KB of the file). Deterministic: the same data and code write the
    same bytes, give or take the JPEG encoder's version."""
    path, _ = inspected
    assert path.stat().st_size <= 274_000, path.stat().st_size
    assert L.END in R.entity_paths(path) and not any(L.matches(e) in R.entity_paths(path) for e in ESTIMATORS)


def test_eval_recording_has_metric_and_motion_tabs(eval_run):
    assert list(R.blueprint_tabs(eval_run / "eval.rrd")) == ["metrics", "motion", "curves", "summary"]


def test_open_on_a_tab_that_does_not_exist_is_a_one_line_error(inspected):
    path, _ = inspected
    r = run_fviz("open", path, "--tab", "nope")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.strip() == f"error: --tab nope: {path} has no tab 'nope' (tabs: overview, 8point, ransac, magsac, probe)"


# ---------------------------------------------------------------------------------------------- colours


def test_one_colour_per_estimator_everywhere(inspected, eval_run):
    path, doc = inspected
    names = [e["name"] for e in doc["estimators"]]
    expected = L.estimator_colors(names)
    assert expected["gt"] == (255, 255, 255) and len(set(expected.values())) == len(names)

    def rgb(packed: int) -> tuple[int, int, int]:  # Rerun's 0xRRGGBBAA
        return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255

    # comparison bars: one per F per metric, in estimator order
    bar_colors = [rgb(c) for c in rows(path, L.COMPARE, "LineStrips2D:colors")[0]]
    assert bar_colors[: len(names)] == [expected[n] for n in names]
    unit = np.float32(screen_unit(doc["pair"]["size_a"]))  # image px per screen px: line widths are in screen terms
    for v in L.VIEWS:
        epipole_labels = rows(path, L.epipoles(v), "LineStrips2D:labels")[0]
        epipole_colors = rows(path, L.epipoles(v), "LineStrips2D:colors")[0]
        for name in names:
            # its lines and its epipole cross in its own tab, its epipole in the overview
            ent = L.est(v, name, "epilines")
            strips = list(zip(rows(path, ent, "LineStrips2D:colors")[0], rows(path, ent, "LineStrips2D:radii")[0],
                              rows(path, ent, "LineStrips2D:labels")[0]))
            line_colors = {rgb(c) for c, radius, _ in strips if radius in (np.float32(0.9) * unit, np.float32(2.0) * unit)}
            assert line_colors == {expected[name]}, (v, name)
            # below image b: an estimator's numbers; under the ground truth's lines the residual scale
            captions = [label for _, radius, label in strips if radius == 0.0 and label and ": epipole " not in label]
            if v == "a":
                assert not captions
            elif name == "gt":
                scale = [rgb(c) for c, radius, _ in strips if radius == np.float32(6.0) * unit]
                assert scale == [tuple(int(x) for x in c) for c in L.class_color(np.arange(L.RESIDUAL_CLASSES))]
                assert not captions  # the scale's ends are labelled on the overview and in the captions
            else:
                metrics = next(e["metrics"] for e in doc["estimators"] if e["name"] == name)
                assert captions == [f"{name}: SED {metrics['sed_median']:.3g} px | rotation {metrics['rot_err_deg']:.3g}° | "
                                    f"translation {metrics['trans_err_deg']:.3g}° | NSGD {metrics['nsgd']:.3g} | inliers "
                                    f"{int(metrics['n_inliers'])} of {doc['n_matches']} ({100 * metrics['inlier_ratio']:.2g} %) | "
                                    "keypoints: its residual, dark blue on its line to yellow >= 3 px (scale below)"]
            overview = {rgb(c) for c, label in zip(epipole_colors, epipole_labels) if label.startswith(f"{name}: epipole")}
            assert overview == {expected[name]}, (v, name)
    # the run's metric series and motion tracks: named after the estimators, in their colours
    run = eval_run / "eval.rrd"
    series_names = ["gt", *ESTIMATORS]
    for entity in (L.metric("sed_median"), L.motion("epipole_x")):
        assert rows(run, entity, "SeriesLines:names")[0] == series_names
        assert [rgb(c) for c in rows(run, entity, "SeriesLines:colors")[0]] == [L.estimator_colors(series_names)[n] for n in series_names]


def test_keypoint_classes_are_the_residual_bin_and_inlier_flag(inspected):
    """Class ids recomputed from the recorded positions and the F of the --json (OpenCV's lines): the ground
    truth's logged with the matches, an estimator's in its tab's override of them."""
    path, doc = inspected
    n = doc["n_matches"]
    points = np.array(rows(path, L.matches("gt"), "Points2D:positions")[0])
    xa, xb = points[:n], points[n:] - offset_b(doc["pair"]["size_a"])
    for name in ("gt", "ransac"):
        F = F_of(doc, name)
        both = np.array(match_classes(path)[name])
        classes = both[:n]
        assert len(xa) == len(xb) == len(classes) == n and np.array_equal(both[n:], classes)
        residual = np.array([sed(F, p, q) for p, q in zip(xa, xb)])
        bins = classes % L.RESIDUAL_CLASSES
        expected = np.minimum(residual // L.RESIDUAL_BIN_PX, L.RESIDUAL_CLASSES - 1)
        # positions are float32 in the file: a residual on a bin edge may fall either side
        on_edge = np.abs(residual / L.RESIDUAL_BIN_PX - np.round(residual / L.RESIDUAL_BIN_PX)) < 1e-3
        assert np.all((bins == expected) | on_edge)
        outliers = classes >= L.RESIDUAL_CLASSES
        if name == "gt":  # the ground truth has no mask of its own: Sampson distance < 1 px
            assert 0 < outliers.sum() < len(outliers)
        else:
            ratio = next(e for e in doc["estimators"] if e["name"] == name)["metrics"]["inlier_ratio"]
            assert (~outliers).mean() == pytest.approx(ratio)


# ---------------------------------------------------------------------------------------------- probe


def test_probe_walks_the_most_disputed_matches_with_every_line(inspected):
    """Each step's lines are OpenCV's lines of its match under every F; the steps fall in disagreement (the
    largest residual minus the smallest over the ground truth and the estimators, all fitted to the matches)
    and no two steps ring the same place (near-duplicates skipped)."""
    path, doc = inspected
    steps_a = rows(path, L.probe("a"), "LineStrips2D:strips", timeline=L.PROBE_TIMELINE)
    steps_b = rows(path, L.probe("b"), "LineStrips2D:strips", timeline=L.PROBE_TIMELINE)
    labels_a = rows(path, L.probe("a"), "LineStrips2D:labels", timeline=L.PROBE_TIMELINE)
    texts = R.text(path, L.PROBE_TEXT)
    assert len(steps_a) == len(steps_b) == len(texts) == 20  # the default --probe
    assert rows(path, L.probe("a"), L.PROBE_TIMELINE, timeline=L.PROBE_TIMELINE) == list(range(20))
    names = [e["name"] for e in doc["estimators"]]
    worst = []
    for k, (sa, sb, la, text) in enumerate(zip(steps_a, steps_b, labels_a, texts)):
        lines_a = {lab.split(":")[0]: np.array(s) for s, lab in zip(sa, la) if "epipolar line" in lab}
        ring_a = np.array(next(s for s, lab in zip(sa, la) if lab.startswith("match ")))
        ring_b = np.array(sb[-1])  # after b's lines
        xa, xb = ring_a[:-1].mean(0), ring_b[:-1].mean(0)  # ring centres: the match
        residuals = {}
        for name in names:
            F = F_of(doc, name)
            # each F's line in a is OpenCV's line of x_b, and every line passes through the ring's image (clipped)
            assert name in lines_a, (k, name)
            assert same_line(line_through(lines_a[name]), opencv_line(F, xb, 2), tol=1e-4), (k, name)
            residuals[name] = sed(F, xa, xb)
            assert f"| {name} | {residuals[name]:.2f} |" in text
        assert f"step {k + 1} of 20" in text
        worst.append(max(residuals.values()) - min(residuals.values()))
        # the ring and the join between a and b: b's points are drawn below image a
        join = np.array(next(s for s, lab in zip(sa, la) if lab.startswith("match ") and len(s) == 2))
        np.testing.assert_allclose(join[0], xa, atol=1e-3)
        np.testing.assert_allclose(join[1], xb + offset_b(doc["pair"]["size_a"]), atol=1e-3)
    assert all(a >= b - 1e-3 for a, b in zip(worst, worst[1:])), worst  # most disputed first
    assert worst[0] > 3.0  # 8-point misses these matches by pixels
    ends = np.array([np.array(s[-1])[:-1].mean(0) for s in steps_b])  # b's rings, step by step
    gaps = np.linalg.norm(ends[:, None] - ends[None], axis=-1) + np.eye(len(ends)) * 1e9
    assert gaps.min() >= 20.0 * screen_unit(doc["pair"]["size_a"]) - 1e-3, gaps.min()  # no near-duplicate


def test_probe_by_one_estimator_and_probe_off(kitti_root, tmp_path):
    out = tmp_path / "p.rrd"
    r = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frame", "3",
                 "-e", "ransac", "-e", "magsac", "--probe", "5", "--probe-by", "magsac", "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    texts = R.text(out, L.PROBE_TEXT)
    assert len(texts) == 5 and all("magsac's residual" in t for t in texts)
    F = F_of(doc, "magsac")
    rings = [np.array(s[-1])[:-1].mean(0) for s in rows(out, L.probe("b"), "LineStrips2D:strips", timeline=L.PROBE_TIMELINE)]
    strips_a = rows(out, L.probe("a"), "LineStrips2D:strips", timeline=L.PROBE_TIMELINE)
    labels_a = rows(out, L.probe("a"), "LineStrips2D:labels", timeline=L.PROBE_TIMELINE)
    starts = [np.array(next(s for s, lab in zip(strips, labels) if lab.startswith("match ") and len(s) == 2))
              for strips, labels in zip(strips_a, labels_a)]
    res = [sed(F, j[0], xb) for j, xb in zip(starts, rings)]
    assert res == sorted(res, reverse=True)
    bad = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--frame", "0", "-e", "ransac",
                   "--probe-by", "magsac", "--out", tmp_path / "q.rrd")
    assert bad.returncode == 2 and bad.stderr.startswith("error: --probe-by magsac: not an estimator of this pair")
    assert not (tmp_path / "q.rrd").exists()


# ---------------------------------------------------------------------------------------------- motion


def test_motion_tracks_are_the_epipoles_of_the_results(eval_run):
    run = eval_run / "eval.rrd"
    records = [json.loads(line) for line in (eval_run / "results.jsonl").read_text().splitlines()]
    xs = rows(run, L.motion("epipole_x"), "Scalars:scalars")
    ys = rows(run, L.motion("epipole_y"), "Scalars:scalars")
    assert len(xs) == len(ys) == len(records) == 6
    by_index = {r["index"]: r for r in records}
    for i, (x, y) in enumerate(zip(xs, ys)):
        ests = by_index[i]["result"]["estimators"]
        assert [e["name"] for e in ests] == ["gt", *ESTIMATORS]
        for e, ex, ey in zip(ests, x, y):
            _, _, vt = cv2.SVDecomp(np.array(e["F"]))
            ea = vt[2]
            assert ex == pytest.approx(ea[0] / ea[2], rel=1e-6) and ey == pytest.approx(ea[1] / ea[2], rel=1e-6)
    # forward driving: the ground truth's epipole stays inside image a, near its centre
    gt_x = [x[0] for x in xs]
    assert all(300 < v < 950 for v in gt_x)
    # rotation angle and translation direction: from each estimator's recovered pose in results.jsonl
    angles = rows(run, L.motion("rotation_deg"), "Scalars:scalars")
    t = {k: rows(run, L.motion(k), "Scalars:scalars") for k in ("t_x", "t_y", "t_z")}
    for i, ests in ((i, by_index[i]["result"]["estimators"]) for i in range(len(records))):
        t_gt = np.array(ests[0]["t"]) / np.linalg.norm(ests[0]["t"])
        for j, e in enumerate(ests):
            rvec, _ = cv2.Rodrigues(np.array(e["R"]))
            assert angles[i][j] == pytest.approx(np.degrees(np.linalg.norm(rvec)), abs=1e-6)
            te = np.array(e["t"]) / np.linalg.norm(e["t"])
            te = te if te @ t_gt >= 0 else -te  # F fixes no sign of t: the ground truth's
            np.testing.assert_allclose([t["t_x"][i][j], t["t_y"][i][j], t["t_z"][i][j]], te, atol=1e-9)


# ---------------------------------------------------------------------------------------------- verdict


def test_the_verdict_above_the_tabs_names_what_fails_and_whose_fault(inspected):
    """Frames 3 -> 4: 8-point's pose is far off (its own residuals are small), the robust estimators' are not, and
    most matches lie within 2 px of F_gt: the verdict blames the estimation, not the matcher, with the numbers of
    the --json; it is stored as the pair's verdict and the blueprint shows it above the tabs."""
    from fviz.verdicts import POSE_FAIL_DEG

    path, doc = inspected
    metrics = {e["name"]: e["metrics"] for e in doc["estimators"]}
    failing = [n for n in ESTIMATORS if metrics[n]["pose_err_deg"] > POSE_FAIL_DEG or metrics[n]["sed_median"] > 2.0]
    assert failing == ["8point"]
    share = doc["match_precision"]["px_prec@2"]
    assert share >= 0.5 and doc["verdict"] == {"kind": "estimator", "text": (
        f"8point fails (pose error {metrics['8point']['pose_err_deg']:.3g} deg) although {share:.0%} of the "
        f"{doc['n_matches']} matches lie within 2 px of F_gt: not the matcher; ransac, magsac fine")}
    assert R.text(path, L.VERDICT) == [f"**estimator**: {doc['verdict']['text']}"]
    fields = R._blueprint_fields(R.open_rrd(path))
    tabs = next(ref for ref, f in fields.items() if f.get("container_kind") == [1])
    top = next(f for f in fields.values() if tabs in f.get("contents", []))  # the container holding the tabs
    view = top["contents"][0]
    assert top["contents"][1] == tabs and fields[view]["display_name"] == ["verdict"]
    assert fields[view]["space_origin"] == [L.VERDICT] and top["row_shares"] == [1.0, L.VERDICT_SHARE]
