"""``fviz inspect pair``: one pair, every estimator, one recording (and ``--json``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from fviz.cli import options as o
from fviz.cli.browse import UnusedPort, WebBind, WebPort


GT_SUFFIX = {"pose": "", "F": ".F-gt", "correspondences": ".gt-matches", "none": ".no-gt"}


def default_out(name: str, ground_truth: str = "pose") -> Path:
    """runs/<pair>.rrd, with the kind of ground truth when it is not a pose (runs/<pair>.no-gt.rrd, .F-gt, .gt-matches):
    the same pair inspected with and without ground truth keeps both recordings."""
    return Path("runs") / (name.replace("/", "_") + GT_SUFFIX.get(ground_truth, f".{ground_truth}") + ".rrd")


def pair(
    kitti_root: o.KittiRoot = None,
    sequence: o.Sequence_ = None,
    drive: o.Drive = None,
    frame: Annotated[int, typer.Option("--frame", help="Frame of image a.")] = 0,
    pair_kind: o.PairKind = "stereo",
    step: o.Step = 1,
    cams: o.Cams = None,
    estimator: o.Estimators = None,
    features: o.Features = "sift",
    max_keypoints: o.MaxKeypoints = 2000,
    ratio: o.Ratio = 0.8,
    mutual: o.Mutual = True,
    threshold: o.Threshold = "1.0",
    confidence: o.Confidence = 0.999,
    max_iters: o.MaxIters = 10000,
    seed: o.Seed = 0,
    norm: o.Norm = "fbn",
    eval_threshold: o.EvalThreshold = 2.0,
    estimator_timeout: o.EstimatorTimeout = 600.0,
    lines: Annotated[int, typer.Option("--lines", help="Epipolar lines drawn per F (a fixed random subset of matches).")] = 30,
    probe: Annotated[int, typer.Option("--probe", help="Steps of the probe timeline: the worst evaluation matches, one per step.")] = 20,
    probe_by: Annotated[Optional[str], typer.Option("--probe-by", help="Order the probe by this estimator's residual (default: the largest over the estimators), or by 'score': your matches' scores, lowest first.")] = None,
    out: Annotated[Optional[Path], typer.Option("--out", help="Recording to write, *.rrd (default runs/<pair>.rrd; "
                                                "runs/<pair>.no-gt.rrd without ground truth, .F-gt / .gt-matches by its kind).",
                                                callback=o.check_recording_path)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")] = False,
    spawn: Annotated[bool, typer.Option("--spawn", help="Open the native Rerun viewer on the recording.")] = False,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer on 127.0.0.1 (until Ctrl-C) and print its URL.")] = False,
    bind: WebBind = "127.0.0.1",
    port: UnusedPort = 9876,
    web_port: WebPort = 9090,
    synthetic: o.Synthetic = False,
    image_a: o.ImageA = None,
    image_b: o.ImageB = None,
    K: o.KBoth = None,
    K_a: o.KA = None,
    K_b: o.KB = None,
    T_ab: o.TAB = None,
    F_gt: o.FGT = None,
    pairs: o.PairsFile = None,
    images: o.ImagesDir = None,
    index: Annotated[Optional[int], typer.Option("--index", help="With --pairs / --colmap: the pair to inspect, from 0.")] = None,
    colmap: o.Colmap = None,
    min_shared: o.MinShared = 100,
    matches: o.MatchesFile = None,
    gt_matches: o.GtMatches = None,
) -> None:
    """Run estimators on one pair and record images, keypoints, epipolar lines, epipoles, residuals and metrics."""
    from fviz import api
    from fviz.errors import FvizError
    from fviz.estimators.registry import DEFAULT_ESTIMATORS
    from fviz.evaluate import MIN_MATCHES, too_few_matches

    from fviz.geometry import NORMS

    names, threshold = o.thresholds(tuple(estimator or DEFAULT_ESTIMATORS), threshold)
    if norm not in NORMS:
        raise FvizError(f"--norm {norm!r}: choose one of {', '.join(NORMS)}")
    if lines < 0:
        raise FvizError(f"--lines {lines}: must be >= 0")
    if probe < 0:
        raise FvizError(f"--probe {probe}: must be >= 0")
    if out is not None:
        from fviz.atomic import target

        target(out)  # a folder or special file as --out: refused before any work
    _check_viewer(spawn, web, bind, port, web_port)
    from fviz.estimators.options import EstimatorOptions

    # resolved once, before the pair is loaded (a deep model loads once; a bad name fails first)
    ests = EstimatorOptions(names, features, max_keypoints, ratio, mutual, threshold, confidence, max_iters, seed).estimators()
    p = api.load_pair(kitti_root, sequence=sequence, drive=drive, frame=frame, kind=pair_kind, step=step, cams=o.parse_cams(cams),
                      synthetic=synthetic, seed=seed, image_a=image_a, image_b=image_b, K=K, K_a=K_a, K_b=K_b, T_ab=T_ab,
                      F_gt=F_gt, pairs=pairs, images=images, index=index, colmap=colmap, min_shared=min_shared,
                      matches=matches, gt_matches=gt_matches)
    _check_probe_by(probe_by, p, ests, features)  # before the work, as every flag
    from fviz.run.prestart import import_in_background

    import_in_background("rerun")  # ~0.5 s: it loads while the features are computed (after the inputs are checked)
    result = api.inspect_pair(p, ests, features=features, max_keypoints=max_keypoints, ratio=ratio, mutual=mutual,
                              threshold=threshold, confidence=confidence, max_iters=max_iters, seed=seed, norm=norm,
                              eval_threshold=eval_threshold, timeout=estimator_timeout)
    path = api.save_recording(out or default_out(p.id.name, p.ground_truth), p, result, lines=lines, probe=probe, probe_by=probe_by)
    doc = result.to_dict()
    doc["recording"] = str(path)
    if as_json:
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print_table(result, path, result.verdict.line)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in result.errors:
        print(f"error: estimator {line}", file=sys.stderr)
    if spawn:
        from fviz.viewer import spawn_native

        spawn_native(path)
    if web:
        api.viewing.serve(path, bind, port, web_port, pair=p, result=result, lines=lines, probe=probe)
    if too_few_matches(result):
        raise FvizError(
            f"only {result.n_matches} matches between {p.extra.get('path_a', 'image a')} and "
            f"{p.extra.get('path_b', 'image b')} ({MIN_MATCHES} needed); recorded in {path}"
        )
    if result.errors:
        raise typer.Exit(1)


def _check_probe_by(probe_by: str | None, pair, ests, features: str) -> None:
    """--probe-by names an estimator of the run, the ground truth (when the pair has one) or 'score' (your
    matches' scores): checked once the pair is loaded, before the features and estimators run."""
    from fviz.errors import FvizError
    from fviz.estimators.sweep import ORACLE_SUFFIX
    from fviz.record.layout import GT
    from fviz.record.probe import PROBE_BY_SCORE

    if probe_by is None:
        return
    if probe_by == PROBE_BY_SCORE:  # scores: a user's matches' own, or a learned matcher's
        if (pair.matches is not None and pair.matches.scores is None) or (pair.matches is None and features in ("sift", "orb", "akaze")):
            raise FvizError(f"--probe-by {probe_by}: these matches have no scores (give --matches with the matcher's scores)")
        return
    names = [n for n, _ in ests if pair.has_gt or not n.endswith(ORACLE_SUFFIX)] + ([GT] if pair.has_gt else [])
    if probe_by not in names:
        raise FvizError(f"--probe-by {probe_by}: not an estimator of this pair ({', '.join(names)}; or score)")


def _check_viewer(spawn: bool, web: bool, bind: str, port: int, web_port: int) -> None:
    """What would stop the viewer later (no display, a busy port) is an error before any work."""
    from fviz.errors import FvizError
    from fviz.viewer import check_port_free, has_display

    if spawn and not has_display():
        raise FvizError("--spawn: no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset); use --web")
    if web:  # fviz's page serves on --web-port alone (--port is --web-static's, which inspect has not)
        check_port_free(bind, web_port, "--web-port")


# The table's columns: (metric, header). Headers short enough never to be cut (a pipe gives rich 80 columns);
# the caption says what each is.
TABLE_COLUMNS = (("sed_median", "SED px"), ("sampson_median", "Sampson px"), ("rot_err_deg", "rot °"),
                 ("trans_err_deg", "trans °"), ("nsgd", "NSGD"), ("inlier_ratio", "inliers"),
                 ("epipole_err_deg", "epipole °"), ("epi_abs", "EPI-ABS"), ("epi_sqr", "EPI-SQR"),
                 ("agreement_nsgd", "NSGD to closest"))
TABLE_CAPTION = ("SED / Sampson px: medians over the evaluation matches; rot / trans / epipole °: errors of the recovered "
                 "rotation, translation direction and epipole; NSGD: FM-Bench's normalized distance to F_gt; inliers: "
                 "share of all matches; time s: the estimator's run time. Every metric: --json.")


def _print_table(result, path: Path, verdict: str) -> None:
    from rich.console import Console
    from rich.table import Table

    cols = [(c, h) for c, h in TABLE_COLUMNS if any(c in r.metrics for r in result.estimators)]
    t = Table(title=f"{result.pair['name']}  ({result.n_matches} matches, {result.n_eval} for evaluation; "
                    f"EPI means under {result.norm.upper()})", caption=TABLE_CAPTION, caption_justify="left")
    t.add_column("estimator", no_wrap=True)
    for _, h in cols:
        t.add_column(h, justify="right", no_wrap=True, min_width=len(h))
    t.add_column("time s", justify="right", no_wrap=True, min_width=6)
    for r in result.estimators:
        if r.error:
            t.add_row(r.name, f"[red]failed: {r.error.splitlines()[0]}[/red]", *[""] * (len(cols) - 1), "")
        else:
            t.add_row(r.name, *(f"{r.metrics.get(c, float('nan')):.4g}" for c, _ in cols), f"{r.seconds:.3f}")
    console = Console(width=max(Console().width, 130))
    console.print(t)
    if not result.has_gt:
        from fviz.evaluate import agreement_text

        console.print("no ground truth: the estimators are compared with each other (SED and inliers over all "
                      f"matches; agreement_nsgd = NSGD to the closest other estimator): {agreement_text(result.agreement)}")
    from fviz.record.pair_text import precision_lines

    for line in precision_lines(result.match_precision)[1:]:
        console.print(line)
    console.print(f"verdict: {verdict}", markup=False)
    console.print(f"recording: {path}")


def register(app: typer.Typer) -> None:
    app.command("pair")(pair)
