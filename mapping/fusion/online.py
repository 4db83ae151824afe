"""Cross-frame fusion that runs as the agent moves (causal), with instance ids stable over rounds.

Each round, the round's own frames are fused with OpenObj's two phases (``fuse_frames``: coarse
clustering, then fine merge) into round instances; each round instance is then associated with the
agent's persistent instances by 3D point overlap and caption similarity (OpenObj's fine-merge test:
overlap > 0.6 with similar captions, or overlap > 0.9, the overlap measured both ways) or becomes a
new persistent instance with the next id. A persistent instance never changes id; it only grows (its
cloud, running caption feature and confidence). Nothing here reads a frame that was not passed in.

Why this and not re-fusing all frames so far every round: that costs O(frames so far) per round
(about 3 s per 120 frames per agent, so O(rounds^2) over an episode) and re-numbers instances;
fusing the round alone costs O(frames per round).

Instances can also be added from outside (``add_instance``: a peer's instance adopted whole), so that
this agent's later views of that object associate with the adopted id instead of making a duplicate.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from mapping.config_fields import bounded
from mapping.data.frame import Frame
from mapping.fusion.fuse import FusionConfig, fuse_frames
from mapping.pointcloud import voxel_downsample
from mapping.perception.types import FrameSegmentation


@dataclass(frozen=True)
class OnlineFusionConfig:
    """Association of a round's instances with the persistent ones (OpenObj's fine-merge values)."""

    fusion: FusionConfig = field(default_factory=FusionConfig)
    """The per-round fusion (coarse + fine phases)."""
    overlap_radius_m: float = field(default=0.05, metadata=bounded(0, 10, low_open=True))
    """A point overlaps an instance when one of its points is this close (OpenObj: 5 cm)."""
    overlap_similar: float = field(default=0.6, metadata=bounded(0, 1))
    """Associate when the overlap exceeds this and the captions are similar ..."""
    caption_similarity: float = field(default=0.3, metadata=bounded(-1, 1))
    """... (cosine above this) ..."""
    overlap_any: float = field(default=0.9, metadata=bounded(0, 1))
    """... or when the overlap exceeds this whatever the captions say."""
    voxel_size_m: float = field(default=0.01, metadata=bounded(0, 10, low_open=True))
    """Voxel of the persistent clouds."""
    max_points: int = field(default=60_000, metadata=bounded(1, 10_000_000))
    """Cap on a persistent cloud (the voxel coarsens beyond it)."""


@dataclass
class OnlineInstance:
    """One persistent instance of the agent's map.

    Attributes:
        instance_id: stable id (>= 1).
        points: (P, 3) float64 voxel down-sampled world points.
        caption: caption of its most confident round.
        caption_feature: (d,) float32 unit vector (running mean over rounds).
        confidence: eq. 1-2 running mean over the frames that could have shown it.
        frames: frames counted in ``confidence``.
        adopted: taken whole from a peer (no pixels of this agent until it sees it).
    """

    instance_id: int
    points: np.ndarray
    caption: str
    caption_feature: np.ndarray
    confidence: float
    frames: int
    adopted: bool = False
    best_round_confidence: float = 0.0
    _tree: cKDTree | None = None
    _bounds: tuple[np.ndarray, np.ndarray] | None = None

    def tree(self) -> cKDTree:
        if self._tree is None:
            self._tree = cKDTree(self.points)
        return self._tree

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(3,) lowest and highest corner of its points (cached: association tests every instance)."""
        if self._bounds is None:
            self._bounds = (self.points.min(0), self.points.max(0))
        return self._bounds

    def points_changed(self) -> None:
        self._tree = self._bounds = None


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return (v / max(float(np.linalg.norm(v)), 1e-12)).astype(np.float32)


def _cap(points: np.ndarray, voxel: float, max_points: int) -> np.ndarray:
    out = voxel_downsample(points, voxel) if len(points) else points
    while len(out) > max_points:
        voxel *= 1.5
        out = voxel_downsample(points, voxel)
    return out


