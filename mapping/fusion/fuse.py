"""Cross-frame fusion of one agent (paper sec. III-C, after OpenObj): masks over time -> instances O_{k,i}.

    frames + segmentations --observe_masks--> MaskSet --coarse_clusters--> --fine_merge--> AgentInstances

Each mask is back-projected (invalid depth dropped) and voxel down-sampled; it keeps its colour, colour
histogram, 3D and 2D boxes and its features. The coarse phase groups masks over time by a weighted
similarity graph, the fine phase merges groups whose point clouds overlap, and every group becomes one
fused instance with local id 1..n (in order of first appearance) and the confidence of eq. 1-2.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
from scipy import ndimage

from mapping.alignment.confidence import instance_confidence, label_confidences
from mapping.config_fields import bounded
from mapping.data.frame import Frame
from mapping.fusion.clustering import CoarseConfig, MaskSet, coarse_clusters, unit_rows
from mapping.fusion.merge import FineConfig, fine_merge, voxel_downsample
from mapping.perception.types import AgentInstance, FrameSegmentation, FusionResult


@dataclass
class FusionConfig:
    """Settings of one agent's cross-frame fusion (OpenObj's values by default)."""

    coarse: CoarseConfig = field(default_factory=CoarseConfig)
    """Coarse phase: edge weights, threshold, communities."""
    fine: FineConfig = field(default_factory=FineConfig)
    """Fine phase: overlap, caption and colour thresholds."""
    voxel_size_m: float = field(default=0.01, metadata=bounded(0, 10, low_open=True))
    """Voxel of the per-mask and per-instance point clouds."""
    pixel_stride: int = field(default=2, metadata=bounded(1, 1024))
    """Back-project every n-th pixel in both directions (2 = a quarter of the points; the clouds of
    many frames fill in, and at 320 x 240 one frame still gives a point every ~2.5 cm at 2 m)."""
    min_mask_pixels: int = field(default=100, metadata=bounded(0, 100_000_000))
    """Masks with fewer pixels are dropped (OpenObj); they get no local id."""
    min_mask_points: int = field(default=10, metadata=bounded(0, 100_000_000))
    """Masks with fewer valid-depth voxels are dropped too."""
    colour_bins: int = field(default=32, metadata=bounded(1, 256))
    """Histogram bins per RGB channel (OpenObj: 32)."""
    projection_points: int = field(default=64, metadata=bounded(1, 100_000))
    """Points per mask projected into other frames for the 2D box term."""
    border_margin: float = field(default=0.1, metadata=bounded(0, 0.5, high_open=True))
    """Border band of eq. 1's central region, as a share of the image width / height."""
    max_points: int = field(default=100_000, metadata=bounded(1, 10_000_000))
    """Cap on an instance's points: beyond it the voxel grows until the cloud fits (uniform density:
    a random subset would thin large surfaces unevenly and break the alignment's overlap test)."""
    seed: int = field(default=0, metadata=bounded(0, 2**32 - 1))
    """Seed of Louvain."""

    def __post_init__(self) -> None:
        for name in ("pixel_stride", "colour_bins", "projection_points", "max_points"):
            if getattr(self, name) < 1:
                raise ValueError(f"FusionConfig.{name} must be >= 1, got {getattr(self, name)}")
        if self.voxel_size_m <= 0:
            raise ValueError(f"FusionConfig.voxel_size_m must be positive, got {self.voxel_size_m}")


def _feature(vector, what: str, frame_index: int, segment_id: int) -> np.ndarray:
    """A segment's feature as a finite non-zero (d,) float64 vector (ValueError naming the mask otherwise)."""
    if vector is None:
        raise ValueError(f"frame {frame_index}, segment {segment_id}: {what} is None (encode captions first)")
    v = np.asarray(vector, np.float64)
    if v.ndim != 1 or not np.all(np.isfinite(v)) or not np.any(v):
        raise ValueError(f"frame {frame_index}, segment {segment_id}: {what} must be a finite non-zero (d,) vector")
    return v


