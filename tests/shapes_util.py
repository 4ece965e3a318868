"""Image pairs of other shapes than KITTI's, made at test time from fountain-P11 (never stored in the repo):
the 3072x2048 photos as published, a portrait pair (both photos turned a quarter clockwise, half size) and a
4:3 pair (the centre 4:3 crop at 640x480), each with its ground-truth F carried through the same pixel maps."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from sources_util import closed_form_F, fountain, strecha_camera, strecha_projection

VIEWS = ("0000.jpg", "0001.jpg")


def _scaled(s: float) -> np.ndarray:
    """Resizing by ``s`` (OpenCV's pixel centres: x' = s (x + 0.5) - 0.5)."""
    return np.array([[s, 0, 0.5 * s - 0.5], [0, s, 0.5 * s - 0.5], [0, 0, 1]])


def _turned(height: int) -> np.ndarray:
    """A quarter turn clockwise of an image ``height`` rows high: (x, y) -> (height - 1 - y, x)."""
    return np.array([[0, -1, height - 1], [1, 0, 0], [0, 0, 1]], float)


def _shifted(dx: float, dy: float) -> np.ndarray:
    return np.array([[1, 0, dx], [0, 1, dy], [0, 0, 1]], float)


def shaped_pair(shape: str, out: Path) -> list[str]:
    """Write the pair of ``shape`` ("portrait" or "4:3") under ``out``: -> fviz's arguments for it
    (--image-a, --image-b, --K, --F-gt). A pixel map A of both images turns K into A K and F into A^-T F A^-1."""
    d = fountain()
    F = closed_form_F(strecha_projection(VIEWS[0]), strecha_projection(VIEWS[1]))
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for name in VIEWS:
        img = cv2.imread(str(d / "images" / name), cv2.IMREAD_COLOR)
        h, w = img.shape[:2]
        if shape == "portrait":
            img = cv2.resize(cv2.rotate(img, cv2.ROTATE_90_CLOCKWISE), None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
            A = _scaled(0.5) @ _turned(h)
        elif shape == "4:3":
            cw = h * 4 // 3
            x0 = (w - cw) // 2
            img = cv2.resize(img[:, x0: x0 + cw], (640, 480), interpolation=cv2.INTER_AREA)
            A = _scaled(640 / cw) @ _shifted(-x0, 0)
        else:
            raise ValueError(shape)
        paths.append(out / name)
        cv2.imwrite(str(paths[-1]), img, [cv2.IMWRITE_JPEG_QUALITY, 90])
    Ainv = np.linalg.inv(A)  # the same map for both views
    F = Ainv.T @ F @ Ainv
    F_text = ",".join(f"{v:.12e}" for v in (F / np.linalg.norm(F)).ravel())
    # both views share K; a quarter turn of the image turns the camera about its axis: A K = K' R_z
    K = A @ strecha_camera(VIEWS[0])[0] @ (_turned(1).T if shape == "portrait" else np.eye(3))
    return ["--image-a", str(paths[0]), "--image-b", str(paths[1]), "--K", ",".join(f"{v:.9g}" for v in K.ravel()),
            "--F-gt", F_text]


def fountain_args() -> list[str]:
    """fviz's arguments for the 3072x2048 pair 0000 -> 0001 with its published cameras."""
    d = fountain()
    return ["--pairs", str(d / "pairs_with_gt.txt"), "--images", str(d / "images"), "--index", "0"]
