"""Evidence with redundancy, and the user's inputs judged before the ground truth (the evaluation layer's floor, read
by :mod:`fviz.diagnose` and :mod:`fviz.verdicts`).

A fit through as many matches as it has degrees of freedom fits them exactly, so its residuals say nothing: a fit is
evidence only with MIN_SPARE matches beyond F's 7 degrees of freedom, and then only through its out-of-sample
residuals (:func:`heldout_sed`). A misfit between the matches and the ground truth has cheaper explanations than a
wrong ground truth, judged first (:func:`input_mistake`): matches swapped or rescaled, a K for another image."""

from __future__ import annotations

from typing import Any

import numpy as np

from fviz.evaluate import EVAL_THRESHOLD_PX
from fviz.stats import number

STATIC_PX = 0.5  # a match moving less than this is static (identical images: every match)
STATIC_FRACTION = 0.9  # this share of the matches static: degenerate (fviz.verdicts, fviz.triage)
# HELDOUT_FOLDS-fold cross-validation of an 8-point refit (:func:`heldout_sed`)
F_DOF = 7
MIN_SPARE = 8
MIN_EVIDENCE = F_DOF + MIN_SPARE  # 15: fewer matches (a pair) or inliers (a fit) than this are too few to judge
HELDOUT_FOLDS = 5
# the user's inputs, judged before the ground truth (input_mistake). Image evidence, for the user's own matches
# (which only a file can swap or rescale): the median normalized cross-correlation of PATCH_PX patches around
# PATCH_SAMPLES matches, as given against swapped or rescaled, NCC_GAIN higher and at least NCC_MIN. Geometric
# evidence, for any matches: F_gt's median SED over the matches INPUT_RATIO times smaller with a and b swapped (images
# in the wrong order) or at another scale, at most GT_OWN_TIGHT of the evaluation threshold (as tightly as a right
# ground truth fits), with at least INPUT_MIN_SHARE of the matches within the threshold (a few px of pose error moves
# KITTI's lines about as much as a swap of its two frames: 2-3x, never 4x). Static matches (any F fits) say nothing
PATCH_PX, PATCH_SAMPLES, NCC_GAIN, NCC_MIN = 11, 300, 0.2, 0.5
INPUT_RATIO = 4.0
INPUT_MIN_SHARE = 0.25
INPUT_SCALES = (0.25, 0.5, 2.0 / 3.0, 1.5, 2.0, 4.0)
K_CENTRE_OFFSET = 0.25  # of the image's width / height
# the ground truth's own consensus (fviz.diagnose.gt_own_consensus): at least GT_OWN_SHARE of the matches (and
# MIN_EVIDENCE) within the evaluation threshold of its lines, their median SED below GT_OWN_TIGHT of it (a wrong F_gt's
# band holds matches spread over the band, median ~half the threshold: 0.69-1.4 px on the labelled corpus; a right one
# 0.1-0.6 px) and as tight as the best estimate's inliers: the matches hold two consistent sets (repeated texture)
GT_OWN_SHARE = 0.25
GT_OWN_TIGHT = 0.35


def heldout_sed(x_a: np.ndarray, x_b: np.ndarray, folds: int = HELDOUT_FOLDS, seed: int = 0) -> np.ndarray:
    """(N,) out-of-sample symmetric epipolar distance (px) of each correspondence: the matches are split into
    ``folds`` seeded folds and each fold is measured against a normalized 8-point F fitted to the others. All NaN
    for fewer than MIN_EVIDENCE correspondences (the refits would have too few spare matches to mean anything).

    x_a, x_b: (N, 2) pixel coordinates."""
    import cv2

    from fviz.geometry import symmetric_epipolar_distance

    n = len(x_a)
    out = np.full(n, np.nan)
    if n < MIN_EVIDENCE:
        return out
    fold = np.random.default_rng(seed).permutation(n) % folds
    a, b = np.asarray(x_a, np.float64), np.asarray(x_b, np.float64)
    for k in range(folds):
        test = fold == k
        F, _ = cv2.findFundamentalMat(a[~test], b[~test], cv2.FM_8POINT)
        if F is not None and F.shape == (3, 3):
            out[test] = symmetric_epipolar_distance(F, a[test], b[test])
    return out


