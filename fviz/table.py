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
from fviz.stats import fmt

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


# Where Table 1 is read besides the run's own frame (issue 43): key -> (column title, rows_in_frame's reading, rule).
# The paper's F is built from the *unrectified* cameras (calib_cam_to_cam.txt) and its filter keeps the matches whose
# sum of squared epipolar distances to it is below 2 px^2 ("within about one pixel"); which pixels it was scored
# on is not stated, hence two readings (A: the unrectified cameras' pixels; B: the rectified images' own pixels).
FRAME_READINGS = {
    "unrectified": ("A: unrectified frame, paper's filter", "unrectified", "paper"),
    "rectified-pixels": ("B: rectified pixels, unrectified GT, paper's filter", "rectified-pixels", "paper"),
    "unrectified-fviz": ("A, fviz's filter", "unrectified", "fviz"),
}
RECTIFIED_TITLE = "rectified (fviz's frame and filter)"
FRAMES_NOTE = (
    "Readings. The paper's ground truth is the F of the *unrectified* cameras of `calib_cam_to_cam.txt` (K_0x, R_0x, "
    "T_0x; 1392 x 512, distortion left out), where F33 carries most of ||F|| (so ETR is defined and the three norms "
    "nearly agree, as its ground-truth row does); fviz reads the *rectified* images (1242 x 375), whose F has F33 = 0. "
    "**A** maps every F (estimates, constants, networks, ground truth) and every match into the unrectified cameras "
    "(H = K R_rect^T P_rect[:, :3]^-1 per camera) and scores there: the paper's protocol done right. **B** scores the "
    "unrectified cameras' F on the rectified images' pixels, where it does not describe the images, and every "
    "estimate as estimated (rectified pixels): the paper's protocol if its ground truth and its images came from "
    "different frames. Both keep the paper's filter (the sum of the two squared epipolar distances to the ground truth "
    "< 2 px^2); *A, fviz's filter* and the rectified column keep fviz's (their mean < 2 px). Which reading the paper "
    "used is an inference from its figures, not stated by it (docs/training.md). **÷ GT**: a row over the "
    "ground-truth row of its column. Means over pairs of the per-pair means.")


def paper_layout_markdown(rectified: dict[str, list[str]], frames: dict[str, dict[str, list[str]]],
                          n_eval: dict[str, float] | None = None) -> list[str]:
    """Table 1 in the paper's layout (a block per norm): each row with the paper's figures, fviz's under each
    reading of :data:`FRAME_READINGS` present in ``frames`` ({key: {label: table_from_rows row}}), in the rectified
    frame (``rectified``), and the ratios to the ground-truth row (paper, A, B). ``n_eval``: mean evaluation matches
    a pair per column key ("rectified" too), printed below. Network rows the paper has and the run lacks show the
    paper's figures only."""
    gt = CLASSICAL_LABELS["gt"]
    archs = {label.partition(" ")[0] for label in rectified if label.startswith(("Siamese ", "Single-stream "))} or {"Siamese"}
    paper_only = [f"{a} {h}" for a in sorted(archs) for h in HEAD_LABELS.values() if f"{a} {h}" not in rectified]
    labels = [lbl for lbl in rectified if lbl != gt] + paper_only + [gt]
    keys = [k for k in FRAME_READINGS if k in frames]
    ratio_keys = [k for k in ("unrectified", "rectified-pixels") if k in frames]
    md = ["| Norm | Method | paper ABS / SQR | " + " | ".join(f"{FRAME_READINGS[k][0]} ABS / SQR" for k in keys)
          + f" | {RECTIFIED_TITLE} ABS / SQR | ÷ GT, paper | " + " | ".join(f"÷ GT, {FRAME_READINGS[k][0][0]}" for k in ratio_keys)
          + " |", "|---" * (5 + len(keys) + len(ratio_keys)) + "|"]
    ratio = lambda v, g: _cell([a / b if a is not None and b else None for a, b in zip(v, g)]) if v else "—"  # noqa: E731
    for norm in NORMS:
        for label in labels:
            p, r = paper_value(norm, label), _pair_cells(rectified.get(label), norm)
            fs = {k: _pair_cells(frames[k].get(label), norm) for k in keys}
            net = label.startswith(("Siamese ", "Single-stream "))  # an empty network cell: no model of that norm
            rect = "undefined" if norm == "etr" and not net and r == (None, None) else _cell(r)
            undefined = lambda k: (norm == "etr" and not net and label in frames[k] and fs[k] == (None, None))  # noqa: E731
            cells = [_cell(p) if p else "—", *("undefined" if undefined(k) else _cell(fs[k]) for k in keys),
                     rect if label in rectified else "",
                     ratio(p, paper_value(norm, gt))]
            cells += [ratio(fs[k] if label in frames[k] else None, _pair_cells(frames[k].get(gt), norm)) for k in ratio_keys]
            md.append(f"| {norm.upper()} | {label} | " + " | ".join(cells) + " |")
    if n_eval:
        titles = {**{k: v[0] for k, v in FRAME_READINGS.items()}, "rectified": RECTIFIED_TITLE}
        md += ["", "Evaluation matches a pair (mean): " + "; ".join(f"{titles[k]} {v:.0f}" for k, v in n_eval.items() if k in titles) + "."]
    return md


