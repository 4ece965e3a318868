"""One registry from a name to an estimator.

- a built-in name: ``7point``, ``8point``, ``lmeds``, ``ransac``, ``magsac``, OpenCV's USAC presets
  ``usac-default``, ``usac-accurate``, ``usac-prosac``, ``usac-fm8pts``, ``usac-parallel``
  (:mod:`fviz.estimators.classical`), ``poselib``, ``poselib-E``, ``colmap`` (:mod:`fviz.estimators.external`),
  ``deep`` (the bundled networks, by pair kind; ``deep:motion`` / ``deep:stereo`` name each: neither beats the
  constants ``ahead`` and ``mean:SEL`` on pose AUC on held-out drives that chose nothing, see
  ``assets/MANIFEST.json`` ``verdict``), ``ahead`` (the straight-ahead baseline, from the cameras alone);
- ``NAME@T``: a robust estimator at threshold T px, ``NAME@oracle``: the best of a grid per pair, chosen with
  the ground truth (:mod:`fviz.estimators.sweep`; ``--threshold sweep`` writes them);
- ``deep:PATH``: a checkpoint trained by ``fviz train``;
- ``module:function``: a user's own ``function(pair, x_a, x_b) -> F | (F, inlier_mask)``;
- run-level baselines (eval and triage only; :mod:`fviz.run.config` resolves them on the selection):
  ``oracle-mean``, the mean ground-truth F of the evaluated pairs (an oracle: it has seen the labels), and
  ``mean:SEL``, the mean ground-truth F of other sequences (``mean:01,02``) or synthetic seeds (``mean:1000:1100``).

Adding a built-in is one entry in ``BUILTINS``.
"""

from __future__ import annotations

import importlib
from typing import Callable

from fviz.errors import FvizError
from fviz.estimators.base import EstimateFn
from fviz.estimators.classical import MIN_MATCHES, RobustConfig, classical
from fviz.estimators.external import METHODS as EXTERNAL, external


def _deep(spec: str, cfg: RobustConfig) -> EstimateFn:
    from fviz.estimators.deep import deep_estimator

    return deep_estimator(spec.partition(":")[2] or None)


def _ahead(spec: str, cfg: RobustConfig) -> EstimateFn:
    from fviz.estimators.baselines import ahead

    return ahead


BUILTINS: dict[str, Callable[[str, RobustConfig], EstimateFn]] = {
    **{name: (lambda spec, cfg: classical(spec, cfg)) for name in MIN_MATCHES},
    **dict.fromkeys(EXTERNAL, external),  # poselib / pycolmap load on the first estimate
    "deep": _deep,
    "ahead": _ahead,
}

DEFAULT_ESTIMATORS = ("8point", "ransac", "magsac")
AHEAD = "ahead"
ORACLE_MEAN = "oracle-mean"
MEAN_PREFIX = "mean:"


def is_run_baseline(spec: str) -> bool:
    """``oracle-mean`` and ``mean:SEL``: constant F computed from a selection of pairs."""
    return spec == ORACLE_MEAN or spec.startswith(MEAN_PREFIX)


def is_baseline(name: str) -> bool:
    """Whether an estimator (display name) is one of the baselines that read neither images nor matches."""
    return name in (AHEAD, ORACLE_MEAN) or name.startswith("mean-")


def is_oracle(name: str) -> bool:
    """Whether an estimator (display name) has seen the evaluated labels."""
    from fviz.estimators.sweep import ORACLE_SUFFIX

    return name == ORACLE_MEAN or name.endswith(ORACLE_SUFFIX)


def needs_matches(spec: str) -> bool:
    """Whether the estimator reads the matches (deep ones work on the images alone, baselines on nothing)."""
    return not (spec == "deep" or spec.startswith("deep:") or spec == AHEAD or is_run_baseline(spec))


def _import_file(spec: str, path_text: str):
    """The module of a ``file.py:function`` spec, loaded from that file (its folder first on the import
    path, so that its own imports of neighbours work)."""
    import hashlib
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(path_text).expanduser()
    if not path.is_file():
        raise FvizError(f"--estimator {spec}: no such file {path}")
    name = f"fviz_user_{path.stem}_{hashlib.sha1(str(path.resolve()).encode()).hexdigest()[:8]}"
    if name in sys.modules:
        return sys.modules[name]
    folder = str(path.resolve().parent)
    if folder not in sys.path:
        sys.path.insert(0, folder)
    loader_spec = importlib.util.spec_from_file_location(name, path)
    if loader_spec is None or loader_spec.loader is None:
        raise FvizError(f"--estimator {spec}: {path} is not a Python file")
    module = importlib.util.module_from_spec(loader_spec)
    sys.modules[name] = module
    try:
        loader_spec.loader.exec_module(module)
    except BaseException as exc:  # its import failing (or exiting) is a bad --estimator, not a crash
        del sys.modules[name]
        raise FvizError(f"--estimator {spec}: importing {path} failed ({type(exc).__name__}: {' '.join(str(exc).split())})"
                        ) from None
    return module


