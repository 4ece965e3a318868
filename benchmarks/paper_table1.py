"""The paper's Table 1 on raw KITTI City stereo, reproduced with networks trained by ``fviz train``.

    python benchmarks/paper_table1.py                      # both splits: trains what is missing, writes the tables
    python benchmarks/paper_table1.py --split honest --steps 400 --variants siamese-rec-pos-fbn,siamese-rec-pos-abs

Splits (recipes/paper/): ``honest`` trains on the City drives 0001, 0002, 0005 and tests on drive 0013,
never seen; ``paper`` draws random frames of all four drives, 80 / 10 / 10 % (the paper's 1600 / 200 / 200),
so test frames neighbour training frames.  Rows: all 36 networks (Single-stream and Siamese; Base, Base + POS, EPI,
EPI + POS, REC, REC + POS; ETR, FBN, ABS: each normalizes in the unrectified cameras' frame, ``model.norm_frame``, so
ETR is defined), 8-point, LMedS, RANSAC, MAGSAC++, PoseLib (all on SIFT matches), the
learned matches (XFeat, XFeat + LighterGlue, DISK + LightGlue; ``--learned``, where the learned extra is
installed) with MAGSAC++ and PoseLib, the two constants that read no image (``ahead``: straight ahead; the
mean ground-truth F of the training pairs, a fair prior since it saw no test label) and the ground truth.

Each row shows the paper's figures (``fviz.table.PAPER_TABLE1``) and fviz's under two readings of the paper's
protocol, both with the paper's filter (the sum of the two squared epipolar distances to the ground truth < 2 px^2):
**A**, the unrectified cameras of ``calib_cam_to_cam.txt`` (every F and match mapped there: ETR is defined) and
**B**, the unrectified cameras' F scored on the rectified images' own pixels (the reading the paper's figures
favour: see docs/training.md); then A with fviz's filter (the mean of the two distances < 2 px) and the rectified
frame of the images (ETR undefined: F33 = 0), and the ratios to the ground-truth row (paper, A, B).
``fviz table`` on a raw-drive run prints the same columns (``fviz.table.paper_layout_markdown``).

Without the staged training set, the classical rows on the shared drives (about 15 s, no training)::

    python benchmarks/paper_table1.py --split honest --variants "" --learned "" --out /tmp/t1 \
        --set data.root=../shared/data/kitti/raw --set "data.roots=[]" --set 'data.drives=["2011_09_26_drive_0001"]' \
        --test-drive 2011_09_26_drive_0001 --test-drive 2011_09_26_drive_0002

Every rectified stereo pair of one rig has the same F: the training mean *is* the test pairs' F, so a
network that learnt that constant scores like the ground truth.  The second table says, per estimator,
how far its F moves from pair to pair (the epipole's and the rotation's spread, as triage measures them;
0 = constant) beside the epipole error and median SED, so a reader sees whether a network beats the constant
or is it.

Outputs: ``OUT/{split}/table1.md`` (both tables) and ``OUT/{split}/rows.csv`` (every pair and estimator),
the models in ``OUT/{split}/{variant}/``.  Training logs: ``OUT/{split}/{variant}.log``.
"""

from __future__ import annotations

import argparse
import csv
import math
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

PROJECT = Path(__file__).resolve().parents[1]
RECIPES = {"honest": PROJECT / "recipes" / "paper" / "city_stereo.toml",
           "paper": PROJECT / "recipes" / "paper" / "city_stereo_paper_split.toml"}
TEST_DRIVES = {"honest": ["2011_09_26_drive_0013"], "paper": None}  # None: the test part of the training drives
VARIANTS = [f"{a}-{h}-{n}" for a in ("siamese", "single") for h in ("base", "base-pos", "epi", "epi-pos", "rec", "rec-pos")
            for n in ("etr", "fbn", "abs")]  # every network cell of the paper's table: 2 x 6 x 3
CLASSICAL = ["8point", "lmeds", "ransac", "magsac", "poselib", "ahead"]
# today's correspondence pipeline: learned matches (the learned extra, docs/matchers.md) + MAGSAC++ / PoseLib
LEARNED = ["xfeat", "xfeat+lighterglue", "disk+lightglue"]
LEARNED_ESTIMATORS = {"magsac": "MAGSAC++", "poselib": "PoseLib"}


