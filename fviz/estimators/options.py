"""What a run of estimators needs beyond their names: features and robust-estimation settings."""

from __future__ import annotations

from dataclasses import dataclass

from fviz.errors import FvizError

MAX_KEYPOINTS = 1_000_000  # per image: far above any detector's use, below OpenCV's int limit


@dataclass(frozen=True)
class EstimatorOptions:
    names: tuple[str, ...]
    features: str = "sift"
    max_keypoints: int = 2000
    ratio: float = 0.8
    mutual: bool = True
    threshold: float = 1.0
    confidence: float = 0.999
    max_iters: int = 10000
    seed: int = 0

    def feature_config(self):
        from fviz.estimators.features import FeatureConfig

        return FeatureConfig(self.features, self.max_keypoints, self.ratio, self.mutual)

    def estimators(self):
        """[(name, fn)] resolved once (a deep model loads once)."""
        from fviz.estimators import get_estimator
        from fviz.estimators.classical import RobustConfig

        cfg = RobustConfig(self.threshold, self.confidence, self.max_iters, self.seed)
        if len(set(self.names)) != len(self.names):
            raise FvizError(f"--estimator: repeated name in {', '.join(self.names)}")
        from fviz.estimators.registry import display_names

        return [(name, get_estimator(n, cfg)) for name, n in zip(display_names(self.names), self.names)]
