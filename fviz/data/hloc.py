"""hloc's matches.h5 and features.h5 as a user's matches (``--matches``): image names as hloc writes them, pixel-centre
keypoints (OpenCV's origin, as hloc's own files), one-line errors naming the file and the dataset."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fviz.data.correspondences import HLOC_PIXEL_SHIFT, Correspondences, check_inside, from_match_vector
from fviz.errors import FvizError


def hloc_name(pair, v: str) -> str:
    """The name fviz gives image ``v`` ("a" or "b") in hloc files (a run's feature cache): the source's name of
    the image (relative to --images), else its file's path relative to the source's root (KITTI:
    ``odometry/dataset/sequences/00/image_0/000003.png``), else the frame's key (synthetic)."""
    pid = pair.id
    named, path = getattr(pid, f"image_{v}"), pair.extra.get(f"path_{v}")
    if named:
        return named
    if path and pid.root:
        try:
            return Path(path).resolve().relative_to(Path(pid.root).resolve()).as_posix()
        except ValueError:
            pass
    return getattr(pid, f"key_{v}")


def _candidates(pair, v: str) -> list[str]:
    """Names an image may have in an hloc file: fviz's own (:func:`hloc_name`), the source's name, then the
    path's tails (KITTI: image_0/000003.png, ...)."""
    named = getattr(pair.id, f"image_{v}")
    parts = Path(pair.extra.get(f"path_{v}", named)).parts
    tails = ["/".join(parts[i:]) for i in range(len(parts))]
    return list(dict.fromkeys([n for n in [hloc_name(pair, v), named, *reversed(tails[-4:])] if n]))


def names_to_pair(name0: str, name1: str, separator: str = "/") -> str:
    """hloc's key of a pair in matches.h5."""
    return separator.join((name0.replace("/", "-"), name1.replace("/", "-")))


class HlocReader:
    """hloc's matches.h5 and features.h5 (see the module doc)."""

    single = False

    def __init__(self, path: Path):
        import h5py

        self.path = path
        self.features = self._features_file(path)
        self._h5 = h5py

    @staticmethod
    def _features_file(path: Path) -> Path:
        # hloc names a matches file f"{features}_{matches}_{pairs}.h5" beside its f"{features}.h5"
        named = [p for p in path.parent.glob("*.h5") if p != path and path.stem.startswith(p.stem + "_")]
        if named:
            return max(named, key=lambda p: len(p.stem))
        beside = path.parent / "features.h5"
        if beside.is_file():
            return beside
        import h5py

        found = []
        for other in sorted(path.parent.glob("*.h5")):
            if other == path:
                continue
            try:
                with h5py.File(other, "r") as f:
                    has = []
                    f.visit(lambda name: has.append(name) if name.endswith("keypoints") else None)
                    if has:
                        found.append(other)
            except OSError:
                continue
        if len(found) != 1:
            what = "none" if not found else ", ".join(p.name for p in found)
            raise FvizError(f"--matches {path}: hloc's features file not found beside it (FEATURES.h5 beside hloc's "
                            f"FEATURES_matches-..._PAIRS.h5, features.h5, or one other .h5 with keypoints; found {what}): "
                            "name it so, or copy it to features.h5 beside the matches file")
        return found[0]

    def _open(self, path: Path):
        try:
            return self._h5.File(path, "r")
        except OSError as exc:
            raise FvizError(f"--matches {path}: not a readable HDF5 file ({exc})") from None

    def for_pair(self, pair) -> Correspondences:
        names_a, names_b = _candidates(pair, "a"), _candidates(pair, "b")
        with self._open(self.path) as mf, self._open(self.features) as ff:
            for a in names_a:
                for b in names_b:
                    for key, reverse in ((names_to_pair(a, b), False), (names_to_pair(b, a), True),
                                         (names_to_pair(a, b, "_"), False), (names_to_pair(b, a, "_"), True)):
                        if key in mf and isinstance(mf[key], self._h5.Group) and "matches0" in mf[key]:
                            c = self._read(mf, ff, key, (b, a) if reverse else (a, b), reverse, pair)
                            try:
                                return check_inside(c, pair)
                            except FvizError as exc:
                                raise FvizError(f"{exc}{self._exif_hint(pair)}") from None
        raise FvizError(f"--matches {self.path}: no pair {names_to_pair(names_a[0], names_b[0])} (nor reversed) for "
                        f"{pair.id.name}")

    def _read(self, mf, ff, key: str, names: tuple[str, str], reverse: bool, pair) -> Correspondences:
        where = f"{self.path}:{key}"
        kps = []
        for n, v in zip(names, "ba" if reverse else "ab"):
            if n not in ff or "keypoints" not in ff[n]:
                raise FvizError(f"--matches {self.features}: no keypoints of image {n}")
            kp = np.asarray(ff[n]["keypoints"][()])
            if not (np.issubdtype(kp.dtype, np.number) and kp.ndim == 2 and kp.shape[1] == 2):
                raise FvizError(f"--matches {self.features}: keypoints of image {n} are {kp.dtype} {kp.shape}, expected "
                                "numbers (N, 2)")
            kps.append(self._shown(kp.astype(float) - HLOC_PIXEL_SHIFT, ff[n], n, pair, v))
        g = mf[key]
        scores = g["matching_scores0"][()] if "matching_scores0" in g else None
        c = from_match_vector(kps[0], kps[1], g["matches0"][()], scores, where)
        return c.swapped() if reverse else c

    @staticmethod
    def _exif_hint(pair) -> str:
        """Why keypoints may lie outside an image: its EXIF orientation, when it has one."""
        from fviz.data.images import image_header

        for v in "ab":
            path = pair.extra.get(f"path_{v}")
            header = image_header(path) if path else None
            if header is not None and header.orientation != 1:
                return f" (image {v} has EXIF orientation {header.orientation}, which fviz applies and hloc does not)"
        return ""

    def _shown(self, kp: np.ndarray, group, name: str, pair, v: str) -> np.ndarray:
        """Keypoints of image ``v`` in the image as fviz shows it. hloc reads an image as stored, ignoring its
        EXIF orientation (its ``image_size`` is the stored width, height) and knows nothing of a pairs file's
        rot; fviz applies both (the orientation as OpenCV does): hloc's keypoints are turned with them, with a
        note. fviz's own files (groups with its settings attribute) hold keypoints of the shown image already."""
        from fviz.data.images import EXIF_TURNS, exif_map, image_header, rotation_map

        if "fviz_settings" in group.attrs:
            return kp
        size = tuple(int(x) for x in np.asarray(group["image_size"][()]).reshape(-1)[:2]) \
            if "image_size" in group and np.size(group["image_size"]) >= 2 else None
        path = pair.extra.get(f"path_{v}")
        header = image_header(path) if path else None
        k = int(pair.extra.get("rot", (0, 0))["ab".index(v)]) % 4
        shown = tuple(pair.size_a if v == "a" else pair.size_b)
        o = header.orientation if header is not None else 1
        upright = shown[::-1] if k % 2 else shown  # the image before the pairs file's rot
        stored = upright[::-1] if o >= 5 else upright
        turn = EXIF_TURNS.get(o, f"mirrored (EXIF orientation {o})")
        if size is None:
            if o != 1:
                pair.notes.append(f"image {name} has EXIF orientation {o} ({turn}), applied by fviz; the hloc file gives "
                                  "no image_size to tell whether its keypoints were taken before it (hloc's do)")
                return kp
        elif size != stored:
            if size == shown:  # keypoints of the image as fviz shows it (a tool that applied the orientation)
                if o != 1:
                    pair.notes.append(f"the keypoints of {name} are taken as of the image turned by its EXIF orientation "
                                      f"{o}: their image_size is {size[0]}x{size[1]}, as shown, not as stored")
                return kp
            raise FvizError(f"--matches {self.features}: image {name} is {size[0]}x{size[1]} in its image_size, "
                            f"{stored[0]}x{stored[1]} as stored here{f' (EXIF orientation {o})' if o != 1 else ''}: "
                            "keypoints of another image, or of a resized one")
        A = rotation_map(k, *upright) @ exif_map(o, *stored)
        why = [f"its EXIF orientation {o} ({turn}), which hloc ignores" if o != 1 else "",
               f"the pairs file's rot {k}" if k else ""]
        if any(why):
            pair.notes.append(f"hloc's keypoints of {name} turned by {' and '.join(w for w in why if w)}")
        return kp @ A[:2, :2].T + A[:2, 2]


# ------------------------------------------------------------------------------ opening by flag


# ------------------------------------------------------------------------------ writing (an edited match set)


def write_matches(folder: str | Path, pair, x_a: np.ndarray, x_b: np.ndarray, scores: np.ndarray | None = None) -> tuple[Path, Path]:
    """One pair's matches as hloc files in ``folder``: ``features.h5`` (one keypoint per match end in each image,
    named by :func:`hloc_name`, pixel centres at integers as hloc's) and ``matches.h5`` (``matches0``: keypoint i of
    a to keypoint i of b; ``matching_scores0``: ``scores`` or 1). ``--matches folder/matches.h5`` reads them back.
    x_a, x_b: (M, 2); scores: (M,). Each file written whole or not at all."""
    import h5py

    from fviz.atomic import replacing

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    names = hloc_name(pair, "a"), hloc_name(pair, "b")
    n = len(x_a)
    features, matches = folder / "features.h5", folder / "matches.h5"
    with replacing(features) as tmp, h5py.File(tmp, "w") as f:
        for name, x, size in zip(names, (x_a, x_b), (pair.size_a, pair.size_b)):
            g = f.create_group(name)
            g.create_dataset("keypoints", data=np.asarray(x, float) + HLOC_PIXEL_SHIFT)
            g.create_dataset("image_size", data=np.asarray(size, np.int64))
            g.attrs["fviz_settings"] = "edited in fviz (one keypoint per match)"  # the shown image's pixels
    with replacing(matches) as tmp, h5py.File(tmp, "w") as f:
        g = f.create_group(names_to_pair(*names))
        g.create_dataset("matches0", data=np.arange(n, dtype=np.int32))
        g.create_dataset("matching_scores0", data=(np.ones(n) if scores is None else np.asarray(scores)).astype(np.float32))
    return features, matches
