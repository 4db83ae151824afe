"""The spatial overlap of two instance clouds (eq. 3-4), on which the Instance Collaborative Graph's
edges rest.

Each agent voxel down-samples every instance cloud before sending it (paper, sec. III-C: "high
precision is not required"), so the message is small. A point of cloud A *overlaps* cloud B when its
nearest neighbour in B lies within ``radius_m`` (distance <= radius). Then, with |A n B| read as the
number of A's points that overlap B:

    IoB(A, B) = |A n B| / |A|                  (eq. 4; the bound is A's own cloud, so it is directed)
    IoU(A, B) = |A n B| / (|A| + |B| - |A n B|)  (eq. 3)

For IoU to be symmetric, |A n B| there is the mean of the two directed counts (A into B and B into A);
on clouds of equal density the two counts agree. IoB(A, B) = 1 means A lies inside B (A may be a
partial view or a piece of B).

Radius and voxel: the paper's 0.01 m goes with its (finer, unstated) down-sampling. Two agents that
sample one surface independently and keep one centroid per voxel of size v get points up to about v
apart, so a radius much smaller than v finds few overlaps even on identical surfaces. The default
here is v = 0.02 m with a radius equal to v: same-surface points overlap, and objects only touch at
their contact line. The radius must also be at least the spacing of the input points, or IoB of a
dense cloud into a sparse one drops.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy.spatial import cKDTree

from mapping.pointcloud import check_points


def directed_overlap_count(a: np.ndarray, b: np.ndarray, radius_m: float) -> int:
    """Number of points of ``a`` whose nearest neighbour in ``b`` is within ``radius_m``.

    Args:
        a: (n, 3) float points.
        b: (m, 3) float points.
        radius_m: overlap distance (>= 0).
    """
    a, b = check_points(a, "a"), check_points(b, "b")
    if radius_m < 0:
        raise ValueError(f"radius_m must be >= 0, got {radius_m}")
    if len(a) == 0 or len(b) == 0:
        return 0
    dist, _ = cKDTree(b).query(a, k=1)
    return int(np.count_nonzero(dist <= radius_m))


def iou_from_counts(n_a: int | np.ndarray, n_b: int | np.ndarray, n_ab: int | np.ndarray,
                    n_ba: int | np.ndarray) -> np.ndarray:
    """Eq. 3 from cloud sizes and the two directed overlap counts (broadcasts; 0 for two empty clouds)."""
    inter = 0.5 * (np.asarray(n_ab, np.float64) + np.asarray(n_ba, np.float64))
    union = np.asarray(n_a, np.float64) + np.asarray(n_b, np.float64) - inter
    return np.divide(inter, union, out=np.zeros(np.broadcast(inter, union).shape), where=union > 0)


def iou(a: np.ndarray, b: np.ndarray, radius_m: float = 0.02) -> float:
    """Eq. 3: symmetric overlap of two clouds, (n, 3) and (m, 3), in [0, 1]."""
    n_ab, n_ba = directed_overlap_count(a, b, radius_m), directed_overlap_count(b, a, radius_m)
    return float(iou_from_counts(len(a), len(b), n_ab, n_ba))


def iob(a: np.ndarray, b: np.ndarray, radius_m: float = 0.02) -> float:
    """Eq. 4: share of ``a``'s points that overlap ``b`` (1 when a lies inside b; 0 for empty a)."""
    n_ab = directed_overlap_count(a, b, radius_m)
    return n_ab / len(a) if len(a) else 0.0


def pairwise_overlap_counts(clouds_a: Sequence[np.ndarray], clouds_b: Sequence[np.ndarray],
                            radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Directed overlap counts between every cloud of one set and every cloud of another.

    One KD-tree pair over the concatenated clouds instead of a tree per instance pair: every point pair
    within the radius is found once, then counted per (point, other instance).

    Args:
        clouds_a: na clouds, each (n_i, 3).
        clouds_b: nb clouds, each (m_j, 3).
        radius_m: overlap distance.

    Returns:
        n_ab: (na, nb) int64, points of a_i that overlap b_j.
        n_ba: (na, nb) int64, points of b_j that overlap a_i.
    """
    na, nb = len(clouds_a), len(clouds_b)
    n_ab, n_ba = np.zeros((na, nb), np.int64), np.zeros((na, nb), np.int64)
    if na == 0 or nb == 0:
        return n_ab, n_ba
    pa, owner_a = _concatenate(clouds_a)
    pb, owner_b = _concatenate(clouds_b)
    if len(pa) == 0 or len(pb) == 0:
        return n_ab, n_ba
    pairs = cKDTree(pa).sparse_distance_matrix(cKDTree(pb), radius_m, output_type="ndarray")
    i, j = pairs["i"], pairs["j"]
    _count_unique(i, owner_a, owner_b[j], n_ab, nb)
    _count_unique(j, owner_b, owner_a[i], n_ba.T, na)
    return n_ab, n_ba


def _concatenate(clouds: Sequence[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """All points stacked, (N, 3), and the index of the cloud each came from, (N,)."""
    sizes = [len(c) for c in clouds]
    points = np.concatenate([np.asarray(c, np.float64).reshape(-1, 3) for c in clouds])
    return points, np.repeat(np.arange(len(clouds)), sizes)


def _count_unique(point: np.ndarray, owner: np.ndarray, other: np.ndarray, out: np.ndarray,
                  n_other: int) -> None:
    """out[c, o] += distinct points of cloud c with a neighbour in cloud o, from (point, other) pairs.

    ``owner`` maps every point index to its cloud; a point near several points of one cloud counts once.
    """
    key = np.unique(point * n_other + other)
    p, o = np.divmod(key, n_other)
    np.add.at(out, (owner[p], o), 1)
