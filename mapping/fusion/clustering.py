"""Coarse phase of cross-frame fusion (OpenObj phase 1): a graph over all masks, then communities.

Every mask of every frame of one agent is a node. Two masks of different frames get an edge when

    s = w_box * box3d_overlap + w_cap * caption_cos + w_vis * visual_cos + w_col * colour_cos
        + w_2d * projected_box2d_iou  >=  threshold

(OpenObj's weights 0.30 / 0.20 / 0.30 / 0.20 / 0.60 and threshold 1.0). When a pair lacks visual
features (no image-text encoder), its visual term is absent and the threshold is scaled by the share
of weight that is present (1.3 / 1.6 of 1.0 by default), so the remaining terms must agree as much as
before. Masks of the same frame never get an edge: the segmenter already said they differ. The 2D
term projects each mask's points into the other's frame and averages the two directions' box IoUs;
the 3D term is by default OpenObj's intersection over the smaller box (``CoarseConfig.box_overlap``).

Scale: about 1800 masks per agent, so pairs are never looped over in Python. Candidates are pairs
whose padded 3D boxes intersect (vectorised in row blocks); the cheap terms are scored for all of
them; the projection term, the only costly one, is computed only for pairs that could still reach the
threshold with a perfect 2D IoU.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import networkx as nx
import numpy as np

from mapping.config_fields import bounded

_ROW_BLOCK = 256  # rows per block of the (n, n) box-overlap test: bounds memory at ~n * 256 booleans
_PAIR_BLOCK = 8192  # pairs per block of the projection term


@dataclass
class CoarseConfig:
    """Weights and threshold of the coarse edge score (OpenObj's values)."""

    w_box3d: float = field(default=0.30, metadata=bounded(0, 100))
    """Weight of the 3D box overlap."""
    w_caption: float = field(default=0.20, metadata=bounded(0, 100))
    """Weight of the caption-feature cosine."""
    w_visual: float = field(default=0.30, metadata=bounded(0, 100))
    """Weight of the visual-feature cosine (dropped, with threshold rescaling, when absent)."""
    w_colour: float = field(default=0.20, metadata=bounded(0, 100))
    """Weight of the colour-histogram cosine."""
    w_box2d: float = field(default=0.60, metadata=bounded(0, 100))
    """Weight of the IoU between a mask's 2D box and the other mask's points projected into its frame."""
    threshold: float = field(default=1.0, metadata=bounded(0, 100))
    """Edge when the score reaches this (with all five terms present)."""
    box_overlap: str = "smaller"
    """3D box overlap: "smaller" (intersection over the smaller box, as OpenObj's code computes its
    "IoU": a partial view inside the whole scores high) or "iou" (plain IoU)."""
    box_padding_m: float = field(default=0.02, metadata=bounded(0, 10))
    """Each 3D box grows by this on every side before the overlap, so flat walls and floors have volume."""
    candidate_margin_m: float = field(default=0.05, metadata=bounded(0, 10))
    """Pairs are scored only when their boxes, grown by this, intersect."""
    communities: str = "louvain"
    """"louvain" (networkx, seeded) or "components" (connected components)."""


@dataclass
class MaskSet:
    """The per-mask data of one agent's frames, stacked (n masks, F frames).

    Attributes:
        frame_pos: (n,) int position of the mask's frame in the agent's frame list.
        frame_index: (n,) int ``Frame.index`` of that frame.
        segment_id: (n,) int the mask's id in its ``FrameSegmentation``.
        pixels: (n,) int mask area.
        captions: n caption texts.
        caption_features: (n, 384) float32 unit vectors.
        visual_features: (n, D) float32 unit vectors (zeros where absent), or None when no mask has one.
        has_visual: (n,) bool.
        histograms: (n, B) float64 raw colour-histogram counts.
        colours: (n, 3) mean rgb in [0, 1].
        boxes3d: (n, 6) float64 world box (xmin, ymin, zmin, xmax, ymax, zmax) of the points.
        boxes2d: (n, 4) float64 pixel box (u0, v0, u1, v1), exclusive upper edges.
        points: n (m_i, 3) float64 voxel down-sampled world points.
        samples: (n, K, 3) float64 points of each mask for the projection term (repeats when m_i < K).
        source_ids: n ground-truth id tuples (simulator diagnostics only).
        world_to_camera: (F, 4, 4) float64 per frame.
        cameras: (F, 6) float64 per frame: fx, fy, cx, cy, width, height.
    """

    frame_pos: np.ndarray
    frame_index: np.ndarray
    segment_id: np.ndarray
    pixels: np.ndarray
    captions: list[str]
    caption_features: np.ndarray
    visual_features: np.ndarray | None
    has_visual: np.ndarray
    histograms: np.ndarray
    colours: np.ndarray
    boxes3d: np.ndarray
    boxes2d: np.ndarray
    points: list[np.ndarray]
    samples: np.ndarray
    source_ids: list[tuple[int, ...]]
    world_to_camera: np.ndarray
    cameras: np.ndarray

    def __len__(self) -> int:
        return int(self.frame_pos.shape[0])


def unit_rows(x: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows stay zero)."""
    norm = np.linalg.norm(x, axis=-1, keepdims=True)
    return np.divide(x, norm, out=np.zeros_like(x, dtype=np.float64), where=norm > 0)


def candidate_pairs(boxes: np.ndarray, frame_pos: np.ndarray, margin_m: float) -> np.ndarray:
    """(p, 2) int pairs i < j with different ``frame_pos`` whose boxes (n, 6), grown by ``margin_m``, meet."""
    lo, hi = boxes[:, :3] - margin_m, boxes[:, 3:] + margin_m
    n, out = len(boxes), []
    for start in range(0, n, _ROW_BLOCK):
        rows = np.arange(start, min(start + _ROW_BLOCK, n))
        meet = np.all((lo[rows, None] <= hi[None]) & (hi[rows, None] >= lo[None]), axis=2)
        meet &= np.arange(n)[None] > rows[:, None]
        meet &= frame_pos[rows, None] != frame_pos[None]
        r, c = np.nonzero(meet)
        out.append(np.stack([rows[r], c], axis=1))
    return np.concatenate(out) if out else np.zeros((0, 2), np.int64)


def box3d_overlap(a: np.ndarray, b: np.ndarray, mode: str = "iou") -> np.ndarray:
    """(p,) overlap of paired boxes a, b : (p, 6); "iou" or "smaller" (intersection / smaller volume)."""
    inter = np.prod(np.clip(np.minimum(a[:, 3:], b[:, 3:]) - np.maximum(a[:, :3], b[:, :3]), 0, None), axis=1)
    va, vb = np.prod(a[:, 3:] - a[:, :3], axis=1), np.prod(b[:, 3:] - b[:, :3], axis=1)
    if mode == "iou":
        denom = va + vb - inter
    elif mode == "smaller":
        denom = np.minimum(va, vb)
    else:
        raise ValueError(f"box_overlap must be 'iou' or 'smaller', got {mode!r}")
    return np.divide(inter, denom, out=np.zeros_like(inter), where=denom > 0)


def box2d_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(p,) IoU of paired pixel boxes a, b : (p, 4) as (u0, v0, u1, v1)."""
    inter = np.prod(np.clip(np.minimum(a[:, 2:], b[:, 2:]) - np.maximum(a[:, :2], b[:, :2]), 0, None), axis=1)
    union = np.prod(a[:, 2:] - a[:, :2], axis=1) + np.prod(b[:, 2:] - b[:, :2], axis=1) - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def projected_boxes2d(samples: np.ndarray, w2c: np.ndarray, cameras: np.ndarray, min_depth_m: float = 0.05):
    """Pixel boxes of point sets seen by other cameras.

    Args:
        samples: (p, K, 3) world points.
        w2c: (p, 4, 4) world-to-camera of the camera each set is projected into.
        cameras: (p, 6) fx, fy, cx, cy, width, height of those cameras.

    Returns:
        boxes : (p, 4) float64 (u0, v0, u1, v1) clipped to the image, and visible : (p,) bool (some
        point in front of the camera and the box not empty after clipping).
    """
    cam = np.matmul(samples, np.transpose(w2c[:, :3, :3], (0, 2, 1))) + w2c[:, None, :3, 3]
    z = cam[..., 2]
    front = z > min_depth_m
    zs = np.where(front, z, 1.0)
    u = cameras[:, None, 0] * cam[..., 0] / zs + cameras[:, None, 2]
    v = cameras[:, None, 1] * cam[..., 1] / zs + cameras[:, None, 3]
    big = np.inf
    u0 = np.where(front, u, big).min(axis=1)
    u1 = np.where(front, u, -big).max(axis=1)
    v0 = np.where(front, v, big).min(axis=1)
    v1 = np.where(front, v, -big).max(axis=1)
    box = np.stack([np.round(u0), np.round(v0), np.round(u1) + 1, np.round(v1) + 1], axis=1)
    box = np.where(np.isfinite(box), box, 0.0)
    box[:, [0, 2]] = np.clip(box[:, [0, 2]], 0, cameras[:, 4:5])
    box[:, [1, 3]] = np.clip(box[:, [1, 3]], 0, cameras[:, 5:6])
    visible = front.any(axis=1) & (box[:, 2] > box[:, 0]) & (box[:, 3] > box[:, 1])
    return box, visible


def paired_cosine(unit: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(p,) dot products of rows i and j of ``unit`` (n, d) unit rows, in float32 blocks to bound memory."""
    unit = unit.astype(np.float32, copy=False)
    out = np.empty(len(i))
    for s in range(0, len(i), _PAIR_BLOCK):
        a, b = i[s:s + _PAIR_BLOCK], j[s:s + _PAIR_BLOCK]
        out[s:s + _PAIR_BLOCK] = np.einsum("pd,pd->p", unit[a], unit[b])
    return out


def _projection_term(masks: MaskSet, i: np.ndarray, j: np.ndarray) -> np.ndarray:
    """(p,) mean over both directions of IoU(2D box of i, j's points projected into i's frame)."""
    out = np.zeros(len(i))
    for s in range(0, len(i), _PAIR_BLOCK):
        a, b = i[s:s + _PAIR_BLOCK], j[s:s + _PAIR_BLOCK]
        total = np.zeros(len(a))
        for dst, src in ((a, b), (b, a)):
            f = masks.frame_pos[dst]
            box, visible = projected_boxes2d(masks.samples[src], masks.world_to_camera[f], masks.cameras[f])
            total += np.where(visible, box2d_iou(masks.boxes2d[dst], box), 0.0)
        out[s:s + _PAIR_BLOCK] = total / 2.0
    return out


def edge_scores(masks: MaskSet, config: CoarseConfig) -> tuple[np.ndarray, np.ndarray]:
    """The coarse graph's edges.

    Returns:
        pairs : (e, 2) int mask indices (i < j) and scores : (e,) float64, only the pairs whose score
        reaches the (possibly rescaled) threshold.
    """
    c = config
    total_w = c.w_box3d + c.w_caption + c.w_visual + c.w_colour + c.w_box2d
    if total_w <= 0:
        raise ValueError("the coarse weights must not all be zero")
    pad = np.array([-1, -1, -1, 1, 1, 1]) * c.box_padding_m
    boxes = masks.boxes3d + pad
    pairs = candidate_pairs(boxes, masks.frame_pos, c.candidate_margin_m)
    i, j = pairs[:, 0], pairs[:, 1]
    score = c.w_box3d * box3d_overlap(boxes[i], boxes[j], c.box_overlap)
    score += c.w_caption * paired_cosine(masks.caption_features, i, j)
    score += c.w_colour * paired_cosine(unit_rows(masks.histograms), i, j)
    visual = masks.has_visual[i] & masks.has_visual[j]
    if masks.visual_features is not None and visual.any():
        score += np.where(visual, c.w_visual * paired_cosine(masks.visual_features, i, j), 0.0)
    # Absent visual term: the threshold shrinks by the share of weight that is missing.
    threshold = c.threshold * np.where(visual, 1.0, (total_w - c.w_visual) / total_w)
    hopeful = score + c.w_box2d >= threshold
    i, j, score, threshold = i[hopeful], j[hopeful], score[hopeful], threshold[hopeful]
    score = score + c.w_box2d * _projection_term(masks, i, j)
    keep = score >= threshold
    return np.stack([i[keep], j[keep]], axis=1), score[keep]


def coarse_clusters(masks: MaskSet, config: CoarseConfig | None = None, seed: int = 0) -> list[list[int]]:
    """Group the masks into coarse clusters (OpenObj phase 1).

    Returns:
        clusters as sorted lists of mask indices, ordered by their smallest index; every mask is in
        exactly one cluster (isolated masks form their own).
    """
    config = config or CoarseConfig()
    pairs, scores = edge_scores(masks, config)
    graph = nx.Graph()
    graph.add_nodes_from(range(len(masks)))
    graph.add_weighted_edges_from((int(a), int(b), float(s)) for (a, b), s in zip(pairs, scores))
    if config.communities == "louvain":
        groups = nx.community.louvain_communities(graph, weight="weight", seed=seed)
    elif config.communities == "components":
        groups = nx.connected_components(graph)
    else:
        raise ValueError(f"communities must be 'louvain' or 'components', got {config.communities!r}")
    return sorted((sorted(int(n) for n in g) for g in groups), key=lambda g: g[0])
