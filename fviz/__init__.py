"""fviz: interactive visual debugging of fundamental-matrix estimation (KITTI, Rerun).

The public Python API (:mod:`fviz.api`), imported on first use so that ``import fviz`` stays instant::

    fviz.kitti_pair, fviz.synthetic_pair, fviz.pair_from_images, fviz.pairs_file_pair, fviz.colmap_pair,
    fviz.with_matches, fviz.load_pair (every source's flags)  ->  fviz.Pair
    fviz.inspect_pair                      ->  fviz.PairResult
    fviz.log_result, fviz.save_recording, fviz.log_training_step
    fviz.reestimate, fviz.edit             ->  a PairResult of an edited match set, an EditSession

    fviz.select                            ->  fviz.Selection (which pairs)
    fviz.evaluate_run, fviz.read_run       ->  fviz.Run (a run folder)
    fviz.read_pair                         ->  a run's pair and its result, rebuilt on demand (editable)
    fviz.triage_run, fviz.compare_runs, fviz.run_table, fviz.merge_runs, fviz.train
"""

from fviz.version import __version__  # noqa: F401

__all__ = ["Pair", "PairResult", "load_pair", "pair_from_images", "inspect_pair", "log_result", "save_recording",
           "log_training_step", "kitti_pair", "synthetic_pair", "pairs_file_pair", "colmap_pair", "with_matches", "reestimate", "edit",
           "Selection", "Run", "select", "evaluate_run", "triage_run", "compare_runs", "run_table",
           "read_run", "read_pair", "merge_runs", "train"]


def __getattr__(name: str):
    if name in __all__:
        from fviz import api

        return getattr(api, name)
    raise AttributeError(f"module 'fviz' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
