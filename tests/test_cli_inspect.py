"""``fviz inspect pair`` end to end on the real samples: JSON, recording contents, bad input."""

import json
import sys

import cv2
import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from rerun.chunk import RrdReader

from fviz.geometry import epipoles, symmetric_epipolar_distance
from fviz.record import layout as L
from fviz.record.marks import LINE_PX, TAG_CHAR_PX
from fviz.record.placement import offset_b, screen_unit

ESTIMATORS = ("8point", "ransac", "magsac")


def read_entities(path):
    """entity path -> {column: value of its (only) row}, static and temporal chunks merged; the probe's
    entities (one row per step, tests/test_main_screen.py) left out."""
    out = {}
    for ch in RrdReader(path).stream().to_chunks():
        if ch.entity_path.startswith(("/a/probe", "/b/probe", "/probe")):
            continue
        rb = ch.to_record_batch()
        assert rb.num_rows == 1
        cols = [c for c in rb.schema.names if c != "log_time"]
        out.setdefault(ch.entity_path.lstrip("/"), {}).update({c: rb.column(c).to_pylist()[0] for c in cols})
    return out


def col(entity, name):
    """The values of a component."""
    return entity[name]


def one(batch, name):
    """A mono component's single value."""
    (value,) = col(batch, name)
    return value


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    out = tmp_path_factory.mktemp("inspect") / "pair.rrd"
    args = ["inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frame", "5",
            "--lines", "25", "--out", out, "--json"]
    for e in ESTIMATORS:
        args += ["--estimator", e]
    proc = run_fviz(*args)
    assert proc.returncode == 0, proc.stderr
    assert "WARN" not in proc.stderr, proc.stderr  # Rerun's note on files without a footer is not the user's business
    return json.loads(proc.stdout), read_entities(out), out


def test_json_describes_pair_gt_and_every_estimator(inspected):
    doc, _, out = inspected
    assert doc["pair"]["frame_a"] == 5 and doc["pair"]["frame_b"] == 6 and doc["pair"]["size_a"] == [1241, 376]
    assert doc["norm"] == "fbn" and doc["recording"] == str(out)
    names = [e["name"] for e in doc["estimators"]]
    assert names == ["gt", *ESTIMATORS]
    for e in doc["estimators"]:
        assert e["error"] is None and np.asarray(e["F"]).shape == (3, 3)
        assert {"epi_abs", "epi_sqr", "sed_median", "sampson_median", "inlier_ratio", "epipole_err_deg"} <= set(e["metrics"])
    assert doc["n_matches"] >= doc["n_eval"] > 100


def test_recording_holds_jpeg_images_and_a_blueprint(inspected):
    doc, ent, out = inspected
    for v in ("a", "b"):
        b = ent[L.image(v)]
        assert one(b, "EncodedImage:media_type") == "image/jpeg"
        img = cv2.imdecode(np.frombuffer(bytes(one(b, "EncodedImage:blob")), np.uint8), cv2.IMREAD_UNCHANGED)
        assert img.shape[:2] == (376, 1241)
    assert RrdReader(out).blueprints(), "the layout must be stored with the recording"


def test_match_residuals_match_an_independent_computation(inspected):
    """One set of match positions (the ground truth's entity); each estimator's classes (its tab's override)."""
    from fviz.record.rebuild import match_classes

    doc, ent, out = inspected
    n = doc["n_matches"]
    points = np.array(col(ent[L.matches("gt")], "Points2D:positions"))
    assert points.shape == (2 * n, 2) and not any(L.matches(e["name"]) in ent for e in doc["estimators"][1:])
    xa, xb = points[:n], points[n:] - offset_b(doc["pair"]["size_a"])  # b's ends sit below image a
    classes_of = match_classes(out)
    assert set(classes_of) == {e["name"] for e in doc["estimators"]}
    for e in doc["estimators"]:
        name, F = e["name"], np.array(e["F"])
        both = np.array(classes_of[name])
        assert len(both) == 2 * n
        classes = both[:n]
        np.testing.assert_array_equal(classes, both[n:])  # the two ends of a match: one residual
        # the residual bin (class modulo the bins), away from bin edges (positions are float32 in the file)
        res = symmetric_epipolar_distance(F, xa, xb)
        steps = res / L.RESIDUAL_BIN_PX
        clear = np.abs(steps - np.round(steps)) > 1e-3
        np.testing.assert_array_equal((classes % L.RESIDUAL_CLASSES)[clear], L.residual_classes(res)[clear])
        assert (classes < L.RESIDUAL_CLASSES).sum() == e["metrics"]["n_inliers"]  # inlier classes first