def _frame_masks(frame: Frame, seg: FrameSegmentation, cfg: FusionConfig, pos: int) -> list[dict]:
    """The kept masks of one frame, as dicts of MaskSet columns."""
    labels = np.asarray(seg.labels)
    if labels.shape != frame.depth.shape:
        raise ValueError(f"frame {frame.index}: labels {labels.shape} do not match depth {frame.depth.shape}")
    if not np.issubdtype(labels.dtype, np.integer) or (labels.size and labels.min() < 0):
        raise ValueError(f"frame {frame.index}: labels must be a non-negative integer image")
    ids = [s.segment_id for s in seg.segments]
    if any(i < 1 for i in ids) or len(set(ids)) != len(ids):
        raise ValueError(f"frame {frame.index}: segment ids must be unique and >= 1, got {sorted(ids)}")
    area = np.bincount(labels.ravel())
    segs = [s for s in seg.segments if s.segment_id < len(area) and area[s.segment_id] >= cfg.min_mask_pixels]
    if not segs:
        return []
    lut = np.full(len(area), -1, np.int64)  # segment id -> row in segs
    lut[[s.segment_id for s in segs]] = np.arange(len(segs))
    # per-pixel statistics on the strided grid: colour, histogram, back-projected points
    st = cfg.pixel_stride
    rows = lut[labels[::st, ::st]]
    sel = rows >= 0
    k, rgb = rows[sel], frame.rgb[::st, ::st][sel].astype(np.int64)
    per_mask = np.bincount(k, minlength=len(segs))
    bins = cfg.colour_bins
    chan = (rgb * bins) // 256 + np.arange(3) * bins
    hist = np.bincount((k[:, None] * (3 * bins) + chan).ravel(), minlength=len(segs) * 3 * bins)
    hist = hist.reshape(len(segs), 3 * bins).astype(np.float64)
    colour = np.stack([np.bincount(k, weights=rgb[:, c], minlength=len(segs)) for c in range(3)], axis=1)
    colour /= 255.0 * np.maximum(per_mask, 1)[:, None]
    pts, valid = frame.backproject_pixels(st, lut[labels] >= 0)
    pts, owner = voxel_downsample(pts, cfg.voxel_size_m, rows[valid])  # one point per (mask, voxel)
    starts = np.searchsorted(owner, np.arange(len(segs) + 1))
    slices = ndimage.find_objects(labels)
    out = []
    for r, sg in enumerate(segs):
        p = pts[starts[r]:starts[r + 1]]
        if len(p) < cfg.min_mask_points:
            continue
        visual = sg.visual_feature
        if visual is not None:
            visual = _feature(visual, "visual_feature", frame.index, sg.segment_id)
        sv, su = slices[sg.segment_id - 1]
        out.append(dict(frame_pos=pos, frame_index=frame.index, segment_id=sg.segment_id,
                        pixels=int(area[sg.segment_id]),
                        caption=sg.caption,
                        caption_feature=_feature(sg.caption_feature, "caption_feature", frame.index, sg.segment_id),
                        visual_feature=visual, histogram=hist[r], colour=colour[r],
                        box3d=np.concatenate([p.min(axis=0), p.max(axis=0)]),
                        box2d=np.array([su.start, sv.start, su.stop, sv.stop], np.float64), points=p,
                        samples=_samples(p, cfg.projection_points), source_ids=tuple(sg.source_ids)))
    return out


def _samples(points: np.ndarray, k: int) -> np.ndarray:
    """(k, 3) points that span the cloud: its six extreme points, then evenly spaced ones."""
    extremes = np.concatenate([points.argmin(axis=0), points.argmax(axis=0)])
    spread = np.linspace(0, len(points) - 1, max(k - len(extremes), 1)).round().astype(np.int64)
    return points[np.concatenate([extremes, spread])[:k]]


def observe_masks(frames: Sequence[Frame], segmentations: Sequence[FrameSegmentation],
                  config: FusionConfig | None = None) -> MaskSet:
    """Per-mask 3D data of all of one agent's frames.

    Masks under ``min_mask_pixels`` pixels or ``min_mask_points`` valid-depth voxels are left out, and
    so are label ids that have no ``Segment``.

    Args:
        frames: the agent's frames.
        segmentations: one per frame, same order, ``frame_index == frame.index``, captions encoded.
        config: fusion settings.
    """
    cfg = config or FusionConfig()
    if len(frames) != len(segmentations):
        raise ValueError(f"{len(frames)} frames but {len(segmentations)} segmentations")
    indices = [f.index for f in frames]
    if len(set(indices)) != len(indices):
        raise ValueError("frame indices must be unique within one agent's frames")
    rows: list[dict] = []
    for pos, (frame, seg) in enumerate(zip(frames, segmentations)):
        if seg.frame_index != frame.index:
            raise ValueError(f"segmentation {pos} is for frame {seg.frame_index}, "
                             f"but frame {pos} has index {frame.index}")
        rows.extend(_frame_masks(frame, seg, cfg, pos))
    visual = [r["visual_feature"] for r in rows if r["visual_feature"] is not None]
    for name, vectors in (("caption", [r["caption_feature"] for r in rows]), ("visual", visual)):
        if len({v.shape for v in vectors}) > 1:
            raise ValueError(f"{name} features of different dimensions in one agent's segmentations")
    vis_dim = visual[0].shape[0] if visual else 0
    k = [f.intrinsics for f in frames]
    n = len(rows)

    def col(name: str, dtype=None) -> np.ndarray:
        return np.array([r[name] for r in rows], dtype=dtype)

    return MaskSet(
        frame_pos=col("frame_pos", np.int64).reshape(n), frame_index=col("frame_index", np.int64).reshape(n),
        segment_id=col("segment_id", np.int64).reshape(n), pixels=col("pixels", np.int64).reshape(n),
        captions=[r["caption"] for r in rows],
        caption_features=unit_rows(col("caption_feature").reshape(n, -1)) if n else np.zeros((0, 0)),
        visual_features=unit_rows(np.stack([np.zeros(vis_dim) if r["visual_feature"] is None else r["visual_feature"]
                                            for r in rows])) if visual else None,
        has_visual=np.array([r["visual_feature"] is not None for r in rows], bool),
        histograms=col("histogram").reshape(n, 3 * cfg.colour_bins), colours=col("colour").reshape(n, 3),
        boxes3d=col("box3d").reshape(n, 6), boxes2d=col("box2d").reshape(n, 4),
        points=[r["points"] for r in rows], samples=col("samples").reshape(n, cfg.projection_points, 3),
        source_ids=[r["source_ids"] for r in rows],
        world_to_camera=np.array([np.linalg.inv(f.pose) for f in frames]).reshape(len(frames), 4, 4),
        cameras=np.array([[c.fx, c.fy, c.cx, c.cy, c.width, c.height] for c in k], np.float64).reshape(len(frames), 6))


