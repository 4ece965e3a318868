"""A pair's verdict (fviz.verdicts.pair_verdict) and the numbers in what users read: a synthetic pair (no dataset
needed) given a ground truth that misses every match by 200 px and a stated accuracy of many digits, as a fit to
hand-labelled correspondences gives one."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

import fviz
from fviz.record import layout as L
from fviz.record.reader import text

LONG_FLOAT = re.compile(r"\d\.\d{6,}")  # a float printed with all its digits ("0.3363559717763374")
ACCURACY = 0.3363559717763374
F_200_PX_OFF = np.array([[0, 0, 0], [0, 0, -1], [0, 1, 200]], float)  # y_b = y_a + 200: no match lies on its lines


@pytest.fixture(scope="module")
def off(tmp_path_factory):
    """(pair, result, recording) of synthetic scene 1 with F_200_PX_OFF as its ground truth, good to ~ACCURACY px."""
    pair = dataclasses.replace(fviz.load_pair(synthetic=True, seed=1), F_gt=F_200_PX_OFF, gt_accuracy_px=ACCURACY,
                               R=None, t=None)
    result = fviz.inspect_pair(pair, estimators=("8point", "ransac"))
    return pair, result, fviz.save_recording(tmp_path_factory.mktemp("verdict") / "off.rrd", pair, result, probe=5)


def test_no_evaluation_match_is_the_verdict_and_the_probe_walks_the_matchers_errors(off):
    from fviz.verdicts import NO_EVAL, verdict_of

    pair, result, rrd = off
    assert result.n_matches > 100 and result.n_eval == 0
    v = verdict_of(pair, result)
    assert v.kind == NO_EVAL and v.text.startswith(f"0 of {result.n_matches} matches within 2 px of F_gt's lines")
    # the estimates' consensus sits ~200 px off F_gt's lines, ~0.3 px off their own
    assert re.search(r"; ground truth suspect: (8point|ransac)'s \d+ inliers \(\d+%\) sit (19\d|20\d) px off F_gt's lines, "
                     r"0\.\d+ px off F's refitted without them \(out of sample\)$", v.text), v.text
    assert text(rrd, L.VERDICT) == [v.markdown()]
    probe = text(rrd, L.PROBE_TEXT)  # no evaluation match to walk: every match, by the ground truth's residual
    assert len(probe) == 5 and all("By the ground truth's residual over all matches (no evaluation match" in t for t in probe), probe


def test_user_facing_numbers_are_rounded(off):
    """Every text a user reads of the pair (the recording's summary, verdict and probe text, the notes inspect prints)
    rounds its numbers: the stated accuracy reads "~0.34 px", never with its 16 digits."""
    from fviz.diagnose import GT_SUSPECT_NOTE

    pair, result, rrd = off
    texts = {"summary": text(rrd, L.SUMMARY)[0], "verdict": text(rrd, L.VERDICT)[0], "probe": text(rrd, L.PROBE_TEXT)[0],
             "notes": "\n".join(result.notes)}
    assert "good to ~0.34 px" in texts["summary"]
    assert any(n.startswith(GT_SUSPECT_NOTE) and "ground truth good to ~0.34 px" in n for n in result.notes)
    for what, t in texts.items():
        assert not LONG_FLOAT.findall(t), (what, LONG_FLOAT.findall(t), t)
