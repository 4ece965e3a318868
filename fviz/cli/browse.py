"""``fviz open`` (a recording in Rerun's native or web viewer) and ``fviz summary`` (its pairs and metrics,
no viewer). Both work on any fviz recording: ``inspect``, ``eval`` and ``triage`` files."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from fviz.cli import options as o
from fviz.errors import FvizError

Recording = Annotated[Path, typer.Argument(help="A .rrd written by fviz (inspect, eval or triage).", show_default=False)]


WebBind = Annotated[str, typer.Option("--bind", help="Address the web viewer listens on; 0.0.0.0 exposes it to the network.")]
Port = Annotated[int, typer.Option("--port", help="Port of Rerun's recording (gRPC) server, with --web-static only (--web serves all on --web-port).",
                                   callback=o.checked("--port", lambda p: 1 <= p <= 65535, "must be a port 1 .. 65535"))]
# inspect's --port: kept so that scripts passing it still run; its --web serves on --web-port alone
UnusedPort = Annotated[int, typer.Option("--port", help="Unused (was the recording server's port): --web serves on --web-port alone.",
                                         callback=o.checked("--port", lambda p: 1 <= p <= 65535, "must be a port 1 .. 65535"))]
WebPort = Annotated[int, typer.Option("--web-port", help="Port of the web viewer: its page and, with --web, the page's WebSocket.",
                                      callback=o.checked("--web-port", lambda p: 1 <= p <= 65535, "must be a port 1 .. 65535"))]


CLICK_HINT = ("clicks (a point's epipolar lines under every F) need a viewer that sends them: fviz open {path} --web, "
              "or fviz.notebook.open in Jupyter (the native viewer sends none; its probe tab steps through the worst matches)")

NO_CLICKS = "no pair images in this recording (a run's without --full): nothing to click; fviz eval --full records them"


def open_recording(
    path: Recording,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer (until Ctrl-C) and print its URL; click a point there for its epipolar lines.")] = False,
    web_static: Annotated[bool, typer.Option("--web-static", help="Serve Rerun's own web viewer instead (rerun --serve-web; no clicks).")] = False,
    bind: WebBind = "127.0.0.1",
    port: Port = 9876,
    web_port: WebPort = 9090,
    tab: Annotated[Optional[str], typer.Option("--tab", help="Open on this tab: an estimator's name, overview, probe, metrics or motion.")] = None,
    pair: Annotated[Optional[str], typer.Option("--pair", help="PATH is a run folder: show this pair of it (its index on the pair timeline, or its name), rebuilt from the run's folder (its matches and settings; no other pair evaluated again) into PATH/pairs/<name>.rrd; with --web, editable.")] = None,
    versus: Annotated[Optional[Path], typer.Option("--versus", help="With --pair: another run folder (checkpoint, matcher, settings) on the same pair: both runs' F's in one recording, named <run>-<estimator>, one click answered in all.")] = None,
) -> None:
    """Open a recording in Rerun's native viewer, or with --web in the browser (served on 127.0.0.1); with --pair, a
    pair of a run folder, as inspect shows it."""
    from fviz import api

    if pair is not None:
        path, native = api.viewing.open_run_pair(path, pair, versus=versus, web=web, web_static=web_static, bind=bind,
                                                 port=port, web_port=web_port, tab=tab, shown=_shown)
    elif versus is not None:
        raise FvizError("--versus: only with --pair (a pair of PATH, a run folder, beside the same pair of --versus)")
    else:
        native = api.viewing.open_recording(path, web=web, web_static=web_static, bind=bind, port=port, web_port=web_port, tab=tab)
    if native:
        print(f"native viewer started on {path}")
        print(CLICK_HINT.format(path=path) if api.viewing.clickable(path) else NO_CLICKS)


def _shown(path: Path, result) -> None:
    """A run's pair, written: its recording, verdict and notes (before the viewer opens)."""
    print(f"{result.pair['name']}: {result.verdict.line}")
    print(f"recording: {path}", flush=True)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)



def summary(
    path: Recording,
    as_json: Annotated[bool, typer.Option("--json", help="Print the summary as JSON on stdout (NaN -> null).")] = False,
) -> None:
    """Print the pairs and metrics stored in a recording: one row per pair and estimator (no viewer)."""
    from rich.console import Console
    from rich.table import Table

    from fviz import api

    s = api.viewing.read_recording(path)
    if as_json:
        json.dump(s.to_dict(), sys.stdout, indent=2)
        sys.stdout.write("\n")
        return
    cols, other_times, items = api.viewing.summary_rows(s)
    t = Table(title=f"{path}  ({s.app_id}; {len(s.items)} item(s) on timeline {s.timeline or '-'}; "
                    f"blueprint {'stored' if s.has_blueprint else 'none'})")
    index_header = "#" if s.timeline in (None, "pair") else s.timeline
    t.add_column(index_header, justify="right")
    for name in other_times:
        t.add_column(f"{name} #", justify="right")
    t.add_column("pair", overflow="fold", min_width=12)
    t.add_column("estimator", overflow="fold")
    for c in cols:
        t.add_column(c, justify="right")
    if any(it.errors for it in s.items):
        t.add_column("error", overflow="fold", style="red")
    for rows in items:
        for k, row in enumerate(rows):
            t.add_row(*row, end_section=k == len(rows) - 1)
    console = Console()
    if not console.is_terminal:  # piped: never wrap or cut, whatever the width
        console = Console(width=max(Console(width=10_000).measure(t).maximum, 80))
    console.print(t)
    if not s.items:
        console.print(f"no pairs in {path} (entities: {', '.join(s.entity_paths) or 'none'})")
    elif len(cols) < len(s.metrics):
        console.print(f"{len(s.metrics) - len(cols)} more metrics per estimator: fviz summary {path} --json")


def register(app: typer.Typer) -> None:
    app.command("open")(open_recording)
    app.command("summary")(summary)
