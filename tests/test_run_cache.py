"""The run folder's feature cache (features.h5 / matches.h5, hloc's layout) on KITTI odometry 00: what eval
writes equals a fresh detection with OpenCV; a new estimator (``triage -e``, ``eval --resume -e``) detects
nothing and reads every image's features from it, with the metrics of a run from scratch; a cut or foreign
cache is ignored with a note and rewritten; and a user reads the cache back as hloc files (``--matches``)."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
from cli_util import run_fviz

pytestmark = [pytest.mark.kitti, pytest.mark.slow]

FRAMES = (0, 9)  # temporal pairs 0-1 .. 7-8: 8 pairs (two workers), 9 images
N_IMAGES = FRAMES[1] - FRAMES[0]
OPTS = ("--max-keypoints", "400", "--no-progress")
VOLATILE = ("seconds",)


def selection(kitti_root):
    return ("--kitti-root", kitti_root, "--sequence", "00", "--pair", "temporal", "--frames", f"{FRAMES[0]}:{FRAMES[1]}")


def fviz_ok(*args, timeout=600):
    r = run_fviz(*args, timeout=timeout)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return r


def records(run):
    return [json.loads(line) for line in (run / "results.jsonl").read_text().splitlines()]


def metrics(run, estimators):
    """{(pair, estimator): metrics.csv row without timings}."""
    with open(run / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    return {(r["name"], r["estimator"]): {k: v for k, v in r.items() if k not in VOLATILE and k != "index"}
            for r in rows if r["estimator"] in estimators}


def image_path(kitti_root, frame):
    return kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0" / f"{frame:06d}.png"


def hloc_name(frame):
    return f"odometry/dataset/sequences/00/image_0/{frame:06d}.png"


@pytest.fixture(scope="module")
def run(kitti_root, tmp_path_factory):
    """eval with 8point, two workers: the run whose cache the tests reuse (copied, never changed)."""
    out = tmp_path_factory.mktemp("cache") / "run"
    fviz_ok("eval", *selection(kitti_root), "-e", "8point", *OPTS, "--workers", "2", "--out-dir", out)
    return out


@pytest.fixture(scope="module")
def fresh(kitti_root, tmp_path_factory):
    """The same selection with 8point and ransac from scratch, one worker: the metrics to reproduce."""
    out = tmp_path_factory.mktemp("cache") / "fresh"
    fviz_ok("eval", *selection(kitti_root), "-e", "8point", "-e", "ransac", *OPTS, "--workers", "1", "--out-dir", out)
    return metrics(out, ("gt", "8point", "ransac"))


def copy_of(run, tmp_path):
    dest = tmp_path / "run"
    shutil.copytree(run, dest)
    return dest


def test_the_cache_holds_opencvs_detection_in_hlocs_layout(run, kitti_root):
    import cv2
    import h5py

    from fviz.estimators.features import FeatureConfig, Features, match

    cfg = FeatureConfig(max_keypoints=400)
    fresh = {}
    with h5py.File(run / "features.h5", "r") as f:
        for frame in range(*FRAMES):
            gray = cv2.imread(str(image_path(kitti_root, frame)), cv2.IMREAD_GRAYSCALE)
            kps, desc = cv2.SIFT_create(nfeatures=400, enable_precise_upscale=True).detectAndCompute(gray, None)
            g = f[hloc_name(frame)]
            kp = np.array([k.pt for k in kps])
            assert g["keypoints"].dtype == np.float32 and g["descriptors"].shape == (128, len(kps))
            np.testing.assert_array_equal(g["keypoints"][()], kp)  # OpenCV's origin, as hloc keeps keypoints
            unit = desc / np.linalg.norm(desc.astype(np.float64), axis=1, keepdims=True)  # hloc's extractors write them unit
            np.testing.assert_allclose(g["descriptors"][()].T, unit, atol=1e-6)
            np.testing.assert_allclose(np.linalg.norm(g["descriptors"][()].astype(np.float64), axis=0), 1.0, atol=1e-5)
            restored = np.rint(g["descriptors"][()].T.astype(np.float64) * g["descriptor_norms"][()][:, None])
            np.testing.assert_array_equal(restored, desc)  # OpenCV's whole-number SIFT, restored exactly
            np.testing.assert_array_equal(g["scores"][()], np.array([k.response for k in kps], np.float32))
            assert list(g["image_size"][()]) == [gray.shape[1], gray.shape[0]]
            fresh[frame] = Features(kp, desc)
    with h5py.File(run / "matches.h5", "r") as f:
        for frame in range(FRAMES[0], FRAMES[1] - 1):
            key = "/".join(hloc_name(i).replace("/", "-") for i in (frame, frame + 1))  # hloc's names_to_pair
            m0, scores = f[key]["matches0"][()], f[key]["matching_scores0"][()]
            m = match(fresh[frame], fresh[frame + 1], cfg)
            expected = np.full(len(fresh[frame].keypoints), -1)
            expected[m.idx[:, 0]] = m.idx[:, 1]
            np.testing.assert_array_equal(m0, expected)
            assert (scores[m0 < 0] == 0).all() and (scores[m0 >= 0] > 0).all()
            # the best match (smallest distance) has the highest score
            assert m0[np.argmax(scores)] == m.idx[0, 1]


def test_triage_with_a_new_estimator_detects_nothing_and_matches_a_fresh_run(run, fresh, tmp_path):
    out = copy_of(run, tmp_path)
    before = (out / "features.h5").read_bytes()
    r = fviz_ok("triage", "--out-dir", out, "-e", "ransac", "--top", "2", "--no-progress")
    assert f"0 feature detections, {N_IMAGES} images' features read from the run's features.h5" in r.stderr, r.stderr
    recs = records(out)[-(FRAMES[1] - FRAMES[0] - 1):]
    assert all(rec["detections"] == 0 and rec["cached_matches"] == 1 for rec in recs), recs
    assert sum(rec["cached_features"] for rec in recs) == N_IMAGES
    assert (out / "features.h5").read_bytes() == before  # nothing new: the file is not rewritten
    assert metrics(out, ("gt", "8point", "ransac")) == fresh


def test_a_cut_cache_is_ignored_with_a_note_and_rewritten(run, fresh, tmp_path):
    import h5py

    out = copy_of(run, tmp_path)
    data = (out / "features.h5").read_bytes()
    (out / "features.h5").write_bytes(data[: len(data) // 3])  # a crash of another program, a full disk
    r = fviz_ok("eval", "--out-dir", out, "--resume", "-e", "ransac", *OPTS)
    assert "features.h5: unreadable" in r.stderr and "computed again" in r.stderr, r.stderr
    assert f"{N_IMAGES} feature detections, 0 images' features read" in r.stderr, r.stderr
    assert metrics(out, ("gt", "8point", "ransac")) == fresh
    with h5py.File(out / "features.h5", "r") as f:  # whole again
        assert all(f[hloc_name(i)]["keypoints"].shape[0] > 100 for i in range(*FRAMES))


def test_foreign_entries_are_ignored_with_a_note(run, fresh, tmp_path):
    """One image's features made with other settings, another's taken from a different image, and a match
    whose keypoints are not the images': each is computed again, the others are read."""
    import h5py

    out = copy_of(run, tmp_path)
    with h5py.File(out / "features.h5", "r+") as f:
        g = f[hloc_name(3)]
        g.attrs["fviz_settings"] = g.attrs["fviz_settings"].replace('"max_keypoints": 400', '"max_keypoints": 2000')
        g5, g6 = f[hloc_name(5)], f[hloc_name(6)]
        for k in ("keypoints", "descriptors", "scores"):  # frame 6's features under frame 5's name
            del g5[k]
            g5[k] = g6[k][()]
        g5.attrs["fviz_image"] = g6.attrs["fviz_image"]
    r = fviz_ok("eval", "--out-dir", out, "--resume", "-e", "ransac", *OPTS, "--workers", "1")
    assert "features.h5: entries made with other feature settings: ignored, computed again" in r.stderr, r.stderr
    assert "features.h5: entries of another image (its pixels differ)" in r.stderr, r.stderr
    assert f"2 feature detections, {N_IMAGES - 2} images' features read" in r.stderr, r.stderr
    assert metrics(out, ("gt", "8point", "ransac")) == fresh
    with h5py.File(out / "features.h5", "r") as f, h5py.File(run / "features.h5", "r") as orig:
        for i in (3, 5):  # rewritten right
            np.testing.assert_array_equal(f[hloc_name(i)]["keypoints"][()], orig[hloc_name(i)]["keypoints"][()])
            assert dict(f[hloc_name(i)].attrs) == dict(orig[hloc_name(i)].attrs)


