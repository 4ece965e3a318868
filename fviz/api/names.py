"""Errors in the caller's words: the run's checks name the command line's flags (``--frames 0:9: ...``); called
from Python, :func:`python_errors` renames the flag that starts the message after the parameter
(``frames 0:9: ...``). The ``fviz`` commands run inside :func:`fviz.errors.command_line` and keep their flags."""

from __future__ import annotations

import functools
import re
from typing import Callable, TypeVar

from fviz.errors import FvizError, from_command_line

F = TypeVar("F", bound=Callable)

# flags whose parameter is not the flag's own name (--kitti-root -> kitti_root is the rule)
PARAMETERS = {"--pair": "kinds", "--step": "steps", "--estimator": "estimators", "-e": "estimators",
              "--synthetic": "seeds", "--cams": "cams", "--index": "index", "--run-a": "a", "--run-b": "b",
              "--a": "estimators", "--b": "estimators", "--set": "overrides"}
_FLAG = re.compile(r"^(--?[A-Za-z][\w-]*)")


def parameter(flag: str) -> str:
    """The parameter a command line flag sets: ``--kitti-root`` -> ``kitti_root``, ``--pair`` -> ``kinds``."""
    return PARAMETERS.get(flag, flag.lstrip("-").replace("-", "_"))


def word(flag: str) -> str:
    """``flag`` for the command line, its parameter for Python (for notes printed by the API)."""
    return flag if from_command_line() else parameter(flag)


def renamed(exc: FvizError) -> FvizError:
    """``exc`` (same type) with the flag that starts its message renamed after its parameter."""
    text = _FLAG.sub(lambda m: parameter(m[1]), str(exc), count=1)
    if text == str(exc):
        return exc
    new = type(exc).__new__(type(exc))  # not type(exc)(text): a subclass may take more arguments
    new.args = (text,)
    new.__dict__.update(exc.__dict__)
    return new


def python_errors(fn: F) -> F:
    """``fn`` raising its FvizErrors with parameter names, unless the command line called it."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except FvizError as exc:
            if from_command_line():
                raise
            raise renamed(exc) from None

    return wrapper  # type: ignore[return-value]
