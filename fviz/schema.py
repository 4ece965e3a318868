"""The one typed-config validator: a value checked against a type annotation (:func:`convert`) and a dataclass's fields
from a dict (:func:`fields_of`), for run.json and the training recipes (:mod:`fviz.train.recipe` adds its bounds and
wording); so a hand-edited file is a one-line error naming the field, never a TypeError deep in a run."""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from typing import Any

from fviz.errors import FvizError


def _name(tp) -> str:
    origin = typing.get_origin(tp)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_name(a) for a in typing.get_args(tp))
    if origin in (tuple, list):
        return "a list"
    if origin is dict:
        return "an object"
    return {type(None): "null", bool: "true/false", int: "an integer", float: "a number", str: "a string",
            dict: "an object", list: "a list"}.get(
        tp, getattr(tp, "__name__", str(tp)))


def convert(value: Any, tp, where: str) -> Any:  # noqa: C901 (one branch per annotation kind; issue 41: one validator for run.json, recipes, records)
    """``value`` checked against the annotation ``tp`` (lists become tuples where ``tp`` says tuple);
    raises FvizError ``WHERE is ..., expected ...``."""
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        for arg in args:
            try:
                return convert(value, arg, where)
            except FvizError:
                continue
        raise _bad(value, tp, where)
    if tp is type(None):
        if value is not None:
            raise _bad(value, tp, where)
        return None
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise _bad(value, tp, where)
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise _bad(value, tp, where)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise _bad(value, tp, where)
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise _bad(value, tp, where)
        return value
    if origin in (tuple, list):
        if not isinstance(value, list | tuple):
            raise _bad(value, tp, where)
        if origin is tuple and args and args[-1] is not Ellipsis:
            if len(value) != len(args):
                raise FvizError(f"'{where}' has {len(value)} entries, expected {len(args)}")
            items = [convert(v, a, f"{where}[{i}]") for i, (v, a) in enumerate(zip(value, args))]
        else:
            item = args[0] if args else Any
            items = [convert(v, item, f"{where}[{i}]") for i, v in enumerate(value)]
        return tuple(items) if origin is tuple else items
    if origin is dict:
        if not isinstance(value, dict):
            raise _bad(value, tp, where)
        key_tp, val_tp = args or (Any, Any)
        return {convert(k, key_tp, f"{where} key"): convert(v, val_tp, f"{where}.{k}") for k, v in value.items()}
    if tp in (dict, list):
        if not isinstance(value, tp):
            raise _bad(value, tp, where)
        return value
    if dataclasses.is_dataclass(tp):
        return tp(**fields_of(value, tp, where))
    return value


def _bad(value: Any, tp, where: str) -> FvizError:
    shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
    return FvizError(f"'{where}' is {shown} ({type(value).__name__}), expected {_name(tp)}")


def fields_of(d: Any, cls, where: str) -> dict[str, Any]:
    """The keyword arguments of dataclass ``cls`` from the object ``d``: unknown keys and keys without a
    default that are missing are refused, each value checked against its annotation."""
    if not isinstance(d, dict):
        raise FvizError(f"{repr(where) if where else 'the file'} is {type(d).__name__}, expected an object")
    hints = typing.get_type_hints(cls)
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