def _cell(v) -> str:
    """'ABS / SQR', empty when neither is known."""
    return "" if not v or all(x is None for x in v) else " / ".join(fmt(x, 3, "") for x in v)


def _pair_cells(cells: list[str] | None, norm: str) -> tuple[float | None, float | None]:
    """(EPI-ABS, EPI-SQR) under ``norm`` of a :func:`table_from_rows` row, None where empty."""
    if cells is None:
        return None, None
    i = 1 + 2 * NORMS.index(norm)
    return tuple(float(c) if c else None for c in cells[i:i + 2])  # type: ignore[return-value]


def frame_rows(result, H_a, H_b) -> dict[str, list[dict]]:
    """{reading key: :func:`fviz.evaluate.rows_in_frame` rows} of one pair under every :data:`FRAME_READINGS`."""
    from fviz.evaluate import rows_in_frame

    return {k: rows_in_frame(result, H_a, H_b, rule=rule, reading=reading) for k, (_, reading, rule) in FRAME_READINGS.items()}


def mean_n_eval(rows) -> float:
    """Mean evaluation matches a pair (the ground truth's rows)."""
    n = [float(r["n_eval"]) for r in rows if r["estimator"] == "gt" and not r.get("error")]
    return sum(n) / len(n) if n else math.nan


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


def paper_frame_rows(run_dir: Path) -> tuple[dict[str, list[dict]], str]:
    """({reading key: rows} of every pair of the run with ground truth, "") where the run's calibration has the
    unrectified cameras (a KITTI raw drive's ``calib_cam_to_cam.txt``), else ({}, why not). The pairs' matches come
    back from the run's feature cache (matches.h5; detected again where it has none), their F from results.jsonl."""
    from dataclasses import fields

    from fviz.data.kitti import raw_cameras
    from fviz.data.pair import PairId
    from fviz.estimators.features import FeatureCache, user_matches
    from fviz.run.hloc_cache import RunCache, digest
    from fviz.run.store import ResultStore, read_config, result_from_record

    config = read_config(run_dir)
    source = config.selection.source()
    ds = getattr(source, "ds", None)
    if ds is None or ds.source != "raw":
        where = (f"odometry sequence {ds.name}: its calib.txt holds only the rectified projections P0..P3" if ds is not None
                 else "pairs that are not a KITTI raw drive's")
        return {}, (f"rectified frame only: the paper's frame needs the unrectified cameras of a KITTI raw drive's "
                    f"calib_cam_to_cam.txt (K_0x, R_0x, T_0x, R_rect_0x, P_rect_0x); this run has {where}")
    try:
        cams = raw_cameras(ds.calib_path)
    except FvizError as e:
        return {}, f"rectified frame only: {e}"
    cfg = config.options.feature_config()
    cache, disk = FeatureCache(cfg, threads=1, fingerprint=digest), RunCache(run_dir, cfg)
    known = {f.name for f in fields(PairId)}
    out: dict[str, list[dict]] = {k: [] for k in FRAME_READINGS}
    missing = set()
    for rec in ResultStore(run_dir, config).records():
        result = result_from_record(rec, config)
        pid = PairId(**{k: v for k, v in rec["ref"].items() if k in known})
        if rec.get("result") is None or result.F_gt is None:
            continue
        if pid.cam_a not in cams or pid.cam_b not in cams:
            missing.update({pid.cam_a, pid.cam_b} - set(cams))
            continue
        pair = source.load(pid)
        if pair.matches is not None:
            result.matches = user_matches(pair.matches)
        else:
            matcher = disk.prepare(pair, cache)
            result.matches = matcher(*cache.get_pair(pid.key_a, lambda: pair.image_a, pid.key_b, lambda: pair.image_b))
            cache.clear()
        for k, rows in frame_rows(result, cams[pid.cam_a].H, cams[pid.cam_b].H).items():
            out[k] += [{**r, "error": r["error"] or rec["error"] or ""} for r in rows]
    if not out["unrectified"]:
        why = f" (cameras {sorted(missing)} are not in {ds.calib_path})" if missing else ""
        return {}, f"rectified frame only: no pair of the run has ground truth and matches to map{why}"
    return out, ""


