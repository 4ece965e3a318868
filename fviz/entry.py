"""The ``fviz`` executable (and ``python -m fviz``): the workers of ``eval`` / ``triage`` start before the
command line itself is imported (typer and the commands, ~0.25 s), so that their imports overlap it."""

from __future__ import annotations

import sys


def main() -> None:
    from fviz.prestart import prestart

    prestart(sys.argv[1:])
    from fviz.cli import main as cli_main

    cli_main()
