"""Training-time augmentation of a pair: a shared or independent crop and resize (the target F follows the pixel maps:
F' = A_b^-T F A_a^-1) and photometric jitter."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fviz.models.predict import flip_matrix


@dataclass(frozen=True)
class Augment:
    """Augmentations that keep F exact.  Every one maps image pixels by an affine A (x' = A x), so
    F' = A_b^-T F A_a^-1 (:func:`transform_f`), or exchanges the images (F' = F^T):

    - ``swap``: probability of exchanging a and b;
    - ``flip``: probability of mirroring both images, x' = (W - 1) - x;
    - ``crop``: each image independently cropped to a random box of (1 - c) .. 1 of its size, at a
      random position (scale + shift), before the resize to the model input;
    - ``photometric``: per-image gain, gamma and sensor noise (F unchanged).
    """

    swap: float = 0.0
    flip: float = 0.0
    crop: float = 0.0
    photometric: float = 0.0

    @property
    def active(self) -> bool:
        return any((self.swap, self.flip, self.crop, self.photometric))


def translation(dx: float, dy: float) -> np.ndarray:
    """x' = x + (dx, dy).  (3, 3)."""
    return np.array([[1.0, 0.0, dx], [0.0, 1.0, dy], [0.0, 0.0, 1.0]])


def transform_f(F: np.ndarray, A_a: np.ndarray, A_b: np.ndarray) -> np.ndarray:
    """F of the transformed images, x'_a = A_a x_a and x'_b = A_b x_b: A_b^-T F A_a^-1.  (..., 3, 3)."""
    return np.swapaxes(np.linalg.inv(A_b), -1, -2) @ F @ np.linalg.inv(A_a)


def crop_resize(image: np.ndarray, box: tuple[int, int, int, int], out_wh: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """Crop ``box`` = (x0, y0, w, h) and resize it to ``out_wh``: (image, A with x_out = A x_in)."""
    import cv2

    from fviz.models.predict import scale_matrix

    x0, y0, w, h = box
    crop = image[y0 : y0 + h, x0 : x0 + w]
    interp = cv2.INTER_AREA if (w >= out_wh[0] and h >= out_wh[1]) else cv2.INTER_LINEAR
    out = cv2.resize(crop, out_wh, interpolation=interp)
    return out, scale_matrix((w, h), out_wh) @ translation(-x0, -y0)


def photometric(image: np.ndarray, strength: float, rng: np.random.Generator) -> np.ndarray:
    """float32 image in [0, 1]: gain, gamma and Gaussian noise scaled by ``strength`` (geometry untouched)."""
    gain = 1.0 + strength * rng.uniform(-0.4, 0.4)
    gamma = float(np.exp(strength * rng.uniform(-0.4, 0.4)))
    noise = strength * rng.uniform(0.0, 0.03)
    out = np.clip(image, 0.0, 1.0) ** gamma * gain + noise * rng.standard_normal(image.shape)
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def augmented_pair(
    image_a: np.ndarray, image_b: np.ndarray, F: np.ndarray, input_hw: tuple[int, int], aug: Augment, rng: np.random.Generator,
    return_maps: bool = False,
):
    """Two full-resolution images and their F -> (img_a, img_b float32 (h, w) gray in [0, 1], F at the input size).

    With ``Augment()`` this is exactly a resize (:func:`fviz.models.predict.to_model_input` and
    :func:`fviz.models.predict.f_to_input`).  ``return_maps`` adds (A_a, A_b, swapped): the pixel maps
    x_out = A x_in of the output images from the input images (after the swap, when ``swapped``).
    """
    import cv2

    h, w = input_hw
    swapped = rng.random() < aug.swap
    if swapped:
        image_a, image_b, F = image_b, image_a, F.T
    flip = rng.random() < aug.flip
    out, A = [], []
    for image in (image_a, image_b):
        H, W = image.shape[:2]
        s = 1.0 - aug.crop * rng.random() if aug.crop else 1.0
        cw, ch = max(int(round(W * s)), 8), max(int(round(H * s)), 8)
        box = (int(rng.integers(0, W - cw + 1)), int(rng.integers(0, H - ch + 1)), cw, ch)
        gray = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY) if image.ndim == 3 else image
        small, M = crop_resize(gray, box, (w, h))
        small = small.astype(np.float32) / 255.0
        if flip:
            small, M = small[:, ::-1].copy(), flip_matrix(w) @ M
        if aug.photometric:
            small = photometric(small, aug.photometric, rng)
        out.append(small)
        A.append(M)
    F_out = transform_f(np.asarray(F, np.float64), A[0], A[1])
    return (out[0], out[1], F_out, (A[0], A[1], swapped)) if return_maps else (out[0], out[1], F_out)


# ----------------------------------------------------------------------------------------------- KITTI