def _frames_section(run_dir: Path, rectified: dict[str, list[str]], header: list[str]) -> tuple[list[str], list[str]]:
    """(table.md's section on the paper's frame, table_frames.csv's lines: empty where the calibration has no
    unrectified cameras, the section then says why)."""
    try:
        frames, why = paper_frame_rows(run_dir)
    except (FvizError, OSError) as e:  # the run's data moved or changed: the run's own table still stands
        frames, why = {}, f"the paper's frame not computed: {' '.join(str(e).split())}"
    md = ["", "## Table 1 in the paper's frame", ""]
    if not frames:
        return md + [why + "."], []
    from fviz.run.store import read_config

    variants = deep_variants(list(read_config(run_dir).options.names))
    tables = {k: {r[0]: r for r in table_from_rows(rows, variants, k)[1]} for k, rows in frames.items()}
    n_eval = {k: mean_n_eval(rows) for k, rows in frames.items()}
    path = run_dir / "metrics.csv"
    with open(path, newline="") as f:
        n_eval["rectified"] = mean_n_eval(_rows(f, path))
    md += paper_layout_markdown(rectified, tables, n_eval) + ["", FRAMES_NOTE, "",
                                                             "Every reading's cells: table_frames.csv (`reading` column)."]
    lines = [",".join(["reading", *header])]
    for k, table in [*tables.items(), ("rectified", rectified)]:
        lines += [",".join([k, *(f'"{c}"' if "," in c else c for c in r)]) for r in table.values()]
    return md, lines


def write_table(run_dir: str | Path) -> tuple[Path, Path]:
    """table.md and table.csv in the run folder; on a KITTI raw drive, table.md also has Table 1 in the paper's
    frame under each reading (:data:`FRAME_READINGS`), and table_frames.csv its cells; elsewhere table.md says why
    not."""
    from fviz.run.reports import EPI_CAVEAT, figures_markdown

    run_dir = Path(run_dir)
    header, rows = paper_table(run_dir)
    md = ["| " + " | ".join(header) + " |", "|---" * len(header) + "|"] + ["| " + " | ".join(r) + " |" for r in rows]
    note = ("\nEPI-ABS = mean |x_b^T F x_a|, EPI-SQR = mean (x_b^T F x_a)^2 per pair over matches whose ground-truth "
            "symmetric epipolar distance is below the run's threshold, then averaged over pairs; F normalized by the "
            "column's norm (ETR: F33, FBN: Frobenius, ABS: max |entry|). Empty: undefined (ETR with F33 = 0) or no model.\n\n"
            + EPI_CAVEAT + "\n")
    frames, frame_lines = _frames_section(run_dir, {r[0]: r for r in rows}, header)
    figures = ["", "## Standard figures", "", *figures_markdown(run_figures(run_dir))]
    md_path, csv_path = run_dir / "table.md", run_dir / "table.csv"
    lines = [",".join(header)] + [",".join(f'"{c}"' if "," in c else c for c in r) for r in rows]
    from fviz.atomic import owning

    with owning(run_dir):  # a table.md planted as a link to a file outside the run is never written through
        write_text(md_path, "\n".join(md) + "\n" + note + "\n".join(frames + figures) + "\n")
        write_text(csv_path, "\n".join(lines) + "\n")
        if frame_lines:
            write_text(run_dir / "table_frames.csv", "\n".join(frame_lines) + "\n")
    return md_path, csv_path