def train_missing(split: str, variants: list[str], out: Path, steps: int, overrides: list[str]) -> dict[str, Path]:
    """model.pt of every variant, trained with ``fviz train`` where missing.  {variant: path}."""
    models = {}
    for v in variants:
        run = out / split / v
        if not (run / "model.pt").is_file():
            log = out / split / f"{v}.log"
            log.parent.mkdir(parents=True, exist_ok=True)
            sets = [f"model.variant={v}", f"train.out_dir={run}", f"train.max_steps={steps}", *overrides]
            cmd = [sys.executable, "-m", "fviz", "train", str(RECIPES[split])] + [a for s in sets for a in ("--set", s)]
            if (run / "last.pt").is_file():
                cmd.append("--resume")
            t0 = time.perf_counter()
            with open(log, "w") as fh:
                rc = subprocess.call(cmd, stdout=fh, stderr=subprocess.STDOUT, cwd=PROJECT)
            print(f"  trained {split}/{v}: exit {rc}, {time.perf_counter() - t0:.0f} s wall (log {log})", flush=True)
            if rc != 0:
                continue
        models[v] = run / "model.pt"
    return models


def test_pairs(split: str, recipe, test_drives: list[str] | None):
    """The test stereo pairs of a split (forward direction): ``test_drives`` (honest) or the test part of the
    training drives (paper), each with the homographies (H_a, H_b) into the drive's unrectified cameras."""
    from fviz.train.splits import frames_of, open_named, paper_split_frames, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    from fviz.data.kitti import raw_cameras

    for name in test_drives or d.drives:
        _, ds = open_named(roots, name)
        cams = raw_cameras(ds.calib_path)
        frames = frames_of(ds, 0) & frames_of(ds, 1)
        if not test_drives:
            frames &= paper_split_frames(name, set().union(*(frames_of(ds, c) for c in ds.projections)), "test")
        for f in sorted(frames):
            yield ds.pair(f, "stereo", cams=(0, 1)), (cams[0].H, cams[1].H)


def training_mean_f(split: str, recipe) -> np.ndarray:
    """The mean ground-truth F of the split's training pairs (no test label)."""
    from fviz.estimators.baselines import mean_fundamental
    from fviz.train.data import kitti_pair_id
    from fviz.train.splits import kitti_items, open_named, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    Fs = []
    for name in d.drives:
        _, ds = open_named(roots, name)
        for item in kitti_items(recipe, name, "train" if split == "paper" else None):
            if not item.reverse:
                Fs.append(ds.ground_truth(kitti_pair_id(ds, item))[4])
    return mean_fundamental(Fs)


def spreads(results: list) -> dict[str, tuple[float, float]]:
    """Per F, how far it moves from pair to pair, as triage measures it (:mod:`fviz.triage`): the spread of its
    epipole's viewing ray and of its recovered rotation (deg; median angle to the median), 0 for a constant."""
    from fviz.geometry import epipoles
    from fviz.findings import direction_spread_deg, rotation_spread_deg

    rays, Rs = {}, {}
    for result, pair in results:
        for r in result.estimators:
            if r.F is not None:
                ray = np.linalg.solve(pair.K_a, epipoles(r.F)[0])
                rays.setdefault(r.name, []).append(ray / np.linalg.norm(ray))
            if r.R is not None:
                Rs.setdefault(r.name, []).append(r.R)
    spread = lambda f, xs: f(np.array(xs)) if len(xs) > 1 else math.nan  # noqa: E731
    return {n: (spread(direction_spread_deg, rays.get(n, [])), spread(rotation_spread_deg, Rs.get(n, []))) for n in rays}


NO_COUNTERPART = ("—: no counterpart. MAGSAC++, PoseLib and the learned matchers postdate the paper; the constants (straight ahead, the training "
                  "drives' mean F) are fviz's controls, not the paper's; a paper network row fviz did not train "
                  "here shows only the paper's figures.")


def learned_estimators(kinds: list[str]) -> dict[str, tuple]:
    """{kind: (FeatureCache, [(row name, estimator)])} of the learned matchers usable here (the extra installed,
    LightGlue's weights found); the others are named and left out."""
    from fviz.errors import FvizError
    from fviz.estimators.features import FeatureCache, FeatureConfig
    from fviz.estimators.registry import get_estimator

    usable = {}
    for kind in kinds:
        try:
            cfg = FeatureConfig(kind)
            if kind == "disk+lightglue":
                from fviz.estimators.learned import _lightglue_file

                _lightglue_file("disk_lightglue.pth")
        except FvizError as e:
            print(f"  left out: {e}", flush=True)
            continue
        usable[kind] = (FeatureCache(cfg, threads=1),
                        [(f"{kind} + {label}", get_estimator(name)) for name, label in LEARNED_ESTIMATORS.items()])
    return usable