def _user_function(spec: str) -> EstimateFn:
    """``module:function`` (importable from the working directory too, as with ``python -m``) or
    ``path/to/file.py:function``."""
    import os
    import sys

    module_name, _, attr = spec.rpartition(":")
    if module_name.endswith(".py") or "/" in module_name or os.sep in module_name:
        module = _import_file(spec, module_name)
    else:
        if "" not in sys.path and os.getcwd() not in sys.path:
            sys.path.append(os.getcwd())
        try:
            module = importlib.import_module(module_name)
        except ImportError as exc:
            raise FvizError(f"--estimator {spec}: cannot import module {module_name!r} ({exc})") from None
        except Exception as exc:  # the module itself raised while importing
            raise FvizError(f"--estimator {spec}: importing {module_name!r} failed ({type(exc).__name__}: {exc})") from None
    fn = getattr(module, attr, None)
    if not callable(fn):
        raise FvizError(f"--estimator {spec}: {module_name} has no function {attr!r}")
    return fn


def get_estimator(spec: str, cfg: RobustConfig = RobustConfig()) -> EstimateFn:
    """Resolve ``--estimator`` values; unknown names raise FvizError listing the known ones."""
    head = spec.partition(":")[0]
    if spec == "constant":
        raise FvizError("--estimator constant: renamed oracle-mean (the mean ground-truth F of the evaluated pairs has "
                        "seen the test labels); for a fair prior use ahead or mean:SEQ,... of other sequences")
    from fviz.estimators.sweep import split_threshold, threshold_estimator

    if split_threshold(spec)[1] is not None:
        return threshold_estimator(spec, cfg, get_estimator)
    if is_run_baseline(spec):
        raise FvizError(f"--estimator {spec}: a run-level baseline (computed over a selection of pairs): use it with "
                        "fviz eval or triage")
    if spec in BUILTINS or head == "deep":
        return BUILTINS["deep" if head == "deep" else spec](spec, cfg)
    if ":" in spec:
        return _user_function(spec)
    raise FvizError(f"--estimator {spec!r}: unknown (built-in: {', '.join(BUILTINS)}; or deep:PATH, module:function, "
                    "and in eval/triage oracle-mean, mean:SEL)")


def is_user_spec(spec: str) -> bool:
    """Whether ``spec`` names a user's own function (``module:function``, ``file.py:function``): code fviz does not
    know, which may crash the process it runs in (eval then runs it in a worker process, whatever the run's size)."""
    from fviz.estimators.sweep import split_threshold

    head = spec.partition(":")[0]
    return (":" in spec and head != "deep" and spec not in BUILTINS and not is_run_baseline(spec)
            and split_threshold(spec)[1] is None)


def _name_levels(spec: str) -> list[str]:
    """Ever longer names of a spec: ``deep:runs/a/model.pt`` -> deep-model, deep-a-model, deep-runs-a-model;
    ``pkg.mod:fn`` -> fn, pkg.mod.fn; a built-in -> itself."""
    import re
    from pathlib import PurePath

    from fviz.estimators.sweep import split_threshold, threshold_name

    base, th = split_threshold(spec)
    if th is not None:
        return [re.sub(r"[^A-Za-z0-9_.-]+", "-", threshold_name(base, th))]
    head, _, rest = spec.partition(":")
    if not rest:
        return [spec]
    if head == "mean":
        return [re.sub(r"[^A-Za-z0-9_.-]+", "-", f"mean-{rest}")]
    if head == "deep":
        parts = PurePath(rest).with_suffix("").parts
        levels = [f"deep-{'-'.join(parts[-k:])}" for k in range(1, len(parts) + 1)]
    else:
        levels = [rest, f"{head}.{rest}"]
    return [re.sub(r"[^A-Za-z0-9_.-]+", "-", n).strip("-") for n in levels]


def display_name(spec: str) -> str:
    """A short name safe in entity paths and CSV columns: ``deep:runs/x/best.pt`` -> ``deep-best``."""
    return _name_levels(spec)[0]


def display_names(specs: tuple[str, ...] | list[str]) -> list[str]:
    """Unique display names, in order: a spec whose short name another one shares gets the shortest longer
    name (more of its path or module) that tells them apart, e.g. ``deep-a-model`` and ``deep-b-model``."""
    levels = [_name_levels(s) for s in specs]
    names = [lv[0] for lv in levels]
    for depth in range(1, max((len(lv) for lv in levels), default=1)):
        clash = {n for n in names if names.count(n) > 1}
        if not clash:
            break
        names = [lv[min(depth, len(lv) - 1)] if n in clash else n for n, lv in zip(names, levels)]
    counts, seen = {n: names.count(n) for n in names}, {}
    for i, n in enumerate(names):  # the same file spelt twice: numbered
        seen[n] = seen.get(n, 0) + 1
        names[i] = n if counts[n] == 1 else f"{n}-{seen[n]}"
    return names
