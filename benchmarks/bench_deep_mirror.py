"""Why ``-e deep`` sees a pair mirrored and reversed, its yaw scaled: the motion network on held-out KITTI drives, one pass
against four ways of adding the mirrored and the reversed pair (docs/changelog.md, 2026-12-01).

    python benchmarks/bench_deep_mirror.py --kitti-root ../kitti-train-data/odometry --test 04 --test 2011_09_26_drive_0005

Rows, each through :func:`fviz.train.heldout.evaluate_heldout` (median SED, rotation error, yaw correlation
and slope from E = K_b^T F K_a):
- ``one pass``: the network as trained (``-e deep:PATH``);
- ``mirror, mean F``: the mirrored pair's F mapped back, the two F's averaged (unit norm, signs aligned,
  rank 2 enforced);
- ``mirror, mean motion``: the mean of the two motions (:func:`fviz.geometry.mean_motion_f`);
- ``swapped, mean motion``: the pair (b, a) instead of the mirror, its F transposed;
- ``mirror + swapped, mean motion``: both;
- ``mirror + swapped, yaw x G``: that mean motion's yaw times G (``--yaw-gain``; what ``-e deep`` does with
  the bundled gain of assets/MANIFEST.json, ``inference.yaw_gain``);
- the straight-ahead constant.

``--timing`` prints, first, the CPU ms a pair of one pass, of ``-e deep``'s three views (the reversed pair
reusing the pair's image streams, :meth:`fviz.models.model.FNet.indexed`) and of the three views as three
separate pairs, on 1 and 2 threads, measured in the same run.

``--fit-yaw-gain`` first fits that gain on the recipe's training pairs (``data.sequences`` and ``data.drives``,
step 1 forward; :func:`fviz.train.heldout.fit_yaw_gain`) and adds its row.
Held-out pairs: ``--recipe``'s data settings (default: recipes/kitti_motion.toml, both gray cameras; docs/changelog.md's
figures: ``--cameras 0``), temporal step 1 forward, of the ``--test`` sequences or drives.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from common import KITTI_ROOT, PROJECT


def views_apart(model, a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """The F's of (a, b), of the pair mirrored and of (b, a), predicted as three separate pairs (no shared streams)."""
    from fviz.models.predict import predict_F_batch

    return predict_F_batch(model, [(a, b), (a[:, ::-1].copy(), b[:, ::-1].copy()), (b, a)])


def variants(model, gains=()):
    """{row: estimator (pair, x_a, x_b) -> F} of the mirrored uses of ``model``, the yaw scaled by each of
    ``gains`` in the last rows."""
    from fviz.geometry import enforce_rank2, mean_motion_f
    from fviz.models.predict import flip_matrix, predict_F_batch

    def passes(pair, mirrored: bool = True, swapped: bool = False):
        """One pass's F, then the mirrored pair's and the swapped pair's, each mapped back to a -> b."""
        a, b = np.asarray(pair.image_a), np.asarray(pair.image_b)
        F = views_apart(model, a, b)
        F[1] = flip_matrix(b.shape[1]).T @ F[1] @ flip_matrix(a.shape[1])
        F[2] = F[2].T
        return [F[0]] + [F[1]] * mirrored + [F[2]] * swapped

    def mean_f(pair, x_a=None, x_b=None):
        Fs = [F / np.linalg.norm(F) for F in passes(pair)]
        return enforce_rank2(sum(F if np.sum(F * Fs[0]) >= 0 else -F for F in Fs))

    return {
        "one pass": lambda pair, x_a=None, x_b=None: predict_F_batch(model, [(pair.image_a, pair.image_b)])[0],
        "mirror, mean F": mean_f,
        "mirror, mean motion": lambda pair, x_a=None, x_b=None: mean_motion_f(passes(pair), pair.K_a, pair.K_b),
        "swapped, mean motion": lambda pair, x_a=None, x_b=None: mean_motion_f(passes(pair, False, True), pair.K_a, pair.K_b),
        "mirror + swapped, mean motion": lambda pair, x_a=None, x_b=None: mean_motion_f(passes(pair, True, True), pair.K_a, pair.K_b),
        **{f"mirror + swapped, yaw x {g:g}": (lambda pair, x_a=None, x_b=None, g=g: mean_motion_f(passes(pair, True, True), pair.K_a, pair.K_b, g))
           for g in gains},
    }


