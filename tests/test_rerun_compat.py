"""fviz.rerun_compat, the one module that uses rerun's private names: it parses the JSON the viewer widget sends for
a click, sends a recording's bytes to a notebook viewer, and refuses a rerun other than 0.41.* in one line naming it;
no other fviz module names a private rerun attribute."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import rerun

from fviz import rerun_compat
from fviz.errors import FvizError
from test_interactive import _selection  # the JSON string the notebook widget sends for a click

ROOT = Path(__file__).resolve().parents[1]


def test_a_click_event_is_parsed_into_rerun_s_selection_event():
    event = rerun_compat.viewer_event_from_json(_selection("/a/image", [12.5, 3.0, None], instance=7))
    assert event.type == "selection_change"
    assert (event.application_id, event.recording_id) == ("fviz-notebook", "r")
    (item,) = event.items
    assert (item.type, item.entity_path, item.instance_id, item.view_name) == ("entity", "/a/image", 7, "overview")
    assert list(item.position) == [12.5, 3.0, None]


def test_a_string_that_is_no_event_is_a_value_or_key_error():
    """What the click server drops (its answer catches these two)."""
    with pytest.raises(ValueError):
        rerun_compat.viewer_event_from_json('{"type": "dance", "application_id": "a", "recording_id": "r"}')
    with pytest.raises(KeyError):
        rerun_compat.viewer_event_from_json('{"type": "selection_change"}')
    with pytest.raises(ValueError):
        rerun_compat.viewer_event_from_json("not json")


def test_the_installed_rerun_is_supported():
    assert rerun_compat.check_version() == rerun.__version__
    assert rerun_compat.check_version("0.41.3") == "0.41.3"


@pytest.mark.parametrize("version", ["0.40.0", "0.42.0", "1.41.0", "0.4.1"])
def test_another_rerun_is_refused_in_one_line_naming_it(monkeypatch, version):
    monkeypatch.setattr(rerun, "__version__", version)
    for call in (rerun_compat.check_version, lambda: rerun_compat.viewer_event_from_json(_selection("/a/image")),
                 lambda: rerun_compat.send_rrd(object(), b"")):
        with pytest.raises(FvizError) as e:
            call()
        msg = str(e.value)
        assert "\n" not in msg and f"rerun {version} is installed" in msg and "0.41.*" in msg


def test_send_rrd_hands_the_bytes_to_the_widget():
    sent = []

    class Widget:
        def send_rrd(self, data):
            sent.append(data)

    class Viewer:
        _viewer = Widget()

    rerun_compat.send_rrd(Viewer(), b"RRF2...")
    assert sent == [b"RRF2..."]


def test_no_other_module_names_a_private_rerun_name():
    """``rerun._x`` / ``from rerun._x`` / ``rerun.y._x`` / ``._viewer`` (the notebook widget) only in rerun_compat."""
    private = re.compile(r"\brerun(\.\w+)*\._\w|from rerun(\.\w+)* import _\w|\._viewer\b")
    found = [f"{p.relative_to(ROOT)}:{i}" for p in sorted((ROOT / "fviz").rglob("*.py")) if p.name != "rerun_compat.py"
             for i, line in enumerate(p.read_text().splitlines(), 1) if private.search(line)]
    assert found == []