def lines_of(entity, size) -> np.ndarray:
    """The epipolar-line strips of an ``epilines`` entity (its epipole cross left out)."""
    strips, labels, radii = col(entity, "LineStrips2D:strips"), col(entity, "LineStrips2D:labels"), col(entity, "LineStrips2D:radii")
    # the cross's two strips are thicker, the captions and names labelled
    return np.array([s for s, lab, r in zip(strips, labels, radii)
                     if not lab and r == np.float32(LINE_PX * screen_unit(size))])


def test_epipolar_lines_are_clipped_and_pass_through_the_epipole(inspected):
    doc, ent, _ = inspected
    w, h = doc["pair"]["size_a"]
    for e in doc["estimators"]:
        F = np.array(e["F"])
        for v, ep in zip(("a", "b"), epipoles(F)):
            strips = lines_of(ent[L.est(v, e["name"], "epilines")], (w, h))
            assert 0 < len(strips) <= 25
            assert strips[..., 0].min() >= -0.5 - 1e-3 and strips[..., 0].max() <= w - 0.5 + 1e-3
            assert strips[..., 1].min() >= -0.5 - 1e-3 and strips[..., 1].max() <= h - 0.5 + 1e-3
            for p, q in strips:  # every epipolar line goes through the epipole
                line = np.cross(np.r_[p, 1], np.r_[q, 1])
                assert abs(line @ ep) / (np.linalg.norm(line[:2]) * np.linalg.norm(ep)) < 1e-4


def test_metrics_table_and_summary_agree_with_json(inspected):
    doc, ent, _ = inspected
    names = [e["name"] for e in doc["estimators"]]
    table = ent[L.PAIR_METRICS]
    assert col(table, "estimators") == names
    np.testing.assert_allclose(col(table, "sed_median"), [e["metrics"]["sed_median"] for e in doc["estimators"]], rtol=1e-6)
    md = one(ent[L.SUMMARY], "TextDocument:text")
    assert doc["pair"]["name"] in md and "probe" in md
    for e in doc["estimators"]:
        assert f"| {e['name']} | {e['metrics']['sed_median']:.3g} |" in md


def test_every_epipole_is_named_in_the_overview(inspected):
    """Per F a glyph of its own centred on its epipole (on the border towards it when outside), over a black
    halo, and its name in a label above it (stacked: one row per F)."""
    doc, ent, _ = inspected
    for v, k in (("a", 0), ("b", 1)):
        labels = col(ent[L.epipoles(v)], "LineStrips2D:labels")
        radii = col(ent[L.epipoles(v)], "LineStrips2D:radii")
        strips = col(ent[L.epipoles(v)], "LineStrips2D:strips")
        names = col(ent[L.epipoles(v)], "Points2D:labels")
        tags = np.array(col(ent[L.epipoles(v)], "Points2D:positions"))
        assert names[: len(doc["estimators"])] == [e["name"] for e in doc["estimators"]]
        w, h = doc["pair"]["size_a"]
        image_centre = np.array([(w - 1) / 2, (h - 1) / 2])
        shapes = set()
        for i, e in enumerate(doc["estimators"]):
            mine = [np.array(s) for s, lab, r in zip(strips, labels, radii)
                    if lab.startswith(f"{e['name']}: epipole at (") and r == np.float32(1.6 * screen_unit((w, h)))]
            assert mine
            shapes.add(tuple(np.round(np.concatenate(mine) - np.concatenate(mine).mean(0), 1).ravel()))
            pts = np.concatenate(mine)
            centre = (pts.min(0) + pts.max(0)) / 2
            # its name above it, its box kept inside the image when the glyph sits on the border
            half = (len(e["name"]) + 2) * TAG_CHAR_PX * screen_unit((w, h)) / 2
            assert tags[i][0] == pytest.approx(min(max(centre[0], half), w - half)) and tags[i][1] < centre[1]
            ep = epipoles(np.array(e["F"]))[k]
            p = ep[:2] / ep[2]
            if -0.5 <= p[0] <= w - 0.5 and -0.5 <= p[1] <= h - 0.5:  # the glyph is on the epipole
                np.testing.assert_allclose(centre, p, atol=1e-3)
            else:  # on the border, on the way from the image centre to the epipole
                on_border = min(abs(centre[0] + 0.5), abs(centre[0] - w + 0.5), abs(centre[1] + 0.5), abs(centre[1] - h + 0.5))
                assert on_border < 1e-3
                d1, d2 = centre - image_centre, p - image_centre
                assert abs(d1[0] * d2[1] - d1[1] * d2[0]) < 1e-6 * np.linalg.norm(d1) * np.linalg.norm(d2)
                assert d1 @ d2 > 0
        assert len(shapes) == len(doc["estimators"])  # no two F share a glyph
        halo = [r for r, lab in zip(radii, labels) if not lab]
        assert halo and all(r > np.float32(1.6 * screen_unit((w, h))) for r in halo)


