"""The ``fviz`` executable (and ``python -m fviz``): the workers of ``eval`` / ``triage`` start before the
command line itself is imported (typer and the commands, ~0.25 s), so that their imports overlap it."""

from __future__ import annotations

import sys


def main() -> None:
    import gc

    from fviz.run.prestart import prestart, take

    prestart(sys.argv[1:])  # eval / triage: workers import while the options are parsed
    from fviz.cli import main as cli_main

    try:
        cli_main()
    finally:  # workers no run took (--help, a bad flag): they ignore SIGTERM, so multiprocessing could not end them;
        take(0)
        gc.freeze()  # the exit's last collection would walk every object numpy, rerun and pyarrow made (~0.15 s) to free nothing
