"""A user's two images with optional cameras and ground truth -> the one Pair type.

Shared by every user source (``fviz inspect pair --image-a A --image-b B``, pairs files, COLMAP models):
images are read with OpenCV, EXIF orientation applied (as OpenCV's IMREAD_COLOR does); a pairs file's
``rot`` (0-3, quarter turns counter-clockwise, SuperGlue's ``np.rot90``) turns the image further, and its K
and F with it (:func:`rotation_map`). Ground truth, each optional: intrinsics K (at the image's resolution),
a relative pose T_ab (x_b = R x_a + t; F then follows in closed form, F = K_b^-T [t]x R K_a^-1) or an F.
Pixel coordinates are OpenCV's (origin at the centre of the top-left pixel).

Before decoding, a PNG's or JPEG's header is read (:func:`image_header`): an image of more than
:data:`MAX_IMAGE_PIXELS` is refused (a decompression bomb); a JPEG without its end marker (a cut file, whose
missing part OpenCV decodes as flat grey) is refused; a 16-bit PNG is scaled to 8 bits by its largest
sample (OpenCV's 8-bit read keeps the high byte: 12-bit data would be nearly black), with a note.
One K for both images (``--K``) needs images of one size; a ground-truth F must have rank 2 (:func:`check_rank2`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError
from fviz.geometry import fundamental_from_motion, is_valid, normalize


MAX_IMAGE_PIXELS = 200_000_000  # larger images are refused before decoding (a decompression bomb: 20000x20000 is 400 MP)
EXIF_TURNS = {3: "turned 180 degrees", 6: "turned 90 degrees clockwise", 8: "turned 90 degrees counter-clockwise"}


@dataclass(frozen=True)
class ImageHeader:
    """What a PNG or JPEG file's header says, read without decoding: format, width x height as stored (before
    any EXIF orientation), bits per sample, EXIF orientation (1 = none), and for a JPEG whether its end
    marker is there (a cut file has none)."""

    format: str
    width: int
    height: int
    bits: int = 8
    orientation: int = 1
    complete: bool = True


def image_header(path: str | Path) -> ImageHeader | None:
    """The header of a PNG or JPEG file (None for other formats or a header that cannot be parsed)."""
    import struct

    try:
        with open(path, "rb") as f:
            head = f.read(32)
            if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
                w, h, bits = struct.unpack(">IIB", head[16:25])
                return ImageHeader("png", w, h, bits)
            if head[:2] != b"\xff\xd8":
                return None
            f.seek(2)
            size, orientation = None, 1
            while True:
                marker = f.read(2)
                while len(marker) == 2 and marker[0] == 0xFF and marker[1] == 0xFF:  # fill bytes
                    marker = marker[1:] + f.read(1)
                if len(marker) < 2 or marker[0] != 0xFF:
                    return None if size is None else ImageHeader("jpeg", *size, 8, orientation, False)
                kind = marker[1]
                if kind in (0xD8, 0x01) or 0xD0 <= kind <= 0xD7:
                    continue
                length = struct.unpack(">H", f.read(2) or b"\0\0")[0]
                body = f.read(length - 2)
                if kind == 0xE1 and body[:6] == b"Exif\0\0":
                    try:
                        orientation = _exif_orientation(body[6:]) or orientation
                    except (struct.error, IndexError):  # a broken EXIF block: OpenCV ignores it too
                        pass
                elif kind in (0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF) and len(body) >= 5:
                    h, w = struct.unpack(">HH", body[1:5])
                    size = (w, h)
                elif kind == 0xDA:  # start of scan: the entropy-coded data runs to the end marker
                    rest = f.read()
                    if size is None:
                        return None
                    # 0xFF in coded data is stuffed (FF 00) and restart markers are FF D0-D7: FF D9 is the end
                    return ImageHeader("jpeg", *size, 8, orientation, b"\xff\xd9" in rest)
    except (OSError, struct.error, ValueError):
        return None


def _exif_orientation(tiff: bytes) -> int | None:
    """Tag 0x0112 of IFD0 of an EXIF block (a TIFF header onwards)."""
    import struct

    if tiff[:2] not in (b"II", b"MM"):
        return None
    e = "<" if tiff[:2] == b"II" else ">"
    (ifd,) = struct.unpack(e + "I", tiff[4:8])
    (n,) = struct.unpack(e + "H", tiff[ifd:ifd + 2])
    for i in range(n):
        entry = tiff[ifd + 2 + 12 * i: ifd + 14 + 12 * i]
        tag, typ, _count = struct.unpack(e + "HHI", entry[:8])
        if tag == 0x0112 and typ == 3:
            value = struct.unpack(e + "H", entry[8:10])[0]
            return value if 1 <= value <= 8 else None
    return None


def exif_map(orientation: int, width: int, height: int) -> np.ndarray:
    """(3, 3) pixel map from a stored width x height image to it shown with its EXIF ``orientation`` (as OpenCV's
    imread applies it): x_shown = A x_stored, OpenCV's pixel origin."""
    w, h = width - 1.0, height - 1.0
    maps = {1: [[1, 0, 0], [0, 1, 0]], 2: [[-1, 0, w], [0, 1, 0]], 3: [[-1, 0, w], [0, -1, h]], 4: [[1, 0, 0], [0, -1, h]],
            5: [[0, 1, 0], [1, 0, 0]], 6: [[0, -1, h], [1, 0, 0]], 7: [[0, -1, h], [-1, 0, w]], 8: [[0, 1, 0], [-1, 0, w]]}
    return np.array(maps.get(orientation, maps[1]) + [[0, 0, 1]], float)


