"""Reading KITTI's files with one-line errors that name the file: text, images, and a PNG's shape from its header
(so that an image is decoded only when its pixels are read)."""

from __future__ import annotations

import errno
import functools
import os
from pathlib import Path

import numpy as np

from fviz.data.pair import LazyImage
from fviz.errors import FvizError

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def check_file(path: Path, what: str) -> Path:
    """``path`` if it is a file; else a one-line FvizError saying what is wrong with it."""
    if path.is_dir():
        raise FvizError(f"{what} {path}: a folder, not a file")
    if not path.exists():
        if path.is_symlink():
            try:
                os.stat(path)
            except OSError as exc:
                why = "a symlink loop" if exc.errno == errno.ELOOP else f"a symlink to the missing {os.readlink(path)}"
                raise FvizError(f"{what} {path}: {why}") from None
        raise FvizError(f"missing {what}: {path}")
    return path


def read_text(path: Path, what: str) -> str:
    try:
        return check_file(path, what).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FvizError(f"cannot read {what} {path} ({getattr(exc, 'strerror', None) or exc})") from None


def read_image(path: Path) -> np.ndarray:
    """uint8 (H, W) gray or (H, W, 3) RGB; a one-line FvizError naming the file otherwise."""
    import cv2

    check_file(path, "image")
    if not os.access(path, os.R_OK):
        raise FvizError(f"cannot read image {path} (permission denied)")
    from fviz.quiet import native_stderr_silenced

    with native_stderr_silenced():  # libpng's own "libpng error: ..." line: fviz's error says it
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None or img.size == 0:
        raise FvizError(f"unreadable or corrupt image: {path}")
    if img.dtype != np.uint8:
        img = cv2.convertScaleAbs(img, alpha=255.0 / max(float(img.max()), 1.0))
    if img.ndim == 3:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB if img.shape[2] == 4 else cv2.COLOR_BGR2RGB)
    return img

def png_shape(path: Path) -> tuple[int, ...] | None:
    """The shape :func:`read_image` gives an 8- or 16-bit gray or RGB PNG, from its header alone ((H, W) or
    (H, W, 3)); None for any other file, or a header whose CRC does not match (read it whole)."""
    import zlib

    try:
        with open(path, "rb") as f:
            head = f.read(33)
    except OSError:
        return None
    if len(head) < 33 or head[:8] != PNG_SIGNATURE or head[12:16] != b"IHDR":
        return None
    if zlib.crc32(head[12:29]) != int.from_bytes(head[29:33], "big"):  # a damaged header: decode now, which names it
        return None
    width, height = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    depth, colour = head[24], head[25]
    if width == 0 or height == 0 or depth not in (8, 16) or colour not in (0, 2):  # gray, RGB
        return None
    return (height, width) if colour == 0 else (height, width, 3)


def lazy_image(path: Path) -> "np.ndarray | LazyImage":
    """:func:`read_image` of ``path`` deferred to the first read of the pixels (a PNG whose header gives its
    shape), else read now. A missing or unreadable file is an error now either way."""
    check_file(path, "image")
    if not os.access(path, os.R_OK):
        raise FvizError(f"cannot read image {path} (permission denied)")
    shape = png_shape(path)
    return read_image(path) if shape is None else LazyImage(functools.partial(read_image, path), shape)  # picklable

