"""Issue 10's targets for the correspondence-free estimator, on real KITTI pairs it never trained on.

    python benchmarks/bench_deep_kitti.py                                  # bundled and synthetic models
    python benchmarks/bench_deep_kitti.py -e deep:runs/kitti_finetune/model.pt --json out.json

Held-out set: ``--test SEQ`` (repeatable), else the sequences named in ``--recipe``'s ``data.val_sequences`` (recipes/kitti_finetune.toml:
04 and 10 of the shared samples), temporal step 1 forward (every camera present) and stereo pairs.
Each estimator runs through :func:`fviz.train.heldout.evaluate_heldout` (the eval's metrics, plus
rotation error and yaw from E = K_b^T F K_a).  Rows: the deep models, the straight-ahead constant,
and the classical 8-point and MAGSAC++ (OpenCV, SIFT matches), beside the paper's Table 1 protocol
(FBN EPI-ABS / EPI-SQR means over the evaluation matches) on the same pairs.

Targets (issue 10): temporal median SED <= 1 px, median rotation error <= 0.2 deg, yaw correlation
>= 0.95; straight driving below the constant; stereo median epipole error < 10 deg.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

from common import KITTI_ROOT, PROJECT

TARGETS = [
    ("temporal_sed_median", "temporal median SED (px)", "<=", 1.0),
    ("temporal_rot_err_median", "temporal median rotation error (deg)", "<=", 0.2),
    ("temporal_yaw_corr", "temporal yaw correlation", ">=", 0.95),
    ("temporal_yaw_slope", "temporal yaw slope (pred / true)", "~", 1.0),
    ("straight_sed_median", "straight driving median SED (px)", "< constant", None),
    ("stereo_epipole_err_median", "stereo median epipole error (deg)", "<", 10.0),
    ("stereo_sed_median", "stereo median SED (px)", "", None),
    ("epi_abs", "Table 1 EPI-ABS (FBN, mean)", "", None),
    ("epi_sqr", "Table 1 EPI-SQR (FBN, mean)", "", None),
]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", default=str(PROJECT / "recipes" / "kitti_finetune.toml"))
    ap.add_argument("--kitti-root", default=str(KITTI_ROOT))
    ap.add_argument("-e", "--estimator", action="append", default=[], help="more estimators (deep:PATH, ...)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--test", action="append", default=[], metavar="SEQ",
                    help="held-out sequence or drive (repeatable; default: the recipe's data.val_sequences)")
    ap.add_argument("--json", default="")
    ap.add_argument("--no-baselines", action="store_true",
                    help="only the -e estimators (the bundled models, constant and classical rows are left out)")
    args = ap.parse_args()

    import torch

    from fviz.estimators.registry import display_name, get_estimator
    from fviz.train.heldout import evaluate_heldout, heldout_pairs, straight_ahead_f
    from fviz.train.recipe import load_recipe

    torch.set_num_threads(args.threads)
    overrides = [f"data.root={json.dumps(args.kitti_root)}", "data.steps=[1]", "data.both_directions=false"]
    if args.test:  # test sequences replace the validation ones (and leave the training lists)
        overrides += [f"data.val_sequences={json.dumps(args.test)}", "data.sequences=[]", "data.drives=[]"]
    recipe = load_recipe(args.recipe, overrides)
    specs = ([] if args.no_baselines else ["deep", "deep:synthetic"]) + args.estimator
    estimators = [(display_name(s), get_estimator(s)) for s in specs]
    if not args.no_baselines:
        estimators += [("constant", straight_ahead_f), ("8point", get_estimator("8point")), ("magsac", get_estimator("magsac"))]
    t0 = time.perf_counter()
    pairs = list(heldout_pairs(recipe))
    print(f"held-out: {', '.join(recipe.data.val_sequences)} of {args.kitti_root}: {len(pairs)} pairs "
          f"({sum(p.id.kind == 'temporal' for p in pairs)} temporal step 1, {sum(p.id.kind == 'stereo' for p in pairs)} stereo)")
    summary = evaluate_heldout(pairs, estimators)
    names = [n for n, _ in estimators] + ["gt"]
    width = max(len(n) for n in names) + 2
    print(f"\n{'figure':40s} {'target':>12s} " + " ".join(f"{n:>{width}s}" for n in names))
    for key, label, op, bound in TARGETS:
        target = f"{op} {bound:g}" if bound is not None else op
        cells = []
        for n in names:
            v = summary.get(n, {}).get(key, math.nan)
            cells.append(f"{v:>{width}.3f}" if v == v else f"{'-':>{width}s}")
        print(f"{label:40s} {target:>12s} " + " ".join(cells))
    s0 = summary[names[0]]
    print(f"\npairs: temporal {s0['temporal_pairs']} (straight, |GT yaw| < 0.2 deg: {s0['straight_pairs']}), stereo {s0['stereo_pairs']}; "
          f"{time.perf_counter() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps({"recipe": args.recipe, "pairs": len(pairs), "summary": summary}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