def read_user_image(path: str | Path, what: str = "image", notes: list[str] | None = None) -> np.ndarray:
    """uint8 (H, W, 3) RGB (or (H, W) for a gray file), EXIF orientation applied; one-line error otherwise (a cut
    JPEG included). What the reading did that a user should know (16-bit samples scaled) is added to ``notes``."""
    import cv2

    path = Path(path)
    if path.is_dir():
        raise FvizError(f"{what} {path}: a folder, not an image")
    if not path.exists():
        raise FvizError(f"{what} {path}: no such file")
    if not os.access(path, os.R_OK):
        raise FvizError(f"{what} {path}: cannot read it (permission denied)")
    notes = [] if notes is None else notes
    header = image_header(path)
    if header is not None and header.width * header.height > MAX_IMAGE_PIXELS:
        raise FvizError(f"{what} {path}: {header.width}x{header.height} pixels, more than fviz decodes "
                        f"({MAX_IMAGE_PIXELS // 1_000_000} megapixels): downscale it first")
    if header is not None and not header.complete:
        raise FvizError(f"{what} {path}: the JPEG file is cut short (no end marker, {path.stat().st_size} bytes): OpenCV "
                        "would decode the part after the cut as flat grey; copy or download it again")
    if header is not None and header.bits == 16:
        img = cv2.imread(str(path), cv2.IMREAD_ANYDEPTH | cv2.IMREAD_ANYCOLOR)
        if img is not None and img.dtype == np.uint16:
            top = int(img.max())
            img = (img.astype(np.float64) * (255.0 / max(top, 1))).round().astype(np.uint8)
            img = img[..., 0] if img.ndim == 3 and img.shape[2] == 2 else img  # gray and alpha
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR) if img.ndim == 2 else img[..., :3]
            notes.append(f"{what} {path.name} has 16-bit samples (largest {top}): scaled to 8 bits by that largest value")
    else:
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)  # applies the EXIF orientation
    if img is None or img.size == 0:
        raise FvizError(f"{what} {path}: unreadable or not an image OpenCV can decode")
    if (img[..., 0] == img[..., 1]).all() and (img[..., 1] == img[..., 2]).all():
        return img[..., 0].copy()
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_text(path: str | Path, what: str, encoding: str = "utf-8") -> str:
    """A text file's content; a binary file (a MATLAB .mat, an HDF5 or NumPy file, anything that is not UTF-8 text)
    is a one-line error naming ``what`` and the file and saying what it is, before any work."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except FileNotFoundError:
        raise FvizError(f"{what} {path}: no such file") from None
    except OSError as exc:
        raise FvizError(f"{what} {path}: cannot read it ({exc.strerror or exc})") from None
    if raw[:10] == b"MATLAB 5.0" or (raw[:4] == b"\x89HDF" and path.suffix.lower() == ".mat"):
        raise FvizError(f"{what} {path}: a MATLAB .mat file, not text: export its numbers as text (MATLAB: writematrix(X, "
                        "'x.txt', 'Delimiter', ' '); Python: numpy.savetxt of scipy.io.loadmat's array)")
    kind = ("an HDF5 file" if raw[:4] == b"\x89HDF" else "a NumPy file" if raw[:6] == b"\x93NUMPY" or raw[:4] == b"PK\x03\x04"
            else None)
    if kind is None:
        try:
            text = raw.decode(encoding)
        except UnicodeDecodeError as exc:
            raise FvizError(f"{what} {path}: not UTF-8 text (at byte {exc.start}): a binary file, or another encoding") from None
        else:
            if "\x00" not in text:
                return text
            kind = "a binary file (NUL bytes)"
    raise FvizError(f"{what} {path}: {kind}, not a text file of numbers")


def parse_numbers(text: str, counts: tuple[int, ...], what: str) -> np.ndarray:
    """Numbers separated by commas or spaces, or a file holding them; exactly one of ``counts`` of them."""
    source = text
    if not _looks_numeric(text) and Path(text).is_file():
        source = read_text(text, what)
    try:
        values = np.array([float(v) for v in source.replace(",", " ").split()], float)
    except ValueError:
        raise FvizError(f"{what} {text!r}: expected {' or '.join(map(str, counts))} numbers (or a file of them)") from None
    if len(values) not in counts or not np.isfinite(values).all():
        raise FvizError(f"{what} {text!r}: {len(values)} numbers, expected {' or '.join(map(str, counts))} finite ones")
    return values


def _looks_numeric(text: str) -> bool:
    try:
        [float(v) for v in text.replace(",", " ").split()]
        return True
    except ValueError:
        return False


def intrinsics(values: np.ndarray, what: str) -> np.ndarray:
    """fx, fy, cx, cy (4 numbers) or a row-major 3x3 K -> (3, 3)."""
    if len(values) == 4:
        fx, fy, cx, cy = values
        K = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    else:
        K = np.asarray(values, float).reshape(3, 3)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and abs(np.linalg.det(K)) > 0):
        raise FvizError(f"{what}: not an intrinsic matrix (focal lengths must be > 0)")
    return K


def parse_K(text: str, what: str) -> np.ndarray:
    return intrinsics(parse_numbers(text, (4, 9), what), what)


def pose_matrix(values: np.ndarray, what: str) -> np.ndarray:
    """12 (3x4) or 16 (4x4) row-major numbers -> (4, 4) T, with R checked to be a rotation and a 4x4's last row
    0 0 0 1 (a column-major, i.e. transposed, T is named as such)."""
    values = np.asarray(values, float).ravel()
    T = np.eye(4)
    T[:3] = values.reshape(-1, 4)[:3]
    if len(values) == 16 and np.isfinite(values).all() and not np.allclose(values[12:], [0, 0, 0, 1], atol=1e-9):
        transposed = np.allclose(values[3::4][:3], 0, atol=1e-9) and abs(values[15] - 1) < 1e-9
        raise FvizError(f"{what}: the last row of a 4x4 T is {' '.join(f'{v:g}' for v in values[12:])}, not 0 0 0 1"
                        + (": the matrix is transposed (column-major); give it row by row" if transposed else ""))
    with np.errstate(over="ignore", invalid="ignore"):
        finite = np.isfinite(T).all() and np.isfinite(np.linalg.norm(T[:3, 3]))
    if not finite:
        raise FvizError(f"{what}: its translation is not a finite number of metres (too large to compute with)")
    R = T[:3, :3]
    if np.abs(R @ R.T - np.eye(3)).max() > 1e-3 or np.linalg.det(R) < 0:
        hint = ""
        if len(values) == 12:  # the 3x4 written column by column (4 rows of 3)?
            Rt = values.reshape(4, 3)[:3].T
            if np.abs(Rt @ Rt.T - np.eye(3)).max() <= 1e-3 and np.linalg.det(Rt) > 0:
                hint = ": its numbers are the 3x4 T column by column (transposed); give it row by row"
        raise FvizError(f"{what}: its 3x3 part is not a rotation (R R^T != I){hint}")
    return T


def parse_T(text: str, what: str = "--T-ab") -> np.ndarray:
    return pose_matrix(parse_numbers(text, (12, 16), what), what)


def parse_F(text: str, what: str = "--F-gt") -> np.ndarray:
    F = parse_numbers(text, (9,), what).reshape(3, 3)
    if not is_valid(F):
        raise FvizError(f"{what}: all zero")
    # scaled first: a norm of subnormal entries (1e-320) underflows
    return normalize(check_rank2(F / np.abs(F).max(), what), "fbn")


RANK2_TOLERANCE = 1e-3  # s3 / s2 of a fundamental matrix above this: rank 3, not an F (a typed F of 4 digits stays below)


def check_rank2(F: np.ndarray, what: str) -> np.ndarray:
    """F itself when it has rank 2 (its smallest singular value at most RANK2_TOLERANCE of the middle one); a
    one-line error naming ``what`` otherwise: a rank-3 matrix has no epipoles and is no F, and fviz does not
    project it to rank 2 behind the user's back (scores would then be of another matrix)."""
    s = np.linalg.svd(np.asarray(F, float), compute_uv=False)
    if not s[1] > 0:
        raise FvizError(f"{what}: rank {int((s > 0).sum())} (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g}): an F has rank 2")
    if s[2] > RANK2_TOLERANCE * s[1]:
        raise FvizError(f"{what}: rank 3 (singular values {s[0]:.3g}, {s[1]:.3g}, {s[2]:.3g}): an F has rank 2; project it "
                        "first (U diag(s1, s2, 0) V^T of its SVD) if that is what you mean")
    return F


