"""fviz from Python: pairs (:mod:`fviz.api.pairs`), their edits (:mod:`fviz.api.editing`),
runs (:mod:`fviz.api.runs`), a run's pairs (:mod:`fviz.api.runpairs`), training (:func:`train`).

Every public name here is re-exported by ``import fviz``; each module is imported on first use, so that ``import
fviz`` and the command line's start stay instant. The command line is a client of these functions: each ``fviz``
command parses its flags and makes one call here (errors then name the flags; called from Python, the parameters).
"""

from __future__ import annotations

import importlib

_PAIRS = ("Pair", "PairResult", "load_pair", "pair_from_images", "inspect_pair", "log_result", "save_recording",
          "log_training_step", "watch_points", "WATCH_POINTS", "DEFAULT_ESTIMATORS", "KITTI_ROOT_ENV", "check_result_of",
          "pair_fingerprint")
_RUNS = ("Selection", "Run", "Compared", "select", "evaluate_run", "triage_run", "compare_runs", "run_table", "read_run",
         "merge_runs")
_RUN_PAIRS = ("read_pair",)
_TRAINING = ("train",)
_EDITING = ("reestimate", "edit")
_SOURCES = ("kitti_pair", "synthetic_pair", "pairs_file_pair", "colmap_pair", "with_matches")
_MODULE = {**{n: "pairs" for n in _PAIRS}, **{n: "runs" for n in _RUNS}, **{n: "runpairs" for n in _RUN_PAIRS},
           **{n: "training" for n in _TRAINING}, **{n: "editing" for n in _EDITING}, **{n: "sources" for n in _SOURCES}}

__all__ = ["Pair", "PairResult", "load_pair", "pair_from_images", "inspect_pair", "log_result", "save_recording",
           "log_training_step", *_SOURCES, *_EDITING, *_RUNS, *_RUN_PAIRS, *_TRAINING]


def __getattr__(name: str):
    if name in _MODULE:
        return getattr(importlib.import_module(f"fviz.api.{_MODULE[name]}"), name)
    if name in ("pairs", "inspecting", "runs", "runpairs", "training", "viewing", "names", "editing", "sources"):
        return importlib.import_module(f"fviz.api.{name}")
    raise AttributeError(f"module 'fviz.api' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted([*globals(), *_MODULE])