def timing(model, pair, repeat: int = 15) -> None:
    """Median ms a pair of one pass, the three views with shared streams, and the three views apart."""
    import torch

    from fviz.models.predict import predict_F_batch

    a, b = np.asarray(pair.image_a), np.asarray(pair.image_b)
    runs = {"one pass": lambda: predict_F_batch(model, [(a, b)]),
            "three views (-e deep)": lambda: predict_F_batch(model, [(a, b)], [(pair.K_a, pair.K_b)]),
            "three views apart": lambda: views_apart(model, a, b)}
    threads = torch.get_num_threads()
    for n in (1, 2):
        torch.set_num_threads(n)
        times = {name: [] for name in runs}
        for _ in range(repeat):  # interleaved: the machine's speed drifts alike for each
            for name, run in runs.items():
                t0 = time.perf_counter()
                run()
                times[name].append(1e3 * (time.perf_counter() - t0))
        one = np.median(times["one pass"])
        print(f"{n} thread(s): " + ", ".join(f"{name} {np.median(t):.1f} ms ({np.median(t) / one:.2f}x)" for name, t in times.items()))
    torch.set_num_threads(threads)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--recipe", default=str(PROJECT / "recipes" / "kitti_motion.toml"))
    ap.add_argument("--kitti-root", default=str(KITTI_ROOT))
    ap.add_argument("--weights", default=str(PROJECT / "assets" / "fviz-deep.pt"))
    ap.add_argument("--test", action="append", default=[], metavar="SEQ", required=True)
    ap.add_argument("--cameras", type=int, nargs="+", default=None, help="data.cameras (default: the recipe's)")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--yaw-gain", type=float, action="append", default=[], metavar="G", help="add a row with the yaw times G")
    ap.add_argument("--fit-yaw-gain", action="store_true", help="fit the gain on the recipe's training pairs first")
    ap.add_argument("--timing", action="store_true", help="CPU ms a pair of one pass and of the three views, first")
    args = ap.parse_args()

    import torch

    from fviz.models.weights import load_model
    from fviz.train.heldout import evaluate_heldout, fit_yaw_gain, heldout_pairs, straight_ahead_f
    from fviz.train.recipe import load_recipe

    torch.set_num_threads(args.threads)
    model = load_model(args.weights, "cpu")[0]

    def recipe_of(names):
        """The recipe with ``names`` as its held-out sequences: their step-1 forward pairs."""
        return load_recipe(args.recipe, [f"data.root={json.dumps(args.kitti_root)}", "data.steps=[1]",
                                         "data.both_directions=false", f"data.val_sequences={json.dumps(names)}",
                                         "data.sequences=[]", "data.drives=[]",
                                         *([f"data.cameras={args.cameras}"] if args.cameras else [])])

    if args.timing:
        timing(model, next(iter(heldout_pairs(recipe_of(args.test[:1])))))
    gains = list(args.yaw_gain)
    if args.fit_yaw_gain:
        training = load_recipe(args.recipe).data
        names = [*training.sequences, *training.drives]
        t0 = time.perf_counter()
        pairs = list(heldout_pairs(recipe_of(names)))
        gain, errors = fit_yaw_gain(model, pairs)
        print(f"yaw gain fit on {', '.join(names)} ({len(pairs)} pairs, {time.perf_counter() - t0:.0f} s): {gain:g}")
        print("  median rotation error, deg: " + ", ".join(f"x{g:g} {e:.3f}" for g, e in errors.items()))
        gains.append(gain)
    estimators = [*variants(model, gains).items(), ("constant", straight_ahead_f)]
    for test in args.test:
        recipe = recipe_of([test])
        t0 = time.perf_counter()
        pairs = list(heldout_pairs(recipe))
        summary = evaluate_heldout(pairs, estimators)
        print(f"\n{test}: {len(pairs)} temporal pairs, {time.perf_counter() - t0:.0f} s")
        print(f"{'':32s} {'SED px':>8s} {'rot deg':>8s} {'yaw corr':>9s} {'yaw slope':>10s}")
        for name, _ in estimators:
            s = summary[name]
            print(f"{name:32s} {s['temporal_sed_median']:8.3f} {s['temporal_rot_err_median']:8.3f} "
                  f"{s.get('temporal_yaw_corr', float('nan')):9.3f} {s.get('temporal_yaw_slope', float('nan')):10.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
