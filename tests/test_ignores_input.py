"""``ignores-input`` is a paired judgement: an estimator is flagged while the slope of its pair-to-pair offsets on
the ground truth's cannot be told from below IGNORES_FRACTION (a paired bootstrap's interval), so a spread of 11 %
of the truth's made of jitter is no pass, and a damped but faithful one is. Records built as eval writes them."""

from __future__ import annotations

import numpy as np

from fviz.geometry import fundamental_from_motion
from fviz.findings import IGNORES_FRACTION, estimator_findings, tracking_slope

K = np.array([[700.0, 0.0, 620.0], [0.0, 700.0, 190.0], [0.0, 0.0, 1.0]])


def _t(yaw_deg: float) -> np.ndarray:
    a = np.radians(yaw_deg)
    return np.array([np.sin(a), 0.0, np.cos(a)])


def _records(yaws: np.ndarray, estimates: dict[str, np.ndarray]) -> list[dict]:
    """One eval record per pair: the ground truth and each estimator moving straight along its yaw (R = I)."""
    row = lambda name, yaw: {"name": name, "error": None, "metrics": {"sed_median": 0.5, "pose_err_deg": 1.0},  # noqa: E731
                             "F": fundamental_from_motion(K, K, np.eye(3), _t(yaw)).tolist(), "R": np.eye(3).tolist()}
    return [{"error": None, "diagnostics": {},
             "result": {"pair": {"K_a": K.tolist()}, "F_gt": fundamental_from_motion(K, K, np.eye(3), _t(y)).tolist(),
                        "estimators": [row("gt", y)] + [row(n, e[i]) for n, e in estimates.items()]}}
            for i, y in enumerate(yaws)]


def test_jitter_at_the_threshold_is_no_pass_and_a_damped_follower_is():
    rng = np.random.default_rng(1)
    yaws = rng.normal(0.0, 1.0, 12)
    estimates = {"follows": yaws + rng.normal(0.0, 0.05, 12), "damped": 0.3 * yaws, "constant": np.zeros(12),
                 "jitter": rng.normal(0.0, 0.11 * yaws.std(), 12)}  # moves 11 % as much as the truth, not with it
    found = {f.name: dict(f.flags) for f in estimator_findings(_records(yaws, estimates), list(estimates))}
    assert "ignores-input" not in found["follows"] and "ignores-input" not in found["damped"]
    assert "ignores-input" in found["constant"]
    assert "ignores-input" in found["jitter"] and "interval" in found["jitter"]["ignores-input"]


def test_the_slope_is_paired_seeded_and_brackets_a_known_damping():
    rng = np.random.default_rng(2)
    yaws = rng.normal(0.0, 2.0, 40)
    gt, est = np.array([_t(y) for y in yaws]), np.array([_t(0.5 * y) for y in yaws])
    b, lo, hi = tracking_slope(est, gt, rotations=False)
    assert (b, lo, hi) == tracking_slope(est, gt, rotations=False)  # the same run, the same interval
    assert b == np.float64(b) and abs(b - 0.5) < 0.01 and lo <= b <= hi and hi - lo < 0.02  # paired: no sampling spread
    Rs = np.array([[[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]] for a in np.radians(yaws)])
    b, lo, hi = tracking_slope(np.repeat(np.eye(3)[None], 40, 0), Rs, rotations=True)
    assert b == lo == hi == 0.0  # a constant rotation ignores the truth's turns
    assert tracking_slope(Rs, Rs, rotations=True)[1] > 0.99 and lo < IGNORES_FRACTION
