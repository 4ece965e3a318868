"""The one typed-config validator: a value checked against a type annotation (:func:`convert`) and a dataclass's fields
from a dict (:func:`fields_of`), for run.json, the training recipes (:mod:`fviz.train.recipe` adds its bounds and
wording) and results.jsonl's records (:mod:`fviz.run.store`: TypedDicts, :data:`Real` numbers); so a hand-edited
file is a one-line error naming the field, never a TypeError deep in a run."""

from __future__ import annotations

import dataclasses
import functools
import math
import types
import typing
from typing import Any, Callable

from fviz.errors import FvizError

# A number as JSON written with allow_nan holds it: int or float, NaN and infinities included (a metric's value).
Real = typing.NewType("Real", float)


class Mismatch(FvizError):
    """A value of the wrong type: ``where`` names it, ``value`` is it."""

    def __init__(self, message: str, where: str = "", value: Any = None):
        super().__init__(message)
        self.where, self.value = where, value

    @property
    def brief(self) -> str:
        """``'WHERE' is TYPE``: the mismatch in a few words (a warning about a skipped record)."""
        return f"'{self.where}' is {type(self.value).__name__}"


_number = lambda v: isinstance(v, (int, float)) and not isinstance(v, bool)  # noqa: E731
_SCALARS = {type(None): lambda v: v is None, bool: lambda v: isinstance(v, bool), str: lambda v: isinstance(v, str),
            int: lambda v: isinstance(v, int) and not isinstance(v, bool), Real: _number,
            float: lambda v: _number(v) and math.isfinite(v)}
# Tests that, when true, mean a value passes its check unchanged (a float: a finite float, not an int to widen)
_PLAIN = {**_SCALARS, float: lambda v: type(v) is float and math.isfinite(v)}


@functools.lru_cache(maxsize=None)
def _plain(tp) -> Callable[[Any], bool] | None:
    """The plain test of a scalar or a union of scalars (:data:`_PLAIN`), else None."""
    if tp in _PLAIN:
        return _PLAIN[tp]
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        tests = [_plain(a) for a in typing.get_args(tp)]
        if all(tests):
            return functools.reduce(lambda f, g: lambda v: f(v) or g(v), tests)
    return None


@functools.lru_cache(maxsize=None)
def _hints(cls) -> dict[str, Any]:
    return typing.get_type_hints(cls)


def _name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_name(a) for a in typing.get_args(tp))
    if origin in (tuple, list):
        return "a list"
    if origin is dict or typing.is_typeddict(tp):
        return "an object"
    return {type(None): "null", Real: "a number", bool: "true/false", int: "an integer", float: "a number", str: "a string",
            dict: "an object", list: "a list"}.get(
        tp, getattr(tp, "__name__", str(tp)))


def convert(value: Any, tp, where: str) -> Any:
    """``value`` checked against the annotation ``tp`` (lists become tuples where ``tp`` says tuple);
    raises FvizError ``WHERE is ..., expected ...``."""
    return _checker(tp)(value, where)


Check = Callable[[Any, str], Any]


@functools.lru_cache(maxsize=None)
def _checker(tp) -> Check:  # noqa: C901 (one branch per annotation kind)
    """The check of annotation ``tp``, made once: ``check(value, where)`` -> the value (a record holds thousands)."""
    if tp in _SCALARS:
        ok = _SCALARS[tp]

        def scalar(v, where):
            if not ok(v):
                raise _bad(v, tp, where)
            return float(v) if tp is float else v

        return scalar
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        checks, plain = [_checker(a) for a in args], _plain(tp)

        def union(v, where):
            if plain is not None and plain(v):
                return v
            for check in checks:
                try:
                    return check(v, where)
                except FvizError:
                    continue
            raise _bad(v, tp, where)

        return union
    if origin is tuple and args and args[-1] is not Ellipsis:
        items, plains = [_checker(a) for a in args], [_plain(a) for a in args]
        plain = all(plains)

        def fixed(v, where):
            if not isinstance(v, list | tuple):
                raise _bad(v, tp, where)
            if plain and len(v) == len(items) and all(p(x) for p, x in zip(plains, v)):
                return tuple(v)
            if len(v) != len(items):
                raise FvizError(f"'{where}' has {len(v)} entries, expected {len(items)}")
            return tuple(check(x, f"{where}[{i}]") for i, (x, check) in enumerate(zip(v, items)))

        return fixed
    if origin in (tuple, list):
        item, kind, plain = _checker(args[0] if args else Any), origin, _plain(args[0] if args else Any)

        def sequence(v, where):
            if not isinstance(v, list | tuple):
                raise _bad(v, tp, where)
            if plain is not None and all(map(plain, v)):
                return kind(v)
            return kind(item(x, f"{where}[{i}]") for i, x in enumerate(v))

        return sequence
    if origin is dict:
        (key, val), plains = (_checker(a) for a in (args or (Any, Any))), [_plain(a) for a in args]
        plain = len(plains) == 2 and all(plains)

        def mapping(v, where):
            if not isinstance(v, dict):
                raise _bad(v, tp, where)
            if plain and all(map(plains[0], v)) and all(map(plains[1], v.values())):
                return dict(v)
            return {key(k, f"{where} key"): val(x, f"{where}.{k}") for k, x in v.items()}

        return mapping
    if tp in (dict, list):
        return lambda v, where: v if isinstance(v, tp) else _raise(_bad(v, tp, where))
    if dataclasses.is_dataclass(tp):
        return lambda v, where: tp(**fields_of(v, tp, where))
    if typing.is_typeddict(tp):
        return _keys_of(tp)
    return lambda v, where: v  # Any, and what has no check


def _raise(exc: Exception):
    raise exc


def _bad(value: Any, tp, where: str) -> Mismatch:
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
    return Mismatch(f"'{where}' is {shown} ({type(value).__name__}), expected {_name(tp)}", where, value)


def _keys_of(tp) -> Check:
    """The check of an object with the keys of the TypedDict ``tp``: its required keys present, each of its keys
    against its annotation; other keys are kept as they are (a record may carry more)."""
    keys = [(name, _checker(hint), name in tp.__required_keys__) for name, hint in _hints(tp).items()]

    def typed_dict(d, where):
        if not isinstance(d, dict):
            raise _bad(d, tp, where)
        prefix = f"{where}." if where else ""
        out = dict(d)
        for name, check, required in keys:
            if name in d:
                out[name] = check(d[name], prefix + name)
            elif required:
                raise FvizError(f"no '{prefix}{name}'")
        return out

    return typed_dict


def fields_of(d: Any, cls, where: str) -> dict[str, Any]:
    """The keyword arguments of dataclass ``cls`` from the object ``d``: unknown keys and keys without a
    default that are missing are refused, each value checked against its annotation."""
    if not isinstance(d, dict):
        raise FvizError(f"{repr(where) if where else 'the file'} is {type(d).__name__}, expected an object")
    hints = _hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    prefix = f"{where}." if where else ""
    unknown = [k for k in d if k not in fields]
    if unknown:
        raise FvizError(f"unknown key '{prefix}{unknown[0]}' (known: {', '.join(fields)})")
    out = {}
    for name, f in fields.items():
        if name not in d:
            if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING:
                raise FvizError(f"no '{prefix}{name}'")
            continue
        out[name] = convert(d[name], hints[name], f"{prefix}{name}")
    return out
