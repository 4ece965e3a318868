"""A user's correspondence files opened by what the path is (``--matches``, ``--gt-matches``): a text or npz table, a
folder of per-pair files, SuperGlue's npz, hloc's matches.h5 (:mod:`fviz.data.correspondences`, :mod:`fviz.data.hloc`)."""

from __future__ import annotations

from pathlib import Path

from fviz.data.correspondences import SuperGlueReader, TableReader, open_npz
from fviz.data.hloc import HlocReader
from fviz.errors import FvizError


def open_matches(path: str | Path):
    """The reader of ``--matches`` by what the path is (see the module doc)."""
    path = Path(path)
    if not path.exists():
        raise FvizError(f"--matches {path}: no such file or folder")
    if path.is_dir():
        if any(path.glob("*_matches.npz")):
            return SuperGlueReader(path)
        return TableReader(path, "--matches", (4, 5), "{stem0}_{stem1}.txt", gt=False)
    if path.suffix in (".h5", ".hdf5"):
        return HlocReader(path)
    if path.suffix == ".npz":
        with open_npz(path, "--matches") as z:
            superglue = all(k in z for k in SuperGlueReader.KEYS)
        return SuperGlueReader(path) if superglue else TableReader(path, "--matches", (4, 5), "", gt=False)
    return TableReader(path, "--matches", (4, 5), "", gt=False)


def open_gt_matches(path: str | Path) -> TableReader:
    path = Path(path)
    if not path.exists():
        raise FvizError(f"--gt-matches {path}: no such file or folder")
    return TableReader(path, "--gt-matches", (4, 7), "{stem0}_{stem1}.txt", gt=True)
