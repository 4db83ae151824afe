"""A geometric segmenter for RGB-D recordings that come without instance masks (TUM- or 7-Scenes-style).

Per frame, on the back-projected depth: the large planes first (walls, floor, table tops; RANSAC),
each split into its connected pieces on the pixel grid, then Euclidean clusters of what remains
(open3d's ``cluster_dbscan``, one radius per frame). ``RANGE_AWARE`` is the
other setting: plane membership and clustering (PCL's organized Euclidean clustering, grid neighbours
joined when closer than a threshold) grow with the sensor's depth noise (square of depth) and the
grid's spacing at each point's depth, so a wall 4 m away is one plane, not scattered noise. It labels
more of a frame but, with today's mapper, makes worse maps of what it adds (docs/real_data.md), so it
is not the default. Masks carry neutral captions ("a planar surface", "an object"):
the instances they fuse into are geometric, not semantic, and the run says so. Cross-frame fusion
then links the per-frame pieces into instances, as it does for any segmenter's masks.

The work is done on a strided pixel grid (at most ``max_points`` points) and the labels are carried
back to full resolution by nearest grid cell, which costs masks about ``stride`` pixels of precision at
their borders and keeps a frame to tens of milliseconds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from mapping.data.frame import Frame, backproject_pixels
from mapping.perception.types import FrameSegmentation, Segment

PLANE_CAPTION = "a planar surface"
"""Caption of a mask cut out as a plane (instances become "planar surface K")."""
OBJECT_CAPTION = "an object"
"""Caption of a mask cut out as a Euclidean cluster (instances become "object K")."""
CLUSTERINGS = ("organized", "dbscan")
"""How the points off every plane are grouped (``GeometricSegmenterConfig.clustering``)."""


@dataclass(frozen=True)
class GeometricSegmenterConfig:
    """Thresholds of the plane + cluster segmentation (metres, shares of a frame's valid points)."""

    max_points: int = 10_000
    """Points per frame the segmentation works on (the pixel grid is strided to fit): at 160x120,
    10k points (stride 2) took 15 ms a frame and 20k (stride 1) 54 ms for the same masks."""
    plane_distance_m: float = 0.02
    """RANSAC inlier distance, and a plane's membership distance where the sensor is more precise than
    that (structured light: closer than about 2 m)."""
    depth_noise_m_per_m2: float = 0.0
    """The sensor's depth noise at 1 m, growing with depth squared (Kinect v1: about 1.5 mm;
    Khoshelham and Elberink 2012). A point belongs to a plane within ``max(plane_distance_m,
    noise_sigmas x noise(z))``: at 4 m (noise 2.4 cm) a fixed 2 cm holds about 60 % of a wall.
    0 (the default) keeps one plane distance at every depth."""
    noise_sigmas: float = 3.0
    """Depth-noise standard deviations a point may lie off its plane or its neighbour."""
    plane_min_share: float = 0.08
    """A plane must hold this share of the frame's points: smaller ones (a box's top) are left to the
    clustering, so an object is not cut into its faces."""
    max_planes: int = 6
    """Planes tried per frame."""
    ransac_iterations: int = 200
    """RANSAC iterations per plane."""
    clustering: str = "dbscan"
    """How the points off every plane are grouped: ``"dbscan"`` (one neighbourhood for the whole frame:
    far points, sparser and noisier, fall out as noise; on a TUM sequence only 64 % of the pixels at
    3-4 m and 14 % beyond got a mask) or ``"organized"`` (grid neighbours joined when closer than
    ``max(cluster_eps_m, 3 spacings + noise_sigmas x noise)`` at their depth: 89-90 % there)."""
    cluster_eps_m: float = 0.05
    """Smallest joining distance (organized) or DBSCAN neighbourhood (raised to 3 point spacings at the
    frame's median depth where the grid is coarser than that)."""
    cluster_min_points: int = 10
    """Smallest piece (organized) or DBSCAN core-point neighbours."""
    cluster_core_neighbours: int = 0
    """Organized clustering only: pieces grow through points with at least this many of their 8 grid
    neighbours joined (DBSCAN's core rule; 0: every joined pair). 6 keeps a trail of stray points from
    joining two objects, but on 7-Scenes it also gave back most of what ``RANGE_AWARE`` gains
    (20 against 13 % of the depth check off)."""
    max_depth_m: float | None = None
    """Pixels deeper than this get no mask (None: every valid pixel is segmented). E.g. 3.5 m, the far
    end of a Kinect v1's practical range, where its noise reaches 1.8 cm."""
    max_object_extent_m: float | None = 1.0
    """Object clusters wider than this on some axis are cut along a world-aligned lattice of this spacing
    (the same cuts in every frame, so fusion sees the same pieces; pieces under ``cluster_min_points`` get no
    mask). One 32-wide network smooths a 3 m cluster of a counter and what stands on it into surface in front
    of it; cut at 1 m, 7-Scenes (2 agents, `fast`, seeds 0 / 1) came to 11.9 / 12.2 % of pixels off against
    13.2 / 14.2, team coverage 96.9 % against 90.0 / 86.7, TUM unchanged (docs/real_data.md). None: never cut."""
    min_mask_pixels: int = 100
    """Masks with fewer full-resolution pixels are dropped (OpenObj's 100)."""
    seed: int = 0
    """Seed of RANSAC's draws, with the frame's index: a frame gets the same masks every time."""

    def __post_init__(self) -> None:
        if self.max_object_extent_m is not None and not self.max_object_extent_m > 0:
            raise ValueError(f"max_object_extent_m must be a positive length or None, got {self.max_object_extent_m}")


RANGE_AWARE = GeometricSegmenterConfig(depth_noise_m_per_m2=0.0015, clustering="organized")
"""Thresholds that grow with a structured-light sensor's noise and the grid's spacing at each depth: far
surfaces get masks (a TUM sequence: 97 % of its valid pixels labelled, against 94 %). Measured: on a
7-Scenes sequence (all within 3 m) 13 % of the depth check off against 20-27 %; on TUM (out to 5 m) worse,
36-45 % against 25-28 % (docs/real_data.md#segments-at-range)."""

SEGMENTER_SETTINGS = {"fixed": GeometricSegmenterConfig(), "range_aware": RANGE_AWARE}
"""The geometric segmenter's settings by name (``openmulti run --data DIR --segmenter NAME``): ``fixed``
thresholds (the default) or ``range_aware`` ones (for recordings within about 3 m)."""


def segmenter_settings(name: str) -> GeometricSegmenterConfig:
    """The settings called ``name`` in ``SEGMENTER_SETTINGS`` (ValueError listing the known names)."""
    if name not in SEGMENTER_SETTINGS:
        raise ValueError(f"unknown segmenter settings {name!r}; known: {', '.join(SEGMENTER_SETTINGS)}")
    return SEGMENTER_SETTINGS[name]


class GeometricSegmenter:
    """Planes plus Euclidean clusters of one frame, numbered 1..K (planes first, then clusters)."""

    def __init__(self, config: GeometricSegmenterConfig | None = None):
        self.config = config or GeometricSegmenterConfig()
        if self.config.clustering not in CLUSTERINGS:
            raise ValueError(f"unknown clustering {self.config.clustering!r}; known: {', '.join(CLUSTERINGS)}")

    def segment(self, frame: Frame) -> FrameSegmentation:
        """Masks of ``frame`` with neutral captions; pixels without depth stay 0."""
        cfg = self.config
        h, w = frame.depth.shape
        usable = np.isfinite(frame.depth) & (frame.depth > 0)
        if cfg.max_depth_m is not None:
            usable &= frame.depth <= cfg.max_depth_m
        depth = np.where(usable, frame.depth, 0.0)
        valid_count = int(np.count_nonzero(usable))
        stride = max(1, int(np.ceil(np.sqrt(valid_count / cfg.max_points)))) if valid_count else 1
        points, valid = backproject_pixels(depth, frame.intrinsics, frame.pose, stride=stride)
        grid = np.zeros(valid.shape, np.int32)
        captions: list[str] = []
        if len(points) >= cfg.cluster_min_points:
            labels, captions = self._label_points(points, valid, depth, frame, stride)
            grid[valid] = labels
        full = np.repeat(np.repeat(grid, stride, axis=0), stride, axis=1)[:h, :w]
        full[~usable] = 0
        return _numbered(frame.index, full, captions, cfg.min_mask_pixels)

    def _label_points(self, points: np.ndarray, valid: np.ndarray, depth: np.ndarray, frame: Frame,
                      stride: int) -> tuple[np.ndarray, list[str]]:
        """(n,) labels 1..K of the points (0 = none) and the caption of each label.

        ``valid`` is the pixel grid the points came from (row-major): a plane's inliers are split into
        pieces by connectivity on that grid (``scipy.ndimage.label``), which on a depth image is 3D
        connectivity within the plane at a fraction of DBSCAN's cost; the rest is clustered by
        ``config.clustering``.
        """
        cfg = self.config
        rng = np.random.default_rng((cfg.seed, frame.index))
        labels = np.zeros(len(points), np.int32)
        captions: list[str] = []
        z = depth[::stride, ::stride][valid].astype(np.float64)  # depth of each point, row-major
        noise = cfg.noise_sigmas * cfg.depth_noise_m_per_m2 * z**2  # 0 by default
        plane_tolerance = np.maximum(cfg.plane_distance_m, noise)
        remaining = np.arange(len(points))
        min_plane = cfg.plane_min_share * len(points)
        for _ in range(cfg.max_planes):
            if len(remaining) < max(3, min_plane):
                break
            inliers = remaining[ransac_plane(points[remaining], plane_tolerance[remaining], cfg.ransac_iterations, rng)]
            pieces = _grid_pieces(inliers, valid)
            if not pieces or len(pieces[0]) < min_plane:
                break
            # RANSAC's best plane may cut strips off several parallel surfaces (two box tops at
            # different heights): refit it to its largest connected piece, then take that plane's inliers
            normal, offset = _fit_plane(points[inliers[pieces[0]]])
            members = remaining[np.abs(points[remaining] @ normal - offset) < plane_tolerance[remaining]]
            for piece in _grid_pieces(members, valid):
                if len(piece) >= min_plane / 4:  # coplanar pieces (two table tops) are planes; strips are not
                    captions.append(PLANE_CAPTION)
                    labels[members[piece]] = len(captions)
            left = remaining[labels[remaining] == 0]
            if len(left) == len(remaining):
                break
            remaining = left
        if cfg.clustering == "organized":
            spacing = z * stride / frame.intrinsics.fx  # distance between grid neighbours facing the camera
            join = np.maximum(cfg.cluster_eps_m, 3.0 * spacing + noise)
            pieces = _organized_clusters(points, remaining, valid, join, cfg.cluster_min_points,
                                         cfg.cluster_core_neighbours)
        else:
            ranges = np.linalg.norm(points - frame.pose[:3, 3], axis=1)
            eps = max(cfg.cluster_eps_m, 3.0 * float(np.median(ranges)) * stride / frame.intrinsics.fx)
            pieces = _clusters(points[remaining], eps, cfg.cluster_min_points)
        if cfg.max_object_extent_m is not None:
            pieces = [part for piece in pieces for part in lattice_parts(points[remaining], piece,
                                                                         cfg.max_object_extent_m,
                                                                         cfg.cluster_min_points)]
        for piece in pieces:
            captions.append(OBJECT_CAPTION)
            labels[remaining[piece]] = len(captions)
        return labels, captions


def ransac_plane(points: np.ndarray, tolerance: np.ndarray, iterations: int, rng: np.random.Generator,
                  block: int = 32, scored: int = 2_000) -> np.ndarray:
    """Positions of the inliers (``|n . x - d| < tolerance``) of the plane through three of ``points``
    that holds the most, over ``iterations`` draws. Written out rather than open3d's ``segment_plane``,
    whose draws are not repeatable across calls in one process (the same frame got other planes in 12
    of 54 frames). The hypotheses are scored ``block`` at a time with one matrix product, on every k-th
    point (at most ``scored``): all 10,000 points cost 28 ms a call."""
    if len(points) < 3:
        return np.zeros(0, np.int64)
    triples = points[rng.integers(0, len(points), size=(iterations, 3))]
    normals = np.cross(triples[:, 1] - triples[:, 0], triples[:, 2] - triples[:, 0])
    lengths = np.linalg.norm(normals, axis=1)
    keep = lengths > 1e-12  # three collinear or repeated points span no plane
    if not keep.any():
        return np.zeros(0, np.int64)
    normals = normals[keep] / lengths[keep, None]
    offsets = np.einsum("ij,ij->i", normals, triples[keep, 0])
    step = -(-len(points) // scored)
    sample, sample_tolerance = points[::step], tolerance[::step, None]
    counts = np.concatenate([
        (np.abs(sample @ normals[s:s + block].T - offsets[s:s + block]) < sample_tolerance).sum(0)
        for s in range(0, len(normals), block)])
    best = int(np.argmax(counts))  # the first of equals: repeatable
    return np.flatnonzero(np.abs(points @ normals[best] - offsets[best]) < tolerance)


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane of ``points``: unit normal n and offset d with n . x = d."""
    centre = points.mean(axis=0)
    normal = np.linalg.svd(points - centre, full_matrices=False)[2][-1]
    return normal, float(normal @ centre)


def lattice_parts(points: np.ndarray, piece: np.ndarray, spacing_m: float, min_points: int) -> list[np.ndarray]:
    """``piece`` (indices of ``points``, (n, 3) world) whole when it spans at most ``spacing_m`` on every
    axis, else its parts in the cells of a world lattice of that spacing (parts under ``min_points`` left
    out), largest first."""
    cloud = points[piece]
    if np.all(np.ptp(cloud, axis=0) <= spacing_m):
        return [piece]
    _, cell = np.unique(np.floor(cloud / spacing_m).astype(np.int64), axis=0, return_inverse=True)
    parts = [piece[cell.ravel() == k] for k in range(int(cell.max()) + 1)]
    return sorted((part for part in parts if len(part) >= min_points), key=len, reverse=True)


def _grid_pieces(members: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
    """Positions in ``members`` (indices of points, row-major over ``valid``) of each 8-connected piece
    they form on the pixel grid, largest first."""
    cells = np.flatnonzero(valid.ravel())[members]
    mask = np.zeros(valid.size, bool)
    mask[cells] = True
    pieces, count = ndimage.label(mask.reshape(valid.shape), structure=np.ones((3, 3), bool))
    piece_of = pieces.ravel()[cells]
    groups = [np.flatnonzero(piece_of == k) for k in range(1, count + 1)]
    return sorted(groups, key=len, reverse=True)


def _organized_clusters(points: np.ndarray, members: np.ndarray, valid: np.ndarray, join: np.ndarray,
                        min_points: int, core_neighbours: int) -> list[np.ndarray]:
    """Positions in ``members`` of each connected piece they form when 8-neighbours on the pixel grid
    closer than the larger of their ``join`` distances are linked (PCL's organized Euclidean clustering,
    depth-dependent, with DBSCAN's core points: ``core_neighbours`` of 8 linked); pieces under
    ``min_points`` and points with no core neighbour are left out. Largest first."""
    from scipy.sparse import coo_matrix  # noqa: PLC0415
    from scipy.sparse.csgraph import connected_components  # noqa: PLC0415

    if len(members) < min_points:
        return []
    cells = np.flatnonzero(valid.ravel())[members]
    position = np.full(valid.size, -1, np.int64)
    position[cells] = np.arange(len(members))
    rows, cols = np.divmod(cells, valid.shape[1])
    heads, tails = [], []
    for dr, dc in ((0, 1), (1, -1), (1, 0), (1, 1)):
        r, c = rows + dr, cols + dc
        inside = (r < valid.shape[0]) & (c >= 0) & (c < valid.shape[1])
        other = np.full(len(members), -1, np.int64)
        other[inside] = position[r[inside] * valid.shape[1] + c[inside]]
        a = np.flatnonzero(other >= 0)
        b = other[a]
        pa, pb = members[a], members[b]
        close = np.linalg.norm(points[pa] - points[pb], axis=1) < np.maximum(join[pa], join[pb])
        heads.append(a[close])
        tails.append(b[close])
    head, tail = np.concatenate(heads), np.concatenate(tails)
    # as DBSCAN on the grid: pieces grow through core points (most of their 8 neighbours joined), and a
    # border point joins the piece of a core neighbour, so a trail of stray points bridges nothing
    degree = np.bincount(head, minlength=len(members)) + np.bincount(tail, minlength=len(members))
    core = degree >= core_neighbours
    inner = core[head] & core[tail]
    graph = coo_matrix((np.ones(int(inner.sum()), np.int8), (head[inner], tail[inner])),
                       shape=(len(members), len(members)))
    _, ids = connected_components(graph, directed=False)
    ids = np.where(core, ids, -1)
    # (border point, core neighbour) pairs; each border point takes its first core neighbour's piece
    border = np.concatenate([np.c_[tail, head][core[head] & ~core[tail]],
                             np.c_[head, tail][core[tail] & ~core[head]]])
    _, first = np.unique(border[:, 0], return_index=True)
    ids[border[first, 0]] = ids[border[first, 1]]
    sizes = np.bincount(ids[ids >= 0], minlength=int(ids.max(initial=-1)) + 1)
    order = np.argsort(-sizes, kind="stable")
    return [np.flatnonzero(ids == k) for k in order if sizes[k] >= max(min_points, 1)]


def _clusters(points: np.ndarray, eps: float, min_points: int) -> list[np.ndarray]:
    """Index arrays of the DBSCAN clusters of ``points`` (noise left out), largest first."""
    import open3d as o3d  # noqa: PLC0415

    if len(points) < min_points:
        return []
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
    ids = np.asarray(cloud.cluster_dbscan(eps=eps, min_points=min_points, print_progress=False))
    groups = [np.flatnonzero(ids == k) for k in range(int(ids.max(initial=-1)) + 1)]
    return sorted(groups, key=len, reverse=True)


def _numbered(frame_index: int, labels: np.ndarray, captions: list[str], min_pixels: int) -> FrameSegmentation:
    """Drop masks under ``min_pixels`` and renumber the rest 1..K in label order."""
    counts = np.bincount(labels.ravel(), minlength=len(captions) + 1)
    keep = [k for k in range(1, len(captions) + 1) if counts[k] >= min_pixels]
    lut = np.zeros(len(captions) + 1, np.int32)
    lut[keep] = np.arange(1, len(keep) + 1, dtype=np.int32)
    segments = [Segment(n, captions[k - 1], int(counts[k])) for n, k in enumerate(keep, start=1)]
    return FrameSegmentation(frame_index, lut[labels], segments)


def instance_caption(caption: str, instance_id: int) -> str:
    """The neutral caption of a fused geometric instance: "planar surface 3", "object 7"."""
    kind = "planar surface" if caption == PLANE_CAPTION else "object"
    return f"{kind} {instance_id}"