def rotation_map(k: int, width: int, height: int) -> np.ndarray:
    """(3, 3) pixel map of ``np.rot90(image, k)`` (k quarter turns counter-clockwise) of a width x height
    image: x_rotated = A x. One turn takes (x, y) to (y, W - 1 - x)."""
    A = np.eye(3)
    w, h = width, height
    for _ in range(k % 4):
        A = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, w - 1.0], [0.0, 0.0, 1.0]]) @ A
        w, h = h, w
    return A


def ground_truth(K_a, K_b, T_ab, F_gt, what: str) -> dict:
    """Pair fields (K_a, K_b, R, t, F_gt) from what is known: F from the pose and cameras in closed form,
    or the given F; both at once must agree with each other (else a one-line error)."""
    out = {"K_a": K_a, "K_b": K_b, "R": None, "t": None, "F_gt": F_gt}
    if T_ab is not None:
        if K_a is None or K_b is None:
            raise FvizError(f"{what}: a relative pose needs the intrinsics of both images (--K, or --K-a and --K-b)")
        out["R"], out["t"] = T_ab[:3, :3].copy(), T_ab[:3, 3].copy()
        if np.linalg.norm(out["t"]) == 0:
            raise FvizError(f"{what}: the translation is zero (pure rotation): F is undefined")
        F = normalize(fundamental_from_motion(K_a, K_b, out["R"], out["t"]), "fbn")
        if F_gt is not None and min(np.abs(F - F_gt).max(), np.abs(F + F_gt).max()) > 1e-6:
            raise FvizError(f"{what}: the given F and the F of the pose and cameras differ; give one of them")
        out["F_gt"] = F
    return out


