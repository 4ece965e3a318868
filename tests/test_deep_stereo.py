"""``-e deep`` chooses its bundled model by the pair's kind: stereo pairs get the stereo network (trained by
``fviz train`` on real KITTI City stereo), every other pair the motion network. Checked on odometry 04, a
recording day and rig the stereo network never saw (colour cameras 2/3, 2011_09_30)."""

from __future__ import annotations

import numpy as np
import pytest

from fviz.estimators.deep import BUNDLED, STEREO, bundled_yaw_gain, deep_batch_predictor, deep_estimator
from fviz.evaluate import evaluate_pair

pytestmark = pytest.mark.usefixtures("torch_one_thread")


@pytest.fixture(scope="module")
def seq04(kitti_root):
    from fviz.data.kitti import open_dataset

    return open_dataset(kitti_root, sequence="04")


def test_stereo_pairs_get_a_stereo_F_on_an_unseen_rig(seq04):
    deep, synthetic = deep_estimator(), deep_estimator("synthetic")
    errors = {"deep": [], "deep:synthetic": []}
    for frame in range(0, 10, 3):
        result = evaluate_pair(seq04.pair(frame, "stereo", cams=(2, 3)), [("deep", deep), ("deep:synthetic", synthetic)])
        for name in errors:
            errors[name].append(result.get(name).metrics["epipole_err_deg"])
    assert np.median(errors["deep"]) < 10.0, errors  # the target; measured 0.4 deg
    assert np.median(errors["deep:synthetic"]) > 45.0, errors  # the motion model alone is blind on stereo


def test_the_kind_picks_the_model_per_pair_and_in_batches(seq04):
    from fviz.models.predict import predict_F
    from fviz.models.weights import load_model

    deep = deep_estimator()
    stereo, motion = deep_estimator(STEREO), load_model(BUNDLED, "cpu")[0]
    s, t = seq04.pair(2, "stereo", cams=(2, 3)), seq04.pair(2, "temporal", cams=(2, 2))
    np.testing.assert_array_equal(deep(s, None, None), stereo(s, None, None))  # stereo: one pass, not mirrored
    np.testing.assert_array_equal(deep(t, None, None), predict_F(motion, t.image_a, t.image_b, (t.K_a, t.K_b), bundled_yaw_gain()))
    assert not np.allclose(stereo(t, None, None), deep(t, None, None))
    batch = deep_batch_predictor()([s, t])
    np.testing.assert_allclose(batch[0], deep(s, None, None), atol=1e-5)
    np.testing.assert_allclose(batch[1], deep(t, None, None), atol=1e-5)
