"""The verdict of a pair in a real browser (as tests/test_web_viewer.py): a KITTI pair whose ground truth puts every
epipolar line 200 px below its match, so that none of its matches is an evaluation match. Opened on the probe tab,
the screen states that verdict in one line above the tabs, fully inside its view, and the probe, with no evaluation
match to walk, walks every match by the ground truth's residual and says so. (The KITTI pair's verdict line
is checked on tests/test_web_viewer.py's overview, triage's banner on its triage screen.)"""

from __future__ import annotations

import json

import pytest
from browser import run_fviz
from test_web_viewer import Shot, assert_verdict_line_inside, text_lines

from fviz.record import layout as L

pytestmark = [pytest.mark.browser, pytest.mark.kitti, pytest.mark.slow]

# y_b = y_a + 200 (F_gt's lines in b are rows 200 px below each point of a): KITTI's matches move < 50 px
F_GT_200_PX_OFF = "0,0,0,0,0,-1,0,1,200"


@pytest.fixture(scope="module")
def no_eval(kitti_root, tmp_path_factory):
    """(recording, --json) of odometry 00's frames 3 -> 4 as two images with F_GT_200_PX_OFF as their ground truth."""
    seq = kitti_root / "odometry" / "dataset" / "sequences" / "00" / "image_0"
    out = tmp_path_factory.mktemp("web-verdict") / "no-eval.rrd"
    r = run_fviz("inspect", "pair", "--image-a", seq / "000003.png", "--image-b", seq / "000004.png",
                 "--F-gt", F_GT_200_PX_OFF, "--out", out, "--json")
    assert r.returncode == 0, r.stderr
    return out, json.loads(r.stdout)


def test_no_evaluation_matches_is_stated_above_the_probe_which_says_what_it_walks(no_eval, tmp_path):
    from fviz.record.reader import text

    rrd, doc = no_eval
    assert doc["n_eval"] == 0 and doc["n_matches"] > 100 and doc["verdict"]["kind"] == "no evaluation matches"
    (verdict,) = text(rrd, L.VERDICT)
    assert verdict == f"**{doc['verdict']['kind']}**: {doc['verdict']['text']}"
    walk = text(rrd, L.PROBE_TEXT)
    assert walk and all("By the ground truth's residual over all matches (no evaluation match" in t for t in walk), walk[:1]
    shot = Shot(rrd, tmp_path / "no-eval-probe.png", "--tab", "probe")
    assert_verdict_line_inside(shot, verdict)
    # the probe's text view (the right quarter, below the tabs): the step and its order, wrapped over several lines
    h, w = shot.rgb.shape[:2]
    lines = [ln for ln in text_lines(shot.rgb, (int(0.77 * w), 150, w - int(0.77 * w) - 10, h - 300)) if ln[1] - ln[0] >= 6]
    print(f"probe text view: {len(lines)} lines of text {lines}")
    assert len(lines) >= 3, f"the probe's text view is empty: {lines}; {shot.context}"