def rotated(image: np.ndarray, K: np.ndarray | None, k: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, np.ndarray]:
    """The image turned k quarter turns (np.rot90), its K, the pixel map A and the camera's turn Rc.

    A K = K' Rc with K' upper-triangular (SuperGlue's ``rotate_intrinsics``: a turned camera is a camera, its
    focal lengths on the diagonal) and Rc the turn about the optical axis (x_turned = Rc x in camera
    coordinates; SuperGlue's ``rotate_pose_inplane``)."""
    A = rotation_map(k, image.shape[1], image.shape[0])
    Rc = np.eye(3)
    Rc[:2, :2] = A[:2, :2]
    if k % 4 == 0:
        return image, K, A, Rc
    return np.ascontiguousarray(np.rot90(image, k)), None if K is None else A @ K @ Rc.T, A, Rc


def make_pair(pid: PairId, path_a: Path, path_b: Path, K_a=None, K_b=None, T_ab=None, F_gt=None,
              rot: tuple[int, int] = (0, 0), gt_accuracy_px: float | None = None, what: str = "pair",
              what_K: tuple[str, str] | None = None, what_images: str | None = None, shared_K: str | None = None) -> Pair:
    """Read both images and build the Pair; ``rot`` turns them (and their cameras and F) as SuperGlue does.
    ``what_K``: where each K came from (a flag, a file's line), named when its principal point lies outside its image.
    The same file twice is refused; two files with identical pixels get a note."""
    if Path(path_a).resolve() == Path(path_b).resolve():
        raise FvizError(f"{what_images or what}: image a and image b are the same file {path_a}: every F through the points fits two "
                        "copies of one image (residuals ~0, 100 % inliers say nothing); give two different images")
    notes: list[str] = []
    image_a, image_b = read_user_image(path_a, "image a", notes), read_user_image(path_b, "image b", notes)
    return pair_of_arrays(pid, image_a, image_b, K_a, K_b, T_ab, F_gt, rot, gt_accuracy_px, what,
                          extra={"path_a": str(path_a), "path_b": str(path_b), "rot": tuple(rot)}, what_K=what_K, notes=notes,
                          shared_K=shared_K)


