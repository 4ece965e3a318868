"""Which pairs, without flags: a :class:`Selection` (a KITTI sequence or drive, kinds x steps over a frame range;
synthetic seeds; or a user's source: two images, a pairs file, a COLMAP model, with their matches) and the KITTI and
synthetic sources it opens. The API's ``fviz.select`` and a run's configuration (``run.json``) both use it."""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from fviz.data.kitti import PAIR_KINDS
from fviz.data.pair import PairId
from fviz.errors import FvizError, note_once



def user_source_conflict(pairs, colmap) -> str:
    """Why a KITTI or synthetic flag goes with a user's source (it would be ignored): the rest of a one-line error."""
    if pairs is None and colmap is None:
        return ("not with --image-a/--image-b (the two images are the pair; the flag would be ignored): "
                "give one source")
    return "not with --pairs / --colmap (their pairs are listed; select lines with --frames A:B)"


@dataclass(frozen=True)
class Selection:
    """Which pairs: a KITTI sequence/drive (kinds x steps over a frame range) or synthetic seeds.

    frames: (start, end) of camera-0 frames, end exclusive, None = the sequence's ends; both frames
    of a pair lie in the range. seeds: (first, last + 1) of synthetic scenes, one pair per seed and kind.
    """

    kitti_root: str | None = None
    sequence: str | None = None
    drive: str | None = None
    kinds: tuple[str, ...] = ("stereo",)
    steps: tuple[int, ...] = (1,)
    cams: tuple[int, int] | None = None
    frames: tuple[int | None, int | None] = (None, None)
    synthetic: bool = False
    seeds: tuple[int, int] | None = None
    pairs: str | None = None  # a user's pairs file (fviz.data.pairsfile), or the pairs to take of --colmap
    images: str | None = None
    colmap: str | None = None
    min_shared: int = 100
    matches: str | None = None  # the user's matches for every pair (fviz.data.correspondences)
    gt_matches: str | None = None
    image_a: str | None = None  # two images (fviz.data.images) and the ground truth their flags give
    image_b: str | None = None
    K: str | None = None
    K_a: str | None = None
    K_b: str | None = None
    T_ab: str | None = None
    F_gt: str | None = None

    @property
    def user(self) -> bool:
        """Whether the pairs are a user's (--pairs / --colmap / --image-a) rather than KITTI or synthetic ones."""
        return self.pairs is not None or self.colmap is not None or self.image_a is not None or self.image_b is not None

    def _images_source(self):
        from fviz.data.sources import TwoImagesSource

        if self.pairs is not None or self.colmap is not None:
            raise FvizError("--image-a/--image-b and --pairs/--colmap: choose one source")
        if self.image_a is None or self.image_b is None:
            raise FvizError(f"--image-{'a' if self.image_a is None else 'b'}: missing (give both images)")
        return TwoImagesSource(self.image_a, self.image_b, dict(K=self.K, K_a=self.K_a, K_b=self.K_b, T_ab=self.T_ab, F_gt=self.F_gt))

    def __post_init__(self):
        if self.user:
            others = {"--kitti-root": self.kitti_root, "--sequence": self.sequence, "--drive": self.drive,
                      "--cams": self.cams, "--synthetic": self.synthetic or None, "--seeds": self.seeds,
                      "--step": self.steps != (1,) or None, "--pair": self.kinds != ("stereo",) or None}
            given = [flag for flag, v in others.items() if v is not None]
            if given:
                raise FvizError(f"{given[0]}: {user_source_conflict(self.pairs, self.colmap)}")
            return
        for kind in self.kinds:
            if kind not in PAIR_KINDS:
                raise FvizError(f"--pair {kind!r}: choose one of {', '.join(PAIR_KINDS)}")
        if not self.kinds:
            raise FvizError("--pair: give at least one of stereo, temporal")
        if any(s < 1 for s in self.steps):
            raise FvizError(f"--step {min(self.steps)}: must be >= 1")
        if self.synthetic and self.seeds is None:
            raise FvizError("--synthetic: give the scenes as --seeds A:B (seeds A .. B-1)")
        if not self.synthetic and self.seeds is not None:
            raise FvizError("--seeds: only with --synthetic")
        if self.synthetic:
            kitti_only = {"--kitti-root": self.kitti_root, "--sequence": self.sequence, "--drive": self.drive,
                          "--cams": self.cams, "--frames": self.frames != (None, None) or None,
                          "--step": self.steps != (1,) or None}
            given = [flag for flag, v in kitti_only.items() if v is not None]
            if given:
                raise FvizError(f"{given[0]}: KITTI selections only, not with --synthetic (select scenes with --seeds A:B)")
        if self.seeds is not None and not 0 <= self.seeds[0] < self.seeds[1]:
            raise FvizError(f"--seeds {self.seeds[0]}:{self.seeds[1]}: need 0 <= A < B")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Selection":
        """Each field checked against its type (:func:`fviz.schema.fields_of`)."""
        from fviz.schema import fields_of

        return cls(**fields_of(d, cls, "selection"))

    def source(self):
        """The pairs' source: KittiSource, SyntheticSource or a user's (fviz.data.sources), with the user's
        matches and ground-truth correspondences attached when given; made once per selection (a source
        reads calibration, poses and the image folders as it is asked)."""
        if "_source" not in self.__dict__:
            object.__setattr__(self, "_source", self._make_source())  # not a field: neither compared nor saved
        return self.__dict__["_source"]

    def _make_source(self):
        gt_flags = [f for f, v in (("--K", self.K), ("--K-a", self.K_a), ("--K-b", self.K_b), ("--T-ab", self.T_ab),
                                   ("--F-gt", self.F_gt)) if v]
        if gt_flags and self.image_a is None and self.image_b is None:
            raise FvizError(f"{gt_flags[0]}: only with --image-a and --image-b")
        if self.image_a is not None or self.image_b is not None:
            source = self._images_source()
        elif self.user:
            from fviz.data.sources import user_source

            source = user_source(self.pairs, self.images, self.colmap, self.min_shared, self.frames)
        else:
            source = SyntheticSource(self) if self.synthetic else KittiSource(self)
        if self.matches or self.gt_matches:
            from fviz.data.sources import WithCorrespondences

            source = WithCorrespondences(source, self.matches, self.gt_matches)
        return source

    def describe(self) -> str:
        if self.image_a is not None:
            return f"images {self.image_a} -> {self.image_b}" + (f", matches {self.matches}" if self.matches else "")
        if self.user:
            what = f"COLMAP model {self.colmap}" if self.colmap else f"pairs file {self.pairs}"
            frames = "all pairs" if self.frames == (None, None) else f"pairs {_range_text(self.frames)}"
            return f"{what} ({frames})" + (f", matches {self.matches}" if self.matches else "")
        if self.synthetic:
            return f"synthetic seeds {self.seeds[0]}..{self.seeds[1] - 1} ({'/'.join(self.kinds)})"
        what = f"sequence {self.sequence}" if self.sequence else f"drive {self.drive}" if self.drive else "auto-detected"
        frames = "all frames" if self.frames == (None, None) else f"frames {_range_text(self.frames)}"
        steps = f", step {'/'.join(map(str, self.steps))}" if "temporal" in self.kinds else ""
        return f"KITTI {what} under {self.kitti_root}: {'/'.join(self.kinds)} pairs{steps}, {frames}"


