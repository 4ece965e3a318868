"""Readers of a user's files: pairs-file lines of every documented length and none other (a byte-order mark, a
translation too large to compute with, an --F-gt of subnormal entries), COLMAP cameras, poses and binary files,
hloc and SuperGlue match files, images (a decompression bomb, a cut JPEG (refused), 16-bit samples, EXIF orientation
against hloc's keypoints), a pairs file's rot under a calibrated estimator, fviz's own features.h5."""

from __future__ import annotations

import re
import shutil
import struct
import zlib

import numpy as np
import pytest
from cli_util import assert_one_line_error, run_fviz
from sources_util import fountain

from fviz.data.correspondences import SuperGlueReader
from fviz.data.hloc import HlocReader
from fviz.data.match_files import open_matches
from fviz.data.images import MAX_IMAGE_PIXELS, image_header, parse_F, two_images
from fviz.data.pairsfile import parse_line, read_pairs
from fviz.errors import FvizError
from fviz.geometry import normalize

# ------------------------------------------------------------------------------ helpers


def textured(h=240, w=320, seed=0) -> np.ndarray:
    """A gray image with corners to detect: smoothed noise, upscaled."""
    import cv2

    rng = np.random.default_rng(seed)
    small = (rng.random((h // 8, w // 8)) * 255).astype(np.uint8)
    return cv2.GaussianBlur(cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST), (3, 3), 0)


def exif_jpeg(image: np.ndarray, orientation: int, path) -> None:
    """``image`` stored as a JPEG with an EXIF block (little-endian TIFF, IFD0 with tag 0x0112) of ``orientation``."""
    import cv2

    ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 98])
    data = buf.tobytes()
    tiff = b"II*\x00" + struct.pack("<IH", 8, 1) + struct.pack("<HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack("<I", 0)
    body = b"Exif\x00\x00" + tiff
    path.write_bytes(data[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + data[2:])


def small_pair(tmp_path, names=("a.png", "b.png")):
    import cv2

    for i, n in enumerate(names):
        cv2.imwrite(str(tmp_path / n), textured(seed=i))
    return two_images(str(tmp_path / names[0]), str(tmp_path / names[1]))


def write_hloc(folder, kps: dict, matches0, scores0=None, features="features.h5", matches="matches.h5", sizes=None):
    import h5py

    with h5py.File(folder / features, "w") as f:
        for name, kp in kps.items():
            g = f.create_group(name)
            g["keypoints"] = kp
            if sizes and name in sizes:
                g["image_size"] = np.array(sizes[name])
    names = list(kps)
    with h5py.File(folder / matches, "w") as f:
        g = f.create_group(f"{names[0]}/{names[1]}")
        g["matches0"] = matches0
        if scores0 is not None:
            g["matching_scores0"] = scores0
    return folder / matches


def clean_model(tmp_path, cameras=None, images=None):
    """fountain-P11's text model with its camera numbers as numbers; ``cameras``/``images`` edit the lines."""
    src = fountain() / "colmap"
    d = tmp_path / "model"
    d.mkdir()
    cams = re.sub(r"np\.float64\(([^)]*)\)", r"\1", (src / "cameras.txt").read_text())
    (d / "cameras.txt").write_text(cameras(cams) if cameras else cams)
    ims = (src / "images.txt").read_text()
    (d / "images.txt").write_text(images(ims) if images else ims)
    (d / "points3D.txt").write_text("")
    return d


def first_line(text: str, edit) -> str:
    lines = text.splitlines()
    i = next(k for k, line in enumerate(lines) if line.strip() and not line.startswith("#"))
    lines[i] = edit(lines[i].split())
    return "\n".join(lines) + "\n"


def colmap_source(model, images=None):
    from fviz.data.colmap import ColmapSource

    return ColmapSource(model, images or fountain() / "images", None, 100)


# ------------------------------------------------------------------------------ pairs files


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


# ------------------------------------------------------------------------------ COLMAP


def test_a_colmap_camera_of_zero_focal_length_is_one_line(tmp_path):
    model = clean_model(tmp_path, cameras=lambda t: first_line(t, lambda f: " ".join(f[:4] + ["0"] + f[5:])))
    proc = run_fviz("inspect", "pair", "--colmap", model, "--images", fountain() / "images", "--index", "0")
    assert_one_line_error(proc, 2, f"--colmap {model}: camera 1 (image 0000.jpg): focal length 0, ", "must be finite and > 0")


def test_a_negative_focal_length_is_refused(tmp_path):
    model = clean_model(tmp_path, cameras=lambda t: first_line(t, lambda f: " ".join(f[:5] + ["-2764.16"] + f[6:])))
    with pytest.raises(FvizError, match=r"camera 1 \(image 0000.jpg\): focal length 2759.48, -2764.16 px"):
        colmap_source(model)


def test_a_zero_quaternion_is_refused(tmp_path):
    model = clean_model(tmp_path, images=lambda t: first_line(t, lambda f: " ".join(f[:1] + ["0"] * 4 + f[5:])))
    with pytest.raises(FvizError, match=r"image 1 \(0000.jpg\): its pose \(quaternion QW QX QY QZ 0 0 0 0,.*unit quaternion"):
        colmap_source(model)


def test_a_camera_larger_than_its_images_is_refused(tmp_path):
    import cv2

    model = clean_model(tmp_path)  # cameras of 3072x2048, images at half that resolution
    images = tmp_path / "half"
    images.mkdir()
    for n in ("0000.jpg", "0001.jpg"):
        im = cv2.imread(str(fountain() / "images" / n))
        cv2.imwrite(str(images / n), cv2.resize(im, (1536, 1024)))
    src = colmap_source(model, images)
    with pytest.raises(FvizError, match=r"camera 1 is 3072x2048 but its image .*0000.jpg is 1536x1024: give the images"):
        src.load(src.pair_ids()[0])


@pytest.fixture
def binary_model(tmp_path):
    import pycolmap

    d = tmp_path / "bin"
    d.mkdir()
    pycolmap.Reconstruction(str(clean_model(tmp_path))).write_binary(str(d))
    return d


def test_a_cut_images_bin_is_one_line(binary_model):
    path = binary_model / "images.bin"
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) - 100])
    with pytest.raises(FvizError, match=rf"^{re.escape(str(path))}: cut short or not a COLMAP binary file \(.*image"):
        colmap_source(binary_model)
    path.write_bytes(whole[:300])  # fewer bytes than its images need at the least
    with pytest.raises(FvizError, match=rf"^{re.escape(str(path))}: 11 images cannot fit in its 300 bytes \(cut short"):
        colmap_source(binary_model)