def patch_agreement(image_a: np.ndarray, image_b: np.ndarray, x_a: np.ndarray, x_b: np.ndarray) -> float:
    """Median normalized cross-correlation of the PATCH_PX x PATCH_PX grey patches around x_a in image a and x_b in
    image b, over up to PATCH_SAMPLES evenly spaced matches whose patches lie inside both images (NaN for fewer
    than MIN_EVIDENCE): how much the matches look like the same points."""
    import cv2

    def grey(im: np.ndarray) -> np.ndarray:
        im = np.asarray(im)
        return (cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) if im.ndim == 3 else im).astype(np.float32)

    ga, gb, r = grey(image_a), grey(image_b), PATCH_PX // 2
    ia, ib = np.rint(x_a).astype(np.int64, copy=False), np.rint(x_b).astype(np.int64, copy=False)
    inside = np.ones(len(ia), bool)
    for g, i in ((ga, ia), (gb, ib)):
        inside &= (i[:, 0] >= r) & (i[:, 1] >= r) & (i[:, 0] < g.shape[1] - r) & (i[:, 1] < g.shape[0] - r)
    idx = np.flatnonzero(inside)
    if len(idx) < MIN_EVIDENCE:
        return float("nan")
    idx = idx[np.linspace(0, len(idx) - 1, min(PATCH_SAMPLES, len(idx))).astype(int)]
    d = np.arange(-r, r + 1)
    pa = ga[ia[idx, 1, None, None] + d[:, None], ia[idx, 0, None, None] + d].reshape(len(idx), -1)
    pb = gb[ib[idx, 1, None, None] + d[:, None], ib[idx, 0, None, None] + d].reshape(len(idx), -1)
    pa, pb = pa - pa.mean(1, keepdims=True), pb - pb.mean(1, keepdims=True)
    den = np.sqrt((pa * pa).sum(1) * (pb * pb).sum(1))
    return float(np.median(np.where(den > 0, (pa * pb).sum(1) / np.maximum(den, 1e-12), 0.0)))


def input_evidence(pair, x_a: np.ndarray, x_b: np.ndarray, threshold_px: float) -> dict[str, Any]:
    """The evidence of :func:`input_mistake`: F_gt's median SED over the matches as given, with a and b swapped and
    at the best of INPUT_SCALES (in the matches' units), and how many lie within ``threshold_px``; how far the matches spread over the
    images; how far K's principal point is from its image's centre; for the user's own matches (``pair.matches``)
    also :func:`patch_agreement` as given, swapped and at the best scale. {} without ground truth or matches."""
    from fviz.geometry import symmetric_epipolar_distance

    if not pair.has_gt or len(x_a) == 0:
        return {}

    def fit(a: np.ndarray, b: np.ndarray, s: float = 1.0) -> tuple[float, int]:
        """In the matches' own units (/ s): shrunk coordinates shrink every flow, and any F fits a flow of zero."""
        d = np.nan_to_num(symmetric_epipolar_distance(pair.F_gt, s * a, s * b), nan=np.inf) / s
        return float(np.median(d)), int(np.sum(d < threshold_px))

    scaled = {s: fit(x_a, x_b, s) for s in INPUT_SCALES}
    best = min(scaled, key=lambda s: scaled[s][0])
    sizes = np.array([pair.size_a, pair.size_b], float)
    extent = np.maximum(np.percentile(x_a, 99, axis=0) / sizes[0], np.percentile(x_b, 99, axis=0) / sizes[1])
    (d_gt, n_gt), (d_sw, n_sw) = fit(x_a, x_b), fit(x_b, x_a)
    out = {"d_gt": d_gt, "n_gt": n_gt, "d_swapped": d_sw, "n_swapped": n_sw, "scale": best, "d_scaled": scaled[best][0],
           "n_scaled": scaled[best][1], "extent": [float(v) for v in extent]}
    if pair.has_K:
        out["pp_offset"] = float(max(np.max(np.abs(K[:2, 2] - (size - 1) / 2) / size)
                                     for K, size in ((pair.K_a, sizes[0]), (pair.K_b, sizes[1]))))
    if pair.matches is not None:  # only a file can swap or rescale matches: look at the images
        ncc = {s: patch_agreement(pair.image_a, pair.image_b, s * x_a, s * x_b) for s in INPUT_SCALES}
        top = max(ncc, key=lambda s: np.nan_to_num(ncc[s], nan=-np.inf))
        out.update(ncc_given=patch_agreement(pair.image_a, pair.image_b, x_a, x_b),
                   ncc_swapped=patch_agreement(pair.image_a, pair.image_b, x_b, x_a), ncc_scale=top, ncc_scaled=ncc[top])
    return out


