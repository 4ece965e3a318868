"""The paper's Table 1 on raw KITTI City stereo, reproduced with networks trained by ``fviz train``.

    python benchmarks/paper_table1.py                      # both splits: trains what is missing, writes the tables
    python benchmarks/paper_table1.py --split honest --steps 400 --variants siamese-rec-pos-fbn,siamese-rec-pos-abs

Splits (recipes/paper/): ``honest`` trains on the City drives 0001, 0002, 0005 and tests on drive 0013,
never seen; ``paper`` draws random frames of all four drives, 80 / 10 / 10 % (the paper's 1600 / 200 / 200),
so test frames neighbour training frames.  Rows: the Siamese Base, REC, REC + POS, EPI, EPI + POS under FBN
and ABS, the Single-stream REC + POS, 8-point, LMedS, RANSAC, MAGSAC++, the two constants that read no
image (``ahead``: straight ahead; the mean ground-truth F of the training pairs, a fair prior since it saw
no test label) and the ground truth.  ETR columns are undefined on rectified stereo (F33 = 0).

Every rectified stereo pair of one rig has the same F: the training mean *is* the test pairs' F, so a
network that learnt that constant scores like the ground truth.  The second table says, per estimator,
how far its F moves from pair to pair (``spread``: median f_dist of its F to its own mean F; 0 = constant)
beside the epipole error and median SED, so a reader sees whether a network beats the constant or is it.

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
VARIANTS = [f"siamese-{h}-{n}" for h in ("base", "rec", "rec-pos", "epi", "epi-pos") for n in ("fbn", "abs")]
VARIANTS += ["single-rec-pos-fbn"]
CLASSICAL = ["8point", "lmeds", "ransac", "magsac", "ahead"]


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
    training drives (paper)."""
    from fviz.train.data import _open_named, frames_of, paper_split_frames, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    for name in test_drives or d.drives:
        _, ds = _open_named(roots, name)
        frames = frames_of(ds, 0) & frames_of(ds, 1)
        if not test_drives:
            frames &= paper_split_frames(name, set().union(*(frames_of(ds, c) for c in ds.projections)), "test")
        for f in sorted(frames):
            yield ds.pair(f, "stereo", cams=(0, 1))


def training_mean_f(split: str, recipe) -> np.ndarray:
    """The mean ground-truth F of the split's training pairs (no test label)."""
    from fviz.estimators.baselines import mean_fundamental
    from fviz.train.data import _open_named, kitti_items, kitti_pair_id, resolve_root

    d = recipe.data
    roots = [str(resolve_root(r)) for r in [d.root, *d.roots] if r]
    Fs = []
    for name in d.drives:
        _, ds = _open_named(roots, name)
        for item in kitti_items(recipe, name, "train" if split == "paper" else None):
            if not item.reverse:
                Fs.append(ds.ground_truth(kitti_pair_id(ds, item))[4])
    return mean_fundamental(Fs)


def spread(Fs: list[np.ndarray]) -> float:
    """Median f_dist of each F to the mean of all of them: 0 for an estimator that returns a constant."""
    from fviz.estimators.baselines import mean_fundamental
    from fviz.geometry import f_distance

    if len(Fs) < 2:
        return math.nan
    mean = mean_fundamental(Fs)
    return float(np.median([f_distance(F, mean) for F in Fs]))


def evaluate(split: str, models: dict[str, Path], out: Path, overrides: list[str], test_drives: list[str] | None) -> Path:
    from fviz.estimators.baselines import constant_estimator
    from fviz.estimators.deep import deep_estimator
    from fviz.estimators.features import FeatureCache, FeatureConfig
    from fviz.estimators.registry import get_estimator
    from fviz.evaluate import evaluate_pair
    from fviz.models.model import parse_variant
    from fviz.table import table_from_rows
    from fviz.train.recipe import load_recipe

    recipe = load_recipe(RECIPES[split], overrides)
    estimators = [(v, deep_estimator(p)) for v, p in models.items()]
    estimators += [(name, get_estimator(name)) for name in CLASSICAL]
    estimators.append(("mean-training drives", constant_estimator(training_mean_f(split, recipe))))
    cache = FeatureCache(FeatureConfig(), threads=1)
    rows, Fs, t0 = [], {}, time.perf_counter()
    for pair in test_pairs(split, recipe, test_drives):
        result = evaluate_pair(pair, estimators, cache=cache)
        rows += result.rows()
        for est in result.estimators:
            if est.F is not None:
                Fs.setdefault(est.name, []).append(est.F)
    print(f"  {split}: {len({r['name'] for r in rows})} test pairs, {len(estimators)} estimators, "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    header, table = table_from_rows(rows, {v: parse_variant(v) for v in models})
    table = [[c if (c or not h.startswith("ETR")) else "undefined" for h, c in zip(header, r)] for r in table]
    md = [f"## Table 1, {split} split ({RECIPES[split].relative_to(PROJECT)}), {len({r['name'] for r in rows})} test pairs", "",
          "| " + " | ".join(header) + " |", "|---" * len(header) + "|", *("| " + " | ".join(r) + " |" for r in table), "",
          "ETR: undefined, every rectified stereo F has F33 = 0.  Means over pairs of the per-pair means over the "
          "evaluation matches (SIFT matches within 2 px of the ground truth), at full resolution 1242 x 375.", "",
          "| Estimator | spread (0 = constant) | median epipole error (deg) | median SED (px) | failures |",
          "|---|---|---|---|---|"]
    for name in [e for e, _ in estimators] + ["gt"]:
        mine = [r for r in rows if r["estimator"] == name]
        ok = [r for r in mine if not r["error"]]
        med = lambda k: np.nanmedian([float(r.get(k, math.nan)) for r in ok]) if ok else math.nan  # noqa: E731
        md.append(f"| {name} | {spread(Fs.get(name, [])):.3g} | {med('epipole_err_deg'):.3g} | {med('sed_median'):.3g} | "
                  f"{len(mine) - len(ok)} |")
    path = out / split / "table1.md"
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
    args = ap.parse_args()

    import torch

    torch.set_num_threads(1)
    out = Path(args.out)
    for split in ("honest", "paper") if args.split == "both" else (args.split,):
        print(f"{split} split: training {args.variants}", flush=True)
        models = train_missing(split, args.variants.split(","), out, args.steps, args.set)
        drives = (args.test_drive or TEST_DRIVES[split]) if split == "honest" else None
        path = evaluate(split, models, out, args.set, drives)
        print(path.read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
