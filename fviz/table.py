"""The paper's Table 1 from an ``fviz eval`` run: rows are network variants plus 8-point, LMedS, RANSAC
(and any other estimator) and Ground-truth; columns EPI-ABS and EPI-SQR under each normalization.

A network is trained with one normalization layer, so a variant's row takes its ETR, FBN and ABS
columns from the three checkpoints of that architecture and head trained with each norm (cells
without such a checkpoint stay empty). Classical estimators and the ground truth are normalized
each way. Values are means over pairs of the per-pair means (see :mod:`fviz.evaluate`).

Below it, the numbers a reviewer compares methods by (:func:`fviz.run.reports.standard_figures`): pose AUC,
NSGD recall, median SED / Sampson and failures per estimator; the oracle baseline is marked as such.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from pathlib import Path

from fviz.atomic import write_text
from fviz.errors import FvizError

NORMS = ("etr", "fbn", "abs")
CLASSICAL_LABELS = {"8point": "8-point", "lmeds": "LMedS", "ransac": "RANSAC", "7point": "7-point", "magsac": "MAGSAC++",
                    "ahead": "Straight ahead (cameras only)", "oracle-mean": "Mean GT F of the test pairs (oracle)",
                    "gt": "Ground-truth"}
HEAD_LABELS = {("base", False): "Base", ("base", True): "POS", ("epi", False): "EPI", ("epi", True): "EPI + POS",
               ("rec", False): "REC", ("rec", True): "REC + POS"}
ARCH_LABELS = {"single": "Single-stream", "siamese": "Siamese"}


# The paper's published Table 1 (Poursaeed et al.): (norm, method) -> (Siamese EPI-ABS, EPI-SQR, Single-stream
# EPI-ABS, EPI-SQR); the classical and ground-truth rows are the same in both halves. Method labels as in this table.
PAPER_TABLE1 = {
    ("etr", "Base"): (3.77, 27.16, 4.43, 34.34), ("etr", "POS"): (4.05, 21.90, 2.47, 9.79),
    ("etr", "EPI"): (0.52, 0.28, 1.00, 0.99), ("etr", "EPI + POS"): (0.88, 1.02, 1.00, 1.00),
    ("etr", "REC"): (0.56, 0.45, 0.99, 0.99), ("etr", "REC + POS"): (0.97, 0.98, 1.00, 0.99),
    ("etr", "8-point"): (1.91, 152.83) * 2, ("etr", "LMedS"): (1.09, 25.50) * 2, ("etr", "RANSAC"): (0.60, 3.85) * 2,
    ("etr", "Ground-truth"): (0.05, 0.004) * 2,
    ("fbn", "Base"): (1.44, 2.58, 2.45, 9.99), ("fbn", "POS"): (1.97, 5.66, 2.78, 8.55),
    ("fbn", "EPI"): (0.07, 0.01, 0.91, 0.91), ("fbn", "EPI + POS"): (0.06, 0.005, 0.67, 0.58),
    ("fbn", "REC"): (0.92, 1.11, 0.78, 1.24), ("fbn", "REC + POS"): (0.43, 0.44, 0.87, 0.81),
    ("fbn", "8-point"): (1.06, 11.7) * 2, ("fbn", "LMedS"): (0.39, 0.68) * 2, ("fbn", "RANSAC"): (0.27, 0.21) * 2,
    ("fbn", "Ground-truth"): (0.05, 0.004) * 2,
    ("abs", "Base"): (4.76, 30.63, 3.55, 18.04), ("abs", "POS"): (3.74, 22.59, 2.87, 10.4),
    ("abs", "EPI"): (0.18, 0.06, 0.92, 1.94), ("abs", "EPI + POS"): (0.12, 0.03, 0.82, 0.77),
    ("abs", "REC"): (0.22, 0.06, 0.77, 0.99), ("abs", "REC + POS"): (0.28, 0.10, 0.87, 0.81),
    ("abs", "8-point"): (1.17, 15.4) * 2, ("abs", "LMedS"): (0.72, 3.88) * 2, ("abs", "RANSAC"): (0.33, 0.39) * 2,
    ("abs", "Ground-truth"): (0.05, 0.004) * 2,
}


def paper_value(norm: str, label: str) -> tuple[float, float] | None:
    """The paper's (EPI-ABS, EPI-SQR) for a row label of :func:`table_from_rows` ("Siamese REC + POS", "RANSAC",
    "Ground-truth") under ``norm``; None where the paper has no such row (MAGSAC++, the constants)."""
    arch, _, head = label.partition(" ")
    if arch == "Single-stream" or arch == "Siamese":
        v = PAPER_TABLE1.get((norm, head))
        return None if v is None else (v[2:] if arch == "Single-stream" else v[:2])
    v = PAPER_TABLE1.get((norm, label))
    return None if v is None else v[:2]


def deep_variants(specs: list[str]) -> dict[str, dict]:
    """Display name -> parsed variant ({arch, head, pos, norm}) of every deep estimator spec."""
    from fviz.estimators.deep import bundled_weights
    from fviz.estimators.registry import display_names
    from fviz.models.model import parse_variant
    from fviz.models.weights import read_checkpoint

    out = {}
    for name, spec in zip(display_names(specs), specs):
        head, _, rest = spec.partition(":")
        if head != "deep":
            continue
        path = Path(rest) if rest else bundled_weights()
        config = read_checkpoint(path).get("model_config") or {}
        variant = "{arch}-{head}{pos}-{norm}".format(**{**config, "pos": "-pos" if config.get("pos") else ""})
        out[name] = parse_variant(variant)
    return out


def paper_table(run_dir: str | Path) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of Table 1 from ``run_dir/metrics.csv`` and ``run_dir/run.json``."""
    run_dir = Path(run_dir)
    csv_path, cfg_path = run_dir / "metrics.csv", run_dir / "run.json"
    for p in (csv_path, cfg_path):
        if not p.is_file():
            raise FvizError(f"{p}: missing (run fviz eval --out-dir {run_dir} first)")
    from fviz.run.store import read_config

    specs = list(read_config(run_dir).options.names)
    with open(csv_path, newline="") as f:
        return table_from_rows(_rows(f, csv_path), deep_variants(specs), str(csv_path))