def _fused_instance(masks: MaskSet, members: list[int], local_id: int, confidence: float,
                    cfg: FusionConfig) -> AgentInstance:
    """One fused instance from its masks (step 5 of the fusion)."""
    area = masks.pixels[members].astype(np.float64)
    votes: dict[str, float] = defaultdict(float)
    for m, a in zip(members, area):
        votes[masks.captions[m]] += a
    caption = max(sorted(votes), key=votes.__getitem__)  # area-weighted vote; ties -> alphabetical
    caption_feature = unit_rows(area @ masks.caption_features[members]).astype(np.float32)
    visual = None
    with_vis = [m for m in members if masks.has_visual[m]]
    if with_vis:
        weights = masks.pixels[with_vis].astype(np.float64)
        visual = unit_rows(weights @ masks.visual_features[with_vis]).astype(np.float32)
    points = voxel_downsample(np.concatenate([masks.points[m] for m in members]), cfg.voxel_size_m)
    voxel = cfg.voxel_size_m
    while len(points) > cfg.max_points:  # coarser voxels keep the density uniform (overlap tests need that)
        voxel *= max(1.1, float(np.sqrt(len(points) / cfg.max_points)))
        points = voxel_downsample(points, voxel)
    colour = area @ masks.colours[members] / area.sum()
    # Segment.source_ids gives order, not counts: credit pixels / (rank + 1) (diagnostics only)
    credit: dict[int, float] = defaultdict(float)
    for m, a in zip(members, area):
        for rank, sid in enumerate(masks.source_ids[m]):
            credit[int(sid)] += a / (rank + 1)
    source_ids = tuple(sorted(credit, key=lambda s: (-credit[s], s)))
    observations = [(int(masks.frame_index[m]), int(masks.segment_id[m])) for m in members]
    return AgentInstance(local_id, caption, caption_feature, visual, confidence, points, colour,
                         observations, source_ids)


def fuse_frames(frames: Sequence[Frame], segmentations: Sequence[FrameSegmentation],
                config: FusionConfig | None = None) -> FusionResult:
    """Fuse one agent's masks over time into instances (coarse clustering, then fine merge).

    Args:
        frames: the agent's frames (depth, pose, intrinsics, rgb are read).
        segmentations: one per frame, same order; captions encoded (``caption_feature`` set).
        config: fusion settings.

    Returns:
        instances with local ids 1..n in order of first appearance, and the (frame_index, segment_id)
        -> local id assignment of every kept mask. Deterministic for a given config.
    """
    cfg = config or FusionConfig()
    masks = observe_masks(frames, segmentations, cfg)
    if len(masks) == 0:
        return FusionResult({}, {})
    groups = fine_merge(masks, coarse_clusters(masks, cfg.coarse, cfg.seed), cfg.fine, cfg.voxel_size_m)
    assignment = {(int(masks.frame_index[m]), int(masks.segment_id[m])): local
                  for local, g in enumerate(groups, start=1) for m in g}
    # eq. 1 on the union of each instance's masks per frame, eq. 2 over all the agent's frames
    per_frame: dict[int, list[float]] = defaultdict(list)
    for seg in segmentations:
        lut = np.zeros(int(np.max(seg.labels, initial=0)) + 1, np.int64)
        for s in seg.segments:
            if 0 < s.segment_id < len(lut):
                lut[s.segment_id] = assignment.get((seg.frame_index, s.segment_id), 0)
        for local, c in label_confidences(lut[seg.labels], cfg.border_margin).items():
            per_frame[local].append(c)
    instances = {local: _fused_instance(masks, g, local, instance_confidence(per_frame[local], len(frames)), cfg)
                 for local, g in enumerate(groups, start=1)}
    return FusionResult(instances, assignment)
