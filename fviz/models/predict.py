"""Run a model on full-resolution images and get F in *their* pixel coordinates.

Resizing an image of size (W, H) to (w, h) with OpenCV maps pixel centres as

    x_small = (x_full + 0.5) * w / W - 0.5,   y_small = (y_full + 0.5) * h / H - 0.5,

i.e. x_small = S x_full with S = [[sx, 0, sx/2 - 1/2], [0, sy, sy/2 - 1/2], [0, 0, 1]].
If the model gives F_small (x_b,small^T F_small x_a,small = 0) then

    F_full = S_b^T F_small S_a          (:func:`f_to_full`)

and the training targets go the other way, F_small = S_b^-T F_full S_a^-1 (:func:`f_to_input`).
"""

from __future__ import annotations

import cv2
import numpy as np

from fviz.errors import FvizError
from fviz.geometry.fundamental import normalize


def scale_matrix(src_wh: tuple[int, int], dst_wh: tuple[int, int]) -> np.ndarray:
    """S with x_dst = S x_src (homogeneous pixels) for a resize from src (W, H) to dst (w, h).  (3, 3)."""
    sx = dst_wh[0] / src_wh[0]
    sy = dst_wh[1] / src_wh[1]
    return np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])


def f_to_full(F_small: np.ndarray, size_a: tuple[int, int], size_b: tuple[int, int], input_hw: tuple[int, int]) -> np.ndarray:
    """F in model-input pixels -> F in the original pixels (not normalized).  size_*: (W, H) of the originals."""
    dst = (input_hw[1], input_hw[0])
    return scale_matrix(size_b, dst).T @ np.asarray(F_small, dtype=np.float64) @ scale_matrix(size_a, dst)


def f_to_input(F_full: np.ndarray, size_a: tuple[int, int], size_b: tuple[int, int], input_hw: tuple[int, int]) -> np.ndarray:
    """F in the original pixels -> F in model-input pixels (not normalized).  Inverse of :func:`f_to_full`."""
    dst = (input_hw[1], input_hw[0])
    S_a_inv = np.linalg.inv(scale_matrix(size_a, dst))
    S_b_inv = np.linalg.inv(scale_matrix(size_b, dst))
    return S_b_inv.T @ np.asarray(F_full, dtype=np.float64) @ S_a_inv


def to_model_input(image: np.ndarray, input_hw: tuple[int, int]) -> np.ndarray:
    """uint8 (H, W) gray or (H, W, 3) RGB -> float32 (h, w) gray in [0, 1] at the model's input size."""
    img = np.asarray(image)
    if img.ndim == 3 and img.shape[2] == 3:
        img = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[..., 0]
    if img.ndim != 2:
        raise FvizError(f"expected an (H, W) or (H, W, 3) image, got shape {img.shape}")
    h, w = input_hw
    interp = cv2.INTER_AREA if (img.shape[0] >= h and img.shape[1] >= w) else cv2.INTER_LINEAR
    small = cv2.resize(img, (w, h), interpolation=interp)
    scale = 1.0 / 255.0 if small.dtype == np.uint8 else 1.0
    return small.astype(np.float32) * np.float32(scale)


