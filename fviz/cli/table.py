"""``fviz table RUN_DIR``: the paper's Table 1 (Markdown and CSV) from an ``fviz eval`` run."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer


def table(run_dir: Optional[Path] = typer.Argument(None, metavar="RUN", help="An fviz eval --out-dir (with metrics.csv and run.json).",
                                                   show_default=False),
          out_dir: Optional[Path] = typer.Option(None, "--out-dir", help="The run folder, as eval / triage / compare take it "
                                                                         "(the same as RUN).")) -> None:
    """The paper's Table 1 from an eval run: table.md and table.csv.

    Rows: network variants (one per architecture and head; the norm a checkpoint was trained with picks its
    columns), 8-point, LMedS, RANSAC, other estimators, Ground-truth. Columns: EPI-ABS / EPI-SQR per norm.
    EPI values depend on the norm and on the pairs; under ETR the Ground-truth row can be the worst (F / F33
    blows up where the true F33 is near 0). On a KITTI raw drive, also Table 1 in the paper's frame with the
    paper's filter (reading A: the unrectified cameras; B: their F on the rectified pixels), as
    benchmarks/paper_table1.py prints it, and table_frames.csv; elsewhere it says why not. Below: pose AUC, NSGD
    recall, median SED / Sampson per estimator.

    Example: fviz eval --synthetic --seeds 0:500 -e 8point -e lmeds -e ransac -e deep:runs/a/model.pt ...
    --out-dir runs/t && fviz table runs/t
    """
    from fviz import api
    from fviz.cli.triage import one_run_folder
    from fviz.errors import FvizError

    run_dir = one_run_folder(run_dir, out_dir)
    if run_dir is None:
        raise FvizError("table: give the run folder, as RUN or --out-dir RUN")
    md, csv_path = api.run_table(run_dir)
    print(md.read_text(), end="")
    print(f"written: {md} {csv_path}")


def register(app: typer.Typer) -> None:
    app.command("table")(table)