def pair_of_arrays(pid: PairId, image_a: np.ndarray, image_b: np.ndarray, K_a=None, K_b=None, T_ab=None, F_gt=None,
                   rot: tuple[int, int] = (0, 0), gt_accuracy_px: float | None = None, what: str = "pair",
                   extra: dict | None = None, what_K: tuple[str, str] | None = None,
                   notes: list[str] | None = None, shared_K: str | None = None) -> Pair:
    """The Pair of two decoded images (uint8, (H, W) or (H, W, 3) RGB) and what is known of their geometry
    (see :func:`ground_truth`); ``rot`` turns them (and their cameras and F) as SuperGlue does. ``what_K``: where
    each K came from (a flag, a file's line), named when its principal point lies outside its image; ``notes``:
    what reading the images found (16-bit samples); ``shared_K``: the argument that gave one K for both images (then
    of one size: a K is of one resolution)."""
    notes = list(notes or [])
    if shared_K and image_a.shape[:2] != image_b.shape[:2]:
        raise FvizError(f"{shared_K}: one K for both images, but image a is {image_a.shape[1]}x{image_a.shape[0]} and "
                        f"image b {image_b.shape[1]}x{image_b.shape[0]}: a K holds for one resolution; give each image its "
                        f"own K ({'--K-a and --K-b' if shared_K.startswith('--') else 'K_a and K_b'})")
    gt = ground_truth(K_a, K_b, T_ab, F_gt, what)
    if image_a.ndim != image_b.ndim:
        import cv2

        gray = lambda im: cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im  # noqa: E731
        image_a, image_b = gray(image_a), gray(image_b)
        notes.append("one image is gray, the other colour: both are evaluated and recorded in gray")
    if any(rot):
        image_a, gt["K_a"], A_a, Rc_a = rotated(image_a, gt["K_a"], rot[0])
        image_b, gt["K_b"], A_b, Rc_b = rotated(image_b, gt["K_b"], rot[1])
        if gt["R"] is not None:  # the cameras turned with their images: x_b' = Rc_b (R Rc_a^T x_a' + t)
            gt["R"], gt["t"] = Rc_b @ gt["R"] @ Rc_a.T, Rc_b @ gt["t"]
        if gt["F_gt"] is not None:
            gt["F_gt"] = normalize(np.linalg.inv(A_b).T @ gt["F_gt"] @ np.linalg.inv(A_a), "fbn")
        notes.append(f"images turned by rot {rot[0]}, {rot[1]} (quarter turns counter-clockwise) as the pairs file says")
    for i, (v, K, im) in enumerate((("a", gt["K_a"], image_a), ("b", gt["K_b"], image_b))):
        if K is not None:
            h, w = im.shape[:2]
            if not (-0.5 <= K[0, 2] <= w - 0.5 and -0.5 <= K[1, 2] <= h - 0.5):
                flag = what_K[i] if what_K else f"{what}: K of image {v}"
                raise FvizError(f"{flag}: principal point ({K[0, 2]:.1f}, {K[1, 2]:.1f}) lies outside the {w}x{h} image "
                                f"{v}: is K for this image's resolution (a resized image with the full-size K)?")
    if image_a.shape == image_b.shape and np.array_equal(image_a, image_b):
        notes.append("image a and image b have identical pixels: any F through the points fits them, so near-zero "
                     "residuals and 100 % inliers say nothing")
    return Pair(id=pid, image_a=image_a, image_b=image_b, gt_accuracy_px=gt_accuracy_px, notes=notes,
                extra=dict(extra or {}), **gt)


def two_images(image_a: str, image_b: str, K: str | None = None, K_a: str | None = None, K_b: str | None = None,
               T_ab: str | None = None, F_gt: str | None = None) -> Pair:
    """``fviz inspect pair --image-a A --image-b B [--K | --K-a --K-b] [--T-ab] [--F-gt]``."""
    if K is not None and (K_a is not None or K_b is not None):
        raise FvizError("--K sets both cameras: give --K, or --K-a and --K-b, not both")
    Ka = parse_K(K, "--K") if K else parse_K(K_a, "--K-a") if K_a else None
    Kb = parse_K(K, "--K") if K else parse_K(K_b, "--K-b") if K_b else None
    if (Ka is None) != (Kb is None):
        raise FvizError(f"--K-{'b' if Kb is None else 'a'}: missing (give both --K-a and --K-b, or one --K)")
    pa, pb = Path(image_a), Path(image_b)
    pid = PairId("images", "", "pair", 0, 1, root=str(pa.parent), image_a=pa.name, image_b=pb.name)
    if pa.name == pb.name:
        pid = PairId("images", "", "pair", 0, 1, root="", image_a=str(pa), image_b=str(pb))
    return make_pair(pid, pa, pb, Ka, Kb, parse_T(T_ab) if T_ab else None, parse_F(F_gt) if F_gt else None,
                     what="--T-ab/--F-gt", what_K=("--K", "--K") if K else ("--K-a", "--K-b"), what_images="--image-a/--image-b",
                     shared_K="--K" if K else None)