def input_mistake(diag: dict[str, Any] | None) -> dict[str, str] | None:
    """A mistake in the user's inputs that explains the matches' misfit more cheaply than a wrong ground truth:
    {"detail": "K" | "swapped" | "scale", "text": the evidence in one line} or None (also for runs made before
    this evidence was kept). Judged in this order:

    - ``K``: a principal point more than K_CENTRE_OFFSET of the image from its centre (a K for another image size);
    - ``swapped``: the user's matches look alike (:func:`patch_agreement`) NCC_GAIN more with x_a and x_b swapped,
      or F_gt's median SED is INPUT_RATIO times smaller with a and b swapped (F_gt transposed) and INPUT_MIN_SHARE
      of the matches lie within the threshold so: the matches' columns, or the images, in the wrong order;
    - ``scale``: the same at another scale of the coordinates (matches made on resized images)."""
    ev = (diag or {}).get("inputs") or {}
    if not ev or number((diag or {}).get("static_fraction")) >= STATIC_FRACTION:
        return None
    n = int(number((diag or {}).get("n_matches")))
    pp = number(ev.get("pp_offset"))
    if pp > K_CENTRE_OFFSET:
        return {"detail": "K", "text": f"K's principal point lies {pp:.0%} of the image from its centre: a K for another "
                "image size or crop? F_gt's lines and the pose errors rest on it"}
    given = number(ev.get("ncc_given"))

    def looks(key: str) -> bool:
        v = number(ev.get(key))
        return v >= NCC_MIN and v >= np.nan_to_num(given, nan=-1.0) + NCC_GAIN

    def fits(d: str, k: str) -> bool:  # as tightly as a right ground truth fits its matches (GT_OWN_TIGHT)
        return (INPUT_RATIO * number(ev.get(d)) <= ev["d_gt"] and number(ev.get(d)) <= GT_OWN_TIGHT * EVAL_THRESHOLD_PX
                and ev[k] >= max(MIN_EVIDENCE, INPUT_MIN_SHARE * n))

    def numbers(d: str, k: str, ncc: str) -> str:
        look = f"; patches correlate {number(ev.get(ncc)):.2f} so, {given:.2f} as given" if looks(ncc) else ""
        return (f"F_gt's lines {number(ev.get(d)):.2g} px from them so ({ev[k]}/{n} within {EVAL_THRESHOLD_PX:g} px), "
                f"{ev['d_gt']:.3g} px as given{look}")

    if looks("ncc_swapped") or fits("d_swapped", "n_swapped"):
        return {"detail": "swapped", "text": "the matches fit with images a and b swapped: "
                f"{numbers('d_swapped', 'n_swapped', 'ncc_swapped')}: columns x_b y_b x_a y_a, or the images in the "
                "wrong order?"}
    if looks("ncc_scaled") or fits("d_scaled", "n_scaled"):
        s = ev.get("ncc_scale") if looks("ncc_scaled") else ev["scale"]
        fx, fy = ev["extent"]
        spread = f"; they reach {fx:.0%} of the images' width, {fy:.0%} of their height" if max(fx, fy) < 0.8 else ""
        return {"detail": "scale", "text": f"the matches fit at {s:.3g}x their coordinates: "
                f"{numbers('d_scaled', 'n_scaled', 'ncc_scaled')}{spread}: made on images of another resolution?"}
    return None