def test_a_garbage_points3d_bin_is_one_line_not_a_hang(binary_model):
    (binary_model / "points3D.bin").write_bytes(np.random.default_rng(0).bytes(4096))
    proc = run_fviz("inspect", "pair", "--colmap", binary_model, "--images", fountain() / "images", "--index", "0", timeout=60)
    assert_one_line_error(proc, 2, f"{binary_model / 'points3D.bin'}: ", "3D points cannot fit in its 4096 bytes")


def test_a_garbage_track_length_is_one_line(binary_model):
    points = binary_model / "points3D.bin"  # one point whose track claims 2^40 observations
    points.write_bytes(struct.pack("<QQ3d3BdQ", 1, 7, 0.0, 0.0, 10.0, 1, 2, 3, 0.5, 1 << 40) + struct.pack("<II", 1, 0))
    with pytest.raises(FvizError, match=r"1099511627776 observations of 3D point 7 cannot fit"):
        colmap_source(binary_model)


def test_a_whole_binary_model_still_reads(binary_model):
    src = colmap_source(binary_model)
    assert len(src.views) == 11


# ------------------------------------------------------------------------------ hloc / SuperGlue files


@pytest.fixture
def hloc_pair(tmp_path):
    pair = small_pair(tmp_path)
    rng = np.random.default_rng(1)
    kps = {"a.png": rng.uniform(10, 200, (6, 2)), "b.png": rng.uniform(10, 200, (5, 2))}
    return pair, kps


