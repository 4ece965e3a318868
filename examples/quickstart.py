"""fviz from Python: two image arrays and your own F -> metrics beside fviz's estimators, and a recording.

    FVIZ_KITTI_ROOT=/path/to/kitti python examples/quickstart.py [OUT.rrd]

Uses only the public API (``import fviz``) on KITTI odometry 00's first stereo pair (the shared samples:
``$FVIZ_KITTI_ROOT``, default ``../shared/data/kitti`` beside this repository). Open the recording with
``rerun OUT.rrd`` (or ``fviz open OUT.rrd``): an overview, one tab per F (yours: "mine"), the probe.
"""

import os
import sys
from pathlib import Path

import cv2
import numpy as np

import fviz

root = Path(os.environ.get("FVIZ_KITTI_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data" / "kitti"))
seq = root / "odometry" / "dataset" / "sequences" / "00"
out = Path(sys.argv[1] if len(sys.argv) > 1 else "quickstart.rrd")

# 1. Two images as arrays (H, W) uint8, and what you know of the cameras: KITTI's rectified stereo rig,
#    camera b 0.54 m to the right of a (X_b = R X_a + t).
image_a = cv2.imread(str(seq / "image_0" / "000000.png"), cv2.IMREAD_GRAYSCALE)
image_b = cv2.imread(str(seq / "image_1" / "000000.png"), cv2.IMREAD_GRAYSCALE)
P = {line[:2]: np.array(line.split()[1:], float).reshape(3, 4) for line in (seq / "calib.txt").read_text().splitlines()}
K = P["P0"][:, :3]
t = np.array([P["P1"][0, 3] / K[0, 0], 0.0, 0.0])
pair = fviz.pair_from_images(image_a, image_b, K=K, R=np.eye(3), t=t)

# 2. Your own F (x_b^T F x_a = 0, pixels): here OpenCV's 8-point on ORB matches stands in for your method.
orb = cv2.ORB_create(2000)
(ka, da), (kb, db) = orb.detectAndCompute(image_a, None), orb.detectAndCompute(image_b, None)
matches = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True).match(da, db)
x_a = np.float64([ka[m.queryIdx].pt for m in matches])
x_b = np.float64([kb[m.trainIdx].pt for m in matches])
F_mine, _ = cv2.findFundamentalMat(x_a, x_b, cv2.FM_8POINT)

# 3. Score it beside fviz's estimators, on fviz's own SIFT matches, against the ground truth.
result = fviz.inspect_pair(pair, estimators=("8point", "magsac"), F={"mine": F_mine})
print(f"{result.n_matches} matches, {result.n_eval} within {result.eval_threshold_px:g} px of the ground truth")
for r in result.estimators:
    m = r.metrics
    print(f"{r.name:8s} SED {m['sed_median']:8.3f} px  rotation {m['rot_err_deg']:7.3f} deg  NSGD {m['nsgd']:.4f}")

# 4. The recording fviz inspect pair writes (or fviz.log_result(rec, pair, result) into a stream of yours).
print("recording:", fviz.save_recording(out, pair, result))
