"""Geometry floor of fviz: pure numpy, imports nothing else of fviz but its error type."""

from fviz.geometry.epipolar import (
    Epipole,
    apply_homography,
    border_point,
    clip_lines,
    describe_epipole,
    epipoles,
    homogeneous,
    lines_in_a,
    lines_in_b,
)
from fviz.geometry.fmbench import NSGD_RECALL_THRESHOLD, gt_inlier_ratio, nsgd
from fviz.geometry.fundamental import (
    NORMS,
    NormalizationError,
    enforce_rank2,
    f_distance,
    fundamental_from_motion,
    fundamental_from_projections,
    is_valid,
    normalize,
    skew,
    transfer_fundamental,
)
from fviz.geometry.pose import (
    AUC_THRESHOLDS_DEG,
    essential_from_fundamental,
    mean_motion_f,
    nearest_rotation,
    pose_auc,
    recover_pose,
    rotation_angle_deg,
    rotation_error_deg,
    scale_yaw,
    small_motion,
    translation_error_deg,
    yaw_deg,
)
from fviz.geometry.precision import PRECISION_KEYS, match_precision, normalized_epipolar_distance
from fviz.geometry.residuals import (algebraic, epipolar_residuals, sampson_distance, squared_epipolar_distances,
                                    symmetric_epipolar_distance)

__all__ = [
    "AUC_THRESHOLDS_DEG", "NSGD_RECALL_THRESHOLD", "essential_from_fundamental", "nearest_rotation", "gt_inlier_ratio", "nsgd", "pose_auc",
    "recover_pose", "rotation_angle_deg", "rotation_error_deg", "translation_error_deg", "small_motion", "mean_motion_f",
    "scale_yaw", "yaw_deg",
    "NORMS", "Epipole", "NormalizationError", "algebraic",
    "epipolar_residuals", "border_point", "clip_lines", "describe_epipole",
    "enforce_rank2", "epipoles", "f_distance", "fundamental_from_motion", "fundamental_from_projections",
    "apply_homography", "transfer_fundamental", "homogeneous", "is_valid", "lines_in_a", "lines_in_b", "normalize",
    "sampson_distance", "skew",
    "symmetric_epipolar_distance", "squared_epipolar_distances", "PRECISION_KEYS", "match_precision", "normalized_epipolar_distance",
]