class OnlineFusion:
    """One agent's persistent instances, grown round by round."""

    def __init__(self, config: OnlineFusionConfig | None = None):
        self.config = config or OnlineFusionConfig()
        self.instances: dict[int, OnlineInstance] = {}
        self.next_id = 1
        self.frames_seen = 0

    def add_round(self, frames: Sequence[Frame], segmentations: Sequence[FrameSegmentation]) -> list[np.ndarray]:
        """Fuse one round's frames and associate them; returns each frame's (H, W) int32 image of
        persistent instance ids (0 = no kept mask)."""
        if len(frames) != len(segmentations):
            raise ValueError(f"{len(frames)} frames but {len(segmentations)} segmentations")
        if not frames:
            return []
        result = fuse_frames(frames, segmentations, self.config.fusion)
        n_frames = len(frames)
        # earlier instances' confidence: they were not in these frames unless associated below
        lut = {}
        for local in sorted(result.instances):
            inst = result.instances[local]
            target = self._associate(inst.points, inst.caption_feature)
            if target is None:
                target = self._new_instance(inst.points, inst.caption, inst.caption_feature, 0.0, 0)
            self._absorb(self.instances[target], inst.points, inst.caption, inst.caption_feature, inst.confidence,
                         n_frames)
            lut[local] = target
        associated = set(lut.values())
        for iid, persistent in self.instances.items():
            if iid not in associated and not persistent.adopted:
                persistent.confidence = persistent.confidence * persistent.frames / (persistent.frames + n_frames)
                persistent.frames += n_frames
        self.frames_seen += n_frames
        images = []
        for seg in segmentations:
            local = result.label_image(seg)
            table = np.zeros(int(local.max(initial=0)) + 1, np.int32)
            for k, v in lut.items():
                if k < len(table):
                    table[k] = v
            images.append(table[local])
        return images

    def add_instance(self, points: np.ndarray, caption: str, caption_feature: np.ndarray, confidence: float
                     ) -> int:
        """Add an instance taken whole from a peer; returns its new id."""
        iid = self._new_instance(points, caption, caption_feature, confidence, 0)
        self.instances[iid].adopted = True
        return iid

    def merge(self, source: int, target: int) -> None:
        """``source`` is a piece of ``target``: its points join, its id retires (never reused)."""
        src, dst = self.instances.pop(source), self.instances[target]
        self._absorb(dst, src.points, dst.caption, dst.caption_feature, dst.confidence, 0)

    def _new_instance(self, points, caption, feature, confidence, frames) -> int:
        iid = self.next_id
        self.next_id += 1
        self.instances[iid] = OnlineInstance(iid, _cap(np.asarray(points, np.float64), self.config.voxel_size_m,
                                                       self.config.max_points),
                                             caption, _unit(feature), float(confidence), frames)
        return iid

    def _associate(self, points: np.ndarray, feature: np.ndarray) -> int | None:
        """The persistent instance a round instance is (OpenObj's fine-merge test), or None.

        Speed, with the same answer as testing every instance: only points inside the other's box (grown by
        the radius) can be near it, so their share bounds the overlap; an instance whose bound cannot beat
        the threshold its captions set (or the best so far) gets no KD query and no tree. The round
        instance's points are tested against every candidate box in one pass."""
        cfg = self.config
        if len(points) == 0 or not self.instances:
            return None
        r = cfg.overlap_radius_m
        lo, hi = points.min(0) - r, points.max(0) + r
        candidates = []
        for iid, inst in self.instances.items():
            if len(inst.points) == 0:
                continue
            p_lo, p_hi = inst.bounds()
            if np.any(p_hi < lo) or np.any(p_lo > hi):
                continue
            candidates.append((iid, inst))
        if not candidates:
            return None
        box_lo = np.stack([inst.bounds()[0] for _, inst in candidates]) - r  # (K, 3)
        box_hi = np.stack([inst.bounds()[1] for _, inst in candidates]) + r
        near_new_all = np.all((points[:, None, :] >= box_lo) & (points[:, None, :] <= box_hi), axis=2)  # (n, K)
        unit = _unit(feature)
        similar_all = np.array([float(unit @ inst.caption_feature) for _, inst in candidates]) > cfg.caption_similarity
        query: cKDTree | None = None
        best, best_score = None, 0.0
        for k, (iid, inst) in enumerate(candidates):
            p = inst.points
            near_new = near_new_all[:, k]
            near_old = np.all((p >= lo) & (p <= hi), axis=1)
            bound = max(near_new.sum() / len(points), near_old.sum() / len(p))
            needed = min(cfg.overlap_similar, cfg.overlap_any) if similar_all[k] else cfg.overlap_any
            if bound <= max(needed, best_score):
                continue  # even if every point in the box overlapped, this instance could not win
            query = query if query is not None else cKDTree(points)
            d_new, _ = inst.tree().query(points[near_new], k=1, distance_upper_bound=r)
            d_old, _ = query.query(p[near_old], k=1, distance_upper_bound=r)
            overlap = max(np.isfinite(d_new).sum() / len(points), np.isfinite(d_old).sum() / len(p))
            if (overlap > cfg.overlap_similar and similar_all[k]) or overlap > cfg.overlap_any:
                if overlap > best_score:
                    best, best_score = iid, overlap
        return best

    def _absorb(self, inst: OnlineInstance, points, caption, feature, confidence, frames) -> None:
        cfg = self.config
        inst.points = _cap(np.concatenate([inst.points, np.asarray(points, np.float64)]), cfg.voxel_size_m,
                           cfg.max_points)
        inst.points_changed()
        total = inst.frames + frames
        if frames:
            inst.confidence = (inst.confidence * inst.frames + confidence * frames) / total
            weight = frames / total
            inst.caption_feature = _unit((1 - weight) * inst.caption_feature + weight * _unit(feature))
            if confidence > inst.best_round_confidence:
                inst.caption, inst.best_round_confidence = caption, confidence
        inst.frames = total
        if frames and inst.adopted:
            inst.adopted = False  # this agent sees it now

    # ---- checkpoints -------------------------------------------------------------------------------
    def state(self) -> dict:
        """Instances as tensors, numbers and strings (for a weights-only checkpoint)."""
        import torch  # noqa: PLC0415

        return {"next_id": self.next_id, "frames_seen": self.frames_seen,
                "instances": {int(i): {"points": torch.as_tensor(v.points), "caption": v.caption,
                                       "feature": torch.as_tensor(v.caption_feature), "confidence": float(v.confidence),
                                       "frames": int(v.frames), "adopted": bool(v.adopted),
                                       "best": float(v.best_round_confidence)}
                              for i, v in self.instances.items()}}

    def restore(self, state: dict) -> None:
        """Inverse of ``state``."""
        self.next_id, self.frames_seen = state["next_id"], state["frames_seen"]
        self.instances = {int(i): OnlineInstance(int(i), v["points"].numpy(), v["caption"], v["feature"].numpy(),
                                                 float(v["confidence"]), int(v["frames"]), bool(v["adopted"]),
                                                 float(v["best"])) for i, v in state["instances"].items()}