def flip_matrix(width: int) -> np.ndarray:
    """Horizontal mirror of an image ``width`` pixels wide (pixel centres at integers): x' = W - 1 - x.  (3, 3)."""
    return np.array([[-1.0, 0.0, width - 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])


def predict_F(model, image_a: np.ndarray, image_b: np.ndarray, cameras=None, yaw_gain: float = 1.0) -> np.ndarray:
    """F (3, 3) float64, FBN-normalized, in pixels of the given (full-resolution) images.

    image_a, image_b: uint8 (H, W) or (H, W, 3) RGB, any size (each is resized to the model input).
    cameras: (K_a, K_b) to average the prediction with the mirrored and the reversed pair's, whose mean yaw
    is multiplied by ``yaw_gain`` (:func:`predict_F_batch`).
    Raises FvizError (NormalizationError) when an ETR model predicts F33 ~ 0.
    """
    return predict_F_batch(model, [(image_a, image_b)], [cameras], yaw_gain)[0]


def predict_F_batch(model, pairs: list[tuple[np.ndarray, np.ndarray]], cameras: list | None = None,
                    yaw_gain: float = 1.0) -> list[np.ndarray]:
    """:func:`predict_F` of several (image_a, image_b) pairs in one forward pass on the model's device
    (the resizing runs on the CPU). Each F: (3, 3) float64, FBN-normalized, in its images' pixels.
    The model is in eval mode (normalization layers use running statistics), so a pair's F does not
    depend on the batch it is in.

    cameras: per pair (K_a, K_b) or None. A pair with cameras is also predicted mirrored (both inputs flipped
    left-right, which turns a left turn into a right one) and swapped ((b, a): the inverse motion), and its F
    is that of the mean of the three motions (:func:`fviz.geometry.mean_motion_f`, each F mapped back to a -> b
    first): what a network gets wrong the same way whichever way it sees the pair (a yaw bias, a learnt
    asymmetry, a drift towards the motions it saw most) cancels; the reversed pair reuses the pair's image
    features (:meth:`fviz.models.model.FNet.indexed`). ``yaw_gain`` then multiplies that mean
    motion's yaw (the model's calibration, :func:`fviz.train.heldout.fit_yaw_gain`).
    """
    import torch

    if not pairs:
        return []
    from fviz.geometry import mean_motion_f

    hw = model.config.input_hw
    try:
        device = next(model.parameters()).device
    except StopIteration:  # pragma: no cover - a model without parameters
        device = torch.device("cpu")
    cameras = list(cameras or [None] * len(pairs))
    seen = [i for i, c in enumerate(cameras) if c is not None]  # also seen mirrored and swapped
    n, k = len(pairs), len(seen)
    a = np.stack([to_model_input(ia, hw) for ia, _ in pairs])
    b = np.stack([to_model_input(ib, hw) for _, ib in pairs])
    images = np.concatenate([a, b, a[seen, :, ::-1], b[seen, :, ::-1]])  # resizing commutes with the mirror
    rows, views, mirrors = np.arange(n), np.asarray(seen, int), 2 * n + np.arange(k)
    index = np.concatenate([np.stack([rows, n + rows], 1),  # (a, b)
                            np.stack([mirrors, mirrors + k], 1),  # (a, b) mirrored
                            np.stack([n + views, views], 1)])  # (b, a): the streams of (a, b) again
    was_training = model.training
    model.eval()
    try:
        with torch.inference_mode():
            F_small = model.indexed(torch.from_numpy(np.ascontiguousarray(images))[:, None].to(device),
                                    torch.from_numpy(index).to(device), strict_norm=True).double().cpu().numpy()
    finally:
        model.train(was_training)
    H = flip_matrix(hw[1])
    mirrored = {i: H.T @ F @ H for i, F in zip(seen, F_small[n:n + k])}  # x_b^T (H^T F' H) x_a = (H x_b)^T F' (H x_a)
    swapped = {i: F.T for i, F in zip(seen, F_small[n + k:])}  # x_a^T F' x_b = 0: F'^T maps a to b
    out = []
    for i, (ia, ib) in enumerate(pairs):
        size_a, size_b = (int(np.shape(ia)[1]), int(np.shape(ia)[0])), (int(np.shape(ib)[1]), int(np.shape(ib)[0]))
        F = f_to_full(F_small[i], size_a, size_b, hw)
        if i in mirrored:
            K_a, K_b = (np.asarray(K, float) for K in cameras[i])
            F = mean_motion_f([F, *(f_to_full(G[i], size_a, size_b, hw) for G in (mirrored, swapped))], K_a, K_b, yaw_gain)
        out.append(normalize(F, "fbn"))
    return out
