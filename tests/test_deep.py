"""The bundled network as an estimator beside the classical ones."""

import hashlib
import json
from pathlib import Path

import numpy as np
from cli_util import assert_one_line_error, run_fviz

from fviz.estimators.deep import BUNDLED

ASSETS = Path(__file__).resolve().parents[1] / "assets"


def test_bundled_weights_match_their_manifest():
    manifest = json.loads((ASSETS / "MANIFEST.json").read_text())
    data = BUNDLED.read_bytes()
    assert hashlib.sha256(data).hexdigest() == manifest["sha256"]
    assert len(data) <= 20 * 2**20
    assert manifest["variant"] == "siamese-rec-pos-fbn" and manifest["steps"] > 0
    from fviz.estimators.deep import STEREO

    stereo = manifest["stereo_model"]
    data = STEREO.read_bytes()
    assert stereo["file"] == STEREO.name and hashlib.sha256(data).hexdigest() == stereo["sha256"]
    assert len(data) <= 10 * 2**20 and "CC BY-NC-SA" in stereo["license"]


def test_deep_estimator_in_inspect(tmp_path):
    out = tmp_path / "deep.rrd"
    proc = run_fviz("inspect", "pair", "--synthetic", "--seed", "11", "--pair", "temporal", "-e", "deep",
                    "-e", f"deep:{BUNDLED}", "-e", "8point", "--out", out, "--json")
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)
    names = [e["name"] for e in doc["estimators"]]
    assert names == ["gt", "deep", "deep-fviz-deep", "8point"]
    deep, one_pass = (np.array(doc["estimators"][i]["F"]) for i in (1, 2))
    assert not np.allclose(deep, one_pass, atol=1e-4)  # plain deep averages the pair with its mirror image (K known)
    for F in (deep, one_pass):
        s = np.linalg.svd(F, compute_uv=False)
        assert s[2] < 1e-6 * s[0]  # REC head, and the mean motion's [t]x R: rank 2 by construction
    assert doc["estimators"][1]["metrics"]["f_dist"] < 0.5 and doc["estimators"][2]["metrics"]["f_dist"] < 0.5
    from rerun.chunk import RrdReader

    entities = {ch.entity_path for ch in RrdReader(out).stream().to_chunks()}
    assert {"/est/gt/matches", "/a/est/deep/epilines", "/b/est/deep/epilines"} <= entities


def test_bad_checkpoints(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_text("not a checkpoint")
    assert_one_line_error(run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{junk}"), 2, "junk.pt")
    assert_one_line_error(run_fviz("inspect", "pair", "--synthetic", "-e", f"deep:{tmp_path}/none.pt"), 2, "none.pt")