def table_from_rows(rows, variants: dict[str, dict], source: str = "row") -> tuple[list[str], list[list[str]]]:
    """(header, rows) of Table 1 from per-pair, per-estimator rows (metrics.csv's, or
    :meth:`fviz.evaluate.PairResult.rows`); ``variants``: display name -> parsed variant of the deep ones.
    A value that is not a number is a one-line error naming ``source``:line and the column."""
    from fviz.run.config import csv_number

    sums: dict[tuple[str, str], list[float]] = defaultdict(list)
    order: dict[str, None] = {}
    for line, row in enumerate(rows, 2):
        est = row["estimator"]
        if row.get("error"):
            continue
        if est in variants:
            v = variants[est]
            label = f"{ARCH_LABELS[v['arch']]} {HEAD_LABELS[(v['head'], v['pos'])]}"
            cells = [v["norm"]]
        else:
            label = CLASSICAL_LABELS.get(est) or (f"Mean GT F of {est[5:]}" if est.startswith("mean-") else est)
            cells = list(NORMS)
        order[label] = None
        for n in cells:
            for m in ("abs", "sqr"):
                x = csv_number(row, f"epi_{m}_{n}", f"{source}:{line}")
                if math.isfinite(x):
                    sums[(label, f"{m}_{n}")].append(x)
    gt = CLASSICAL_LABELS["gt"]
    labels = [lbl for lbl in order if lbl != gt] + ([gt] if gt in order else [])
    header = ["Method"] + [f"{n.upper()} EPI-{m.upper()}" for n in NORMS for m in ("abs", "sqr")]
    table = []
    for lbl in labels:
        vals = [sums.get((lbl, f"{m}_{n}"), []) for n in NORMS for m in ("abs", "sqr")]
        table.append([lbl] + [f"{sum(v) / len(v):.4g}" if v else "" for v in vals])
    return header, table


def run_figures(run_dir: Path) -> dict[str, dict]:
    """The standard figures of a run, from its metrics.csv."""
    from fviz.run.reports import FIGURE_KEYS, figures_known, row_failed, row_kind, standard_figures

    from fviz.run.config import csv_number

    per_pair: dict[str, list[float]] = {}
    pair_gt: dict[str, list[str]] = {}
    failures: dict[str, int] = {}
    ground_truth: set[str] = set()
    path = run_dir / "metrics.csv"
    with open(path, newline="") as f:
        for line, row in enumerate(_rows(f, path), 2):
            ground_truth.update([row["ground_truth"]] if row.get("ground_truth") else [])
            failed = row_failed(row["estimator"], row.get("error"), row.get("pair_error"))
            failures[row["estimator"]] = failures.get(row["estimator"], 0) + failed
            per_pair.setdefault(row["estimator"], []).extend(
                math.nan if failed else csv_number(row, k, f"{path}:{line}") for k in FIGURE_KEYS)
            pair_gt.setdefault(row["estimator"], []).append(row_kind(row["estimator"], row, failed))
    return standard_figures(per_pair, known=figures_known(ground_truth), pair_gt=pair_gt, failures=failures)


def _rows(f, path: Path):
    """The rows of a metrics.csv, refused when it has no header with an ``estimator`` column or no row."""
    reader = csv.DictReader(f)
    if "estimator" not in (reader.fieldnames or []):
        raise FvizError(f"{path}: not an fviz metrics.csv (no 'estimator' column)")
    n = 0
    for row in reader:
        n += 1
        yield row
    if n == 0:
        raise FvizError(f"{path}: no rows (the run evaluated no pair)")


def write_table(run_dir: str | Path) -> tuple[Path, Path]:
    """table.md and table.csv in the run folder."""
    from fviz.run.reports import EPI_CAVEAT, figures_markdown

    run_dir = Path(run_dir)
    header, rows = paper_table(run_dir)
    md = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"] + ["| " + " | ".join(r) + " |" for r in rows]
    note = ("\nEPI-ABS = mean |x_b^T F x_a|, EPI-SQR = mean (x_b^T F x_a)^2 per pair over matches whose ground-truth "
            "symmetric epipolar distance is below the run's threshold, then averaged over pairs; F normalized by the "
            "column's norm (ETR: F33, FBN: Frobenius, ABS: max |entry|). Empty: undefined (ETR with F33 = 0) or no model.\n\n"
            + EPI_CAVEAT + "\n")
    figures = ["", "## Standard figures", "", *figures_markdown(run_figures(run_dir))]
    md_path, csv_path = run_dir / "table.md", run_dir / "table.csv"
    lines = [",".join(header)] + [",".join(f'"{c}"' if "," in c else c for c in r) for r in rows]
    from fviz.atomic import owning

    with owning(run_dir):  # a table.md planted as a link to a file outside the run is never written through
        write_text(md_path, "\n".join(md) + "\n" + note + "\n".join(figures) + "\n")
        write_text(csv_path, "\n".join(lines) + "\n")
    return md_path, csv_path
