"""``fviz summary`` and ``fviz open``, run as users run them (a subprocess), on a recording made by
``fviz inspect pair`` on the KITTI samples."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys

import pytest
from browser import WebServer, inspect_recording, listening, run_fviz

pytestmark = pytest.mark.kitti


@pytest.fixture(scope="module")
def inspected(kitti_root, tmp_path_factory):
    return inspect_recording(kitti_root, tmp_path_factory.mktemp("browse") / "pair.rrd")


def _one_line_error(r, path) -> str:
    assert r.returncode == 2, (r.returncode, r.stdout, r.stderr)
    err = r.stderr.strip()
    assert len(err.splitlines()) == 1 and err.startswith("error: ") and str(path) in err, err
    return err


def test_summary_json_matches_inspect_json(inspected):
    path, doc = inspected
    r = run_fviz("summary", path, "--json")
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["app_id"] == "fviz-inspect" and s["timeline"] == "pair" and s["has_blueprint"] is True
    assert s["estimators"] == [e["name"] for e in doc["estimators"]]
    [item] = s["items"]
    assert item["name"] == doc["pair"]["name"]
    keys = {k for e in doc["estimators"] for k in e["metrics"]}
    assert set(item["metrics"]) == keys  # every metric of the JSON, not only the table's
    for key in keys:
        got = item["metrics"][key]
        want = {e["name"]: e["metrics"].get(key) for e in doc["estimators"]}
        want = {k: None if v is None or (isinstance(v, float) and math.isnan(v)) else v for k, v in want.items()}
        assert got == want, key


def test_summary_table(inspected):
    path, doc = inspected
    r = run_fviz("summary", path)
    assert r.returncode == 0, r.stderr
    out = r.stdout
    assert doc["pair"]["name"] in out  # piped: never cut
    for e in doc["estimators"]:
        assert f" {e['name']} " in out
        assert f"{e['metrics']['epi_abs']:.4g}" in out
    for key in ("epi_abs", "epi_sqr", "sed_median", "inlier_ratio"):
        assert key in out


@pytest.mark.parametrize("command", ["summary", "open"])
def test_truncated_file(inspected, tmp_path, command):
    path, _ = inspected
    cut = tmp_path / "cut.rrd"
    data = path.read_bytes()
    cut.write_bytes(data[: len(data) // 2])
    err = _one_line_error(run_fviz(command, cut, *(["--web"] if command == "open" else [])), cut)
    assert "truncated" in err


@pytest.mark.parametrize("command", ["summary", "open"])
def test_missing_and_foreign_files(tmp_path, command):
    missing = tmp_path / "nope.rrd"
    _one_line_error(run_fviz(command, missing), missing)
    text = tmp_path / "notes.rrd"
    text.write_text("not a recording\n")
    _one_line_error(run_fviz(command, text), text)


@pytest.mark.parametrize("bind", [None, "0.0.0.0"])
def test_open_web_binds_loopback_by_default(inspected, bind):
    """What the server processes actually listen on (psutil), not just the printed URL; and nothing is left
    running once fviz gets SIGTERM."""
    path, _ = inspected
    extra = [] if bind is None else ["--bind", bind]
    with WebServer(path, *extra) as server:
        assert server.url.startswith(f"http://127.0.0.1:{server.web_port}/?token=")  # page and WebSocket (fviz.web)
        sockets = listening(server.processes())
        want = "127.0.0.1" if bind is None else bind
        assert {(ip, port) for ip, port in sockets if port == server.web_port} == {(want, server.web_port)}, sockets
        if bind is None:
            assert all(ip in ("127.0.0.1", "::1") for ip, _ in sockets), sockets
        tree = server.processes()
    assert server.survivors == [], "processes survived SIGTERM to fviz"
    assert not any(p.is_running() and p.status() != "zombie" for p in tree)
    if bind is not None:
        assert "warning: --bind 0.0.0.0" in server.stderr


def test_open_rejects_bad_ports(inspected):
    path, _ = inspected
    # two servers with --web-static (Rerun's); --web serves on --web-port alone
    r = run_fviz("open", path, "--web-static", "--port", "7000", "--web-port", "7000")
    assert r.returncode == 2 and "--port and --web-port" in r.stderr
    r = run_fviz("open", path, "--web", "--port", "70000")
    assert r.returncode == 2 and "--port 70000" in r.stderr


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="a display is an X11/Wayland matter")
@pytest.mark.parametrize("display", [None, ":97"])
def test_open_tab_leaves_no_temporary_folder(inspected, tmp_path, display):
    """Without a display (one-line error) and with one named that no server answers (the viewer starts and
    exits): no fviz-open-* folder is left in the temporary directory."""
    import time

    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env.update(TMPDIR=str(tmp), **({"DISPLAY": display} if display else {}))
    r = subprocess.run([sys.executable, "-m", "fviz", "open", str(inspected[0]), "--tab", "overview"],
                       capture_output=True, text=True, env=env, timeout=300)
    assert "Traceback" not in r.stderr, r.stderr
    end = time.monotonic() + 60
    while list(tmp.glob("fviz-open-*")) and time.monotonic() < end:
        time.sleep(0.5)
    assert not list(tmp.glob("fviz-open-*"))
