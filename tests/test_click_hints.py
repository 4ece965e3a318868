"""The click hint only where clicks work (issue 42, item 5): a recording with a pair's images and F's is clickable; a
run's eval.rrd without ``--full`` has no images, and ``fviz open`` (native viewer) says so instead of telling the
user to click."""

from __future__ import annotations

import pytest
import fviz


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    out = tmp_path_factory.mktemp("hints")
    pair = fviz.synthetic_pair(2, kind="temporal")
    inspected = fviz.save_recording(out / "pair.rrd", pair, fviz.inspect_pair(pair, ("8point",)))
    run = fviz.evaluate_run(fviz.select(seeds=(0, 2)), out / "run", estimators=("8point",), max_keypoints=300, workers=1)
    return inspected, run.out_dir / "eval.rrd"


def test_only_a_recording_with_pair_images_is_clickable(recordings):
    inspected, run = recordings
    assert run.is_file()
    assert fviz.api.viewing.clickable(inspected) is True
    assert fviz.api.viewing.clickable(run) is False


def test_open_hints_at_clicks_only_where_there_is_something_to_click(recordings, monkeypatch):
    from fviz.cli import browse

    inspected, run = recordings
    seen = []
    monkeypatch.setattr(fviz.api.viewing, "open_recording", lambda *a, **k: True)  # no viewer here: the hint alone
    monkeypatch.setattr("builtins.print", lambda *a, **k: seen.append(" ".join(map(str, a))))
    browse.open_recording(inspected)
    browse.open_recording(run)
    assert seen[1].startswith("clicks (a point's epipolar lines") and seen[3] == browse.NO_CLICKS

