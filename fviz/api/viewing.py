"""Recordings from Python: open one in a viewer (Rerun's native one, or fviz's web page where a click draws a point's
epipolar lines), read its pairs and metrics back (and ``fviz summary``'s table of them). ``fviz open``, ``fviz summary``
and ``fviz inspect pair --spawn / --web`` are clients of these functions. Works on any fviz recording (``inspect``,
``eval``, ``triage``, ``compare``)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

from fviz.api.names import python_errors, word
from fviz.errors import FvizError


def serve(path: Path, bind: str, port: int, web_port: int, blueprint: Optional[Path] = None, static: bool = False,
          pair=None, result=None, lines: int = 30, probe: int = 20) -> None:
    """The web viewer on ``path`` until Ctrl-C / SIGTERM / SIGHUP (``open --web`` and ``inspect --web``):
    fviz's page, where a click draws the point's epipolar lines (:mod:`fviz.web`), or with ``static``
    Rerun's own web viewer (``rerun --serve-web``: no clicks). With the ``pair`` and its ``result`` (inspect's), the
    page's edit tools exclude matches and re-estimate (:func:`fviz.edit`), exporting beside the recording
    (``PATH.edited/``). A run's eval.rrd (run.json beside it): a pair the time cursor reaches (a right-click in a plot)
    is read from the run (:func:`fviz.read_pair`) and drawn, its images, matches and lines clickable; a compare.rrd: a
    pair whose point of the chart is clicked, from the run(s) compared."""
    from fviz.viewer import serve_web
    from fviz.web.server import serve_clicks

    for name, value in (("--port", port), ("--web-port", web_port)):
        if not 0 < value < 65536:
            raise FvizError(f"{name} {value}: not a port (1-65535)")
    if bind not in ("127.0.0.1", "localhost", "::1"):
        print(f"warning: {word('--bind')} {bind}: the viewer and the recording are reachable from other machines", file=sys.stderr)
    if static:
        serve_web(path, bind, port, web_port, blueprint)
    elif pair is None:  # a run's eval.rrd, a compare.rrd: their pairs drawn on demand (fviz.interactive.OnDemand)
        from fviz.api.runpairs import run_of_recording

        serve_clicks(path, bind, web_port, blueprint, run=run_of_recording(path))
    else:
        serve_clicks(path, bind, web_port, blueprint, page_editor(pair, result, lines, probe), Path(path).with_suffix(".edited"))


def page_editor(pair, result, lines: int = 30, probe: int = 20):
    """The page's edit tools on ``result`` (inspect's, of ``pair``): ``editor(rec, clicks)`` -> an
    :class:`fviz.editing.EditSession` drawing into ``rec``, the page's stream, with its ``clicks``."""
    from fviz.api.editing import edit

    def editor(rec, clicks):
        # the page's viewer has the legend from the file; logged again from this stream, Rerun 0.41's web viewer
        # drops it and colours the keypoints by class id at random
        return edit(pair, result, rec, lines=lines, probe=probe, clicks=clicks, legend=False)

    return editor


def check_viewer(spawn: bool, web: bool, bind: str, web_port: int) -> None:
    """What would stop the viewer later (no display, a busy port) is an error before any work."""
    from fviz.errors import FvizError
    from fviz.viewer import check_port_free, has_display

    if spawn and not has_display():
        raise FvizError("--spawn: no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset); use --web")
    if web:  # fviz's page serves on --web-port alone (--port is --web-static's, which inspect has not)
        check_port_free(bind, web_port, "--web-port")


def spawn(path: Path) -> None:
    """Rerun's native viewer on ``path`` (returns at once)."""
    from fviz.viewer import spawn_native

    spawn_native(path)


def tab_blueprint(path: Path, tab: str) -> Path:
    """A blueprint file that opens ``path`` on tab ``tab`` (one-line error naming the tabs there are)."""
    import tempfile

    from fviz.record.rebuild import recording_blueprint

    app_id, bp = recording_blueprint(path, active=tab)
    out = Path(tempfile.mkdtemp(prefix="fviz-open-")) / f"{tab}.rbl"  # read by the viewer when it starts
    bp.save(app_id, out)
    return out


_WATCH = """import os, shutil, sys, time
pid = int(sys.argv[1])
while True:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        break
    except PermissionError:
        pass
    time.sleep(0.5)
shutil.rmtree(sys.argv[2], ignore_errors=True)
"""


def remove_when_done(pid: int, folder: Path) -> None:
    """Remove ``folder`` (the --tab blueprint's temporary folder) once the viewer ``pid`` has exited: a small
    detached watcher, since ``fviz open`` returns while the native viewer runs on."""
    import subprocess

    subprocess.Popen([sys.executable, "-c", _WATCH, str(pid), str(folder)], stdin=subprocess.DEVNULL,
                     stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)


