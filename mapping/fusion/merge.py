"""Fine phase of cross-frame fusion (OpenObj phase 2): merge coarse clusters that are one object.

Louvain splits a large object seen from far-apart viewpoints (a floor, a long wall) into several
communities, and a caption that changes between views can cut one object in two. Two clusters merge
when their point clouds overlap and their meanings agree:

    (overlap > 0.6 and caption_cos > 0.3 and colour_cos > 0.6)  or  overlap > 0.9

where overlap is OpenObj's: the larger of the two shares of points (0.01 m voxels) that have a point
of the other cloud within 0.05 m. One change to OpenObj: when only one share passes 0.9 (one cloud is
a subset of the other), the overlap-alone rule also asks for a caption cosine above 0.5 (see
``FineConfig.subset_caption_similarity``), since a rug lies wholly within 0.05 m of the floor; with
-1 the rule is OpenObj's. Merges are applied with a union-find per pass and the passes repeat,
with the merged clusters' clouds and features recomputed, until nothing merges. Within a pass a
cluster joins only its best larger partner, and only if that partner stays put (stars, no chains).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from mapping.config_fields import bounded
from mapping.fusion.clustering import MaskSet, candidate_pairs, unit_rows
from mapping.pointcloud import voxel_downsample


@dataclass
class FineConfig:
    """Thresholds of the fine merge (OpenObj's values)."""

    overlap_distance_m: float = field(default=0.05, metadata=bounded(0, 10))
    """A point overlaps when the other cloud has a point within this distance."""
    overlap: float = field(default=0.6, metadata=bounded(0, 1))
    """Overlap needed together with the caption and colour tests."""
    caption_similarity: float = field(default=0.3, metadata=bounded(-1, 1))
    """Caption-feature cosine needed (strictly above)."""
    colour_similarity: float = field(default=0.6, metadata=bounded(-1, 1))
    """Colour-histogram cosine needed (strictly above)."""
    overlap_alone: float = field(default=0.9, metadata=bounded(0, 1))
    """Overlap above which clusters merge whatever their colours (see ``subset_caption_similarity``)."""
    subset_caption_similarity: float = field(default=0.5, metadata=bounded(-1, 1))
    """Caption cosine that the overlap-alone rule needs unless BOTH shares pass (-1 = OpenObj: none).
    Anything lying on a surface (a rug on the floor, a picture on a wall) lies wholly within 0.05 m of
    it and would otherwise merge into it whatever it is."""
    max_passes: int = field(default=50, metadata=bounded(1, 100_000))
    """Safety bound on the merge passes (a pass that merges nothing ends the loop earlier)."""


class UnionFind:
    """Disjoint sets over 0..n-1 (path halving; the smaller root wins, so results are deterministic)."""

    def __init__(self, n: int):
        self.parent = list(range(n))

    def find(self, a: int) -> int:
        while self.parent[a] != a:
            self.parent[a] = self.parent[self.parent[a]]
            a = self.parent[a]
        return a

    def union(self, a: int, b: int) -> bool:
        """Join the sets of a and b; True when they were apart."""
        ra, rb = self.find(a), self.find(b)
        if ra == rb:
            return False
        self.parent[max(ra, rb)] = min(ra, rb)
        return True


@dataclass
class _Cluster:
    """One cluster's merged cloud and features."""

    points: np.ndarray
    box: np.ndarray
    caption: np.ndarray
    histogram: np.ndarray
    tree: cKDTree


def _summarise(masks: MaskSet, members: list[int], voxel_m: float, clouds: list[np.ndarray] | None = None) -> _Cluster:
    """Cloud and features of a cluster (``clouds``: its parts' clouds when already down-sampled)."""
    clouds = clouds if clouds is not None else [masks.points[m] for m in members]
    pts = voxel_downsample(np.concatenate(clouds), voxel_m)
    pts = pts[np.argsort(pts[:, 0], kind="stable")]  # sorted by x: a box query is a slice first
    area = masks.pixels[members].astype(np.float64)
    caption = unit_rows(area @ masks.caption_features[members].astype(np.float64))
    histogram = unit_rows(masks.histograms[members].sum(axis=0))
    return _Cluster(pts, np.concatenate([pts.min(axis=0), pts.max(axis=0)]), caption, histogram, cKDTree(pts))


def _share_near(a: _Cluster, b: _Cluster, dist: float) -> float:
    """Share of a's points with a point of b within ``dist`` (only a's points near b's box are queried)."""
    lo, hi = np.searchsorted(a.points[:, 0], [b.box[0] - dist, b.box[3] + dist])
    cand = a.points[lo:hi]
    cand = cand[np.all((cand[:, 1:] >= b.box[1:3] - dist) & (cand[:, 1:] <= b.box[4:] + dist), axis=1)]
    if len(cand) == 0:
        return 0.0
    d, _ = b.tree.query(cand, k=1, distance_upper_bound=dist)
    return float(np.count_nonzero(np.isfinite(d))) / len(a.points)


def point_overlap(a: _Cluster, b: _Cluster, dist: float) -> tuple[float, float]:
    """The two directional shares (a near b, b near a) of points with a neighbour within ``dist``."""
    return _share_near(a, b, dist), _share_near(b, a, dist)


def _merge_overlap(a: _Cluster, b: _Cluster, config: FineConfig) -> float | None:
    """OpenObj's overlap of a and b when the fine test says they are one object, else None."""
    shares = point_overlap(a, b, config.overlap_distance_m)
    overlap = max(shares)
    caption = float(a.caption @ b.caption)
    if overlap > config.overlap_alone and (min(shares) > config.overlap_alone
                                           or caption > config.subset_caption_similarity):
        return overlap
    if (overlap > config.overlap and caption > config.caption_similarity
            and float(a.histogram @ b.histogram) > config.colour_similarity):
        return overlap
    return None


def _star_merges(n: int, passing: list[tuple[int, int, float]], sizes: list[int]) -> UnionFind:
    """One pass of merges: each cluster joins its best passing partner among LARGER clusters, and only
    when that partner does not itself move this pass (merges form stars, never chains, so a small
    fragment touching two walls cannot join the walls to each other)."""
    rank = lambda c: (sizes[c], -c)  # noqa: E731 - larger cloud first, then smaller index
    best: dict[int, tuple[float, tuple[int, int], int]] = {}
    for a, b, overlap in passing:
        small, big = (a, b) if rank(a) < rank(b) else (b, a)
        cand = (overlap, rank(big), big)
        if small not in best or cand > best[small]:
            best[small] = cand
    uf = UnionFind(n)
    for small, (_, _, big) in sorted(best.items()):
        if big not in best:
            uf.union(small, big)
    return uf


def fine_merge(masks: MaskSet, clusters: list[list[int]], config: FineConfig | None = None,
               voxel_m: float = 0.01) -> list[list[int]]:
    """Merge coarse clusters until no pair passes the fine test (OpenObj phase 2).

    Args:
        masks: the agent's masks.
        clusters: lists of mask indices (the coarse clusters).
        config: thresholds.
        voxel_m: voxel of the clusters' merged clouds.

    Returns:
        merged clusters as sorted lists of mask indices, ordered by their smallest index.
    """
    config = config or FineConfig()
    groups = [sorted(g) for g in clusters if len(g)]
    summaries = [_summarise(masks, g, voxel_m) for g in groups]
    apart: set[tuple[int, int]] = set()  # pairs (by smallest mask index) already found apart
    for _ in range(config.max_passes):
        boxes = np.stack([s.box for s in summaries])
        passing = []
        for a, b in candidate_pairs(boxes, np.arange(len(groups)), config.overlap_distance_m):
            key = (groups[a][0], groups[b][0])
            if key not in apart:
                overlap = _merge_overlap(summaries[a], summaries[b], config)
                if overlap is None:
                    apart.add(key)
                else:
                    passing.append((int(a), int(b), overlap))
        if not passing:
            break
        uf = _star_merges(len(groups), passing, [len(s.points) for s in summaries])
        joined: dict[int, list[int]] = {}
        for g in range(len(groups)):
            joined.setdefault(uf.find(g), []).append(g)
        new_groups, new_summaries = [], []
        for root in sorted(joined):
            parts = joined[root]
            new_groups.append(sorted(m for p in parts for m in groups[p]))
            new_summaries.append(summaries[parts[0]] if len(parts) == 1 else
                                 _summarise(masks, new_groups[-1], voxel_m, [summaries[p].points for p in parts]))
        # a merged cluster has a new cloud: forget its old verdicts (its key may be reused)
        changed = {g[0] for g, root in zip(new_groups, sorted(joined)) if len(joined[root]) > 1}
        apart = {k for k in apart if k[0] not in changed and k[1] not in changed}
        groups, summaries = new_groups, new_summaries
    return sorted(groups, key=lambda g: g[0])
