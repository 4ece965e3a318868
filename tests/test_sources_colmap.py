"""COLMAP models (--colmap): text and binary through pycolmap, pixel origin, distortion, co-visibility pairs,
on fountain-P11's published cameras (the model written by the test where the shared copy cannot be read)."""

import json
import re

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from sources_util import FAST, closed_form_F, fountain, same_up_to_sign, strecha_projection

from fviz.data.colmap import ColmapSource
from fviz.errors import FvizError


def clean_model(tmp_path, cameras_txt=None, images_txt=None, points_txt=""):
    """The fountain model in tmp_path, its files replaceable (the shared cameras.txt held 'np.float64(2759.48)'
    tokens once; they are turned back into numbers if a copy still holds them)."""
    src = fountain() / "colmap"
    d = tmp_path / "model"
    d.mkdir()
    cams = cameras_txt or re.sub(r"np\.float64\(([^)]*)\)", r"\1", (src / "cameras.txt").read_text())
    (d / "cameras.txt").write_text(cams)
    (d / "images.txt").write_text(images_txt or (src / "images.txt").read_text())
    (d / "points3D.txt").write_text(points_txt)
    return d


def inspect_json(*args):
    proc = run_fviz("inspect", "pair", *args, "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout)


def test_bad_cameras_txt_names_file_and_line(tmp_path):
    """A cameras.txt written by numpy's repr (the shared copy was once such a file): file, line and token named."""
    cams = (fountain() / "colmap" / "cameras.txt").read_text().replace(" 2759.48 ", " np.float64(2759.48) ")
    model = clean_model(tmp_path, cameras_txt=cams)
    proc = run_fviz("inspect", "pair", "--colmap", model, "--out", tmp_path / "x.rrd")
    assert_one_line_error(proc, 2, f"{model / 'cameras.txt'}:2", "np.float64(2759.48)")


def test_text_model_gt_is_the_published_cameras_with_colmaps_origin_converted(tmp_path):
    model = clean_model(tmp_path)
    doc = inspect_json("--colmap", model, "--images", fountain() / "images", "--index", "0", *FAST, "--out", tmp_path / "c.rrd")
    assert (doc["pair"]["image_a"], doc["pair"]["image_b"]) == ("0000.jpg", "0001.jpg")
    # COLMAP's principal point is measured from the pixel corner: 0.5 px more than OpenCV's
    assert doc["pair"]["K_a"][0][2] == pytest.approx(1520.69 - 0.5) and doc["pair"]["K_a"][1][2] == pytest.approx(1006.81 - 0.5)
    F_ref = closed_form_F(strecha_projection("0000.jpg", -0.5), strecha_projection("0001.jpg", -0.5))
    assert same_up_to_sign(doc["F_gt"], F_ref, 1e-6)
    rows = {e["name"]: e["metrics"] for e in doc["estimators"]}
    assert rows["gt"]["sed_median"] < 0.5 and rows["magsac"]["pose_err_deg"] < 2.0


def test_binary_model_reads_as_the_text_one_and_all_pairs_without_points(tmp_path):
    import pycolmap

    text = clean_model(tmp_path)
    binary = tmp_path / "bin"
    binary.mkdir()
    pycolmap.Reconstruction(str(text)).write_binary(str(binary))
    a, b = (ColmapSource(m, fountain() / "images", None, 100) for m in (text, binary))
    assert len(a.pair_ids()) == 55 == len(b.pair_ids())  # no 3D points: every pair of the 11 images
    for pid_a, pid_b in zip(a.pair_ids()[:5], b.pair_ids()[:5]):
        assert (pid_a.image_a, pid_a.image_b) == (pid_b.image_a, pid_b.image_b)
        assert np.abs(a.ground_truth(pid_a) - b.ground_truth(pid_b)).max() < 1e-12
    pid = a.pair_ids()[12]
    F_ref = closed_form_F(strecha_projection(pid.image_a, -0.5), strecha_projection(pid.image_b, -0.5))
    assert same_up_to_sign(a.ground_truth(pid), F_ref, 1e-6)
    proc = run_fviz("inspect", "pair", "--colmap", binary, "--images", fountain() / "images", "--index", "55")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    note, error = proc.stderr.strip().splitlines()  # why every pair is taken, then the error
    assert note.startswith(f"note: --colmap {binary} has no 3D points") and "--min-shared 100 does not apply" in note
    assert error.startswith("error: --index 55") and "0..54" in error


def _covisible_model(tmp_path, shared):
    """Images 1..4 of the fountain model with 3D points seen by the image pairs of ``shared``
    ({(id_a, id_b): n}), each point projected into both images with the published cameras."""
    import pycolmap

    (tmp_path / "src").mkdir()
    source = clean_model(tmp_path / "src")
    rec = pycolmap.Reconstruction(str(source))
    rng = np.random.default_rng(0)
    obs = {i: [] for i in (1, 2, 3, 4)}
    points = []
    for (a, b), n in shared.items():
        for _ in range(n):
            im_a = rec.images[a]  # a point ~10 m in front of camera a (the fountain is ~10 m away)
            X = np.asarray(im_a.projection_center()) + 10.0 * np.asarray(im_a.viewing_direction()) + rng.normal(0, 1.0, 3)
            pid = len(points) + 1
            track = []
            for i in (a, b):
                im = rec.images[i]
                x = rec.cameras[im.camera_id].img_from_cam(im.cam_from_world() * X)
                track.append((i, len(obs[i])))
                obs[i].append((*x, pid))
            points.append((pid, X, track))
    lines = []
    num = lambda *vs: " ".join(repr(float(v)) for v in vs)  # noqa: E731  (numpy's repr is not a number)
    for i in (1, 2, 3, 4):
        im = rec.images[i]
        q = im.cam_from_world().rotation.quat  # x, y, z, w
        t = im.cam_from_world().translation
        lines.append(f"{i} {num(q[3], q[0], q[1], q[2], *t)} {im.camera_id} {im.name}")
        lines.append(" ".join(f"{num(x, y)} {p}" for x, y, p in obs[i]))
    pts = [f"{p} {num(*X)} 128 128 128 0.5 " + " ".join(f"{i} {k}" for i, k in tr) for p, X, tr in points]
    d = tmp_path / "covis"
    d.mkdir()
    cams = (source / "cameras.txt").read_text()
    (d / "cameras.txt").write_text(cams)
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    (d / "points3D.txt").write_text("\n".join(pts) + "\n")
    return d


def test_pairs_from_covisibility_and_from_a_pairs_file(tmp_path):
    model = _covisible_model(tmp_path, {(1, 2): 150, (2, 3): 60, (1, 4): 5})
    names = lambda src: [(p.image_a, p.image_b) for p in src.pair_ids()]  # noqa: E731
    assert names(ColmapSource(model, fountain() / "images", None, 100)) == [("0000.jpg", "0001.jpg")]
    assert names(ColmapSource(model, fountain() / "images", None, 50)) == [("0000.jpg", "0001.jpg"), ("0001.jpg", "0002.jpg")]
    pairs = tmp_path / "pairs.txt"
    pairs.write_text("0003.jpg 0000.jpg\n0001.jpg 0002.jpg\n")
    src = ColmapSource(model, fountain() / "images", pairs, 100)
    assert names(src) == [("0003.jpg", "0000.jpg"), ("0001.jpg", "0002.jpg")]
    F_ref = closed_form_F(strecha_projection("0003.jpg", -0.5), strecha_projection("0000.jpg", -0.5))
    assert same_up_to_sign(src.ground_truth(src.pair_ids()[0]), F_ref, 1e-6)
    pairs.write_text("0003.jpg 0000.jpg\n0001.jpg 0009.jpg\n")
    with pytest.raises(FvizError, match=f"{pairs}:2: image 0009.jpg is not a registered image"):
        ColmapSource(model, fountain() / "images", pairs, 100)
    with pytest.raises(FvizError, match="no two images share 1000 3D points"):
        ColmapSource(model, fountain() / "images", None, 1000)


def test_distortion_is_refused_unless_zero(tmp_path):
    line = "1 SIMPLE_RADIAL 3072 2048 2760.0 1520.69 1006.81 {k}\n"
    images = "1 1 0 0 0 0 0 0 1 0000.jpg\n\n2 1 0 0 0 1 0 0 1 0001.jpg\n\n"
    zero = clean_model(tmp_path, cameras_txt=line.format(k=0.0), images_txt=images)
    src = ColmapSource(zero, fountain() / "images", None, 100)
    assert src.views[1].K[0, 2] == pytest.approx(1520.19)
    (zero / "cameras.txt").write_text(line.format(k=0.05))
    proc = run_fviz("inspect", "pair", "--colmap", zero, "--images", fountain() / "images")
    assert_one_line_error(proc, 2, "SIMPLE_RADIAL has distortion", "image_undistorter")


def test_bad_images_txt_names_file_and_line(tmp_path):
    images = (fountain() / "colmap" / "images.txt").read_text().splitlines()
    pose = [i for i, l in enumerate(images) if l and not l.startswith("#")][2]
    images[pose] = "3 0.5 x 0 0 0 0 0 3 0002.jpg"
    model = clean_model(tmp_path, images_txt="\n".join(images) + "\n")
    proc = run_fviz("inspect", "pair", "--colmap", model, "--images", fountain() / "images")
    assert_one_line_error(proc, 2, f"{model / 'images.txt'}:{pose + 1}", "IMAGE_ID QW QX")