def test_hloc_scores_shorter_than_matches_is_one_line(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    path = write_hloc(tmp_path, kps, np.array([0, 1, -1, 2, -1, 3]), np.ones(3, np.float32))
    with pytest.raises(FvizError, match=r"matches.h5:a.png/b.png: 3 match scores for 6 matches"):
        HlocReader(path).for_pair(pair)


def test_hloc_fractional_matches_are_refused(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    path = write_hloc(tmp_path, kps, np.array([0, 1.5, -1, 2, -1, 3]))
    with pytest.raises(FvizError, match=r"a.png/b.png: match 1 is 1.5, not a keypoint index"):
        HlocReader(path).for_pair(pair)
    path = write_hloc(tmp_path, kps, np.array([0.0, 1.0, -1.0, 2.0, -1.0, 3.0]))  # whole numbers as floats: read
    assert len(HlocReader(path).for_pair(pair).x_a) == 4


def test_hloc_index_below_minus_one_is_named(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    path = write_hloc(tmp_path, kps, np.array([0, 1, -3, 2, -1, 3]))
    with pytest.raises(FvizError, match=r"a.png/b.png: match 2 is -3: an index must be -1 \(unmatched\) or a keypoint"):
        HlocReader(path).for_pair(pair)


def test_hloc_nan_keypoints_are_named(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    kps["b.png"][2] = np.nan
    path = write_hloc(tmp_path, kps, np.array([0, 1, -1, 2, -1, 3]))
    with pytest.raises(FvizError, match=r"a.png/b.png: keypoints1\[2\] is \(nan, nan\): a matched keypoint must be finite"):
        HlocReader(path).for_pair(pair)


def test_hloc_folder_with_two_feature_files_pairs_by_hlocs_names(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    other = {n: kp + 1.0 for n, kp in kps.items()}
    write_hloc(tmp_path, other, np.array([0, 1, -1, 2, -1, 3]), features="feats-disk.h5", matches="feats-disk_matches-lightglue_pairs.h5")
    path = write_hloc(tmp_path, kps, np.array([0, 1, -1, 2, -1, 3]), features="feats-superpoint-n4096-r1024.h5",
                      matches="feats-superpoint-n4096-r1024_matches-superglue_pairs.h5")
    reader = open_matches(path)
    assert reader.features.name == "feats-superpoint-n4096-r1024.h5"
    np.testing.assert_array_equal(reader.for_pair(pair).x_a, kps["a.png"][[0, 1, 3, 5]])
    assert open_matches(tmp_path / "feats-disk_matches-lightglue_pairs.h5").features.name == "feats-disk.h5"
    shutil.copy(path, tmp_path / "m.h5")  # a name hloc does not give: two candidates, named
    with pytest.raises(FvizError, match=r"m.h5: hloc's features file not found .*found feats-disk.h5, "
                                        r"feats-superpoint-n4096-r1024.h5\): name it so, or copy it to features.h5"):
        open_matches(tmp_path / "m.h5")


def test_a_cut_superglue_npz_is_one_line(tmp_path):
    import cv2

    for n in ("a.png", "b.png"):
        cv2.imwrite(str(tmp_path / n), textured())
    rng = np.random.default_rng(0)
    path = tmp_path / "a_b_matches.npz"
    np.savez(path, keypoints0=rng.uniform(0, 200, (500, 2)), keypoints1=rng.uniform(0, 200, (500, 2)),
             matches=np.arange(500), match_confidence=np.ones(500))
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    proc = run_fviz("inspect", "pair", "--image-a", tmp_path / "a.png", "--image-b", tmp_path / "b.png", "--matches", path,
                    "--out", tmp_path / "p.rrd")
    assert_one_line_error(proc, 2, f"--matches {path}: not a readable npz")


def test_a_superglue_npz_with_a_cut_member_is_one_line(tmp_path):
    """The zip's directory whole, one array's bytes corrupt: the error comes when the array is read."""
    pair = small_pair(tmp_path)
    path = tmp_path / "m.npz"
    rng = np.random.default_rng(0)
    np.savez(path, keypoints0=rng.uniform(0, 200, (50, 2)), keypoints1=rng.uniform(0, 200, (50, 2)), matches=np.arange(50))
    data = bytearray(path.read_bytes())
    start = data.index(b"keypoints1.npy") + 200
    data[start:start + 300] = bytes(300)  # zeros in the middle of the array: its CRC fails
    path.write_bytes(bytes(data))
    with pytest.raises(FvizError, match=r"m.npz: (array 'keypoints1' cannot be read|not a readable npz)"):
        SuperGlueReader(path).for_pair(pair)


# ------------------------------------------------------------------------------ images


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose header says width x height (8-bit gray) with one compressed row: nothing near the pixels."""
    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(bytes(width + 1))) + chunk(b"IEND", b"")


def test_a_decompression_bomb_is_refused_before_decoding(tmp_path):
    import cv2

    bomb = tmp_path / "bomb.png"
    bomb.write_bytes(png_header_only(20000, 20000))
    cv2.imwrite(str(tmp_path / "b.png"), textured())
    assert image_header(bomb).width == 20000 and MAX_IMAGE_PIXELS < 20000 * 20000
    proc = run_fviz("inspect", "pair", "--image-a", bomb, "--image-b", tmp_path / "b.png", "--out", tmp_path / "p.rrd")
    assert_one_line_error(proc, 2, f"image a {bomb}: 20000x20000 pixels, more than fviz decodes (200 megapixels)")


def test_a_cut_jpeg_is_a_one_line_error_before_decoding(tmp_path):
    import cv2

    ok, buf = cv2.imencode(".jpg", textured(480, 640))
    (tmp_path / "cut.jpg").write_bytes(buf.tobytes()[: len(buf) * 6 // 10])
    (tmp_path / "whole.jpg").write_bytes(buf.tobytes())
    (tmp_path / "whole2.jpg").write_bytes(buf.tobytes())
    # OpenCV alone decodes it, the lost part flat grey: what fviz would otherwise have matched on
    assert np.ptp(cv2.imread(str(tmp_path / "cut.jpg"), cv2.IMREAD_GRAYSCALE)[-40:]) == 0
    with pytest.raises(FvizError, match=rf"^image a {re.escape(str(tmp_path / 'cut.jpg'))}: the JPEG file is cut short "
                                        r"\(no end marker, \d+ bytes\)"):
        two_images(str(tmp_path / "cut.jpg"), str(tmp_path / "whole.jpg"))
    proc = run_fviz("inspect", "pair", "--image-a", tmp_path / "whole.jpg", "--image-b", tmp_path / "cut.jpg",
                    "--out", tmp_path / "p.rrd")
    assert_one_line_error(proc, 2, f"image b {tmp_path / 'cut.jpg'}: the JPEG file is cut short")
    assert "Premature end" not in proc.stderr  # refused from its header, before libjpeg decodes (and warns)
    assert not (tmp_path / "p.rrd").exists()
    assert not [n for n in two_images(str(tmp_path / "whole.jpg"), str(tmp_path / "whole2.jpg")).notes if "cut" in n]


def test_a_16_bit_png_is_scaled_by_its_largest_value_with_a_note(tmp_path):
    import cv2

    im = textured().astype(np.uint16) * 16  # 12-bit samples in 16 (a raw camera's): OpenCV's 8-bit read is ~0..15
    cv2.imwrite(str(tmp_path / "a.png"), im)
    cv2.imwrite(str(tmp_path / "b.png"), im)
    pair = two_images(str(tmp_path / "a.png"), str(tmp_path / "b.png"))
    expected = np.round(im * (255.0 / im.max())).astype(np.uint8)
    np.testing.assert_array_equal(pair.image_a, expected)
    assert f"image a a.png has 16-bit samples (largest {im.max()}): scaled to 8 bits by that largest value" in pair.notes


# ------------------------------------------------------------------------------ hloc keypoints of EXIF-rotated images


def exif_shown(o: int, x: np.ndarray, w: int, h: int) -> np.ndarray:
    """Written out independently of fviz: a stored pixel (x, y) as shown after EXIF orientation 3, 6 or 8."""
    if o == 3:
        return np.c_[w - 1 - x[:, 0], h - 1 - x[:, 1]]
    if o == 6:  # turned 90 degrees clockwise
        return np.c_[h - 1 - x[:, 1], x[:, 0]]
    return np.c_[x[:, 1], w - 1 - x[:, 0]]  # 8: counter-clockwise


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_hloc_keypoints_of_an_exif_rotated_image_are_turned_with_it(tmp_path, orientation):
    import cv2

    stored_a, stored_b = textured(240, 320, 0), textured(240, 320, 0)[:, ::-1].copy()
    exif_jpeg(stored_a, orientation, tmp_path / "a.jpg")
    exif_jpeg(stored_b, 1, tmp_path / "b.jpg")
    sift = cv2.SIFT_create(nfeatures=200)  # hloc's keypoints: of the stored pixels, as hloc reads them
    kp_a = np.array([k.pt for k in sift.detect(stored_a, None)])
    kp_b = kp_a * [-1, 1] + [319, 0]  # b is a mirrored: the same points, mirrored
    path = write_hloc(tmp_path, {"a.jpg": kp_a, "b.jpg": kp_b}, np.arange(len(kp_a)),
                      sizes={"a.jpg": (320, 240), "b.jpg": (320, 240)})
    pair = two_images(str(tmp_path / "a.jpg"), str(tmp_path / "b.jpg"))
    c = HlocReader(path).for_pair(pair)
    np.testing.assert_allclose(c.x_a, exif_shown(orientation, kp_a, 320, 240), atol=1e-9)
    np.testing.assert_allclose(c.x_b, kp_b)
    assert any(f"hloc's keypoints of a.jpg turned by its EXIF orientation {orientation}" in n for n in pair.notes)
    # the shown image holds the stored pixels at the turned keypoints
    ia, sa = np.rint(c.x_a).astype(int), np.rint(kp_a).astype(int)
    assert np.abs(pair.image_a[ia[:, 1], ia[:, 0]].astype(int) - stored_a[sa[:, 1], sa[:, 0]]).max() <= 6


def test_fvizs_own_keypoints_of_an_exif_rotated_image_are_not_turned_again(tmp_path):
    import h5py

    exif_jpeg(textured(), 3, tmp_path / "a.jpg")
    exif_jpeg(textured(seed=1), 1, tmp_path / "b.jpg")
    kps = {"a.jpg": np.array([[10.0, 20.0], [30.0, 40.0]]), "b.jpg": np.array([[11.0, 21.0], [31.0, 41.0]])}
    path = write_hloc(tmp_path, kps, np.array([0, 1]), sizes={"a.jpg": (320, 240), "b.jpg": (320, 240)})
    with h5py.File(tmp_path / "features.h5", "a") as f:
        for n in kps:
            f[n].attrs["fviz_settings"] = "{}"
    pair = two_images(str(tmp_path / "a.jpg"), str(tmp_path / "b.jpg"))
    np.testing.assert_array_equal(HlocReader(path).for_pair(pair).x_a, kps["a.jpg"])


# ------------------------------------------------------------------------------ pairs file rot and poselib-E


def rot90_points(x: np.ndarray, k: int, w: int, h: int) -> np.ndarray:
    """Written out independently: where np.rot90(image, k) puts pixel (x, y) of a w x h image."""
    for _ in range(k % 4):
        x = np.c_[x[:, 1], w - 1 - x[:, 0]]
        w, h = h, w
    return x


@pytest.mark.parametrize("rot", [(1, 3), (3, 1), (2, 1)])
def test_poselib_e_on_turned_images_of_a_pairs_file(tmp_path, rot):
    import cv2

    from fviz.data.pairsfile import PairsSource, format_line
    from fviz.estimators.external import poselib_essential
    from fviz.estimators.classical import RobustConfig
    from fviz.geometry import symmetric_epipolar_distance

    w, h = 320, 240
    for i, n in enumerate(("a.png", "b.png")):
        cv2.imwrite(str(tmp_path / n), textured(h, w, i))
    K0 = np.array([[300.0, 0, 160], [0, 310, 120], [0, 0, 1]])
    K1 = np.array([[290.0, 0, 150], [0, 300, 125], [0, 0, 1]])
    angle = 0.1
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    t = np.array([-1.0, 0.1, 0.05])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    (tmp_path / "pairs.txt").write_text(format_line("a.png", "b.png", K0, K1, T, rot) + "\n")
    src = PairsSource(tmp_path / "pairs.txt", tmp_path)
    pair = src.load(src.pair_ids()[0])
    for K in (pair.K_a, pair.K_b):  # a turned camera is a camera: focal lengths on the diagonal
        assert K[0, 0] > 0 and K[1, 1] > 0 and K[1, 0] == K[0, 1] == K[2, 0] == K[2, 1] == 0 and K[2, 2] == 1
    rng = np.random.default_rng(0)
    X = np.c_[rng.uniform(-3, 3, 200), rng.uniform(-2, 2, 200), rng.uniform(6, 12, 200)]
    proj = lambda K, P: (P @ K.T)[:, :2] / (P @ K.T)[:, 2:]  # noqa: E731
    x_a, x_b = proj(K0, X), proj(K1, X @ R.T + t)
    keep = (x_a.min(1) > 0) & (x_a[:, 0] < w - 1) & (x_a[:, 1] < h - 1) & (x_b.min(1) > 0) & (x_b[:, 0] < w - 1) & (x_b[:, 1] < h - 1)
    ra, rb = rot90_points(x_a[keep], rot[0], w, h), rot90_points(x_b[keep], rot[1], w, h)
    assert symmetric_epipolar_distance(pair.F_gt, ra, rb).max() < 1e-6
    out = poselib_essential(pair, ra, rb, RobustConfig())
    assert out is not None
    F, inliers = out
    assert inliers.mean() > 0.95 and np.median(symmetric_epipolar_distance(F, ra, rb)) < 1e-3


# ------------------------------------------------------------------------------ fviz's own features.h5


def test_fvizs_sift_descriptors_are_written_unit_norm_as_hlocs_and_read_back_whole(tmp_path):
    import cv2
    import h5py

    from fviz.estimators.features import FeatureConfig, Features
    from fviz.run.hloc_cache import RunCache, features_entry

    cfg = FeatureConfig(max_keypoints=100)
    image = textured()
    kps, desc = cv2.SIFT_create(nfeatures=100).detectAndCompute(image, None)
    f = Features(np.array([k.pt for k in kps]), desc, np.array([k.response for k in kps], np.float32))
    _, name, data, attrs = features_entry("a.png", f, "digest", cfg, (320, 240))
    norms = np.linalg.norm(data["descriptors"].astype(np.float64), axis=0)
    np.testing.assert_allclose(norms, 1.0, atol=1e-5)  # hloc's NN-ratio matcher assumes unit descriptors
    with h5py.File(tmp_path / "features.h5", "w") as h5:
        g = h5.create_group(name)
        for k, v in data.items():
            g[k] = v
        g.attrs.update(attrs)
    cache = RunCache(tmp_path, cfg)
    back = cache._read("features.h5", name, lambda g: cache._features(g, "digest"))
    assert back is not None, cache.notes
    np.testing.assert_array_equal(back.descriptors, desc)  # OpenCV's whole-number SIFT, restored exactly


def test_hloc_keypoints_outside_an_exif_rotated_image_without_image_size_name_exif(tmp_path):
    exif_jpeg(textured(240, 320), 6, tmp_path / "a.jpg")  # shown 240 wide: a stored x of 300 lies outside
    exif_jpeg(textured(240, 320, 1), 1, tmp_path / "b.jpg")
    kps = {"a.jpg": np.array([[300.0, 20.0], [30.0, 40.0]]), "b.jpg": np.array([[11.0, 21.0], [31.0, 41.0]])}
    path = write_hloc(tmp_path, kps, np.array([0, 1]))
    pair = two_images(str(tmp_path / "a.jpg"), str(tmp_path / "b.jpg"))
    with pytest.raises(FvizError, match=r"lies outside the 240x320 image a \(image a has EXIF orientation 6, which fviz "
                                        r"applies and hloc does not"):
        HlocReader(path).for_pair(pair)
    assert any("has EXIF orientation 6" in n and "no image_size" in n for n in pair.notes)


@pytest.mark.parametrize("orientation, rot", [(1, (1, 2)), (6, (1, 0)), (3, (3, 1))])
def test_hloc_keypoints_under_a_pairs_files_rot_are_turned_with_the_image(tmp_path, orientation, rot):
    """hloc knows nothing of a pairs file's rot (nor of EXIF): its keypoints are of the stored image."""
    from fviz.data.pairsfile import PairsSource

    stored_a, stored_b = textured(240, 320, 0), textured(240, 320, 1)
    exif_jpeg(stored_a, orientation, tmp_path / "a.jpg")
    exif_jpeg(stored_b, 1, tmp_path / "b.jpg")
    rng = np.random.default_rng(2)
    kp_a, kp_b = rng.uniform(5, 230, (30, 2)), rng.uniform(5, 230, (30, 2))
    path = write_hloc(tmp_path, {"a.jpg": kp_a, "b.jpg": kp_b}, np.arange(30), sizes={"a.jpg": (320, 240), "b.jpg": (320, 240)})
    (tmp_path / "pairs.txt").write_text(f"a.jpg b.jpg {rot[0]} {rot[1]}\n")
    src = PairsSource(tmp_path / "pairs.txt", tmp_path)
    pair = src.load(src.pair_ids()[0])
    c = HlocReader(path).for_pair(pair)
    shown_a = kp_a if orientation == 1 else exif_shown(orientation, kp_a, 320, 240)
    wa, ha = (320, 240) if orientation in (1, 3) else (240, 320)
    np.testing.assert_allclose(c.x_a, rot90_points(shown_a, rot[0], wa, ha), atol=1e-9)
    np.testing.assert_allclose(c.x_b, rot90_points(kp_b, rot[1], 320, 240), atol=1e-9)
    ia = np.rint(c.x_a).astype(int)  # the shown image holds the stored pixels there
    sa = np.rint(kp_a).astype(int)
    assert np.abs(pair.image_a[ia[:, 1], ia[:, 0]].astype(int) - stored_a[sa[:, 1], sa[:, 0]]).max() <= 6
    assert any(f"the pairs file's rot {rot[0]}" in n for n in pair.notes)


def test_hloc_image_size_of_another_image_is_refused(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    path = write_hloc(tmp_path, kps, np.array([0, 1, -1, 2, -1, 3]), sizes={"a.png": (640, 480), "b.png": (320, 240)})
    with pytest.raises(FvizError, match=r"features.h5: image a.png is 640x480 in its image_size, 320x240 as stored here"):
        HlocReader(path).for_pair(pair)


@pytest.fixture(scope="module")
def fountain_hloc(tmp_path_factory):
    """fountain 0004 / 0005 at 768x512 with hloc-style SIFT matches of their stored pixels (ratio test 0.8)."""
    import cv2

    d = tmp_path_factory.mktemp("hloc_exif")
    imgs = [cv2.resize(cv2.imread(str(fountain() / "images" / n), cv2.IMREAD_GRAYSCALE), (768, 512)) for n in ("0004.jpg", "0005.jpg")]
    sift = cv2.SIFT_create(nfeatures=1000)
    (ka, da), (kb, db) = (sift.detectAndCompute(im, None) for im in imgs)
    m0 = -np.ones(len(ka), int)
    for x, y in cv2.BFMatcher().knnMatch(da, db, k=2):
        if x.distance < 0.8 * y.distance:
            m0[x.queryIdx] = x.trainIdx
    kps = {"a.jpg": np.array([k.pt for k in ka]), "b.jpg": np.array([k.pt for k in kb])}
    return d, imgs, kps, m0


@pytest.mark.parametrize("orientation", [1, 3, 6])
def test_hloc_matches_of_an_exif_rotated_image_find_as_many_inliers_as_unrotated(fountain_hloc, tmp_path, orientation):
    import json

    _, imgs, kps, m0 = fountain_hloc
    exif_jpeg(imgs[0], orientation, tmp_path / "a.jpg")
    exif_jpeg(imgs[1], 1, tmp_path / "b.jpg")
    path = write_hloc(tmp_path, kps, m0, sizes={"a.jpg": (768, 512), "b.jpg": (768, 512)})
    proc = run_fviz("inspect", "pair", "--image-a", tmp_path / "a.jpg", "--image-b", tmp_path / "b.jpg", "--matches", path,
                    "-e", "magsac", "--out", tmp_path / "p.rrd", "--json", timeout=300)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    inliers = doc["estimators"][0]["metrics"]["n_inliers"]
    assert doc["n_matches"] == (m0 >= 0).sum() and inliers > 0.8 * doc["n_matches"]  # unturned: 351 of 394
    assert (f"EXIF orientation {orientation}" in proc.stderr) == (orientation != 1)


def test_hloc_keypoints_whose_image_size_is_the_shown_one_are_not_turned(tmp_path):
    exif_jpeg(textured(240, 320), 6, tmp_path / "a.jpg")  # stored 320x240, shown 240x320
    exif_jpeg(textured(240, 320, 1), 1, tmp_path / "b.jpg")
    kps = {"a.jpg": np.array([[200.0, 300.0], [30.0, 40.0]]), "b.jpg": np.array([[11.0, 21.0], [31.0, 41.0]])}
    path = write_hloc(tmp_path, kps, np.array([0, 1]), sizes={"a.jpg": (240, 320), "b.jpg": (320, 240)})
    pair = two_images(str(tmp_path / "a.jpg"), str(tmp_path / "b.jpg"))
    np.testing.assert_array_equal(HlocReader(path).for_pair(pair).x_a, kps["a.jpg"])
    assert any("taken as of the image turned by its EXIF orientation 6" in n for n in pair.notes)


def test_hloc_keypoints_of_the_wrong_shape_are_named(hloc_pair, tmp_path):
    pair, kps = hloc_pair
    kps["a.png"] = np.c_[kps["a.png"], np.ones(6)]  # (N, 3)
    path = write_hloc(tmp_path, kps, np.array([0, 1, -1, 2, -1, 3]))
    with pytest.raises(FvizError, match=r"features.h5: keypoints of image a.png are float64 \(6, 3\), expected numbers"):
        HlocReader(path).for_pair(pair)
