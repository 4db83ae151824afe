"""Segmenters: frame -> instance masks with captions (CropFormer + TAP stand-ins, or dataset masks).

``OracleSegmenter`` turns the simulator's ground-truth instance image into the masks a real
open-vocabulary front end would give, with the seeded error model of ``errors.py`` applied.
``DatasetMaskSegmenter`` wraps the instance images that ship with Replica / ScanNet sequences.
Both number a frame's segments 1..K and drop masks under the minimum size.
"""

from __future__ import annotations

from typing import Mapping, Protocol, Sequence

import numpy as np
from scipy import ndimage

from mapping.data.frame import Frame, central_region
from mapping.perception.captioner import UNKNOWN_CAPTION, Captioner, TemplateCaptioner
from mapping.perception.errors import ErrorPlan, SegmentationErrorConfig, mask_dropped, plan_errors, split_labels
from mapping.perception.types import FrameSegmentation, InstanceInfo, Segment

_MAX_ANCHOR_POINTS = 4096  # first-sight anchor clouds are subsampled to this many points


class Segmenter(Protocol):
    """Anything that turns a frame into captioned masks."""

    def segment(self, frame: Frame) -> FrameSegmentation:
        """Masks of ``frame`` (labels (H, W) int32, ids 1..K) with their captions."""
        ...


def _instance_image(frame: Frame, who: str) -> np.ndarray:
    if frame.instance is None:
        raise ValueError(f"{who}: frame {frame.index} has no instance image")
    inst = np.asarray(frame.instance)
    if not np.issubdtype(inst.dtype, np.integer):
        raise ValueError(f"{who}: frame {frame.index} instance image must be integer, got {inst.dtype}")
    if inst.size and inst.min() < 0:
        raise ValueError(f"{who}: frame {frame.index} instance image has negative ids")
    return inst


