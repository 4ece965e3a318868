"""The verdict corpus (issue 39, item 5): pairs whose cause is known by construction, each judged by fviz's one-line
verdict (:func:`fviz.verdicts.verdict_of`) and triage's tags (:func:`fviz.triage.tag_pair`), and the confusion
matrix of true cause x predicted cause, with per-cause precision and recall and three target figures:

- **false fine**: estimates the verdict calls fine (kind "no failure", or named in the "...; X fine" tail of its
  text) that fail against the *true* ground truth (not the corrupted one fviz was given): pose error > 10 deg,
  epipole error > 10 deg, no pose although K and the ground truth are known, or median SED > 2 px (or none) on
  the matches within 2 px of the true F. Target 0;
- **gt-suspect precision and recall** on the pairs whose ground truth was corrupted (rotation >= 1 deg,
  translation direction >= 1 deg, focal >= 5 %). Targets: precision >= 0.95, recall >= 0.8;
- **claims below the minimum**: pairs with too few matches for evidence (fewer than MIN_EVIDENCE matches, or
  fewer than MIN_EVIDENCE correct ones among mostly outliers) whose verdict is anything but "too few to judge"
  or "pair failed". Target 0.

Cases are built from bases: KITTI odometry temporal and stereo pairs (fviz's SIFT matches, computed once per base
and reused by every variant), Strecha's fountain (full corpus only), synthetic street scenes
(:func:`fviz.data.synthetic.synthetic_pair`, exact correspondences with 0.5 px of noise) and random 3-D point
clouds seen by a camera that moves and turns (general, planar, pure-rotation scenes). Every variant reaches fviz
as the user's would: its matches through ``Pair.matches`` (``--matches``), its ground truth as the pair's K, R, t
and F_gt. Families and their true cause (label):

- ``correct``: the base as it is (robust estimators ransac and magsac);
- ``matcher``: x_b shuffled on 85-95 % of the matches; repeated texture (60-70 % of the matches moved by one
  offset along the rows: a consistent wrong set, larger than the right one);
- ``estimator``: 20-40 % of x_b replaced by random points, judged with 8point beside ransac and magsac;
- ``gt``: the ground truth corrupted (R turned by 1-5 deg about a random axis, t's direction by 2-10 deg, both
  focals scaled by 0.9-1.1), F_gt recomputed (K_b^-T [t]x R K_a^-1); matches unchanged;
- ``degenerate``: static matches (identical images), one plane, a pure rotation (|t| = 3 mm);
- ``inputs:swapped``: columns swapped (x_b y_b x_a y_a), or the two images given in the wrong order;
  ``inputs:scale``: matches at half the images' resolution; ``inputs:K``: intrinsics of an image twice the size;
- ``too_few``: 8-14 correct matches, or 18-24 matches of which 9-10 are correct.

A case labelled ``matcher`` or ``estimator`` whose judged estimators all pass against the true ground truth is
relabelled ``correct`` (nothing failed: "no failure" is then right). Swaps are built on temporal and general
bases only: rectified stereo's F_gt^T = -F_gt (the swap changes nothing).

    python benchmarks/verdict_corpus.py [--quick] [--out DIR] [--kitti-root ../shared/data/kitti]
                                        [--strecha-root ../shared/data/strecha] [--write-baseline]

Writes ``verdict_corpus.md`` and ``verdict_corpus.json`` (every case: label, family, parameters, seed, verdict,
tags, the judged estimators' errors against the true ground truth) under ``--out`` (default a temporary folder);
``--write-baseline`` also writes the summary to ``benchmarks/verdict_corpus_baseline.json`` (quick corpus: the one
``tests/test_verdict_corpus.py`` compares with).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import math
import os
import re
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

PROJECT = Path(__file__).resolve().parents[1]
KITTI_ROOT = Path(os.environ.get("FVIZ_KITTI_ROOT", PROJECT.parent / "shared" / "data" / "kitti"))
STRECHA_ROOT = Path(os.environ.get("FVIZ_STRECHA_ROOT", PROJECT.parent / "shared" / "data" / "strecha"))
BASELINE = PROJECT / "benchmarks" / "verdict_corpus_baseline.json"

LABELS = ("correct", "matcher", "estimator", "gt", "degenerate", "inputs:swapped", "inputs:scale", "inputs:K", "too_few")
MIN_EVIDENCE = 15  # fewer matches than this (8 spare beyond F's 7 degrees of freedom): too few to judge
FAIL_DEG, FAIL_PX = 10.0, 2.0  # the fail thresholds (fviz.verdicts: POSE_FAIL_DEG, sed_median > 2 px)
GT_MIN_DEG, GT_MIN_FOCAL = 1.0, 0.05  # corruptions the gt-suspect targets hold on
GT_VISIBLE_PX = 1.0  # ... and those that move the true correspondences this far off the given F_gt (median SED)
# the targets. "false fine" where fviz was given the true ground truth (where the given one is corrupted, an
# estimate can pass it and fail the truth: reported apart); gt-suspect recall on corruptions that move F_gt's lines
# (>= GT_VISIBLE_PX): a focal error on forward motion or rectified stereo, or 2 deg of translation direction on
# forward motion, leaves F_gt (nearly) unchanged, and F-based evidence cannot see what F does not hold
TARGETS = {"false_fine_true_gt": 0, "gt_precision": 0.95, "gt_recall_visible": 0.8, "claims_below_minimum": 0}
ROBUST = ("ransac", "magsac")
NOISE_PX = 0.5


# ---------------------------------------------------------------------------------------------- cases


@dataclass
class Case:
    """One labelled pair: ``pair`` is what fviz is given, ``truth`` the same images with the true ground truth (for
    the false-fine figure); ``estimators`` run on it, ``by`` judged (None: fviz's default, all but baselines)."""

    name: str
    label: str
    family: str
    params: dict[str, Any]
    seed: int
    pair: Any
    truth: Any
    estimators: tuple[str, ...] = ROBUST
    by: str | None = None


def variant(pair, **changes):
    """A shallow copy of a Pair with some fields replaced (images, arrays shared; notes and extra copied)."""
    p = copy.copy(pair)
    p.notes, p.extra = list(pair.notes), {k: v for k, v in pair.extra.items() if not k.startswith("depth")}
    for k, v in changes.items():
        setattr(p, k, v)
    return p


def with_matches(pair, x_a: np.ndarray, x_b: np.ndarray, what: str):
    """The pair with the user's matches (``--matches``): fviz's features are not used."""
    from fviz.data.correspondences import Correspondences

    return variant(pair, matches=Correspondences(np.asarray(x_a, float), np.asarray(x_b, float), path=f"<{what}>"),
                   points_a=None, points_b=None)


def rotation(axis: np.ndarray, deg: float) -> np.ndarray:
    """Rodrigues: the rotation by ``deg`` about ``axis``."""
    import cv2

    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return cv2.Rodrigues(axis * math.radians(deg))[0]


def random_axis(rng, perpendicular_to: np.ndarray | None = None) -> np.ndarray:
    a = rng.normal(size=3)
    if perpendicular_to is not None:
        u = perpendicular_to / np.linalg.norm(perpendicular_to)
        a -= (a @ u) * u
    return a / np.linalg.norm(a)


def with_ground_truth(pair, K_a=None, K_b=None, R=None, t=None):
    """The pair with another ground truth (K, R, t), F_gt recomputed from it: F = K_b^-T [t]x R K_a^-1."""
    from fviz.geometry import fundamental_from_motion, normalize

    K_a = pair.K_a if K_a is None else K_a
    K_b = pair.K_b if K_b is None else K_b
    R = pair.R if R is None else R
    t = pair.t if t is None else t
    return variant(pair, K_a=K_a, K_b=K_b, R=R, t=t, F_gt=normalize(fundamental_from_motion(K_a, K_b, R, t), "fbn"))


def reversed_order(pair):
    """The two images in the other order, with their true ground truth (R^T, -R^T t, F^T)."""
    pid = dataclasses.replace(pair.id, frame_a=pair.id.frame_b, frame_b=pair.id.frame_a, cam_a=pair.id.cam_b,
                              cam_b=pair.id.cam_a, image_a=pair.id.image_b, image_b=pair.id.image_a)
    R, t = pair.R.T, -pair.R.T @ pair.t
    return variant(pair, id=pid, image_a=pair.__dict__["image_b"], image_b=pair.__dict__["image_a"], K_a=pair.K_b,
                   K_b=pair.K_a, R=R, t=t, F_gt=pair.F_gt.T.copy(), points_a=pair.points_b, points_b=pair.points_a)


def scaled_K(K: np.ndarray, s: float, focal_only: bool = False) -> np.ndarray:
    K = np.array(K, float)
    K[:2, :2 if focal_only else 3] *= s
    return K


# ---------------------------------------------------------------------------------------------- bases


@dataclass
class Base:
    """A pair whose ground truth is right, and its matches (x_a, x_b) (N, 2): fviz's SIFT matches (``sift``) or
    exact correspondences with noise; ``kind``: "temporal", "stereo" or "general"."""

    name: str
    pair: Any
    x_a: np.ndarray
    x_b: np.ndarray
    kind: str
    sift: bool
    seed: int
    extra_cases: list[Case] = field(default_factory=list)

    def correct_mask(self, px: float = 1.0) -> np.ndarray:
        from fviz.geometry import symmetric_epipolar_distance

        return symmetric_epipolar_distance(self.pair.F_gt, self.x_a, self.x_b) < px

    def true_points(self, reverse: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The base's correct matches (within 1 px of the true F): the images' true correspondences."""
        ok = self.correct_mask()
        return (self.x_b[ok], self.x_a[ok]) if reverse else (self.x_a[ok], self.x_b[ok])


def sift_base(name: str, pair, kind: str, seed: int, cache) -> Base:
    """A real pair and fviz's own matches (the features cached: its variants detect nothing again)."""
    from fviz.evaluate import evaluate_pair

    res = evaluate_pair(pair, [], cache=cache)
    return Base(name, pair, res.matches.x_a.copy(), res.matches.x_b.copy(), kind, True, seed)


def synthetic_base(seed: int, stereo: bool, n: int = 800, outliers: float = 0.1) -> Base:
    """A synthetic street scene (fviz.data.synthetic) and its exact correspondences: n of them, NOISE_PX of noise,
    ``outliers`` of them replaced by random points."""
    from fviz.data.synthetic import SceneConfig, synthetic_pair

    pair = synthetic_pair(seed, SceneConfig(stereo=stereo))
    pair = variant(pair)  # the depth maps left out (every estimator call deep-copies the pair)
    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(pair.points_a))[:n]
    x_a, x_b = pair.points_a[idx], pair.points_b[idx] + rng.normal(0, NOISE_PX, (len(idx), 2))
    x_b = with_outliers(x_b, pair.size_b, outliers, rng)
    kind = "stereo" if stereo else "temporal"
    return Base(f"synthetic/{seed}/{kind}", pair, x_a, x_b, kind, False, seed)


def cloud_pair(seed: int, scene: str = "general", n: int = 800):
    """A camera moving through a cloud of points (``general``: depths 4-40 m, sideways and forward motion, 3-8 deg
    of rotation), in front of one plane (``planar``) or turning on the spot (``rotation``: |t| = 3 mm): the Pair
    (blank KITTI-sized images, the points as points_a/points_b) and noisy matches (x_a, x_b)."""
    from fviz.data.pair import Pair, PairId
    from fviz.data.synthetic import KITTI_SIZE, intrinsics
    from fviz.geometry import fundamental_from_motion, normalize

    rng = np.random.default_rng(1000 + seed)
    W, H = KITTI_SIZE
    K = intrinsics()
    R = rotation(rng.normal([0, 1, 0], 0.2), rng.uniform(3, 8))
    t = np.array([rng.uniform(-1, 1), rng.uniform(-0.2, 0.2), rng.uniform(0.5, 1.5)])
    pix = rng.uniform([0, 0], [W - 1, H - 1], (6 * n, 2))
    rays = np.c_[pix, np.ones(len(pix))] @ np.linalg.inv(K).T
    if scene == "planar":  # a wall 12 m ahead, turned by 30 deg about the vertical
        normal = np.array([math.sin(math.radians(30)), 0.0, math.cos(math.radians(30))])
        depth = 12.0 / (rays @ normal)
    else:
        depth = rng.uniform(4, 40, len(pix))
    if scene == "rotation":
        t = random_axis(rng) * 0.003
    X_a = rays * depth[:, None]  # rays have z = 1: depth is Z
    X_b = X_a @ R.T + t
    x_b = X_b[:, :2] / X_b[:, 2:] @ K[:2, :2].T + K[:2, 2]
    keep = (X_b[:, 2] > 1) & (x_b[:, 0] > 0) & (x_b[:, 0] < W - 1) & (x_b[:, 1] > 0) & (x_b[:, 1] < H - 1)
    pa, pb = pix[keep][:n], x_b[keep][:n]
    blank = np.zeros((H, W), np.uint8)
    pair = Pair(id=PairId("synthetic", f"cloud-{scene}-{seed}", "temporal", 0, 1), image_a=blank, image_b=blank,
                K_a=K.copy(), K_b=K.copy(), R=R, t=t, F_gt=normalize(fundamental_from_motion(K, K, R, t), "fbn"),
                gt_accuracy_px=0.0, points_a=pa, points_b=pb)
    return pair, pa, pb + rng.normal(0, NOISE_PX, pb.shape)


def cloud_base(seed: int) -> Base:
    pair, x_a, x_b = cloud_pair(seed, "general")
    rng = np.random.default_rng(seed)
    return Base(f"cloud/{seed}/general", pair, x_a, with_outliers(x_b, pair.size_b, 0.1, rng), "general", False, seed)


def with_outliers(x_b: np.ndarray, size: tuple[int, int], share: float, rng) -> np.ndarray:
    """x_b with ``share`` of its rows replaced by random points of the image."""
    x_b = x_b.copy()
    idx = rng.permutation(len(x_b))[: int(round(share * len(x_b)))]
    x_b[idx] = rng.uniform([0, 0], [size[0] - 1, size[1] - 1], (len(idx), 2))
    return x_b


# ---------------------------------------------------------------------------------------------- families


def case(base: Base, label: str, family: str, params: dict, pair, truth=None, reverse: bool = False, **kw) -> Case:
    """A case of ``base``: ``truth`` (default the base pair) is judged on the base's true correspondences (the other
    way round with ``reverse``: the images in the other order), whatever matches the case gives fviz."""
    text = ",".join(f"{k}={v}" for k, v in params.items())
    truth = variant(base.pair if truth is None else truth, gt_points=base.true_points(reverse))
    return Case(f"{base.name}/{family}" + (f"({text})" if text else ""), label, family, params, base.seed, pair, truth, **kw)


def given(base: Base, x_a=None, x_b=None, what: str = "matches"):
    """The base pair with these matches as the user's (default: the base's own)."""
    return with_matches(base.pair, base.x_a if x_a is None else x_a, base.x_b if x_b is None else x_b, what)


def correct_case(base: Base, i: int) -> Iterator[Case]:
    yield case(base, "correct", "correct", {}, base.pair if base.sift else given(base))


def gt_cases(base: Base, i: int) -> Iterator[Case]:
    """One corrupted rotation, one translation direction, one focal length (magnitudes cycled over the bases)."""
    rng = np.random.default_rng(7000 + i)
    source = base.pair if base.sift else given(base)
    deg = (1.0, 2.0, 5.0)[i % 3]
    yield case(base, "gt", "gt-rotation", {"deg": deg}, with_ground_truth(source, R=rotation(random_axis(rng), deg) @ base.pair.R))
    deg = (2.0, 5.0, 10.0)[i % 3]
    t = rotation(random_axis(rng, base.pair.t), deg) @ base.pair.t
    yield case(base, "gt", "gt-translation", {"deg": deg}, with_ground_truth(source, t=t))
    s = (0.9, 1.1, 0.95, 1.05)[i % 4]
    yield case(base, "gt", "gt-focal", {"scale": s},
               with_ground_truth(source, K_a=scaled_K(base.pair.K_a, s, True), K_b=scaled_K(base.pair.K_b, s, True)))


def matcher_cases(base: Base, i: int) -> Iterator[Case]:
    rng = np.random.default_rng(8000 + i)
    if i % 2 == 0:
        share = (0.85, 0.95)[(i // 2) % 2]
        x_b = base.x_b.copy()
        idx = rng.permutation(len(x_b))[: int(share * len(x_b))]
        x_b[idx] = x_b[rng.permutation(idx)]
        yield case(base, "matcher", "matcher-shuffled", {"share": share}, given(base, x_b=x_b, what="shuffled"))
    else:
        share, dx = (0.6, 0.7)[(i // 2) % 2], (30.0, -45.0)[(i // 2) % 2]
        x_b = base.x_b.copy()
        idx = rng.permutation(len(x_b))[: int(share * len(x_b))]
        x_b[idx, 0] += dx
        yield case(base, "matcher", "matcher-repeated", {"share": share, "dx": dx}, given(base, x_b=x_b, what="repeated"))


def estimator_cases(base: Base, i: int) -> Iterator[Case]:
    share = (0.2, 0.3, 0.4)[i % 3]
    x_b = with_outliers(base.x_b, base.pair.size_b, share, np.random.default_rng(9000 + i))
    yield case(base, "estimator", "estimator-8point-outliers", {"outliers": share}, given(base, x_b=x_b, what="outliers"),
               estimators=("8point", *ROBUST))


def inputs_cases(base: Base, i: int) -> Iterator[Case]:
    """Two of the user's mistakes per base (cycled); no swap on rectified stereo (F_gt^T = -F_gt: a swap changes
    nothing there)."""
    kinds = ("swapped", "order", "scale", "K") if base.kind != "stereo" else ("scale", "K")
    for k in (kinds[(2 * i) % len(kinds)], kinds[(2 * i + 1) % len(kinds)]):
        if k == "swapped":
            yield case(base, "inputs:swapped", "inputs-columns-swapped", {}, given(base, base.x_b, base.x_a, "swapped"))
        elif k == "order":
            wrong = reversed_order(base.pair)  # the images in the wrong order, the ground truth of the right one
            wrong = variant(wrong, R=base.pair.R, t=base.pair.t, F_gt=base.pair.F_gt, K_a=base.pair.K_a, K_b=base.pair.K_b)
            pair = wrong if base.sift else with_matches(wrong, base.x_b, base.x_a, "reversed")
            yield case(base, "inputs:swapped", "inputs-image-order", {}, pair, truth=reversed_order(base.pair), reverse=True)
        elif k == "scale":
            half = lambda x: (x + 0.5) * 0.5 - 0.5  # noqa: E731 (OpenCV's origin: the centre of the top-left pixel)
            yield case(base, "inputs:scale", "inputs-half-resolution", {"scale": 0.5},
                       given(base, half(base.x_a), half(base.x_b), "half resolution"))
        else:
            source = base.pair if base.sift else given(base)
            yield case(base, "inputs:K", "inputs-K-of-twice-the-size", {"scale": 2.0},
                       with_ground_truth(source, K_a=scaled_K(base.pair.K_a, 2.0), K_b=scaled_K(base.pair.K_b, 2.0)))


def too_few_cases(base: Base, i: int) -> Iterator[Case]:
    rng = np.random.default_rng(10000 + i)
    good = np.flatnonzero(base.correct_mask())
    if i % 2 == 0:
        n = (8, 10, 12, 14)[(i // 2) % 4]
        idx = rng.choice(good, n, replace=False)
        yield case(base, "too_few", "too-few-correct", {"n": n}, given(base, base.x_a[idx], base.x_b[idx], "few"))
    else:
        n, k = (18, 24)[(i // 2) % 2], (9, 10)[(i // 2) % 2]
        idx = rng.choice(good, n, replace=False)
        x_b = base.x_b[idx].copy()
        x_b[k:] = rng.uniform([0, 0], [base.pair.size_b[0] - 1, base.pair.size_b[1] - 1], (n - k, 2))
        yield case(base, "too_few", "too-few-mostly-outliers", {"n": n, "correct": k},
                   given(base, base.x_a[idx], x_b, "few, mostly outliers"))


def static_case(base: Base) -> Case:
    """Identical images: every match stays where it is (SIFT's 0.05 px of jitter)."""
    rng = np.random.default_rng(base.seed)
    x_b = base.x_a + rng.normal(0, 0.05, base.x_a.shape)
    return case(base, "degenerate", "degenerate-static", {}, given(base, base.x_a, x_b, "static"))


def degenerate_scene_cases(seeds) -> Iterator[Case]:
    for seed in seeds:
        for scene in ("planar", "rotation"):
            pair, x_a, x_b = cloud_pair(seed, scene)
            b = Base(f"cloud/{seed}/{scene}", pair, x_a, x_b, "general", False, seed)
            yield case(b, "degenerate", f"degenerate-{scene}", {}, given(b))


FAMILIES: tuple[Callable[[Base, int], Iterator[Case]], ...] = (
    correct_case, gt_cases, matcher_cases, estimator_cases, inputs_cases, too_few_cases)


# ---------------------------------------------------------------------------------------------- the corpus


def kitti_bases(root: Path, quick: bool, cache) -> list[Base]:
    from fviz.data.kitti import open_dataset

    odo = root / "odometry"
    chosen = [("00", "temporal", 0, None), ("01", "stereo", 0, None)] if quick else [
        ("00", "temporal", 0, None), ("00", "temporal", 20, None), ("00", "temporal", 30, None),
        ("01", "temporal", 10, None), ("03", "temporal", 0, None), ("05", "temporal", 2, None),
        ("04", "temporal", 4, (2, 2)), ("00", "stereo", 0, None), ("01", "stereo", 20, None), ("04", "stereo", 0, (2, 3))]
    out = []
    for i, (seq, kind, frame, cams) in enumerate(chosen):
        pair = open_dataset(odo, sequence=seq).pair(frame, kind, 1, cams)
        out.append(sift_base(f"kitti/{seq}/{kind}/{frame}", pair, kind, i, cache))
    return out


def strecha_bases(root: Path, cache) -> list[Base]:
    from fviz.api import load_pair

    scene = root / "fountain-P11"
    out = []
    for i in (0, 2):  # views 0-1 and 1-2
        pair = load_pair(pairs=scene / "pairs_with_gt.txt", images=scene / "images", index=i)
        out.append(sift_base(f"strecha/fountain/{pair.id.image_a}-{pair.id.image_b}", pair, "general", 100 + i, cache))
    return out


def build_corpus(quick: bool, kitti_root: Path = KITTI_ROOT, strecha_root: Path = STRECHA_ROOT) -> tuple[list[Case], dict]:
    """Every case, deterministically (seeded), and what building them took (s)."""
    from fviz.estimators.features import FeatureCache, FeatureConfig

    t0 = time.perf_counter()
    cache = FeatureCache(FeatureConfig())
    bases = kitti_bases(kitti_root, quick, cache)
    if not quick:
        bases += strecha_bases(strecha_root, cache)
    bases += [cloud_base(s) for s in ((0,) if quick else (0, 1, 2))]
    bases += [synthetic_base(s, False) for s in ((0,) if quick else (0, 1))]
    if not quick:
        bases.append(synthetic_base(0, True))
    t1 = time.perf_counter()
    cases = [c for i, b in enumerate(bases) for fam in FAMILIES for c in fam(b, i)]
    cases += [static_case(b) for b in bases[:1] + bases[-1:]] if quick else [static_case(b) for b in bases[::3]]
    cases += list(degenerate_scene_cases((0,) if quick else (0, 1, 2)))
    return cases, {"bases": len(bases), "bases_s": t1 - t0, "cases_s": time.perf_counter() - t1, "cache": cache}


# ---------------------------------------------------------------------------------------------- judging


def predicted_cause(v) -> str:
    """The cause a verdict names (``detail`` refines "inputs suspect"); unknown kinds pass through as "other:KIND"."""
    from fviz import verdicts as V

    kinds = {V.PAIR_FAILED: "pair_failed", getattr(V, "TOO_FEW", "too few to judge"): "too_few", V.NO_EVAL: "no_eval",
             V.DEGENERATE: "degenerate", V.GT_SUSPECT: "gt", V.MATCHER: "matcher", V.ESTIMATOR: "estimator",
             V.FAILS: "fails", V.NO_GT: "no_gt", V.NO_FAILURE: "correct"}
    if v.kind == V.NO_EVAL and "ground truth suspect" in v.text:  # no metric, and the ground truth to blame
        return "gt"
    if v.kind == getattr(V, "INPUTS", "inputs suspect"):
        detail = getattr(v, "detail", "") or ""
        return f"inputs:{detail}" if detail in ("swapped", "scale", "K") else "inputs"
    return kinds.get(v.kind, f"other:{v.kind}")


def called_fine(v, judged: list[str]) -> list[str]:
    """The estimators a verdict calls fine: all judged ones for "no failure", else those of its "...; X, Y fine"."""
    from fviz import verdicts as V

    if v.kind == V.NO_FAILURE:
        return list(judged)
    m = re.search(r";\s*([^;:]+?) fine\s*$", v.text)
    return [n for n in m.group(1).split(", ") if n in judged] if m else []


def true_errors(case: Case, result, name: str) -> dict[str, Any]:
    """An estimate against the true ground truth: its metrics on the images' true correspondences (the truth's
    ``gt_points``: the base's matches within 1 px of the true F), and why it fails ("" when it does not)."""
    from fviz.evaluate import EVAL_THRESHOLD_PX, evaluation_points, score

    r = result.get(name)
    if r is None or r.F is None:
        return {"fails": "gave no F"}
    truth, m = case.truth, result.matches
    mask, evaluation, points = evaluation_points(truth, m, EVAL_THRESHOLD_PX)
    metrics, *_ = score(name, r.F, truth, m, evaluation, "fbn", r.inliers, 1.0, mask if points == "near-gt" else None)
    pose, epi, sed = (float(metrics.get(k, math.nan)) for k in ("pose_err_deg", "epipole_err_deg", "sed_median"))
    why = []
    if pose > FAIL_DEG:
        why.append(f"pose {pose:.3g} deg")
    if truth.has_pose and not math.isfinite(pose):
        why.append("no pose")
    if epi > FAIL_DEG:
        why.append(f"epipole {epi:.3g} deg")
    if not sed <= FAIL_PX:
        why.append(f"median SED {sed:.3g} px" if math.isfinite(sed) else "no median SED")
    return {"pose_err_deg": pose, "epipole_err_deg": epi, "sed_median": sed, "n_eval": int(len(evaluation[0])),
            "fails": ", ".join(why)}


def judge(case: Case, cache=None) -> dict[str, Any]:
    """Evaluate one case as fviz does and read its verdict and tags."""
    from fviz import verdicts as V
    from fviz.diagnose import diagnose
    from fviz.estimators.registry import get_estimator, is_baseline
    from fviz.evaluate import evaluate_pair
    from fviz.triage import tag_pair

    t0 = time.perf_counter()
    result = evaluate_pair(case.pair, [(n, get_estimator(n)) for n in case.estimators], cache=cache)
    v = V.verdict_of(case.pair, result, by=case.by)
    rec = {"error": None, "result": result.to_dict(), "diagnostics": diagnose(case.pair, result, two_view=False)}
    ranked = case.by or ("magsac" if "magsac" in case.estimators else case.estimators[-1])
    tags = [t for t, _ in tag_pair(rec, ranked)]
    judged = [case.by] if case.by else [n for n in case.estimators if not is_baseline(n)]
    truth = {n: true_errors(case, result, n) for n in judged}
    fine = called_fine(v, judged)
    label = case.label
    if label in ("matcher", "estimator") and not any(t["fails"] for t in truth.values()):
        label = "correct"  # nothing failed after all: "no failure" is the right verdict
    elif label == "correct" and any(t["fails"] for t in truth.values()):
        label = "estimator"  # right matches and ground truth, yet an estimate fails the true ground truth
    return {
        "name": case.name, "label": label, "built_as": case.label, "family": case.family, "params": case.params,
        "seed": case.seed, "estimators": list(case.estimators), "by": case.by, "n_matches": result.n_matches,
        "n_correct": int(np.sum(_true_sed(case, result) < 1.0)), "n_eval": result.n_eval, "given_gt_px": given_gt_px(case),
        "kind": v.kind, "detail": getattr(v, "detail", "") or "", "text": v.text, "predicted": predicted_cause(v),
        "tags": tags, "called_fine": fine, "truth": truth,
        "false_fine": [n for n in fine if truth.get(n, {}).get("fails")], "seconds": time.perf_counter() - t0,
    }


def given_gt_px(case: Case) -> float:
    """How much farther the ground truth fviz is given sits from the images' true correspondences than the true one
    (median SED, px, the given F_gt's less the true F's, which is the matches' own noise: 0.1-0.5 px): how visible a
    corrupted ground truth is."""
    from fviz.geometry import symmetric_epipolar_distance

    x_a, x_b = case.truth.gt_points
    given, true = (float(np.median(symmetric_epipolar_distance(F, x_a, x_b))) for F in (case.pair.F_gt, case.truth.F_gt))
    return given - true


def _true_sed(case: Case, result) -> np.ndarray:
    from fviz.geometry import symmetric_epipolar_distance

    return symmetric_epipolar_distance(case.truth.F_gt, result.matches.x_a, result.matches.x_b)


# ---------------------------------------------------------------------------------------------- figures


def below_minimum(row: dict) -> bool:
    """Too few matches for evidence: fewer than MIN_EVIDENCE, or fewer than MIN_EVIDENCE correct ones (a too_few case)."""
    return row["n_matches"] < MIN_EVIDENCE or row["label"] == "too_few"


def gt_target_case(row: dict) -> bool:
    """A ground truth corrupted by at least GT_MIN_DEG (rotation, translation direction) or GT_MIN_FOCAL (focal)."""
    p = row["params"]
    return row["label"] == "gt" and (p.get("deg", 0) >= GT_MIN_DEG or abs(p.get("scale", 1) - 1) >= GT_MIN_FOCAL - 1e-9)


def _magnitude(key: str) -> tuple[str, float]:
    family, value = key.rsplit(" ", 1)
    return family, abs(float(value) - 1) if family == "gt-focal" else float(value)


def _ratio(a: int, b: int) -> float | None:
    return a / b if b else None


def summarize(rows: list[dict]) -> dict[str, Any]:
    """Confusion matrix (true cause x predicted cause), per-cause precision and recall, the target figures."""
    predicted = list(LABELS) + sorted({r["predicted"] for r in rows} - set(LABELS))
    confusion = {lab: {p: sum(1 for r in rows if r["label"] == lab and r["predicted"] == p) for p in predicted}
                 for lab in LABELS}
    per_cause = {}
    for lab in LABELS:
        hit = confusion[lab][lab]
        per_cause[lab] = {"cases": sum(confusion[lab].values()), "predicted": sum(1 for r in rows if r["predicted"] == lab),
                          "precision": _ratio(hit, sum(1 for r in rows if r["predicted"] == lab)),
                          "recall": _ratio(hit, sum(confusion[lab].values()))}
    target = [r for r in rows if gt_target_case(r)]
    visible = [r for r in target if r["given_gt_px"] >= GT_VISIBLE_PX]
    said_gt = [r for r in rows if r["predicted"] == "gt"]
    below = [r for r in rows if below_minimum(r)]
    claims = [r for r in below if r["predicted"] not in ("too_few", "pair_failed")]
    false_fine = [r for r in rows if r["false_fine"]]
    recall_by = {}
    for r in (r for r in rows if r["label"] == "gt"):
        key = f"{r['family']} {next(iter(r['params'].values()))}"
        n, k, px = recall_by.get(key, (0, 0, []))
        recall_by[key] = (n + 1, k + (r["predicted"] == "gt"), px + [r["given_gt_px"]])
    tags = sorted({t for r in rows for t in r["tags"]})
    return {
        "cases": len(rows), "labels": list(LABELS), "predicted": predicted, "confusion": confusion, "per_cause": per_cause,
        "targets": {
            "false_fine": len(false_fine), "false_fine_estimates": sum(len(r["false_fine"]) for r in rows),
            "false_fine_true_gt": sum(1 for r in false_fine if r["label"] != "gt"),
            # images in the wrong order: the given F_gt does not describe the pair as given (its transpose does), so
            # "ground truth suspect" is true of it, though the cheaper cause goes unnamed (inputs:swapped recall)
            "gt_precision": _ratio(sum(1 for r in said_gt if r["label"] == "gt" or r["family"] == "inputs-image-order"),
                                   len(said_gt)),
            "gt_recall": _ratio(sum(1 for r in target if r["predicted"] == "gt"), len(target)),
            "gt_target_cases": len(target),
            "gt_recall_visible": _ratio(sum(1 for r in visible if r["predicted"] == "gt"), len(visible)),
            "gt_visible_cases": len(visible),
            "claims_below_minimum": len(claims), "below_minimum_cases": len(below),
        },
        "gt_recall_by_corruption": {k: {"cases": n, "recall": k_ / n, "given_gt_px": [min(px), max(px)]}
                                    for k, (n, k_, px) in sorted(recall_by.items(), key=lambda kv: _magnitude(kv[0]))},
        "tags": {lab: {t: sum(1 for r in rows if r["label"] == lab and t in r["tags"]) for t in tags} for lab in LABELS},
        "false_fine_cases": [f"{r['name']}: " + ", ".join(f"{n} ({r['truth'][n]['fails']})" for n in r["false_fine"])
                             for r in false_fine],
        "claims_below_minimum_cases": [f"{r['name']}: {r['kind']}" for r in claims],
    }


def _fmt(v) -> str:
    return "-" if v is None else f"{v:.2f}"


def markdown(summary: dict, rows: list[dict], meta: dict) -> str:
    t = summary["targets"]
    P = summary["predicted"]
    out = [f"# Verdict corpus ({meta['corpus']})", "",
           f"{summary['cases']} cases of known cause, judged by `fviz.verdicts.verdict_of` on fviz {meta['fviz']} "
           f"(commit {meta['commit']}); {meta['seconds']:.0f} s ({meta['cpu_seconds']:.0f} s of CPU), {meta['cpus']}. Built by "
           "`benchmarks/verdict_corpus.py` (its docstring says how each family is made).", "",
           "## Targets", "", "| figure | now | target |", "|---|---|---|",
           f"| false fine, fviz given the true ground truth (cases) | {t['false_fine_true_gt']} | 0 |",
           f"| (false fine, all cases; estimates: also where the given ground truth is corrupted) | {t['false_fine']}; "
           f"{t['false_fine_estimates']} | |",
           f"| gt-suspect precision | {_fmt(t['gt_precision'])} | >= {TARGETS['gt_precision']} |",
           f"| gt-suspect recall ({t['gt_target_cases']} corruptions >= {GT_MIN_DEG:g} deg / {GT_MIN_FOCAL:.0%} focal) "
           f"| {_fmt(t['gt_recall'])} | |",
           f"| gt-suspect recall on the {t['gt_visible_cases']} of them that move the true correspondences >= "
           f"{GT_VISIBLE_PX:g} px farther off the given F_gt | {_fmt(t['gt_recall_visible'])} | >= "
           f"{TARGETS['gt_recall_visible']} |",
           f"| claims below the minimum (of {t['below_minimum_cases']} cases under {MIN_EVIDENCE} (correct) matches) "
           f"| {t['claims_below_minimum']} | 0 |", "",
           "## Confusion matrix", "", "Rows: true cause; columns: the cause the verdict names.", "",
           "| true \\ predicted | " + " | ".join(P) + " | recall |", "|---|" + "---|" * (len(P) + 1)]
    for lab in summary["labels"]:
        c = summary["confusion"][lab]
        out.append(f"| **{lab}** | " + " | ".join(str(c[p]) if c[p] else "." for p in P)
                   + f" | {_fmt(summary['per_cause'][lab]['recall'])} |")
    out.append("| precision | " + " | ".join(_fmt(summary["per_cause"][p]["precision"]) if p in summary["per_cause"]
                                             else "" for p in P) + " | |")
    out += ["", "## Ground-truth corruptions: recall per magnitude", "",
            "given F_gt off the truth: how much farther (median SED, px) the images' true correspondences lie from the "
            "F_gt fviz is given than from the true one (smallest, largest over the cases).", "",
            "| corruption | cases | gt-suspect recall | given F_gt off the truth (px) |", "|---|---|---|---|"]
    out += [f"| {k} | {v['cases']} | {v['recall']:.2f} | {v['given_gt_px'][0]:.2f}-{v['given_gt_px'][1]:.2f} |"
            for k, v in summary["gt_recall_by_corruption"].items()]
    tags = sorted({t for v in summary["tags"].values() for t in v})
    out += ["", "## Triage tags per true cause", "", "| true cause | " + " | ".join(tags) + " |", "|---|" + "---|" * len(tags)]
    out += [f"| {lab} | " + " | ".join(str(summary["tags"][lab].get(t, 0) or ".") for t in tags) + " |" for lab in summary["labels"]]
    for title, items in (("False fine", summary["false_fine_cases"]), ("Claims below the minimum", summary["claims_below_minimum_cases"])):
        out += ["", f"## {title}", ""] + ([f"- {x}" for x in items] or ["none"])
    out += ["", "## Every case", "", "given F_gt off: as above; the judged estimators against the true ground truth "
            "(on the images' true correspondences).", "",
            "| case | label | verdict | matches | given F_gt off (px) | judged against the true ground truth |",
            "|---|---|---|---|---|---|"]
    for r in rows:
        truth = "; ".join(f"{n}: {v.get('fails') or 'passes'}" for n, v in r["truth"].items())
        relabel = "" if r["label"] == r["built_as"] else f" (built as {r['built_as']})"
        kind = r["kind"] + (f" ({r['detail']})" if r["detail"] else "")
        out.append(f"| {r['name']} | {r['label']}{relabel} | {kind} | {r['n_matches']} | {r['given_gt_px']:.2f} | {truth} |")
    return "\n".join(out) + "\n"


def run_corpus(quick: bool, kitti_root: Path = KITTI_ROOT, strecha_root: Path = STRECHA_ROOT,
               progress: bool = False) -> tuple[dict, list[dict], dict]:
    """Build and judge the corpus -> (summary, rows, meta)."""
    import platform

    import fviz

    t0, c0 = time.perf_counter(), time.process_time()
    cases, built = build_corpus(quick, kitti_root, strecha_root)
    rows = []
    for i, c in enumerate(cases):
        rows.append(judge(c, built["cache"]))
        if progress:
            print(f"[{i + 1}/{len(cases)}] {c.name}: {rows[-1]['label']} -> {rows[-1]['predicted']}", file=sys.stderr)
    meta = {"corpus": "quick" if quick else "full", "fviz": getattr(fviz, "__version__", "?"), "commit": _commit(),
            "seconds": time.perf_counter() - t0, "cpu_seconds": time.process_time() - c0,
            "cpus": f"one process, {os.cpu_count()} {platform.machine()} cores",
            "build_s": built["bases_s"] + built["cases_s"]}
    return summarize(rows), rows, meta


def _commit() -> str:
    import subprocess

    try:
        return subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=PROJECT, capture_output=True, text=True,
                              check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "?"


def baseline_figures(summary: dict) -> dict[str, Any]:
    """What the test compares with the committed baseline: per-cause precision and recall, the target figures."""
    return {"cases": summary["cases"],
            "per_cause": {k: {"precision": v["precision"], "recall": v["recall"]} for k, v in summary["per_cause"].items()},
            "targets": {k: summary["targets"][k] for k in ("false_fine", "false_fine_true_gt", "gt_precision", "gt_recall",
                                                           "gt_recall_visible", "claims_below_minimum")}}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the small corpus (the test's)")
    ap.add_argument("--out", default=None, help="folder for verdict_corpus.md and .json (default: a temporary one)")
    ap.add_argument("--kitti-root", default=str(KITTI_ROOT))
    ap.add_argument("--strecha-root", default=str(STRECHA_ROOT))
    ap.add_argument("--write-baseline", action="store_true", help=f"write the summary to {BASELINE.relative_to(PROJECT)}")
    args = ap.parse_args(argv)
    summary, rows, meta = run_corpus(args.quick, Path(args.kitti_root), Path(args.strecha_root), progress=True)
    out = Path(args.out or tempfile.mkdtemp(prefix="verdict_corpus_"))
    out.mkdir(parents=True, exist_ok=True)
    (out / "verdict_corpus.md").write_text(markdown(summary, rows, meta))
    (out / "verdict_corpus.json").write_text(json.dumps({"meta": meta, "summary": summary, "cases": rows}, indent=1,
                                                        default=_json))
    if args.write_baseline:
        BASELINE.write_text(json.dumps({"corpus": meta["corpus"], "commit": meta["commit"], **baseline_figures(summary)},
                                       indent=1) + "\n")
    t = summary["targets"]
    print(f"{summary['cases']} cases in {meta['seconds']:.1f} s ({meta['cpu_seconds']:.1f} s CPU): false fine "
          f"{t['false_fine']}, gt precision {_fmt(t['gt_precision'])} recall {_fmt(t['gt_recall'])}, claims below the "
          f"minimum {t['claims_below_minimum']}; {out / 'verdict_corpus.md'}")


def _json(v):
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    raise TypeError(type(v))


if __name__ == "__main__":
    main()