def evaluate(split: str, models: dict[str, Path], out: Path, overrides: list[str], test_drives: list[str] | None,
             learned: list[str] = ()) -> Path:
    from fviz.estimators.baselines import constant_estimator
    from fviz.estimators.deep import deep_estimator
    from fviz.estimators.features import FeatureCache, FeatureConfig
    from fviz.estimators.registry import get_estimator
    from fviz.evaluate import evaluate_pair
    from fviz.models.model import parse_variant
    from fviz.table import FRAME_READINGS, FRAMES_NOTE, frame_rows, mean_n_eval, paper_layout_markdown, table_from_rows
    from fviz.train.recipe import load_recipe

    recipe = load_recipe(RECIPES[split], overrides)
    estimators = [(v, deep_estimator(p)) for v, p in models.items()]
    estimators += [(name, get_estimator(name)) for name in CLASSICAL]
    estimators.append(("mean-training drives", constant_estimator(training_mean_f(split, recipe))))
    cache = FeatureCache(FeatureConfig(), threads=1)
    learned_rows = learned_estimators(list(learned))
    rows, frames, results, t0 = [], {k: [] for k in FRAME_READINGS}, [], time.perf_counter()
    for pair, (H_a, H_b) in test_pairs(split, recipe, test_drives):
        result = evaluate_pair(pair, estimators, cache=cache)
        rows += result.rows()
        for k, v in frame_rows(result, H_a, H_b).items():
            frames[k] += v
        results.append((result, pair))
        for kind, (kcache, kests) in learned_rows.items():  # the same pair, the learned matches
            r = evaluate_pair(pair, kests, features=kcache.cfg, cache=kcache)
            r.estimators = [e for e in r.estimators if e.name != "gt"]
            rows += [x for x in r.rows() if x["estimator"] != "gt"]
            for k, v in frame_rows(r, H_a, H_b).items():
                frames[k] += [x for x in v if x["estimator"] != "gt"]
            results.append((r, pair))
    estimators += [e for _, kests in learned_rows.values() for e in kests]
    n_pairs = len({r['name'] for r in rows})
    print(f"  {split}: {n_pairs} test pairs, {len(estimators)} estimators, {time.perf_counter() - t0:.0f} s", flush=True)
    variants = {v: parse_variant(v) for v in models}
    as_dict = lambda t: {r[0]: r for r in t[1]}  # noqa: E731
    n_eval = {**{k: mean_n_eval(v) for k, v in frames.items()}, "rectified": mean_n_eval(rows)}
    md = [f"## Table 1, {split} split ({RECIPES[split].relative_to(PROJECT)}), {n_pairs} test pairs "
          f"({', '.join(sorted({r['sequence'] for r in rows}))})", "",
          *paper_layout_markdown(as_dict(table_from_rows(rows, variants)),
                                 {k: as_dict(table_from_rows(v, variants)) for k, v in frames.items()}, n_eval), "",
          FRAMES_NOTE, "", NO_COUNTERPART, "",
          "| Estimator | epipole spread deg (0 = constant) | rotation spread deg | median epipole error (deg) | "
          "median SED (px) | failures |", "|---|---|---|---|---|---|"]
    spread = spreads(results)
    for name in [e for e, _ in estimators] + ["gt"]:
        mine = [r for r in rows if r["estimator"] == name]
        ok = [r for r in mine if not r["error"]]
        med = lambda k: np.nanmedian([float(r.get(k, math.nan)) for r in ok]) if ok else math.nan  # noqa: E731
        ep, rot = spread.get(name, (math.nan, math.nan))
        md.append(f"| {name} | {ep:.3g} | {rot:.3g} | {med('epipole_err_deg'):.3g} | {med('sed_median'):.3g} | "
                  f"{len(mine) - len(ok)} |")
    path = out / split / "table1.md"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(md) + "\n")
    with open(out / split / "rows.csv", "w", newline="") as fh:
        keys = sorted({k for r in rows for k in r})
        writer = csv.DictWriter(fh, keys)
        writer.writeheader()
        writer.writerows(rows)
    return path


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--split", choices=["honest", "paper", "both"], default="both")
    ap.add_argument("--variants", default=",".join(VARIANTS))
    ap.add_argument("--steps", type=int, default=400, help="training steps per variant (recipes: 400)")
    ap.add_argument("--out", default=str(PROJECT / "runs" / "paper"))
    ap.add_argument("--set", action="append", default=[], help="recipe override for every variant (KEY=VALUE)")
    ap.add_argument("--test-drive", action="append", default=[], help="honest split: the test drives (default: 0013)")
    ap.add_argument("--learned", default=",".join(LEARNED),
                    help="learned matchers whose matches get MAGSAC++ / PoseLib rows (the learned extra; '' for none)")
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    out = Path(args.out)
    for split in ("honest", "paper") if args.split == "both" else (args.split,):
        print(f"{split} split: training {args.variants}", flush=True)
        models = train_missing(split, [v for v in args.variants.split(",") if v], out, args.steps, args.set)
        drives = (args.test_drive or TEST_DRIVES[split]) if split == "honest" else None
        path = evaluate(split, models, out, args.set, drives, [k for k in args.learned.split(",") if k])
        print(path.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