def _pixel_points(frame: Frame, rows: np.ndarray, cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World points of pixels (rows, cols) and which of them have valid depth: ((n, 3), (n,) bool)."""
    k = frame.intrinsics
    z = frame.depth[rows, cols].astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, 0.0)
    cam = np.stack([(cols - k.cx) / k.fx * z, (rows - k.cy) / k.fy * z, z], axis=1)
    return cam @ frame.pose[:3, :3].T + frame.pose[:3, 3], valid


def _assemble(candidates: np.ndarray, specs: list, min_pixels: int) -> tuple[np.ndarray, list]:
    """Drop candidate masks under ``min_pixels`` and renumber the rest 1..K (in candidate order).

    Returns the (H, W) int32 labels and the kept specs paired with their pixel counts.
    """
    counts = np.bincount(candidates.ravel(), minlength=len(specs) + 1)
    keep = [c for c in range(1, len(specs) + 1) if counts[c] >= min_pixels]
    lut = np.zeros(len(specs) + 1, np.int32)
    lut[keep] = np.arange(1, len(keep) + 1, dtype=np.int32)
    return lut[candidates], [(specs[c - 1], int(counts[c])) for c in keep]


def _inside_central_region(labels: np.ndarray, count: int, margin: float) -> np.ndarray:
    """(count,) bool: whether mask k + 1 lies wholly inside the central region of eq. 1."""
    top, bottom, left, right = central_region(*labels.shape, margin)
    out = np.zeros(count, bool)
    for k, box in enumerate(ndimage.find_objects(labels, max_label=count)):
        if box is not None:
            rows, cols = box
            out[k] = rows.start >= top and rows.stop <= bottom and cols.start >= left and cols.stop <= right
    return out


class OracleSegmenter:
    """Ground-truth masks with the persistent, seeded error model of one agent.

    Args:
        infos: every instance the frames may show (an unknown id in a frame is an error).
        errors: error rates (default ``SegmentationErrorConfig()``).
        captioner: caption source (default ``TemplateCaptioner(seed)``).
        seed, agent: key every error and phrasing draw (non-negative integers).
        anchor_points: optional instance id -> (m, 3) world points of the instance (e.g. sampled from
            its mesh) that fix the over-segmentation planes. Without it, an instance's planes are fixed
            by its points at first sight, so they then depend on the order frames are segmented in.
        plan: explicit persistent errors to plant (default: drawn by ``plan_errors`` from ``errors``);
            mask drops and the minimum size still follow ``errors``.
    """

    def __init__(self, infos: Sequence[InstanceInfo], errors: SegmentationErrorConfig | None = None,
                 captioner: Captioner | None = None, seed: int = 0, agent: int = 0,
                 anchor_points: Mapping[int, np.ndarray] | None = None, plan: ErrorPlan | None = None):
        self.errors = errors if errors is not None else SegmentationErrorConfig()
        self.captioner = captioner if captioner is not None else TemplateCaptioner(seed)
        self.seed, self.agent = int(seed), int(agent)
        self.infos = {info.instance_id: info for info in infos}
        self.plan = plan if plan is not None else plan_errors(list(infos), self.errors, self.seed, self.agent)
        missing = sorted(set(self.plan.over_pieces) - set(self.plan.plane_angles))
        if missing:
            raise ValueError(f"ErrorPlan: over-segmented instances {missing} have no plane_angles")
        self._anchors = {int(k): np.asarray(v, np.float64) for k, v in (anchor_points or {}).items()}

    def segment(self, frame: Frame) -> FrameSegmentation:
        """Masks of ``frame`` after the error model; ``source_ids`` name the true ids under each mask."""
        inst = _instance_image(frame, "OracleSegmenter")
        if frame.index < 0:
            raise ValueError(f"OracleSegmenter: frame index must be >= 0, got {frame.index}")
        ids, inverse, counts = np.unique(inst, return_inverse=True, return_counts=True)
        inverse = inverse.reshape(inst.shape)
        pixels = {int(i): int(c) for i, c in zip(ids, counts) if i != 0}
        unknown = sorted(set(pixels) - set(self.infos))
        if unknown:
            raise ValueError(f"OracleSegmenter: frame {frame.index} shows instance ids {unknown} "
                             "that are not in the InstanceInfo list")
        position = {int(i): p for p, i in enumerate(ids)}
        lut = np.zeros(len(ids), np.int64)  # compact id index -> candidate number (0 = no mask)
        specs: list[tuple[tuple[int, ...], int]] = []  # per candidate: (members, piece)
        over: list[tuple[int, int]] = []  # (instance id, first candidate number)
        done: set[int] = set()
        for iid in sorted(pixels):
            if iid in done:
                continue
            partner = self.plan.under_partner.get(iid)
            members = (iid, partner) if partner in pixels else (iid,)
            done.update(members)
            if self._dropped(frame.index, members):
                continue
            number = len(specs) + 1  # the members' candidate (the first piece when over-segmented)
            if len(members) == 1 and iid in self.plan.over_pieces:
                over.append((iid, number))
                specs.extend(((iid,), piece) for piece in range(self.plan.over_pieces[iid]))
            else:
                specs.append((members, 0))
            lut[[position[m] for m in members]] = number
        candidates = lut[inverse]
        for iid, first in over:
            candidates = self._split(frame, inst, iid, candidates, first)
        labels, kept = _assemble(candidates, specs, self.errors.min_mask_pixels)
        central = _inside_central_region(labels, len(kept), self.errors.central_margin)
        segments = []
        for k, ((members, piece), n_pixels) in enumerate(kept, start=1):
            source = tuple(sorted(members, key=lambda m: (-pixels[m], m)))
            main = self.infos[source[0]]
            wrong = self.plan.wrong_category.get(main.instance_id)
            if wrong is not None and self.errors.semantic_errors_in_partial_views and central[k - 1]:
                wrong = None  # seen whole: even a confusable instance is captioned right
            caption = self.captioner.caption(main, self.agent, frame.index, wrong, piece)
            segments.append(Segment(k, caption, n_pixels, source_ids=source))
        return FrameSegmentation(frame.index, labels, segments)

    def _dropped(self, frame_index: int, members: tuple[int, ...]) -> bool:
        if any(self.infos[m].is_structure for m in members) and not self.errors.structure_errors:
            return False
        return mask_dropped(self.errors, self.seed, self.agent, frame_index, min(members))

    def _split(self, frame: Frame, inst: np.ndarray, iid: int, candidates: np.ndarray, first: int) -> np.ndarray:
        """Give each pixel of over-segmented ``iid`` its piece's candidate number (first .. first+P-1)."""
        rows, cols = np.nonzero(inst == iid)
        points, valid = _pixel_points(frame, rows, cols)
        anchor = self._anchors.get(iid)
        if anchor is None:
            if valid.sum() < 3:
                return candidates  # no geometry yet: the whole instance stays in piece 0 this frame
            anchor = points[valid]
            if len(anchor) > _MAX_ANCHOR_POINTS:
                anchor = anchor[np.linspace(0, len(anchor) - 1, _MAX_ANCHOR_POINTS).astype(int)]
            self._anchors[iid] = anchor
        piece = split_labels(points, anchor, self.plan.plane_angles[iid], self.plan.over_pieces[iid])
        piece[~valid] = 0  # pixels without depth cannot be placed: they stay with the first piece
        candidates = candidates.copy()
        candidates[rows, cols] = first + piece
        return candidates


class DatasetMaskSegmenter:
    """The instance masks that come with a dataset (Replica / ScanNet instance images), one segment per id.

    Args:
        captions: dataset id -> caption; unknown ids get "an object".
        min_mask_pixels: masks with fewer pixels are dropped (OpenObj: 100).
    """

    def __init__(self, captions: Mapping[int, str] | None = None, min_mask_pixels: int = 100):
        if int(min_mask_pixels) < 1:
            raise ValueError(f"min_mask_pixels must be >= 1, got {min_mask_pixels}")
        self.captions = {int(k): str(v) for k, v in (captions or {}).items()}
        self.min_mask_pixels = int(min_mask_pixels)

    def segment(self, frame: Frame) -> FrameSegmentation:
        """One segment per dataset id in ``frame.instance`` (ascending ids), ``source_ids`` = (id,)."""
        inst = _instance_image(frame, "DatasetMaskSegmenter")
        ids, inverse = np.unique(inst, return_inverse=True)
        specs = [int(i) for i in ids if i != 0]
        offset = 0 if ids[0] == 0 else 1  # compact index 0 is background only when id 0 is present
        candidates = inverse.reshape(inst.shape).astype(np.int64) + offset
        labels, kept = _assemble(candidates, specs, self.min_mask_pixels)
        segments = [Segment(k, self.captions.get(iid, UNKNOWN_CAPTION), n, source_ids=(iid,))
                    for k, (iid, n) in enumerate(kept, start=1)]
        return FrameSegmentation(frame.index, labels, segments)
