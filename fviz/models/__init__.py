"""The paper's networks (Poursaeed et al., "Deep Fundamental Matrix Estimation without
Correspondences", ECCV-W 2018), in torch.  One file per concern:

- :mod:`.backbones`: single-stream and Siamese feature extractors;
- :mod:`.pooling`: location-aware pooling (POS);
- :mod:`.heads`: Base, REC (reconstruction layer) and EPI (epipolar parametrization) heads;
- :mod:`.normalization`: ETR, FBN, ABS layers;
- :mod:`.model`: :class:`FNet` and the 36 ``VARIANTS`` (input size / pooling choices documented there);
- :mod:`.predict`: :func:`predict_F` on full-resolution images.

Importing this package imports torch.
"""

from fviz.models.model import (
    ARCHS,
    DEFAULT_INPUT_HW,
    HEAD_NAMES,
    VARIANTS,
    FNet,
    FNetConfig,
    count_parameters,
    parse_variant,
    variant_name,
    variants,
)
from fviz.models.normalization import ABS, ETR, FBN, normalize_f
from fviz.models.predict import (
    f_to_full,
    f_to_input,
    predict_F,
    scale_matrix,
    to_model_input,
)

__all__ = [
    "ABS",
    "ARCHS",
    "DEFAULT_INPUT_HW",
    "ETR",
    "FBN",
    "HEAD_NAMES",
    "VARIANTS",
    "FNet",
    "FNetConfig",
    "count_parameters",
    "f_to_full",
    "f_to_input",
    "normalize_f",
    "parse_variant",
    "predict_F",
    "scale_matrix",
    "to_model_input",
    "variant_name",
    "variants",
]
