"""Failures grouped by cause, where the user looks (issue 28 §2): eval and triage print them at the end, summary.md and
summary.json hold them. A *pair error*: the pair could not be evaluated at all (its record's ``error``); an estimator's
*error*: it gave no F on a pair (its ``error``). Neither is a metric's verdict: a metric "fails" a pair only past its
threshold (:mod:`fviz.verdicts`).

Errors are grouped by their cause: the message with what varies from pair to pair (file and folder names, numbers)
left out; each group keeps its count and one example, the first pair's own message."""

from __future__ import annotations

import re
from typing import Any, Iterable

# what varies between pairs in one cause's messages: paths and file names, numbers
_VOLATILE = re.compile(r"[^\s:;,()\[\]'\"`]*(?:[/\\]|\.[A-Za-z][A-Za-z0-9]{0,4}\b)[^\s:;,()\[\]'\"`]*"
                       r"|(?<![\w-])\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def cause(message: str) -> str:
    """An error's cause: its first line with file names, paths and numbers replaced by ``…``."""
    first = (message or "").strip().splitlines()[0] if (message or "").strip() else "(no message)"
    return _VOLATILE.sub("…", first)


class Failures:
    """Pair and estimator failures of a run, grouped by cause, fed one record (results.jsonl) at a time."""

    def __init__(self) -> None:
        self.pairs = 0
        self.pair_groups: dict[str, dict[str, Any]] = {}
        self.estimator_groups: dict[tuple[str, str], dict[str, Any]] = {}

    def add(self, rec: dict[str, Any]) -> None:
        self.pairs += 1
        key = rec.get("key") or str(rec.get("index"))
        if rec.get("error"):
            _count(self.pair_groups, cause(rec["error"]), rec["error"], key)
            return
        for e in (rec.get("result") or {}).get("estimators", []):
            if e.get("error"):
                g = _count(self.estimator_groups, (e["name"], cause(e["error"])), e["error"], key)
                g["estimator"] = e["name"]

    def document(self) -> dict[str, Any]:
        """summary.json's ``failures``: {"pairs": [{cause, count, example, pair}], "estimators": [{estimator, cause,
        count, of, example, pair}]}, most frequent first."""
        order = lambda groups: sorted(groups.values(), key=lambda g: -g["count"])  # noqa: E731 (stable: first seen)
        evaluated = self.pairs - sum(g["count"] for g in self.pair_groups.values())  # of: the pairs it was run on
        return {"pairs": order(self.pair_groups),
                "estimators": [{**g, "of": evaluated} for g in order(self.estimator_groups)]}


def _count(groups: dict, key, message: str, pair: str) -> dict[str, Any]:
    g = groups.setdefault(key, {"cause": key if isinstance(key, str) else key[1], "count": 0,
                                "example": message.strip().splitlines()[0], "pair": pair})
    g["count"] += 1
    return g


def failure_lines(doc: dict[str, Any] | None) -> list[str]:
    """One line per cause: "5 pairs not evaluated (error): <example> (e.g. <pair>)", "ahead: error (no F) on 1/1
    pairs: <example> (e.g. <pair>)"."""
    if not doc:
        return []
    lines = [f"{g['count']} pair{'s' if g['count'] != 1 else ''} not evaluated (error): {g['example']} (e.g. {g['pair']})"
             for g in doc.get("pairs", [])]
    lines += [f"{g['estimator']}: error (no F) on {g['count']}/{g['of']} pairs: {g['example']} (e.g. {g['pair']})"
              for g in doc.get("estimators", [])]
    return lines


def failure_markdown(doc: dict[str, Any] | None) -> list[str]:
    """summary.md's "Failures" section (empty when nothing failed)."""
    lines = failure_lines(doc)
    if not lines:
        return []
    return ["## Failures", "",
            "Errors grouped by cause (file names and numbers aside), with one example each: a pair error leaves a pair "
            "unevaluated; an estimator's error leaves it without an F there (not the same as *fails*: a value past "
            "its metric's threshold). results.jsonl holds every pair's own reason.", "",
            *(f"- {line}" for line in lines), ""]


def failures_of(records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    f = Failures()
    for rec in records:
        f.add(rec)
    return f.document()
