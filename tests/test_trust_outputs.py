"""What a user's estimator returns (issue "Trust nothing, round two"): a torch tensor that requires grad is
taken as its F; an array-like that will not convert, a complex F and an inlier mask of the wrong length are
that estimator's failure, named, never a traceback or a silently altered result. A real ``fviz inspect``."""

from __future__ import annotations

import json

import numpy as np
from test_trust_estimators import INSPECT, by_name, fviz


def test_odd_returns_are_named_failures_and_a_grad_tensor_is_an_f(tmp_path):
    names = ("grad_tensor", "unconvertible", "complex_f", "short_mask")
    r = fviz(*INSPECT, *[a for n in names for a in ("-e", f"trust_estimators:{n}")], "-e", "8point", "--json",
             "--out", tmp_path / "x.rrd")
    assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
    ests = by_name(json.loads(r.stdout))
    assert ests["grad_tensor"]["error"] is None
    np.testing.assert_allclose(np.array(ests["grad_tensor"]["F"]), np.array(ests["8point"]["F"]), rtol=1e-6, atol=1e-12)
    assert "refuses to convert" in ests["unconvertible"]["error"]
    assert "complex F" in ests["complex_f"]["error"]
    n = json.loads(r.stdout)["n_matches"]
    assert f"an inlier mask of {n - 1} entries for {n} matches" in ests["short_mask"]["error"]
    for name in names[1:]:
        assert f"error: estimator {name}: returned" in r.stderr
