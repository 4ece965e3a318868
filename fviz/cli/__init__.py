"""The ``fviz`` command line. Each command lives in its own module and registers itself here.

Only typer is imported at start-up (its plain help, not rich's): numpy, OpenCV, torch and rerun are
imported inside the commands, so ``fviz --help`` stays instant. A :class:`fviz.errors.FvizError` becomes
one line on stderr and exit 2; Ctrl-C one line saying what was kept, exit 130 (Typer would otherwise exit
130 silently).
"""

from __future__ import annotations

import functools
import importlib
import sys

import typer

app = typer.Typer(
    name="fviz",
    help="Visual debugging of fundamental-matrix estimation on KITTI, recorded with Rerun.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
    rich_markup_mode=None,  # click's plain help: typer's rich help imports rich, markdown-it and pygments (~0.15 s)
)
inspect_app = typer.Typer(help="Inspect one item (a pair) and write a Rerun recording.", no_args_is_help=True,
                          rich_markup_mode=None)
app.add_typer(inspect_app, name="inspect")

@app.callback()
def _root(debug: bool = typer.Option(False, "--debug", help="Keep the traceback of an estimator that raises "
                                                             "(in its error: stderr, JSON, results.jsonl).")) -> None:
    if debug:
        import os

        os.environ["FVIZ_DEBUG"] = "1"  # the workers of eval inherit it


# Modules with a ``register(app)`` function; a missing optional module is skipped.
COMMAND_MODULES = ("inspect", "eval", "triage", "browse", "train", "table")


def _register_all() -> None:
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"fviz.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"fviz.cli.{name}":
                continue
            raise
        module.register(app if name != "inspect" else inspect_app)


# Said when Ctrl-C reaches the entry point: no command that got that far has anything half-written in place.
INTERRUPTED = "nothing half-written was kept: a file being written was discarded, files already there are unchanged"


def _interruptible(callback):
    """``callback`` with Ctrl-C turned into :class:`fviz.errors.Interrupted` (which Typer lets through), run as the
    command line (:func:`fviz.errors.command_line`: errors name its flags)."""

    @functools.wraps(callback)
    def run(*args, **kwargs):
        from fviz.errors import command_line

        try:
            with command_line():  # fviz.api's errors name the flags
                return callback(*args, **kwargs)
        except KeyboardInterrupt:
            from fviz.errors import Interrupted

            raise Interrupted(INTERRUPTED) from None

    return run


_register_all()
for _typer in (app, inspect_app):
    for _info in _typer.registered_commands:
        _info.callback = _interruptible(_info.callback)


def command_hint(argv: list[str]) -> str | None:
    """A one-line error for a command line click would answer with "No such option": ``fviz inspect --kitti-root ...``
    (the subcommand ``pair`` forgotten) gets "did you mean `fviz inspect pair ...`"."""
    import shlex

    args = [a for a in argv if a != "--debug"]
    if len(args) >= 2 and args[0] == "inspect" and args[1].startswith("-") and args[1] not in ("--help", "-h"):
        flag = args[1].split("=", 1)[0]
        return (f"fviz inspect: no such option {flag}: did you mean `fviz inspect pair {shlex.join(args[1:])}`? "
                "(inspect takes what to inspect first: pair)")
    return None


def main() -> None:
    """The command line (the workers of eval / triage are started before it by :func:`fviz.entry.main`)."""
    from fviz.errors import FvizError, Interrupted

    if (hint := command_hint(sys.argv[1:])) is not None:
        print(f"error: {hint}", file=sys.stderr)
        sys.exit(2)
    try:
        app()
    except FvizError as exc:
        print(f"{'interrupted' if isinstance(exc, Interrupted) else 'error'}: {exc}", file=sys.stderr)
        sys.exit(exc.exit_code)
    except KeyboardInterrupt:  # outside any command (argument parsing, start-up)
        print(f"interrupted: {INTERRUPTED}", file=sys.stderr)
        sys.exit(130)
