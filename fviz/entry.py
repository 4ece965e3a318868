"""The ``fviz`` executable (and ``python -m fviz``): the workers of ``eval`` / ``triage`` start before the
command line itself is imported (typer and the commands, ~0.25 s), so that their imports overlap it."""

from __future__ import annotations

import sys


def main() -> None:
    import gc

    from fviz.run.prestart import prestart

    prestart(sys.argv[1:])
    from fviz.cli import main as cli_main

    try:
        cli_main()
    finally:  # the exit's last collection would walk every object numpy, rerun and pyarrow made (~0.15 s) to free nothing
        gc.freeze()