def test_stereo_epipole_at_infinity_is_marked_at_the_border(kitti_root, tmp_path):
    out = tmp_path / "s.rrd"
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "stereo", "-e", "magsac", "--out", out)
    assert proc.returncode == 0, proc.stderr
    ent = read_entities(out)
    labels = col(ent[L.epipoles("a")], "LineStrips2D:labels")
    strips = col(ent[L.epipoles("a")], "LineStrips2D:strips")
    ring = next(np.array(s) for s, lab in zip(strips, labels) if lab)  # the first labelled strip: gt's glyph (after the halo)
    assert next(lab for lab in labels if lab).startswith("gt: epipole at infinity")  # rectified stereo: the true epipole is at infinity
    centre = (ring.min(0) + ring.max(0)) / 2
    assert centre[0] in (pytest.approx(-0.5, abs=1e-3), pytest.approx(1240.5, abs=1e-3))  # on the border
    arrows = col(ent[L.epipoles("a")], "Arrows2D:vectors")
    assert len(arrows) == 2 and abs(arrows[0][1]) < 1e-6 * abs(arrows[0][0])  # gt's: horizontal, towards it
    assert not list(tmp_path.glob(".*tmp*")), "no temporary file is left behind"


def test_failed_estimator_is_reported_and_the_others_still_run(kitti_root, tmp_path):
    (tmp_path / "bad_est.py").write_text("def boom(pair, x_a, x_b):\n    raise RuntimeError('no convergence')\n")
    out = tmp_path / "f.rrd"
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal",
                    "-e", "bad_est:boom", "-e", "magsac", "--out", out, "--json", cwd=tmp_path)
    assert proc.returncode == 1
    assert proc.stderr.strip() == "error: estimator boom: RuntimeError: no convergence"
    doc = json.loads(proc.stdout)
    boom, mag = doc["estimators"][1], doc["estimators"][2]
    assert boom["error"] == "RuntimeError: no convergence" and boom["F"] is None
    assert mag["error"] is None and mag["F"] is not None
    ent = read_entities(out)
    assert "no convergence" in one(ent[L.error("boom")], "TextLog:text")
    assert L.est("a", "boom", "epilines") not in ent and L.est("a", "magsac", "epilines") in ent
    from fviz.record.rebuild import match_classes

    assert set(match_classes(out)) == {"gt", "magsac"}  # no tab classes for the estimator that failed


def test_too_few_matches_is_a_data_error_but_still_recorded(kitti_root, tmp_path):
    out = tmp_path / "few.rrd"
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, "--sequence", "00", "--max-keypoints", "8",
                    "-e", "magsac", "--out", out, "--json")
    assert proc.returncode == 2
    assert proc.stderr.splitlines()[-1].startswith("error: only ") and "000000.png" in proc.stderr
    assert "at least 8 matches" in json.loads(proc.stdout)["estimators"][1]["error"]
    assert out.is_file()


