"""``fviz inspect pair``: one pair, every estimator, one recording (and ``--json``)."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Annotated, Optional

import typer

from fviz.cli import options as o
from fviz.cli.browse import Port, WebBind, WebPort


def load_pair(kitti_root, sequence, drive, frame, pair_kind, step, cams, synthetic: bool, seed: int, user: dict | None = None):
    """The selected pair: a user's (two images, a pairs file, a COLMAP model: ``user`` holds those flags),
    KITTI or synthetic; with the user's matches and ground-truth correspondences attached."""
    user = user or {}
    p = _user_pair(user, frame)
    if p is None:
        p = _kitti_or_synthetic(kitti_root, sequence, drive, frame, pair_kind, step, cams, synthetic, seed)
    if user.get("matches") or user.get("gt_matches"):
        from fviz.data.sources import WithCorrespondences, attach

        given = WithCorrespondences(None, user.get("matches"), user.get("gt_matches"), n_pairs=1)
        p = attach(p, given.matches, given.gt_matches)
    return p


def _user_pair(user: dict, frame: int):
    """The pair of --image-a/--image-b, or line --index of --pairs, or pair --index of --colmap; else None."""
    from fviz.errors import FvizError

    images = user.get("image_a") is not None or user.get("image_b") is not None
    listed = user.get("pairs") is not None or user.get("colmap") is not None
    names = None
    if images and listed:  # the pair of a list, by its images' names
        if user.get("image_a") is None or user.get("image_b") is None or user.get("index") is not None:
            raise FvizError("--pairs/--colmap: pick a pair by --index N or by both names (--image-a NAME --image-b NAME)")
        names, images = (str(user["image_a"]), str(user["image_b"])), False
    gt_flags = [f for f, k in (("--K", "K"), ("--K-a", "K_a"), ("--K-b", "K_b"), ("--T-ab", "T_ab"), ("--F-gt", "F_gt")) if user.get(k)]
    if gt_flags and (not images or names):
        raise FvizError(f"{gt_flags[0]}: only with --image-a and --image-b (a pairs file or model has its own ground truth)")
    if images:
        if user.get("image_a") is None or user.get("image_b") is None:
            raise FvizError(f"--image-{'a' if user.get('image_a') is None else 'b'}: missing (give both images)")
        from fviz.data.images import two_images

        return two_images(str(user["image_a"]), str(user["image_b"]), user.get("K"), user.get("K_a"), user.get("K_b"),
                          user.get("T_ab"), user.get("F_gt"))
    if not listed:
        if user.get("index") is not None:
            raise FvizError("--index: only with --pairs or --colmap")
        return None
    from fviz.data.sources import user_source

    source = user_source(user.get("pairs"), user.get("images"), user.get("colmap"), user.get("min_shared"))
    index = source.index_of(user.get("index"), names)
    return source.load(source.pair_id(index))


def _kitti_or_synthetic(kitti_root, sequence, drive, frame, pair_kind, step, cams, synthetic: bool, seed: int):
    if synthetic:
        from fviz.data.synthetic import SceneConfig, synthetic_pair

        return synthetic_pair(seed, SceneConfig(stereo=pair_kind == "stereo"))
    from fviz.data.kitti import open_dataset

    ds = open_dataset(o.kitti_root(kitti_root), sequence, drive)
    return ds.pair(frame, pair_kind, step, o.parse_cams(cams))