def test_the_cache_reads_back_as_hloc_matches(run, fresh, kitti_root, tmp_path):
    """``--matches RUN/matches.h5``: the same matches in the same order, so the same metrics, ransac included."""
    out = tmp_path / "user"
    fviz_ok("eval", *selection(kitti_root), "--matches", run / "matches.h5", "-e", "8point", "-e", "ransac", *OPTS,
            "--workers", "1", "--out-dir", out)
    got = metrics(out, ("gt", "8point", "ransac"))
    assert got.keys() == fresh.keys()
    for key, row in fresh.items():
        assert {k: v for k, v in got[key].items()} == row, key


def test_a_run_decodes_each_frame_once_and_names_its_pixels(kitti_root, monkeypatch, tmp_path):
    """Over the run's frame schedule, each frame is decoded once, to detect it (the cache's pixel digest is
    taken then, not by decoding again per pair), and features.h5 names each image by the digest of the very
    pixels OpenCV decodes from its file."""
    import cv2
    import h5py

    import fviz.data.kitti.files as kitti
    from fviz.cli.eval import RUN_PARAMS, RunArgs
    from fviz.run.config import prepare
    from fviz.run.evaluator import CACHE_FRESH, PairEvaluator
    from fviz.run.schedule import FrameSchedule, schedule_window
    from fviz.run.hloc_cache import IMAGE_ATTR, CacheWriter, digest

    decoded = []
    read_image = kitti.read_image
    monkeypatch.setattr(kitti, "read_image", lambda path: decoded.append(path) or read_image(path))
    values = {p.name: p.default for p in RUN_PARAMS}
    values.update(kitti_root=kitti_root, sequence="00", pair_kind=["temporal"], step=["1"],
                  frames=f"{FRAMES[0]}:{FRAMES[1]}", estimator=["8point"], max_keypoints=400)
    config = prepare(RunArgs(values).config(()))
    todo = config.pairs()
    schedule = FrameSchedule(todo, schedule_window(todo, 1))
    evaluator = PairEvaluator(config, tmp_path, detect_threads=1)
    writer = CacheWriter(tmp_path)
    while (task := schedule.next_task()) is not None:
        rec, kept = evaluator.run_task(task)
        assert rec["error"] is None
        writer.add(rec[CACHE_FRESH])
        schedule.done(task, kept)
    assert writer.close() == []
    assert len(decoded) == len(set(decoded)) == N_IMAGES == evaluator.cache.misses
    with h5py.File(tmp_path / "features.h5") as f:
        groups = []
        f.visititems(lambda name, obj: groups.append(obj) if isinstance(obj, h5py.Group) and "keypoints" in obj else None)
        assert len(groups) == N_IMAGES
        for path in decoded:
            name = next(g for g in groups if g.name.endswith(path.name))
            assert name.attrs[IMAGE_ATTR] == digest(cv2.imread(str(path), cv2.IMREAD_UNCHANGED))
