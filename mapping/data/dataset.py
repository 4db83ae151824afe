"""Dataset objects shared by all real-data layouts: where a frame's files are, how they are decoded,
and the lazy sequence of frames a loader returns.

A loader validates a scene at load time (folders, frame numbering, counts, trajectory) and keeps only
paths and poses; images are decoded when a frame is indexed, so a 2000-frame Replica scene costs a
few hundred kilobytes until it is used. This module imports no layout module, so ``replica`` and
``scannet`` build on it and ``loaders`` imports them at the top (no import circle).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TypeVar, overload

import numpy as np

from mapping.data.files import DatasetError, DatasetWarning, read_depth, read_labels, read_rgb
from mapping.data.frame import AgentSequence, Frame, Intrinsics, split_contiguous

T = TypeVar("T")


@dataclass(frozen=True)
class FrameFiles:
    """Where one frame lives on disk, plus its already-parsed pose (poses are small; images are not)."""

    index: int
    rgb: Path
    depth: Path
    pose: np.ndarray
    instance: Path | None = None


@dataclass(frozen=True)
class ReadSpec:
    """How files become a Frame: the output camera, the depth unit, and which images may be resized."""

    intrinsics: Intrinsics
    depth_scale: float
    resize_rgb: bool = False
    resize_instance: bool = False

    def read(self, f: FrameFiles) -> Frame:
        """Decode one frame; any unreadable or ill-sized image raises DatasetError naming it."""
        size = (self.intrinsics.width, self.intrinsics.height)
        rgb = read_rgb(f.rgb, size, resize=self.resize_rgb)
        depth = read_depth(f.depth, size, self.depth_scale)
        warn_if_no_depth(depth, f.depth)
        inst = None if f.instance is None else read_labels(f.instance, size, resize=self.resize_instance)
        return Frame(rgb, depth, f.pose.copy(), self.intrinsics, inst, timestamp=float(f.index), index=f.index)


def warn_if_no_depth(depth: np.ndarray, path: Path) -> None:
    """Warn (``DatasetWarning`` naming the file) when a depth frame has no valid pixel. ``read_depth`` has made
    NaN, infinite and negative readings 0 (missing), so a frame of only those reads like an all-zero one (a
    sensor dropout): it keeps its place, pose and colour and is mapped as an empty frame, nothing fused from it.
    Refusing it would stop a long run at one bad frame, and a lazy sequence cannot drop it without renumbering."""
    if not depth.any():
        warnings.warn(f"{path}: no valid depth pixel (every reading is zero, negative, NaN or infinite); the frame "
                      "is kept as an empty frame: nothing of it is mapped", DatasetWarning, stacklevel=3)


class LazyFrames(Sequence[Frame]):
    """A sequence of frames read from disk on ``__getitem__``, so long scenes are never all in memory.

    Slicing or :meth:`take` gives another LazyFrames over the same files (no image is read).
    """

    def __init__(self, files: Sequence[FrameFiles], spec: ReadSpec) -> None:
        self._files = tuple(files)
        self._spec = spec

    def __len__(self) -> int:
        return len(self._files)

    @overload
    def __getitem__(self, i: int) -> Frame: ...
    @overload
    def __getitem__(self, i: slice) -> "LazyFrames": ...
    def __getitem__(self, i: int | slice) -> "Frame | LazyFrames":
        if isinstance(i, slice):
            return LazyFrames(self._files[i], self._spec)
        return self._spec.read(self._files[i])

    def __iter__(self) -> Iterator[Frame]:
        return (self._spec.read(f) for f in self._files)

    def take(self, positions: Sequence[int]) -> "LazyFrames":
        """The frames at ``positions`` (positions in this sequence, not source indices)."""
        return LazyFrames([self._files[p] for p in positions], self._spec)

    @property
    def intrinsics(self) -> Intrinsics:
        """The camera of every frame (images are resampled to it where the layout allows)."""
        return self._spec.intrinsics

    @property
    def indices(self) -> list[int]:
        """Source frame numbers, in order."""
        return [f.index for f in self._files]

    @property
    def poses(self) -> np.ndarray:
        """(n, 4, 4) float64 camera-to-world poses, without reading any image."""
        return np.stack([f.pose for f in self._files]) if self._files else np.zeros((0, 4, 4))

    @property
    def files(self) -> tuple[FrameFiles, ...]:
        """The per-frame file records (paths and poses)."""
        return self._files


class RGBDDataset(LazyFrames):
    """A loaded scene: a lazy sequence of frames that can be cut into per-agent sequences."""

    def __init__(self, files: Sequence[FrameFiles], spec: ReadSpec, kind: str, root: Path,
                 skipped: Sequence[int] = ()) -> None:
        super().__init__(files, spec)
        if not self._files:
            raise DatasetError(f"{root}: no frames left to load")
        self.kind = kind
        self.root = Path(root)
        self.skipped = list(skipped)  # source frame numbers dropped at load (e.g. invalid ScanNet poses)

    @property
    def name(self) -> str:
        """Short scene name (the folder name)."""
        return self.root.name

    @property
    def depth_scale(self) -> float:
        """Raw depth units per metre."""
        return self._spec.depth_scale

    def subset(self, positions: Sequence[int] | range) -> "RGBDDataset":
        """The same scene restricted to the frames at ``positions`` (e.g. ``range(len(ds))[a:b:s]``)."""
        positions = list(positions)
        if not positions:
            raise DatasetError(f"{self.root}: the frame selection leaves no frame (of {len(self)})")
        return RGBDDataset([self._files[p] for p in positions], self._spec, self.kind, self.root, self.skipped)

    def split(self, n_agents: int, mode: str = "contiguous") -> list[AgentSequence]:
        """Cut the scene into one sequence per agent.

        ``"contiguous"`` gives consecutive chunks (the paper's K data sets per scene);
        ``"interleaved"`` deals frames round-robin, so every agent sees the whole trajectory sparsely.
        """
        n = len(self)
        if mode == "contiguous":
            parts = [list(r) for r in split_contiguous(n, n_agents)]
        elif mode == "interleaved":
            split_contiguous(n, n_agents)  # same argument checks
            parts = [list(range(k, n, n_agents)) for k in range(n_agents)]
        else:
            raise ValueError(f"split mode must be 'contiguous' or 'interleaved', got {mode!r}")
        return [AgentSequence(k, self.take(p), name=f"{self.name}/agent_{k}") for k, p in enumerate(parts)]

    def __repr__(self) -> str:
        k = self.intrinsics
        return f"RGBDDataset(kind={self.kind!r}, root='{self.root}', frames={len(self)}, size={k.width}x{k.height})"


def select(items: Sequence[T], stride: int = 1, max_frames: int | None = None) -> list[T]:
    """Every ``stride``-th item, then at most ``max_frames`` of them (argument checks included)."""
    if int(stride) != stride or stride < 1:
        raise ValueError(f"stride must be a positive integer, got {stride}")
    if max_frames is not None and max_frames < 1:
        raise ValueError(f"max_frames must be >= 1 or None, got {max_frames}")
    out = list(items)[:: int(stride)]
    return out if max_frames is None else out[:max_frames]


def check_depth_scale(scale: float) -> float:
    """A positive, finite depth scale as float."""
    if not math.isfinite(scale) or scale <= 0:
        raise ValueError(f"depth_scale must be positive and finite, got {scale}")
    return float(scale)