def default_out(name: str) -> Path:
    return Path("runs") / (name.replace("/", "_") + ".rrd")


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
    out: Annotated[Optional[Path], typer.Option("--out", help="Recording to write, *.rrd (default runs/<pair>.rrd).",
                                                callback=o.check_recording_path)] = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result as JSON on stdout.")] = False,
    spawn: Annotated[bool, typer.Option("--spawn", help="Open the native Rerun viewer on the recording.")] = False,
    web: Annotated[bool, typer.Option("--web", help="Serve the web viewer on 127.0.0.1 (until Ctrl-C) and print its URL.")] = False,
    bind: WebBind = "127.0.0.1",
    port: Port = 9876,
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
    import threading

    # rerun takes ~0.5 s to import: let it load while the features are computed.
    threading.Thread(target=__import__, args=("rerun",), daemon=True).start()
    from fviz.errors import FvizError
    from fviz.estimators.options import EstimatorOptions
    from fviz.estimators.registry import DEFAULT_ESTIMATORS
    from fviz.evaluate import MIN_MATCHES, evaluate_pair, too_few_matches
    from fviz.record.writer import write_pair_recording

    names, threshold = o.thresholds(tuple(estimator or DEFAULT_ESTIMATORS), threshold)
    opts = EstimatorOptions(names, features, max_keypoints, ratio, mutual, threshold, confidence, max_iters, seed)
    if lines < 0:
        raise FvizError(f"--lines {lines}: must be >= 0")
    if probe < 0:
        raise FvizError(f"--probe {probe}: must be >= 0")
    if out is not None:
        from fviz.atomic import target

        target(out)  # a folder or special file as --out: refused before any work
    _check_viewer(spawn, web, bind, port, web_port)
    ests = opts.estimators()
    user = dict(image_a=image_a, image_b=image_b, K=K, K_a=K_a, K_b=K_b, T_ab=T_ab, F_gt=F_gt, pairs=pairs, images=images,
                index=index, colmap=colmap, min_shared=min_shared, matches=matches, gt_matches=gt_matches)
    p = load_pair(kitti_root, sequence, drive, frame, pair_kind, step, cams, synthetic, seed, user)
    from fviz.estimators.base import missing_K

    if (why := next((w for n, fn in ests if (w := missing_K(n, fn, p))), None)) is not None:
        raise FvizError(why)
    result = evaluate_pair(p, ests, opts.feature_config(), norm, eval_threshold, threshold, timeout=estimator_timeout)
    from fviz.diagnose import gt_suspect_note

    if (note := gt_suspect_note(p, result)) is not None:
        result.notes.insert(0, note)
    path = write_pair_recording(out or default_out(p.id.name), p, result, lines, probe, probe_by)
    doc = result.to_dict()
    doc["recording"] = str(path)
    if as_json:
        json.dump(doc, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        _print_table(result, path)
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for line in result.errors:
        print(f"error: estimator {line}", file=sys.stderr)
    if spawn:
        from fviz.viewer import spawn_native

        spawn_native(path)
    if web:
        from fviz.cli.browse import serve

        serve(path, bind, port, web_port)
    if too_few_matches(result):
        raise FvizError(
            f"only {result.n_matches} matches between {p.extra.get('path_a', 'image a')} and "
            f"{p.extra.get('path_b', 'image b')} ({MIN_MATCHES} needed); recorded in {path}"
        )
    if result.errors:
        raise typer.Exit(1)


def _check_viewer(spawn: bool, web: bool, bind: str, port: int, web_port: int) -> None:
    """What would stop the viewer later (no display, a busy port) is an error before any work."""
    from fviz.errors import FvizError
    from fviz.viewer import check_port_free, has_display

    if spawn and not has_display():
        raise FvizError("--spawn: no display for the native viewer (DISPLAY and WAYLAND_DISPLAY are unset); use --web")
    if web:
        if port == web_port:
            raise FvizError(f"--port and --web-port are both {port}: they need two ports")
        check_port_free(bind, port, "--port")
        check_port_free(bind, web_port, "--web-port")


# The table's columns: (metric, header). Headers short enough never to be cut (a pipe gives rich 80 columns);
# the caption says what each is.
TABLE_COLUMNS = (("sed_median", "SED px"), ("sampson_median", "Sampson px"), ("rot_err_deg", "rot °"),
                 ("trans_err_deg", "trans °"), ("nsgd", "NSGD"), ("inlier_ratio", "inliers"),
                 ("epipole_err_deg", "epipole °"), ("epi_abs", "EPI-ABS"), ("epi_sqr", "EPI-SQR"),
                 ("agreement_nsgd", "NSGD to others"))
TABLE_CAPTION = ("SED / Sampson px: medians over the evaluation matches; rot / trans / epipole °: errors of the recovered "
                 "rotation, translation direction and epipole; NSGD: FM-Bench's normalized distance to F_gt; inliers: "
                 "share of all matches; time s: the estimator's run time. Every metric: --json.")


def _print_table(result, path: Path) -> None:
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
        console.print("no ground truth: the estimators are compared with each other (SED and inliers over all "
                      "matches; agreement_nsgd = median NSGD to the other estimators)")
    from fviz.record.writer import precision_lines

    for line in precision_lines(result.match_precision)[1:]:
        console.print(line)
    console.print(f"recording: {path}")


def register(app: typer.Typer) -> None:
    app.command("pair")(pair)
