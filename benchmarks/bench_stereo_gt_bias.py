"""How far the rectified stereo ground truth sits from the images: the mean signed vertical offset (px, y in image b
minus the ground-truth epipolar line of x_a at x_b) of MAGSAC++ inliers (SIFT 2000, ratio 0.8, threshold 1 px) and of
every ratio-test match within 2 px of the line, per drive and camera pair of the KITTI samples (docs/metrics.md).

    python benchmarks/bench_stereo_gt_bias.py [--kitti-root ../shared/data/kitti] [--out bias.json]
"""
import argparse
import json

import cv2
import numpy as np

from fviz.data.kitti import open_dataset

ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
ap.add_argument("--kitti-root", default="../shared/data/kitti", help="the samples (odometry/ and raw/ below it)")
ap.add_argument("--out", default=None, help="write the figures as JSON here")
args = ap.parse_args()
S = args.kitti_root
cv2.setRNGSeed(0)
sets = [("odometry 00 gray", dict(sequence="00"), (0, 1), range(1)), ("odometry 01 gray", dict(sequence="01"), (0, 1), range(51)),
        ("odometry 03 gray", dict(sequence="03"), (0, 1), range(5)),
        ("raw 0001 gray", dict(drive="2011_09_26_drive_0001"), (0, 1), range(10)), ("raw 0002 gray", dict(drive="2011_09_26_drive_0002"), (0, 1), range(10)),
        ("odometry 00 colour", dict(sequence="00"), (2, 3), range(2)), ("odometry 04 colour", dict(sequence="04"), (2, 3), range(10)),
        ("odometry 05 colour", dict(sequence="05"), (2, 3), range(10)),
        ("raw 0001 colour", dict(drive="2011_09_26_drive_0001"), (2, 3), range(10)), ("raw 0002 colour", dict(drive="2011_09_26_drive_0002"), (2, 3), range(10))]
sift = cv2.SIFT_create(2000)
out = {}
for name, sel, cams, frames in sets:
    root = S + ("/odometry" if "sequence" in sel else "/raw")
    ds = open_dataset(root, **sel)
    inl, ev, per_pair = [], [], []
    for f in frames:
        p = ds.load(ds.pair_id(f, kind="stereo", cams=cams))
        ga, gb = [cv2.cvtColor(np.asarray(im), cv2.COLOR_RGB2GRAY) if np.asarray(im).ndim == 3 else np.asarray(im) for im in (p.image_a, p.image_b)]
        ka, da = sift.detectAndCompute(ga, None)
        kb, db = sift.detectAndCompute(gb, None)
        m = [a for a, b in cv2.BFMatcher().knnMatch(da, db, k=2) if a.distance < 0.8 * b.distance]
        xa = np.float64([ka[x.queryIdx].pt for x in m])
        xb = np.float64([kb[x.trainIdx].pt for x in m])
        l = (p.F_gt @ np.c_[xa, np.ones(len(xa))].T).T
        off = xb[:, 1] - (-(l[:, 0] * xb[:, 0] + l[:, 2]) / l[:, 1])
        _, mask = cv2.findFundamentalMat(xa, xb, cv2.USAC_MAGSAC, 1.0, 0.999, 10000)
        mask = mask.ravel().astype(bool)
        inl += list(off[mask])
        ev += list(off[np.abs(off) < 2])
        per_pair.append(float(np.mean(off[mask])))
    out[name] = {"pairs": len(per_pair), "magsac_inliers_mean_px": round(float(np.mean(inl)), 3), "inliers": len(inl),
                 "within_2px_mean_px": round(float(np.mean(ev)), 3), "per_pair_range_px": [round(min(per_pair), 3), round(max(per_pair), 3)]}
    print(name, out[name], flush=True)
if args.out:
    json.dump(out, open(args.out, "w"), indent=1)