@python_errors
def open_recording(path: str | Path, *, web: bool = False, web_static: bool = False, bind: str = "127.0.0.1",
                   port: int = 9876, web_port: int = 9090, tab: Optional[str] = None, pair=None, result=None) -> bool:
    """Open a recording in Rerun's native viewer (returns at once: True), or with ``web`` serve fviz's web viewer
    (``web_static``: Rerun's own, no clicks) on ``bind``:``web_port`` until Ctrl-C / SIGTERM (then False); with the
    ``pair`` and its ``result`` the recording shows, the page's edit tools edit it.

    Args:
        path: a ``*.rrd`` written by fviz (a one-line error on a missing, foreign or truncated file).
        web: serve fviz's web page, where a click draws the point's epipolar lines under every F.
        web_static: serve Rerun's own web viewer (``rerun --serve-web``; its recording server on ``port``).
        bind: the address served on (0.0.0.0 exposes the recording to the network, with a warning).
        port: Rerun's recording (gRPC) server, with ``web_static`` only.
        web_port: the web viewer's page.
        tab: open on this tab: an estimator's name, overview, probe, metrics or motion.
    """
    from fviz.record.reader import open_rrd
    from fviz.viewer import spawn_native

    path = Path(path)
    if path.is_dir() and (path / "run.json").is_file():
        raise FvizError(f"{path}: a run folder, not a recording: open its recording ({path / 'eval.rrd'}) or one of its "
                        f"pairs with --pair I (its index on the pair timeline, or its name)")
    open_rrd(path)  # one-line error on a missing, foreign or truncated file
    blueprint = tab_blueprint(path, tab) if tab is not None else None
    watched = False
    try:
        if web or web_static:
            serve(path, bind, port, web_port, blueprint, static=web_static, pair=pair, result=result)
            return False
        proc = spawn_native(path, blueprint)
        if blueprint is not None:
            remove_when_done(proc.pid, blueprint.parent)
            watched = True
        return True
    finally:
        if blueprint is not None and not watched:  # the web viewer has stopped, or the viewer never started
            import shutil

            shutil.rmtree(blueprint.parent, ignore_errors=True)


# Metric columns of the summary table, in this order when present (every metric: --json).
SUMMARY_METRICS = ("sed_median", "sampson_median", "rot_err_deg", "trans_err_deg", "nsgd", "inlier_ratio",
                   "epipole_err_deg", "epi_abs", "epi_sqr")


def summary_rows(s) -> tuple[list[str], list[str], list[list[list[str]]]]:
    """``fviz summary``'s table of a :func:`read_recording` summary ``s``: (its metric columns, its other timelines,
    per item its rows). An item has a row per estimator, the first with the item's index, its other timelines' and its
    name; the metrics to 4 digits ("-" when unknown); the estimator's error when an item has one."""
    from fviz.stats import fmt

    cols = [m for m in SUMMARY_METRICS if m in s.metrics]
    times = sorted({t for it in s.items for t in it.times})
    errors = any(it.errors for it in s.items)
    items = []
    for it in s.items:
        ests = it.estimators() or ["-"]
        head = [str(it.index), *(str(it.times.get(n, "")) for n in times), it.name or "-"]
        items.append([(head if k == 0 else [""] * len(head)) + [est, *(fmt(it.metrics.get(c, {}).get(est), 4, "-") for c in cols)]
                      + ([it.errors.get(est, "")] if errors else []) for k, est in enumerate(ests)])
    return cols, times, items


@python_errors
def clickable(path: str | Path) -> bool:
    """Whether a recording has pairs with images and F's, where a click in fviz's page draws lines (a run's
    recording without ``--full`` has none; train.rrd's watched pairs are)."""
    from fviz.record.rebuild import click_pairs, watch_pairs

    return bool(click_pairs(Path(path)) or watch_pairs(Path(path)))


@python_errors
def open_run_pair(run, pair: int | str, *, versus=None, labels=None, web: bool = False, web_static: bool = False,
                  bind: str = "127.0.0.1", port: int = 9876, web_port: int = 9090, tab: Optional[str] = None,
                  shown=None) -> tuple[Path, bool]:
    """Pair ``pair`` of a run folder (:func:`fviz.read_pair`, ``versus`` another run on it: nothing else is evaluated
    again) written into RUN/pairs/ and opened as :func:`open_recording` opens a recording; with ``web`` the page's edit
    tools edit it. What would stop the viewer (a taken port, no display) is an error before the pair is read.
    ``shown(path, result)`` is called once the recording is written, before the viewer opens (the command line prints
    them). -> (the recording, whether a native viewer was started)."""
    from fviz.api.runpairs import pair_recording
    from fviz.viewer import check_port_free, has_display

    for what, folder in (("", run), ("--versus ", versus)):
        if folder is not None and Path(getattr(folder, "out_dir", folder)).is_file():
            raise FvizError(f"{what}{folder}: a file, not a run folder: a pair is read from the folder fviz eval wrote "
                            "(its --out-dir)")
    if web or web_static:
        check_port_free(bind, web_port, "--web-port")
    elif not has_display():
        raise FvizError("no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset): add --web")
    path, p, result = pair_recording(run, pair, versus=versus, labels=labels)
    if shown is not None:
        shown(path, result)
    return path, open_recording(path, web=web, web_static=web_static, bind=bind, port=port, web_port=web_port, tab=tab,
                                pair=p, result=result)


@python_errors
def read_recording(path: str | Path):
    """The pairs and metrics stored in a recording (``fviz summary``): ``items`` (one per pair: ``name``, ``metrics``
    by estimator, ``errors``), ``metrics``, ``timeline``, ``app_id``; ``to_dict()`` is ``fviz summary --json``."""
    from fviz.record.summary import read_recording as read

    return read(Path(path))
