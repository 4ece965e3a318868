"""Accuracy and time of every match-based estimator on the 49 temporal pairs of the sample sequence 00.

    python benchmarks/bench_estimators.py                 # the table of docs/estimators.md
    python benchmarks/bench_estimators.py --frames 0:10 --json out.json

SIFT features and matches are computed once per pair (fviz's defaults: 2000 keypoints, ratio 0.8, mutual);
every estimator then runs on the same matches, one after the other in this process (one thread, the
libraries imported and warmed up on the first pair, which is left out of the times). Per estimator: pose
AUC@5/10/20 deg (LightGlue's), median over pairs of the per-pair median SED and of NSGD, failures, and the
time of its call alone (median and p90 over pairs); ratios against OpenCV's MAGSAC++ (``magsac``, fviz's
default robust estimator) measured in the same run. Also the match precision before any estimator.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time

import numpy as np

from common import KITTI_ROOT

ESTIMATORS = ["8point", "lmeds", "ransac", "magsac", "usac-default", "usac-accurate", "usac-prosac", "usac-fm8pts",
              "usac-parallel", "poselib", "poselib-E", "colmap"]
BASELINE = "magsac"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kitti-root", default=str(KITTI_ROOT))
    ap.add_argument("--frames", default="0:50", help="START:END of camera-0 frames (pairs t -> t+1 inside)")
    ap.add_argument("--threshold", type=float, default=1.0)
    ap.add_argument("--json", default="")
    args = ap.parse_args()

    import cv2

    from fviz.data.kitti import open_dataset
    from fviz.estimators.classical import RobustConfig
    from fviz.estimators.features import FeatureCache, FeatureConfig
    from fviz.estimators.registry import get_estimator
    from fviz.evaluate import evaluate_pair
    from fviz.geometry import AUC_THRESHOLDS_DEG, pose_auc

    cv2.setNumThreads(1)
    start, end = (int(v) for v in args.frames.split(":"))
    ds = open_dataset(args.kitti_root, sequence="00")
    cfg = RobustConfig(threshold=args.threshold)
    ests = [(n, get_estimator(n, cfg)) for n in ESTIMATORS]
    cache = FeatureCache(FeatureConfig())
    per: dict[str, dict[str, list]] = {n: {"pose": [], "sed": [], "nsgd": [], "s": [], "failed": 0} for n in ESTIMATORS}
    precision: dict[str, list] = {}
    t0 = time.perf_counter()
    for k, frame in enumerate(range(start, end - 1)):
        result = evaluate_pair(ds.pair(frame, "temporal"), ests, inlier_threshold_px=args.threshold, cache=cache)
        if k == 0:
            continue  # warm-up: library imports and first-call costs
        for key, v in result.match_precision.items():
            precision.setdefault(key, []).append(v)
        for r in result.estimators[1:]:
            d = per[r.name]
            d["s"].append(r.seconds)
            d["failed"] += r.error is not None
            d["pose"].append(math.inf if r.error else r.metrics.get("pose_err_deg", math.inf))
            d["sed"].append(math.nan if r.error else r.metrics["sed_median"])
            d["nsgd"].append(math.nan if r.error else r.metrics["nsgd"])
    rows = {}
    for n, d in per.items():
        s = np.array(d["s"]) * 1e3
        rows[n] = {
            "pairs": len(s), "failed": d["failed"],
            **{f"auc@{t:g}": float(a) for t, a in zip(AUC_THRESHOLDS_DEG, pose_auc(np.nan_to_num(np.array(d["pose"], float), nan=np.inf)))},
            "sed_median": float(np.nanmedian(d["sed"])), "nsgd_median": float(np.nanmedian(d["nsgd"])),
            "ms_median": float(np.median(s)), "ms_p90": float(np.percentile(s, 90)),
        }
    base = rows[BASELINE]
    print(f"# {rows[BASELINE]['pairs']} temporal pairs of KITTI 00 (frames {start}:{end}), SIFT, threshold {args.threshold} px, "
          f"{time.perf_counter() - t0:.0f} s\n")
    print("| estimator | AUC@5° | AUC@10° | AUC@20° | median SED px | median NSGD | failed | median ms | p90 ms | time vs magsac |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n, r in rows.items():
        print(f"| {n} | {r['auc@5']:.3f} | {r['auc@10']:.3f} | {r['auc@20']:.3f} | {r['sed_median']:.3f} | {r['nsgd_median']:.4f} "
              f"| {r['failed']} | {r['ms_median']:.2f} | {r['ms_p90']:.2f} | {r['ms_median'] / base['ms_median']:.2f}x |")
    print("\nmatch precision (mean over pairs): " + ", ".join(f"{k} {np.mean(v):.3f}" for k, v in precision.items()))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"rows": rows, "match_precision": {k: float(np.mean(v)) for k, v in precision.items()}}, f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
