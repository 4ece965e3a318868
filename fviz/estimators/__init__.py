"""Estimators: features and matching, classical (OpenCV) and deep ones, one registry."""

from fviz.estimators.base import Estimate, run_estimator
from fviz.estimators.registry import DEFAULT_ESTIMATORS, get_estimator, needs_matches

__all__ = ["DEFAULT_ESTIMATORS", "Estimate", "get_estimator", "needs_matches", "run_estimator"]