def _range_text(r: tuple[int | None, int | None]) -> str:
    return f"{'' if r[0] is None else r[0]}:{'' if r[1] is None else r[1]}"


class KittiSource:
    """Pairs of one KITTI odometry sequence or raw drive."""

    def __init__(self, sel: Selection):
        from fviz.data.kitti import open_dataset

        if sel.kitti_root is None:
            raise FvizError("--kitti-root: missing (or set $FVIZ_KITTI_ROOT); use --synthetic --seeds A:B for scenes that need no dataset")
        self.sel = sel
        self.ds = open_dataset(sel.kitti_root, sel.sequence, sel.drive)

    def _frame_range(self) -> range:
        """The selected frames of the cameras the pairs use (a colour-only download has no camera 0)."""
        cams = {c for kind in self.sel.kinds for c in self.sel.cams or self.ds.default_cams(kind)}
        for cam in sorted(cams):
            self.ds.check_cam(cam)
        n = self.ds.frames_of(tuple(cams))
        start, end = self.sel.frames
        if end is None:  # by default, only the frames every camera of the pairs has
            common = min(self.ds.frame_counts[c] for c in cams)
            if common < n:
                short = min(cams, key=lambda c: self.ds.frame_counts[c])
                note_once(f"note: {self.ds.image_folder(short)} of {self.ds.name} has frames 0..{common - 1} only: "
                           f"the {n - common} later frames of the other cameras are left out (select them with --frames)")
                n = common
        start, end = 0 if start is None else start, n if end is None else end
        if not 0 <= start < end <= n:
            raise FvizError(f"--frames {_range_text(self.sel.frames)}: {self.ds.source} {self.ds.name} has frames 0..{n - 1} "
                            f"of cameras {','.join(map(str, sorted(cams)))} (START:END, END exclusive)")
        return range(start, end)

    def pair_ids(self) -> list[PairId]:
        """Frame-major (frame, kind, step) order, so that pairs sharing a frame are neighbours."""
        frames = self._frame_range()
        if "temporal" in self.sel.kinds:
            _ = self.ds.poses  # a one-line error now when the layout has no poses
        ids = []
        for frame in frames:
            for kind in self.sel.kinds:
                for step in self.sel.steps if kind == "temporal" else (0,):
                    if frame + step < frames.stop:
                        ids.append(self.ds.pair_id(frame, kind, max(step, 1), self.sel.cams))
        if not ids:
            if self.sel.frames == (None, None):
                raise FvizError(f"--step {max(self.sel.steps)}: longer than the {len(frames)} frames of {self.ds.name} "
                                f"({frames.start}..{frames.stop - 1}): no temporal pair fits")
            raise FvizError(f"--frames {_range_text(self.sel.frames)}: no pair fits in the range (step {max(self.sel.steps)})")
        return ids

    def load(self, pid: PairId):
        return self.ds.load(pid)

    def ground_truth(self, pid: PairId) -> np.ndarray:
        return self.ds.ground_truth(pid)[4]

    def inspect_args(self, pid: PairId) -> list[str]:
        """The ``fviz inspect pair`` flags that select this pair."""
        where = ["--sequence", self.ds.name] if self.ds.source == "odometry" else ["--drive", self.ds.name]
        args = ["--kitti-root", str(self.sel.kitti_root), *where, "--frame", str(pid.frame_a), "--pair", pid.kind]
        if pid.kind == "temporal":
            args += ["--step", str(pid.frame_b - pid.frame_a)]
        return args + ["--cams", f"{pid.cam_a},{pid.cam_b}"]


