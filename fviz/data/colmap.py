"""COLMAP reconstructions (``--colmap MODEL_DIR --images DIR``), text or binary, read with pycolmap.

Ground truth comes from the registered poses (world -> camera, ``cam_from_world``) and cameras:
T_ab = T_b T_a^-1, F = K_b^-T [t]x R K_a^-1. COLMAP's pixel origin is the top-left *corner* of the
top-left pixel; fviz's (OpenCV's) is its centre: the principal point is shifted by -0.5 px here, once.

Camera models: SIMPLE_PINHOLE and PINHOLE directly; a model with distortion whose distortion parameters are
all zero is read as its pinhole part; any other distortion is refused with one line (an F relates
undistorted pixels: run ``colmap image_undistorter`` and give its undistorted model and images).

Checked before use: a binary model is walked within its files' sizes (:func:`check_binary_model`: a cut or
garbage file is one line, never pycolmap's hang), focal lengths finite and > 0, quaternions of unit length,
a camera's width x height that of its images (else K is at another resolution).

Pairs: those of ``--pairs FILE`` (only the names of each line are used), else the images sharing at least
``--min-shared`` 3D points (co-visibility), else, when the model has no 3D points, every pair of registered
images, with a note whatever ``--min-shared`` is (it cannot select them); in image-id order.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from pathlib import Path

import numpy as np

from fviz.data.images import make_pair
from fviz.data.pairsfile import pair_range, read_pairs
from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError, note_once
from fviz.geometry import fundamental_from_motion, normalize

SOURCE = "colmap"
PIXEL_ORIGIN_SHIFT = -0.5  # COLMAP's principal point (corner origin) -> OpenCV's (centre origin)
MODEL_FILES = ("cameras", "images", "points3D")
PINHOLE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE")
# pinhole cameras with lens distortion: accepted when every distortion parameter is zero
DISTORTED_PINHOLE_MODELS = ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV", "SIMPLE_DIVISION", "DIVISION")


@dataclass(frozen=True)
class View:
    """One registered image: its name, K (OpenCV origin, (3, 3)) and world -> camera T (4, 4)."""

    image_id: int
    name: str
    K: np.ndarray
    T: np.ndarray
    size: tuple[int, int] = (0, 0)  # the camera's width, height
    camera_id: int = 0


def _check_model_dir(model: Path) -> str:
    """"txt" or "bin"; a one-line error when the folder does not hold a model."""
    if not model.is_dir():
        raise FvizError(f"--colmap {model}: not a folder")
    for ext in ("bin", "txt"):
        if all((model / f"{f}.{ext}").is_file() for f in MODEL_FILES):
            return ext
    raise FvizError(f"--colmap {model}: no COLMAP model (cameras, images, points3D as .txt or .bin)")


def check_cameras_txt(path: Path) -> None:
    """Each line of a text model's cameras.txt is CAMERA_ID MODEL WIDTH HEIGHT PARAMS[]: a line that is not
    is a one-line error naming the file and line (pycolmap's own message names neither)."""
    for n, raw in enumerate(path.read_text(errors="replace").splitlines(), 1):
        fields = raw.split("#", 1)[0].split()
        if not fields:
            continue
        try:
            int(fields[0]), int(fields[2]), int(fields[3])
            [float(v) for v in fields[4:]]
        except (ValueError, IndexError):
            bad = next((v for v in fields[4:] if not _is_float(v)), " ".join(fields[:4]))
            raise FvizError(f"{path}:{n}: expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS (numbers), found {bad!r}") from None


def check_images_txt(path: Path) -> None:
    """images.txt holds two lines per image (blank lines count: an image without points has an empty second
    line): IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, then X Y POINT3D_ID triplets. A line that is not is a
    one-line error naming the file and line."""
    rows = [(n, raw.split()) for n, raw in enumerate(path.read_text(errors="replace").splitlines(), 1)
            if not raw.lstrip().startswith("#")]
    for k, (n, fields) in enumerate(rows):
        if k % 2 == 0:
            ok = len(fields) >= 10 and fields[0].isdigit() and fields[8].isdigit() and all(map(_is_float, fields[1:8]))
            if not ok and fields:
                raise FvizError(f"{path}:{n}: expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, found {' '.join(fields)[:60]!r}")
        elif len(fields) % 3 or not all(map(_is_float, fields)):
            raise FvizError(f"{path}:{n}: expected the image's points as X Y POINT3D_ID triplets")


def _is_float(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


class _Bin:
    """A bounded reader of one binary model file: each read checks that the bytes are there, each count that
    the file can hold it (pycolmap reads past the end of a cut file or loops on a garbage count)."""

    def __init__(self, path: Path):
        import struct

        self.path, self.data, self.pos, self._struct = path, path.read_bytes(), 0, struct

    def read(self, fmt: str, what: str) -> tuple:
        size = self._struct.calcsize("<" + fmt)
        if self.pos + size > len(self.data):
            raise FvizError(f"{self.path}: cut short or not a COLMAP binary file ({what} runs past its {len(self.data)} bytes)")
        out = self._struct.unpack_from("<" + fmt, self.data, self.pos)
        self.pos += size
        return out

    def count(self, what: str, min_bytes: int) -> int:
        (n,) = self.read("Q", f"the number of {what}")
        if n * min_bytes > len(self.data) - self.pos:
            raise FvizError(f"{self.path}: {n} {what} cannot fit in its {len(self.data)} bytes (cut short, or not a "
                            "COLMAP binary file)")
        return n

    def skip(self, n: int, what: str) -> None:
        if self.pos + n > len(self.data):
            raise FvizError(f"{self.path}: cut short or not a COLMAP binary file ({what} runs past its {len(self.data)} bytes)")
        self.pos += n

    def name(self, what: str) -> str:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise FvizError(f"{self.path}: cut short or not a COLMAP binary file ({what} has no end)")
        raw, self.pos = self.data[self.pos:end], end + 1
        return raw.decode("utf-8", "replace")

    def end(self) -> None:
        if self.pos != len(self.data):
            raise FvizError(f"{self.path}: {len(self.data) - self.pos} bytes after the last entry (not a COLMAP binary "
                            "file of this layout)")


def _model_params() -> dict[int, int]:
    """COLMAP's camera model ids -> their number of parameters (pycolmap's own table)."""
    import pycolmap

    out = {}
    create = getattr(pycolmap.Camera, "create_from_model_id", None) or pycolmap.Camera.create
    for name, mid in pycolmap.CameraModelId.__members__.items():
        if int(mid) >= 0:
            out[int(mid)] = len(create(1, mid, 1.0, 10, 10).params)
    return out


def check_binary_model(model: Path) -> None:
    """Walk cameras.bin, images.bin and points3D.bin within their sizes (COLMAP's reconstruction_io_binary
    layout), so that a cut or garbage file is one line naming it, never a hang or a crash."""
    params = _model_params()
    f = _Bin(model / "cameras.bin")
    for i in range(f.count("cameras", 24)):
        camera_id, model_id, width, height = f.read("IiQQ", f"camera {i + 1}")
        if model_id not in params:
            raise FvizError(f"{f.path}: camera {camera_id} has model id {model_id}, not a COLMAP camera model")
        if not (0 < width < 1 << 20 and 0 < height < 1 << 20):
            raise FvizError(f"{f.path}: camera {camera_id} is {width}x{height} pixels (not a COLMAP binary file?)")
        f.skip(8 * params[model_id], f"camera {camera_id}'s parameters")
    f.end()
    f = _Bin(model / "images.bin")
    for i in range(f.count("images", 69)):
        (image_id,) = f.read("I", f"image {i + 1}")
        f.read("7dI", f"image {image_id}'s pose and camera")
        name = f.name(f"image {image_id}'s name")
        n = f.count(f"points of image {name}", 24)
        f.skip(24 * n, f"the points of image {name}")
    f.end()
    f = _Bin(model / "points3D.bin")
    n_points = f.count("3D points", 51)
    u64, data, pos, size = f._struct.Struct("<Q").unpack_from, f.data, f.pos, len(f.data)
    for i in range(n_points):  # POINT3D_ID X Y Z R G B ERROR TRACK_LENGTH (51 bytes), then 8 bytes per observation
        if pos + 51 > size:
            raise FvizError(f"{f.path}: cut short or not a COLMAP binary file (3D point {i + 1} of {n_points} runs past "
                            f"its {size} bytes)")
        (track,) = u64(data, pos + 43)
        if 8 * track > size - pos - 51:
            raise FvizError(f"{f.path}: {track} observations of 3D point {u64(data, pos)[0]} cannot fit in its {size} "
                            "bytes (cut short, or not a COLMAP binary file)")
        pos += 51 + 8 * track
    f.pos = pos
    f.end()


def pinhole_K(camera, where: str) -> np.ndarray:
    """K of a pinhole camera in OpenCV's pixel origin; distortion refused (unless all zero)."""
    model = camera.model.name
    params = np.asarray(camera.params, float)
    extra = list(camera.extra_params_idxs())
    if model not in PINHOLE_MODELS + DISTORTED_PINHOLE_MODELS:
        raise FvizError(f"{where}: camera model {model} is not a pinhole camera (an F needs one): undistort with "
                        "'colmap image_undistorter' and give its model and images")
    if extra and np.any(params[extra] != 0):
        raise FvizError(f"{where}: camera model {model} has distortion ({', '.join(f'{v:g}' for v in params[extra])}); "
                        "an F relates undistorted pixels: undistort with 'colmap image_undistorter' and give its model and images")
    K = np.asarray(camera.calibration_matrix(), float).copy()
    if not (np.isfinite(params).all() and K[0, 0] > 0 and K[1, 1] > 0):
        raise FvizError(f"{where}: focal length {K[0, 0]:g}, {K[1, 1]:g} px (params {', '.join(f'{v:g}' for v in params)}): "
                        "a camera's focal lengths must be finite and > 0")
    if not (camera.width > 0 and camera.height > 0):
        raise FvizError(f"{where}: the camera is {camera.width}x{camera.height} pixels")
    K[0, 2] += PIXEL_ORIGIN_SHIFT
    K[1, 2] += PIXEL_ORIGIN_SHIFT
    return K


def read_model(model: str | Path):
    """The pycolmap Reconstruction of a model folder; one-line errors."""
    model = Path(model)
    ext = _check_model_dir(model)
    if ext == "txt":
        check_cameras_txt(model / "cameras.txt")
        check_images_txt(model / "images.txt")
    else:
        check_binary_model(model)
    import pycolmap

    try:
        return pycolmap.Reconstruction(str(model))
    except Exception as exc:  # pycolmap raises ValueError / RuntimeError with a C++ location
        msg = " ".join(str(exc).split())
        raise FvizError(f"--colmap {model}: pycolmap cannot read the model ({msg})") from None


def views(rec, model: Path) -> dict[int, View]:
    """Registered images by id (cameras checked on first use)."""
    out = {}
    for image_id in sorted(rec.images):
        im = rec.images[image_id]
        if not getattr(im, "has_pose", True):
            continue
        cam = rec.cameras[im.camera_id]
        K = pinhole_K(cam, f"--colmap {model}: camera {im.camera_id} (image {im.name})")
        cfw = im.cam_from_world() if callable(im.cam_from_world) else im.cam_from_world
        q, t = np.asarray(cfw.rotation.quat, float), np.asarray(cfw.translation, float)
        if not (np.isfinite(q).all() and abs(np.linalg.norm(q) - 1) < 1e-3 and np.isfinite(t).all()):
            raise FvizError(f"--colmap {model}: image {image_id} ({im.name}): its pose (quaternion QW QX QY QZ "
                            f"{q[3]:g} {q[0]:g} {q[1]:g} {q[2]:g}, translation {t[0]:g} {t[1]:g} {t[2]:g}) is not a rotation "
                            "of unit quaternion and a finite translation")
        T = np.eye(4)
        T[:3] = np.asarray(cfw.matrix(), float)
        out[image_id] = View(image_id, im.name, K, T, (int(cam.width), int(cam.height)), im.camera_id)
    if not out:
        raise FvizError(f"--colmap {model}: no registered image")
    return out


def covisible_pairs(rec, min_shared: int) -> list[tuple[int, int]]:
    """(id_a, id_b), id_a < id_b, of images sharing at least ``min_shared`` 3D points."""
    from collections import Counter

    shared: Counter = Counter()
    for p in rec.points3D.values():
        ids = sorted({el.image_id for el in p.track.elements})
        shared.update(combinations(ids, 2))
    return sorted(k for k, n in shared.items() if n >= min_shared)


class ColmapSource:
    """The pairs of a COLMAP model (see the module doc), with ``pair_ids``, ``load``, ``ground_truth``."""

    def __init__(self, model: str | Path, images: str | Path | None, pairs: str | Path | None, min_shared: int,
                 frames: tuple[int | None, int | None] = (None, None)):
        self.model = Path(model)
        self.pairs_file, self.min_shared = pairs, min_shared
        rec = read_model(self.model)
        self.images = Path(images) if images is not None else self.model.parent / "images"
        if not self.images.is_dir():
            raise FvizError(f"--images {self.images}: not a folder (the images the model's names are relative to)")
        self.views = views(rec, self.model)
        self.by_name = {v.name: v for v in self.views.values()}
        self.pairs = self._pairs(rec, pairs, min_shared)
        self.range = pair_range(frames, len(self.pairs), f"the model {self.model}")

    def _pairs(self, rec, pairs, min_shared: int) -> list[tuple[int, int]]:
        if pairs is not None:
            out = []
            for p in read_pairs(pairs):
                missing = [n for n in (p.name0, p.name1) if n not in self.by_name]
                if missing:
                    raise FvizError(f"{pairs}:{p.line}: image {missing[0]} is not a registered image of {self.model}")
                out.append((self.by_name[p.name0].image_id, self.by_name[p.name1].image_id))
            return out
        if len(rec.points3D) == 0:
            out = list(combinations(sorted(self.views), 2))
            # given or the default (the flag cannot tell an explicit 100 from none): co-visibility cannot select pairs
            note_once(f"note: --colmap {self.model} has no 3D points (points3D is empty): all {len(out)} pairs of its "
                       f"{len(self.views)} images are taken and --min-shared {min_shared} does not apply "
                       "(select pairs with --pairs FILE or --frames A:B)")
            return out
        out = [(a, b) for a, b in covisible_pairs(rec, min_shared) if a in self.views and b in self.views]
        if not out:
            raise FvizError(f"--colmap {self.model}: no two images share {min_shared} 3D points (lower --min-shared)")
        return out

    def pair_id(self, index: int) -> PairId:
        a, b = self.pairs[index]
        return PairId(SOURCE, self.model.name, "pair", a, b, root=str(self.images), image_a=self.views[a].name,
                      image_b=self.views[b].name)

    def pair_ids(self) -> list[PairId]:
        return [self.pair_id(i) for i in self.range]

    def index_of(self, index: int | None, names: tuple[str, str] | None) -> int:
        """The pair ``--index N`` (from 0) of the model's pairs, or the one of both names."""
        if names is not None:
            ids = tuple(self.by_name[n].image_id if n in self.by_name else None for n in names)
            if ids not in self.pairs:
                raise FvizError(f"--colmap {self.model}: no pair {names[0]} {names[1]} among its pairs (see --min-shared, --pairs)")
            return self.pairs.index(ids)
        index = 0 if index is None else index
        if not 0 <= index < len(self.pairs):
            raise FvizError(f"--index {index}: the model gives pairs 0..{len(self.pairs) - 1}")
        return index

    def _motion(self, pid: PairId):
        va, vb = self.views[pid.frame_a], self.views[pid.frame_b]
        T_ab = vb.T @ np.linalg.inv(va.T)
        return va, vb, T_ab

    def load(self, pid: PairId) -> Pair:
        va, vb, T_ab = self._motion(pid)
        pair = make_pair(pid, self.images / va.name, self.images / vb.name, va.K, vb.K, T_ab, None,
                         what=f"--colmap {self.model}: images {va.name}, {vb.name}",
                         what_K=(f"--colmap {self.model}: camera of {va.name}", f"--colmap {self.model}: camera of {vb.name}"))
        for v, size in ((va, pair.size_a), (vb, pair.size_b)):
            if v.size != (0, 0) and tuple(size) != v.size:
                turned = " (turned: an EXIF orientation COLMAP did not apply?)" if tuple(size) == v.size[::-1] else ""
                raise FvizError(f"--colmap {self.model}: camera {v.camera_id} is {v.size[0]}x{v.size[1]} but its image "
                                f"{self.images / v.name} is {size[0]}x{size[1]}{turned}: give the images the model was made "
                                "from (its K is at their resolution)")
        return pair

    def ground_truth(self, pid: PairId) -> np.ndarray:
        va, vb, T = self._motion(pid)
        return normalize(fundamental_from_motion(va.K, vb.K, T[:3, :3], T[:3, 3]), "fbn")

    def input_digest(self, pid: PairId) -> str:
        """The pair's two registered images as the model holds them (names, cameras, poses)."""
        from fviz.digest import digest_of

        va, vb = self.views[pid.frame_a], self.views[pid.frame_b]
        return digest_of(va.name, va.K, va.T, vb.name, vb.K, vb.T)

    def inspect_args(self, pid: PairId) -> list[str]:
        args = ["--colmap", str(self.model), "--images", str(self.images),
                "--index", str(self.pairs.index((pid.frame_a, pid.frame_b)))]
        return args + (["--pairs", str(self.pairs_file)] if self.pairs_file else ["--min-shared", str(self.min_shared)])
