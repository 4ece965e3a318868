"""Pair lists in the SuperGlue / LightGlue / LoFTR layout (``--pairs FILE --images DIR``).

One pair per line, whitespace-separated, ``#`` comments and blank lines skipped:

    name0 name1                                          no ground truth
    name0 name1 rot0 rot1 K0[9] K1[9] T_0to1[16]          (38 fields; 12 numbers for T are accepted too)

names are image paths relative to ``--images``; rot (0-3) EXIF quarter turns, applied as SuperGlue does
(``np.rot90``, the cameras and F turned with the image); K0, K1 row-major 3x3 at the image's resolution
(OpenCV pixel origin: SuperGlue's ScanNet / YFCC files use it); T_0to1 row-major, x1 = R x0 + t.
A line that cannot be read is one error naming the file and line (exit 2).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fviz.data.images import intrinsics, make_pair, pose_matrix
from fviz.data.pair import Pair, PairId
from fviz.errors import FvizError

SOURCE = "pairs"


@dataclass(frozen=True)
class PairLine:
    """One parsed line: names, rotations, and the optional cameras and pose."""

    line: int
    name0: str
    name1: str
    rot: tuple[int, int] = (0, 0)
    K0: np.ndarray | None = None
    K1: np.ndarray | None = None
    T: np.ndarray | None = None


def parse_line(fields: list[str], where: str, line: int) -> PairLine:
    if len(fields) == 2:
        return PairLine(line, *fields)
    if len(fields) not in (4, 22, 34, 38):  # names and rotations, then K0 K1, then T as 12 or 16 numbers
        raise FvizError(f"{where}: {len(fields)} fields; expected 'name0 name1' or 'name0 name1 rot0 rot1 K0[9] K1[9] "
                        "T_0to1[16]' (38 fields, or 34 with T as 12 numbers)")
    try:
        rot = (int(fields[2]), int(fields[3]))
        numbers = np.array([float(v) for v in fields[4:]], float)
    except ValueError:
        raise FvizError(f"{where}: rot0 rot1 must be integers and K0 K1 T_0to1 numbers") from None
    if not all(0 <= r <= 3 for r in rot):
        raise FvizError(f"{where}: rot {rot[0]} {rot[1]}: EXIF rotations are 0-3")
    if not np.isfinite(numbers).all():
        raise FvizError(f"{where}: NaN or infinite numbers")
    if len(numbers) == 0:
        return PairLine(line, fields[0], fields[1], rot)
    if len(numbers) == 18:
        raise FvizError(f"{where}: K0 and K1 without T_0to1 (16 numbers)")
    K0 = intrinsics(numbers[:9], f"{where}: K0")
    K1 = intrinsics(numbers[9:18], f"{where}: K1")
    T = pose_matrix(numbers[18:], f"{where}: T_0to1")
    return PairLine(line, fields[0], fields[1], rot, K0, K1, T)


def read_pairs(path: str | Path) -> list[PairLine]:
    """Every pair of a pairs file; one-line errors name the file and line."""
    path = Path(path)
    if path.is_dir():
        raise FvizError(f"--pairs {path}: a folder, not a pairs file")
    from fviz.data.images import read_text

    text = read_text(path, "--pairs", "utf-8-sig")  # a byte-order mark some editors write is not part of a name
    out = []
    for n, raw in enumerate(text.splitlines(), 1):
        fields = raw.split("#", 1)[0].split()
        if fields:
            out.append(parse_line(fields, f"{path}:{n}", n))
    if not out:
        raise FvizError(f"--pairs {path}: no pairs in it")
    return out


def pair_range(frames: tuple[int | None, int | None], n: int, what: str) -> range:
    """``--frames START:END`` (END exclusive, either may be None) of ``n`` listed pairs; one-line error outside."""
    start, end = frames
    start, end = start or 0, n if end is None else end
    if not 0 <= start < end <= n:
        raise FvizError(f"--frames {frames[0] or ''}:{'' if frames[1] is None else frames[1]}: {what} has pairs "
                        f"0..{n - 1} (START:END, END exclusive)")
    return range(start, end)


class PairsSource:
    """The pairs of a pairs file over an image folder: ``pair_ids`` (optionally lines A:B of the
    pairs, counted from 0), ``load``, ``ground_truth`` (F without reading images when the line has a pose)."""

    def __init__(self, pairs: str | Path, images: str | Path | None, frames: tuple[int | None, int | None] = (None, None)):
        self.path = Path(pairs)
        self.images_given = images is not None
        self.images = Path(images) if images is not None else self.path.parent
        if not self.images.is_dir():
            raise FvizError(f"--images {self.images}: not a folder")
        self.lines = read_pairs(self.path)
        self.range = pair_range(frames, len(self.lines), str(self.path))

    @property
    def label(self) -> str:
        return self.path.stem

    def pair_id(self, index: int) -> PairId:
        p = self.lines[index]
        return PairId(SOURCE, self.label, "pair", index, index, root=str(self.images), image_a=p.name0, image_b=p.name1)

    def pair_ids(self) -> list[PairId]:
        return [self.pair_id(i) for i in self.range]

    def index_of(self, index: int | None, names: tuple[str, str] | None) -> int:
        """The pair ``--index N`` (from 0) or the first line naming both images."""
        if names is not None:
            found = [i for i, p in enumerate(self.lines) if (p.name0, p.name1) == names]
            if not found:
                raise FvizError(f"--pairs {self.path}: no line '{names[0]} {names[1]}'")
            return found[0]
        index = 0 if index is None else index
        if not 0 <= index < len(self.lines):
            raise FvizError(f"--index {index}: {self.path} has pairs 0..{len(self.lines) - 1}")
        return index

    def load(self, pid: PairId) -> Pair:
        p = self.lines[pid.frame_a]
        where = f"{self.path}:{p.line}"
        try:
            return make_pair(pid, self.images / p.name0, self.images / p.name1, p.K0, p.K1, p.T, None, p.rot, what=where,
                             what_K=(f"{where}: K0", f"{where}: K1"))
        except FvizError as exc:
            if self.images_given or not str(exc).endswith("no such file"):
                raise
            raise FvizError(f"{exc} (the names in --pairs {self.path} are relative to --images DIR, by default the pairs "
                            f"file's folder: give --images)") from None

    def ground_truth(self, pid: PairId) -> np.ndarray | None:
        from fviz.data.images import ground_truth

        p = self.lines[pid.frame_a]
        if p.T is None or any(p.rot):
            return self.load(pid).F_gt
        return ground_truth(p.K0, p.K1, p.T, None, f"{self.path}:{p.line}")["F_gt"]

    def input_digest(self, pid: PairId) -> str:
        """The pair's line as read (names, rotations, cameras, pose): an edited line is another pair's input."""
        from fviz.digest import digest_of

        p = self.lines[pid.frame_a]
        return digest_of(p.name0, p.name1, p.rot, p.K0, p.K1, p.T)

    def inspect_args(self, pid: PairId) -> list[str]:
        return ["--pairs", str(self.path), "--images", str(self.images), "--index", str(pid.frame_a)]


def format_line(name0: str, name1: str, K0: np.ndarray, K1: np.ndarray, T: np.ndarray, rot: tuple[int, int] = (0, 0)) -> str:
    """One pairs-file line (full precision), e.g. to write a KITTI pair in this layout."""
    T4 = np.eye(4)
    T4[: len(T)] = np.asarray(T, float).reshape(-1, 4)
    nums = [*np.asarray(K0, float).ravel(), *np.asarray(K1, float).ravel(), *T4.ravel()]
    return " ".join([name0, name1, str(rot[0]), str(rot[1]), *(repr(float(v)) for v in nums)])
