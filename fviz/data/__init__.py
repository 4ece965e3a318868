"""Data sources: everything produces a :class:`fviz.data.pair.Pair`."""

from fviz.data.pair import Pair, PairId

__all__ = ["Pair", "PairId"]
