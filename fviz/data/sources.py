"""The user sources by flag: a pairs file (``--pairs``), a COLMAP model (``--colmap``), two images, and the
correspondences a user brings for any source (``--matches``, ``--gt-matches``, :mod:`fviz.data.correspondences`).
Each source has ``pair_ids()``, ``load(pid)``, ``ground_truth(pid)`` and ``inspect_args(pid)``."""

from __future__ import annotations

from pathlib import Path

from fviz.data.pair import Pair, PairId
from fviz.digest import digest_of, file_digest
from fviz.errors import FvizError

COLMAP_MIN_SHARED = 100


def user_source(pairs=None, images=None, colmap=None, min_shared: int = COLMAP_MIN_SHARED,
                frames: tuple[int | None, int | None] = (None, None)):
    """The pairs of ``--colmap`` (optionally restricted to ``--pairs``) or of ``--pairs``; None without either."""
    if colmap is not None:
        from fviz.data.colmap import ColmapSource

        return ColmapSource(colmap, images, pairs, min_shared, frames)
    if pairs is not None:
        from fviz.data.pairsfile import PairsSource

        return PairsSource(pairs, images, frames)
    if images is not None:
        raise FvizError(f"--images {images}: give the pairs with --pairs FILE or --colmap MODEL_DIR")
    return None


class TwoImagesSource:
    """``--image-a A --image-b B`` in eval / triage: one pair (with the ground truth the flags give)."""

    def __init__(self, image_a: str, image_b: str, gt: dict[str, str | None]):
        from fviz.data.images import two_images

        self.args = (image_a, image_b, gt)
        self.pair0 = two_images(image_a, image_b, **gt)  # the flags checked (and the images read) before any work

    def pair_ids(self) -> list[PairId]:
        return [self.pair0.id]

    def load(self, pid: PairId) -> Pair:
        from fviz.data.images import two_images

        image_a, image_b, gt = self.args
        return two_images(image_a, image_b, **gt)

    def ground_truth(self, pid: PairId):
        return self.pair0.F_gt

    def input_digest(self, pid: PairId) -> str:
        p = self.pair0
        return digest_of(*(getattr(p, k, None) for k in ("F_gt", "K_a", "K_b", "R", "t")))

    def inspect_args(self, pid: PairId) -> list[str]:
        image_a, image_b, gt = self.args
        flags = {"K": "--K", "K_a": "--K-a", "K_b": "--K-b", "T_ab": "--T-ab", "F_gt": "--F-gt"}
        return ["--image-a", image_a, "--image-b", image_b, *(x for k, v in gt.items() if v for x in (flags[k], v))]


class WithCorrespondences:
    """A source whose pairs carry the user's matches and/or ground-truth correspondences."""

    def __init__(self, source, matches: str | Path | None, gt_matches: str | Path | None, n_pairs: int | None = None):
        from fviz.data.match_files import open_gt_matches, open_matches

        self.source = source
        self.matches = open_matches(matches) if matches else None
        self.gt_matches = open_gt_matches(gt_matches) if gt_matches else None
        count = n_pairs if n_pairs is not None else len(source.pair_ids())
        for reader, flag in ((self.matches, "--matches"), (self.gt_matches, "--gt-matches")):
            if reader is not None and reader.single and count > 1:
                raise FvizError(f"{flag} {reader.path}: holds the correspondences of one pair, the selection has {count} "
                                "(give a file per pair: a folder, or an hloc matches.h5)")

    def __getattr__(self, name):
        return getattr(self.source, name)

    def load(self, pid: PairId) -> Pair:
        return attach(self.source.load(pid), self.matches, self.gt_matches)

    def ground_truth(self, pid: PairId):
        return self.load(pid).F_gt if self.gt_matches else self.source.ground_truth(pid)

    def input_digest(self, pid: PairId) -> str:
        inner = getattr(self.source, "input_digest", None)
        return digest_of(inner(pid) if inner else None, *(reader_digest(r, pid) for r in (self.matches, self.gt_matches)))

    def inspect_args(self, pid: PairId) -> list[str]:
        extra = [*(["--matches", str(self.matches.path)] if self.matches else []),
                 *(["--gt-matches", str(self.gt_matches.path)] if self.gt_matches else [])]
        return self.source.inspect_args(pid) + extra


def attach(pair: Pair, matches, gt_matches) -> Pair:
    """The pair with the user's matches and ground-truth correspondences (F_gt fitted to those)."""
    from fviz.data.correspondences import fit_gt

    from fviz.data.correspondences import small_extent_note

    if matches is not None:
        pair.matches = matches.for_pair(pair)
        pair.notes.append(f"matches: {len(pair.matches.x_a)} from {pair.matches.path} (fviz's features not used)")
        note = small_extent_note(pair.matches, pair)
        if note:
            pair.notes.append(note)
    if gt_matches is not None:
        c = gt_matches.for_pair(pair)
        F, accuracy, note = fit_gt(c, pair)
        pair.F_gt, pair.gt_points, pair.R, pair.t, pair.gt_accuracy_px = F, (c.x_a, c.x_b), None, None, accuracy
        pair.notes.append(note)
    return pair


# ------------------------------------------------------------------------------ what a record's fingerprint covers


def reader_digest(reader, pid: PairId) -> str | None:
    """The content of the correspondences file(s) ``reader`` takes the pair ``pid`` from: its own file in a
    folder of per-pair files (the whole folder when the pair's image names are unknown), else the file."""
    if reader is None:
        return None
    path = Path(reader.path)
    if getattr(reader, "features", None) is not None:  # hloc: matches.h5 and the features file beside it
        return digest_of(file_digest(path), file_digest(reader.features))
    if not path.is_dir():
        return file_digest(path)
    pattern = getattr(reader, "pattern", None) or "{stem0}_{stem1}_matches.npz"
    if pid.image_a and pid.image_b:
        stems = (Path(pid.image_a).stem, Path(pid.image_b).stem)
        names = [pattern.format(stem0=stems[0], stem1=stems[1]), pattern.format(stem0=stems[1], stem1=stems[0])]
        return digest_of(*(f"{n}:{file_digest(path / n)}" for n in names))
    if getattr(reader, "_folder_digest", None) is None:  # once per reader: a KITTI run asks it for every pair
        reader._folder_digest = digest_of(*(f"{p.name}:{file_digest(p)}" for p in sorted(path.iterdir()) if p.is_file()))
    return reader._folder_digest