class SyntheticSource:
    """One synthetic pair per seed and kind (:mod:`fviz.data.synthetic`, imported lazily)."""

    def __init__(self, sel: Selection):
        try:
            from fviz.data import synthetic
        except ImportError as exc:
            raise FvizError(f"--synthetic: the synthetic data source is not available ({exc})") from None
        self.sel, self.mod = sel, synthetic

    def _config(self, kind: str):
        return self.mod.SceneConfig(stereo=kind == "stereo")

    def pair_ids(self) -> list[PairId]:
        a, b = self.sel.seeds
        return [PairId("synthetic", str(seed), kind, 0, 1, 0, 1 if kind == "stereo" else 0)
                for seed in range(a, b) for kind in self.sel.kinds]

    def load(self, pid: PairId):
        return self.mod.synthetic_pair(int(pid.sequence), self._config(pid.kind))

    def ground_truth(self, pid: PairId) -> np.ndarray:
        """F of the pair (the public API renders the pair: only the mean-F baselines need this)."""
        return self.load(pid).F_gt

    def inspect_args(self, pid: PairId) -> list[str]:
        # inspect's --seed seeds both the scene and the robust estimators.
        return ["--synthetic", "--seed", pid.sequence, "--pair", pid.kind]


# ------------------------------------------------------------------------------ configuration