@pytest.mark.parametrize(
    "args,fragments",
    [
        (["--sequence", "07"], ["--sequence 07", "no odometry layout"]),
        (["--sequence", "00", "--frame", "50"], ["--frame 50 out of range", "0..49"]),
        (["--sequence", "00", "--frame", "49", "--pair", "temporal"], ["--frame + --step 50"]),
        (["--sequence", "00", "--frame", "1"], ["missing image", "image_1/000001.png"]),
        (["--drive", "2011_09_26_drive_0001", "--pair", "temporal"], ["missing oxts packet of frame 1", "0000000001.txt"]),
        (["--drive", "2011_09_26_drive_0077"], ["missing drive folder"]),
        (["--sequence", "00", "-e", "magsack"], ["--estimator 'magsack': unknown"]),
        (["--sequence", "00", "--cams", "0-1"], ["--cams '0-1'"]),
        (["--sequence", "00", "--pair", "sideways"], ["--pair 'sideways'"]),
        (["--sequence", "00", "--norm", "l1"], ["--norm 'l1'"]),
        (["--sequence", "00", "--features", "surf"], ["--features 'surf'"]),
    ],
)
def test_bad_input_is_one_line_and_exit_2(kitti_root, tmp_path, args, fragments):
    proc = run_fviz("inspect", "pair", "--kitti-root", kitti_root, *args, "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, *fragments)
    assert not (tmp_path / "x.rrd").exists()


def test_missing_root_and_unknown_layout(tmp_path):
    assert_one_line_error(run_fviz("inspect", "pair", "--kitti-root", tmp_path / "nope"), 2, "not a folder")
    assert_one_line_error(run_fviz("inspect", "pair", "--kitti-root", tmp_path), 2, "no KITTI layout")


def test_help_is_light():
    code = "import sys, fviz.cli; print(sorted(m for m in ('torch', 'rerun', 'cv2', 'numpy') if m in sys.modules))"
    import subprocess

    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"
    assert run_fviz("--help").returncode == 0


def test_parsing_a_runs_options_imports_no_heavy_library(tmp_path):
    """Everything the main process imports before an eval's first pair delays it (typer 0.29 coerces options
    through pydantic: pinned below it). Parsed up to the bad root's one-line error, exit 2."""
    import subprocess

    code = ("import sys\nfrom fviz.cli import main\nsys.argv = ['fviz', 'eval', '--kitti-root', sys.argv[1], '--sequence', '00',"
            " '--frames', '0:5', '-e', 'magsac', '--workers', '1']\ntry:\n    main()\nexcept SystemExit as e:\n"
            "    print(e.code, sorted(m for m in ('pydantic', 'torch', 'rerun', 'cv2') if m in sys.modules))\n")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "nope")], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "2 []", out.stdout + out.stderr


def test_debug_keeps_a_user_estimators_traceback(tmp_path):
    """Without --debug a raising estimator is one line (its exception); with it, the traceback down to the
    user's own frame, in the JSON and on stderr, and the inspect table keeps to the first line."""
    (tmp_path / "crash_mod.py").write_text(
        "def helper():\n    raise RuntimeError('my estimator crashed')\n\n\ndef crash(pair, x_a, x_b):\n    return helper()\n")
    common = ("inspect", "pair", "--synthetic", "--seed", "0", "-e", "crash_mod:crash", "-e", "ransac", "--probe", "0")
    import os

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}  # this checkout's fviz, and the module

    def fviz(*args):
        return run_fviz(*args, env=env, timeout=300)

    plain = fviz(*common, "--json", "--out", tmp_path / "a.rrd")
    debug = fviz("--debug", *common, "--json", "--out", tmp_path / "b.rrd")
    table = fviz("--debug", *common, "--out", tmp_path / "c.rrd")
    assert plain.returncode == debug.returncode == table.returncode == 1, (plain.stderr, debug.stderr)
    error = lambda r: next(e["error"] for e in json.loads(r.stdout)["estimators"] if e["name"] == "crash")  # noqa: E731
    assert error(plain) == "RuntimeError: my estimator crashed"
    lines = error(debug).splitlines()
    assert lines[0] == "RuntimeError: my estimator crashed" and lines[1] == "Traceback (most recent call last):"
    assert any("crash_mod.py" in ln and "in helper" in ln for ln in lines) and "raise RuntimeError('my estimator crashed')" in error(debug)
    assert "in helper" in debug.stderr and "Traceback" not in plain.stderr
    assert "failed:" in table.stdout and "Traceback" not in table.stdout and "in helper" in table.stderr
