"""Correspondence-free estimators: a network trained by ``fviz train`` regresses F from the two images.

- ``deep``: the bundled models (see ``assets/MANIFEST.json``), chosen by the pair's kind: stereo pairs
  (two cameras of one rig at one time) go to ``assets/fviz-deep-stereo.pt``, every other pair to
  ``assets/fviz-deep.pt``, which also sees the pair mirrored and reversed when the cameras are known and
  gives the F of the mean of its three motions, its yaw times the model's calibrated gain
  (:func:`fviz.models.predict.predict_F_batch`, :func:`bundled_yaw_gain`; docs/changelog.md,
  2026-12-01: held-out median SED 30-60 % lower, rotation error 20-55 % lower).
  Why two models: a rectified rig has one F, so a stereo network learns that rig's lateral baseline,
  while a motion network must follow the car; trained on both kinds at once, one network traded its
  temporal accuracy for a stereo F it did not reach (docs/training.md, docs/changelog.md).
  ``$FVIZ_WEIGHTS`` names one file for every pair instead;
- ``deep:motion`` and ``deep:stereo``: each bundled model by its explicit name, on every pair (``deep:motion``
  with the views and the yaw gain ``deep`` gives it). Neither beats the constants that read no image on the
  standard figure, pose AUC, on held-out drives that chose nothing (odometry 02 and 09 for motion, where the
  straight-ahead ``ahead`` is as good or better; 00, 01, 05 for stereo, where the mean stereo F ``mean:SEQ`` is
  exact): ``deep`` is the networks, not the better estimator (assets/MANIFEST.json ``verdict``, docs/training.md);
- ``deep:synthetic``: the model trained on synthetic scenes only (``assets/fviz-deep-synthetic.pt``
  once KITTI-trained weights take ``fviz-deep.pt``; until then the bundled model is that one);
- ``deep:PATH``: any checkpoint or exported weights file.

``deep:synthetic`` and ``deep:PATH`` give a network's single prediction, as trained.

The model loads once; each call resizes the pair to the model's input and maps F back to the
original pixels (x_b^T F x_a = 0).
"""

from __future__ import annotations

import os
from pathlib import Path

from fviz.errors import FvizError

WEIGHTS_ENV = "FVIZ_WEIGHTS"
ASSETS = Path(__file__).resolve().parents[2] / "assets"
BUNDLED = ASSETS / "fviz-deep.pt"
SYNTHETIC = ASSETS / "fviz-deep-synthetic.pt"
STEREO = ASSETS / "fviz-deep-stereo.pt"


def bundled_weights() -> Path:
    path = Path(os.environ.get(WEIGHTS_ENV, BUNDLED))
    if not path.is_file():
        raise FvizError(f"--estimator deep: bundled weights not found at {path} (install from a checkout with "
                        "pip install -e ., or use deep:PATH)")
    return path


NAMED = ("synthetic", "motion", "stereo")


def named_weights(name: str) -> Path | None:
    """The bundled file of a model name (``synthetic``, ``motion``, ``stereo``), or None when ``name`` is not one."""
    if name not in NAMED or Path(name).is_file():
        return None
    if name == "synthetic":
        return SYNTHETIC if SYNTHETIC.is_file() else bundled_weights()
    path = BUNDLED if name == "motion" else STEREO
    if not path.is_file():
        raise FvizError(f"--estimator deep:{name}: bundled weights not found at {path} (install from a checkout with pip install -e .)")
    return path


def bundled_yaw_gain() -> float:
    """The bundled motion model's yaw gain (``assets/MANIFEST.json``, ``inference.yaw_gain``: fit on its
    training drives by :func:`fviz.train.heldout.fit_yaw_gain`); 1 where the manifest does not name one."""
    import json

    try:
        return float(json.loads((ASSETS / "MANIFEST.json").read_text())["inference"]["yaw_gain"]["value"])
    except (OSError, ValueError, KeyError, TypeError):
        return 1.0


def _models(path: str | Path | None, device: str) -> tuple[dict[str, object], dict[str, float]]:
    """({pair kind or "": model} of a ``deep`` spec: the bundled pair for plain ``deep``, else one model;
    {kind: yaw gain} of the kinds whose pairs are also predicted mirrored and reversed: the bundled motion model's)."""
    from fviz.models.weights import load_model

    if path == "motion" and named_weights("motion"):  # the bundled motion model as deep runs it: views and yaw gain
        return {"": load_model(BUNDLED, device)[0]}, {"": bundled_yaw_gain()}
    if path:
        path = named_weights(str(path)) or Path(path)
    elif WEIGHTS_ENV not in os.environ and STEREO.is_file():
        return ({"": load_model(bundled_weights(), device)[0], "stereo": load_model(STEREO, device)[0]},
                {"": bundled_yaw_gain()})
    else:
        path = bundled_weights()
    return {"": load_model(path, device)[0]}, {}  # one-line errors naming the file (missing, a folder, not a model)


def _cameras(pair, mirrored: bool):
    """(K_a, K_b) where the pair is to be predicted mirrored too (its cameras known), else None."""
    return (pair.K_a, pair.K_b) if mirrored and pair.has_K else None


def deep_estimator(path: str | Path | None = None, device: str = "cpu"):
    """An estimator (pair, x_a, x_b) -> F that ignores the matches."""
    from fviz.models.predict import predict_F

    models, gains = _models(path, device)

    def estimate(pair, x_a, x_b):
        kind = pair.id.kind if pair.id.kind in models else ""
        return predict_F(models[kind], pair.image_a, pair.image_b, _cameras(pair, kind in gains), gains.get(kind, 1.0))

    return estimate


def deep_batch_predictor(path: str | Path | None = None, device: str = "cpu"):
    """``predict(pairs) -> [F]``: the model(s) of :func:`deep_estimator` run on many pairs (:class:`fviz.data.pair.Pair`)
    at once on ``device`` (what ``fviz eval`` does on a GPU)."""
    from fviz.models.predict import predict_F_batch

    if path and not Path(path).is_file() and named_weights(str(path)) is None:
        raise FvizError(f"--estimator deep:{path}: no such file")
    models, gains = _models(path, device)

    def predict(pairs):
        kinds = [p.id.kind if p.id.kind in models else "" for p in pairs]
        out: list = [None] * len(pairs)
        for kind, model in models.items():
            idx = [i for i, k in enumerate(kinds) if k == kind]
            batch = [(pairs[i].image_a, pairs[i].image_b) for i in idx]
            cameras = [_cameras(pairs[i], kind in gains) for i in idx]
            for i, F in zip(idx, predict_F_batch(model, batch, cameras, gains.get(kind, 1.0))):
                out[i] = F
        return out

    return predict
