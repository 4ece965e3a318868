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

    names, threshold = o.thresholds(tuple(estimator or api.DEFAULT_ESTIMATORS), threshold)
    api.inspecting.check_flags(norm, lines, probe, out)
    api.viewing.check_viewer(spawn, web, bind, web_port)
    # resolved once, before the pair is loaded (a deep model loads once; a bad name fails first)
    ests = api.inspecting.estimators(names, features, max_keypoints, ratio, mutual, threshold, confidence, max_iters, seed)
    p = api.load_pair(kitti_root, sequence=sequence, drive=drive, frame=frame, kind=pair_kind, step=step, cams=o.parse_cams(cams),
                      synthetic=synthetic, seed=seed, image_a=image_a, image_b=image_b, K=K, K_a=K_a, K_b=K_b, T_ab=T_ab,
                      F_gt=F_gt, pairs=pairs, images=images, index=index, colmap=colmap, min_shared=min_shared,
                      matches=matches, gt_matches=gt_matches)
    api.inspecting.check_probe_by(probe_by, p, ests, features)  # before the work, as every flag
    api.inspecting.prestart_rerun()  # it loads while the features are computed (after the inputs are checked)
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
        _print_table(api.inspecting.table(result), path, result.verdict.line)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in result.errors:
        print(f"error: estimator {line}", file=sys.stderr)
    if spawn:
        api.viewing.spawn(path)
    if web:
        api.viewing.serve(path, bind, port, web_port, pair=p, result=result, lines=lines, probe=probe)
    api.inspecting.check_enough_matches(p, result, path)
    if result.errors:
        raise typer.Exit(1)


def _print_table(table, path: Path, verdict: str) -> None:
    """inspect's table (:func:`fviz.api.inspecting.table`), its notes, the verdict and the recording."""
    from rich.console import Console
    from rich.table import Table

    t = Table(title=table.title, caption=table.caption, caption_justify="left")
    t.add_column("estimator", no_wrap=True)
    for h in table.headers:
        t.add_column(h, justify="right", no_wrap=True, min_width=len(h))
    t.add_column("time s", justify="right", no_wrap=True, min_width=6)
    for row in table.rows:
        t.add_row(*row)
    console = Console(width=max(Console().width, 130))
    console.print(t)
    for line in table.notes:
        console.print(line)
    console.print(f"verdict: {verdict}", markup=False)
    console.print(f"recording: {path}")


def register(app: typer.Typer) -> None:
    app.command("pair")(pair)
