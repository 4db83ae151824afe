"""Agent camera paths: smooth trajectories through different parts of the room that, together, see
the whole observable surface, while each alone leaves blind zones.

How a path is planned (per agent):
1. the free-space viewpoints are split into one region per agent (k-means on the floor plan), and
   each observable face is owned by the region of the nearest viewpoint that sees it;
2. key views (a viewpoint and a viewing direction) are chosen greedily to cover the region's own
   faces, as a weighted set cover on the visibility computed for culling;
3. the key views are ordered into a tour, joined through free space along shortest paths on the
   viewpoint graph (networkx), and sampled into frames with orientations slerped between key views.
Poses are camera-to-world, OpenCV axes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import networkx as nx
import numpy as np
from scipy.cluster.vq import kmeans2
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation, Slerp

from mapping.config_fields import bounded, lengths
from mapping.data import Intrinsics
from mapping.evaluate.raycast import MeshRaycaster
from mapping.evaluate.visibility import visibility_matrix
from openmulti_env.world.visibility import ObservableSurface

MAX_FRAMES_PER_AGENT = 100_000
"""Most frames a path may have (an hour at 30 frames a second): its poses and the planner's loops grow with it."""


@dataclass(frozen=True)
class PathConfig:
    """How agents move and look."""

    frames_per_agent: int = field(default=120, metadata=bounded(1, MAX_FRAMES_PER_AGENT))
    """Frames each agent records along its path."""
    yaw_steps: int = field(default=12, metadata=bounded(1, 360))
    """Candidate headings per viewpoint (every 30 degrees)."""
    pitches_deg: tuple[float, ...] = field(default=(-55.0, -25.0, 5.0, 35.0),
                                           metadata=lengths(1, 32, bounded(-89, 89)))
    """Candidate tilts (negative looks down)."""
    max_view_distance_m: float = field(default=6.0, metadata=bounded(0, 100, low_open=True))
    """Faces farther than this do not count as covered by a key view (too few pixels on them)."""
    target_region_coverage: float = field(default=0.995, metadata=bounded(0, 1, low_open=True))
    """Stop adding key views once this share of the region's area is covered."""
    max_key_views: int = field(default=40, metadata=bounded(1, 10_000))
    """Upper bound on key views per agent."""
    image_margin: float = field(default=0.08, metadata=bounded(0, 0.5, high_open=True))
    """Share of the image border not counted when choosing key views (the edge is seen at a slant)."""
    foreign_penalty: float = field(default=1.0, metadata=bounded(0, 1e6))
    """Cost of seeing another region's surface, per unit of own new surface: keeps agents looking at
    their own part of the room, which leaves each agent blind zones that only the team covers."""
    smoothing_frames: float = field(default=1.5, metadata=bounded(0, 1000))
    """Gaussian smoothing of positions along the path, in frames (rounds the grid's corners)."""
    planning_points: int = field(default=6000, metadata=bounded(1, 1_000_000))
    """Surface samples the planner reasons about."""


def look_rotation(yaw_deg: float, pitch_deg: float) -> np.ndarray:
    """(3, 3) camera-to-world rotation (OpenCV axes) looking at heading ``yaw`` and tilt ``pitch``."""
    y, p = np.radians(yaw_deg), np.radians(pitch_deg)
    forward = np.array([np.cos(p) * np.cos(y), np.cos(p) * np.sin(y), np.sin(p)])
    right = np.cross(forward, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    return np.stack([right, down, forward], axis=1)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """(4, 4) camera-to-world pose at ``eye`` looking at ``target`` with no roll."""
    d = np.asarray(target, float) - np.asarray(eye, float)
    yaw = np.degrees(np.arctan2(d[1], d[0]))
    pitch = np.degrees(np.arctan2(d[2], np.hypot(d[0], d[1])))
    pose = np.eye(4)
    pose[:3, :3] = look_rotation(yaw, np.clip(pitch, -89.0, 89.0))
    pose[:3, 3] = eye
    return pose


def split_regions(viewpoints: np.ndarray, n_regions: int, seed: int) -> np.ndarray:
    """Region label (0..n_regions-1) of each viewpoint: k-means on the floor plan, ordered by angle
    around the room centre so labels are stable."""
    xy = viewpoints[:, :2]
    if n_regions == 1:
        return np.zeros(len(xy), dtype=int)
    rng = np.random.default_rng(seed)
    centre = xy.mean(axis=0)
    angles = np.linspace(0, 2 * np.pi, n_regions, endpoint=False) + rng.uniform(0, 2 * np.pi / n_regions)
    spread = 0.5 * (xy.max(axis=0) - xy.min(axis=0))
    init = centre + spread * np.stack([np.cos(angles), np.sin(angles)], axis=1) * 0.6
    centroids, labels = kmeans2(xy, init, minit="matrix", iter=30)
    order = np.argsort(np.arctan2(*(centroids - centre).T[::-1]))
    relabel = np.empty(n_regions, dtype=int)
    relabel[order] = np.arange(n_regions)
    return relabel[labels]


def point_owners(points: np.ndarray, viewpoints: np.ndarray, vis: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """Region of each surface point: the region of the nearest viewpoint that sees it."""
    best = np.full(len(points), np.inf)
    owner = np.zeros(len(points), dtype=int)
    for i, eye in enumerate(viewpoints):
        d = np.linalg.norm(points - eye, axis=1)
        better = vis[i] & (d < best)
        best[better] = d[better]
        owner[better] = regions[i]
    return owner


def choose_key_views(points: np.ndarray, vis: np.ndarray, viewpoints: np.ndarray, region_viewpoints: np.ndarray,
                     owned: np.ndarray, intrinsics: Intrinsics, cfg: PathConfig) -> list[tuple[int, float, float]]:
    """Greedy set cover of the region's own surface points by (viewpoint, yaw, pitch) key views, each
    view paying ``foreign_penalty`` for the other regions' surface it sees.

    Args:
        points: (n, 3) surface samples; vis: (m, n) viewpoint-sees-point.
        region_viewpoints: indices of the viewpoints of this region.
        owned: (n,) bool, points of this region.

    Returns:
        key views as (viewpoint index, yaw_deg, pitch_deg), in the order chosen.
    """
    yaws = np.arange(cfg.yaw_steps) * 360.0 / cfg.yaw_steps
    dirs = [(float(y), float(p)) for y in yaws for p in cfg.pitches_deg]
    rots = np.stack([look_rotation(y, p) for y, p in dirs])  # (d, 3, 3)
    k = intrinsics
    cands, seen_rows, inner_rows = [], [], []
    for vp in region_viewpoints:
        seen = vis[vp] & (np.linalg.norm(points - viewpoints[vp], axis=1) < cfg.max_view_distance_m)
        if not (seen & owned).any():
            continue
        idx = np.flatnonzero(seen)
        cam = (points[idx] - viewpoints[vp]) @ rots  # (d, n_seen, 3): camera coordinates per direction
        z = np.maximum(cam[..., 2], 1e-9)
        u, v = k.fx * cam[..., 0] / z + k.cx, k.fy * cam[..., 1] / z + k.cy
        front = cam[..., 2] > 0.1
        mu, mv = cfg.image_margin * k.width, cfg.image_margin * k.height
        in_image = front & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        in_inner = front & (u >= mu) & (u < k.width - mu) & (v >= mv) & (v < k.height - mv)
        for d, (yaw, pitch) in enumerate(dirs):
            if not (in_inner[d] & owned[idx]).any():
                continue
            row_seen = np.zeros(len(points), dtype=bool)
            row_seen[idx[in_image[d]]] = True
            row_inner = np.zeros(len(points), dtype=bool)
            row_inner[idx[in_inner[d]]] = True
            cands.append((int(vp), yaw, pitch))
            seen_rows.append(row_seen)
            inner_rows.append(row_inner)
    if not cands:
        return []
    own_cover = (np.stack(inner_rows) & owned).astype(np.float32)  # (n_candidates, n_points)
    foreign_seen = (np.stack(seen_rows) & ~owned).astype(np.float32)
    goal = cfg.target_region_coverage * own_cover.any(axis=0).sum()
    covered = np.zeros(len(points), dtype=bool)
    exposed = np.zeros(len(points), dtype=bool)
    chosen: list[tuple[int, float, float]] = []
    # at least three frames per key view, so the camera moves between them rather than jumping
    max_keys = max(1, min(cfg.max_key_views, cfg.frames_per_agent // 3))
    while len(chosen) < max_keys and covered.sum() < goal:
        new_own = own_cover @ (~covered).astype(np.float32)
        new_foreign = foreign_seen @ (~exposed).astype(np.float32)
        score = np.where(new_own > 0, new_own - cfg.foreign_penalty * new_foreign, -np.inf)
        best = int(np.argmax(score))
        if new_own[best] <= 0:
            break
        chosen.append(cands[best])
        covered |= own_cover[best] > 0
        exposed |= foreign_seen[best] > 0
    return chosen


def _order_tour(positions: np.ndarray, rotations: list[np.ndarray], start: int = 0) -> list[int]:
    """Nearest-neighbour tour over key views; cost = distance + 0.5 m per radian of turning."""
    n = len(positions)
    forward = np.stack([r[:, 2] for r in rotations])
    cost = np.linalg.norm(positions[:, None] - positions[None], axis=2) + 0.5 * np.arccos(
        np.clip(forward @ forward.T, -1.0, 1.0))
    order, left = [start], np.ones(n, dtype=bool)
    left[start] = False
    while left.any():
        nxt = int(np.argmin(np.where(left, cost[order[-1]], np.inf)))
        order.append(nxt)
        left[nxt] = False
    return order


def viewpoint_graph(viewpoints: np.ndarray, spacing_m: float) -> nx.Graph:
    """Graph of free-space viewpoints joined to their grid neighbours (edges weighted by length)."""
    tree = cKDTree(viewpoints)
    g = nx.Graph()
    g.add_nodes_from(range(len(viewpoints)))
    for i, j in tree.query_pairs(1.8 * spacing_m):
        g.add_edge(int(i), int(j), weight=float(np.linalg.norm(viewpoints[i] - viewpoints[j])))
    return g


def _segment_waypoints(graph: nx.Graph, viewpoints: np.ndarray, a: int, b: int) -> np.ndarray:
    try:
        nodes = nx.shortest_path(graph, a, b, weight="weight")
    except nx.NetworkXNoPath:
        nodes = [a, b]
    return viewpoints[nodes]


def interpolate_path(waypoint_lists: list[np.ndarray], key_rotations: list[np.ndarray], n_frames: int) -> np.ndarray:
    """Sample ``n_frames`` poses along the joined segments; each key view gets a frame.

    Args:
        waypoint_lists: per segment k (key view k -> k+1), its (m_k, 3) positions through free space.
        key_rotations: the rotation of each key view (one more than segments).

    Returns:
        (n_frames, 4, 4) camera-to-world poses.
    """
    n_keys = len(key_rotations)
    if n_keys == 1:
        return np.repeat(_pose(key_rotations[0], waypoint_lists[0][0] if waypoint_lists else None)[None], n_frames, 0)
    rots = Rotation.from_matrix(np.stack(key_rotations))
    costs = []
    for k, wp in enumerate(waypoint_lists):
        length = np.linalg.norm(np.diff(wp, axis=0), axis=1).sum()
        turn = (rots[k].inv() * rots[k + 1]).magnitude()
        costs.append(length / 0.10 + turn / np.radians(8.0) + 1e-6)
    costs = np.asarray(costs)
    # frames per segment (the segment's start key view included), at least one each
    extra = max(n_frames - n_keys, 0)
    per_seg = 1 + np.floor(extra * costs / costs.sum()).astype(int)
    per_seg[np.argsort(-costs)[: max(n_frames - 1 - per_seg.sum(), 0)]] += 1
    poses = []
    for k, wp in enumerate(waypoint_lists):
        seg_len = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(wp, axis=0), axis=1))])
        slerp = Slerp([0.0, 1.0], rots[[k, k + 1]])
        for s in np.arange(per_seg[k]) / per_seg[k]:
            pos = np.array([np.interp(s * seg_len[-1], seg_len, wp[:, d]) for d in range(3)]) if seg_len[-1] > 0 else wp[0]
            poses.append(_pose(slerp([s]).as_matrix()[0], pos))
    poses.append(_pose(key_rotations[-1], waypoint_lists[-1][-1]))
    return np.stack(poses[:n_frames])


def _pose(rotation: np.ndarray, position) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, :3] = rotation
    if position is not None:
        pose[:3, 3] = position
    return pose


def plan_agent_paths(surface: ObservableSurface, caster: MeshRaycaster, n_paths: int, intrinsics: Intrinsics,
                     config: PathConfig | None = None, seed: int = 0, spacing_m: float = 0.35) -> list[np.ndarray]:
    """One smooth path per region; see the module docstring.

    Returns:
        ``n_paths`` arrays of (frames_per_agent, 4, 4) camera-to-world poses.
    """
    cfg = config or PathConfig()
    if not 1 <= n_paths <= 8:
        raise ValueError(f"number of agents must be between 1 and 8, got {n_paths}")
    vps = surface.viewpoints
    points, normals, _ = surface.sample_points(cfg.planning_points, seed=seed)
    vis = visibility_matrix(caster, vps, points, normals)
    regions = split_regions(vps, n_paths, seed)
    owners = point_owners(points, vps, vis, regions)
    graph = viewpoint_graph(vps, spacing_m)
    paths = []
    for r in range(n_paths):
        region_vps = np.flatnonzero(regions == r)
        keys = choose_key_views(points, vis, vps, region_vps, owners == r, intrinsics, cfg)
        if not keys:  # a region that sees nothing of its own: look around from its first viewpoint
            keys = [(int(region_vps[0]), 0.0, 0.0)]
        positions = np.stack([vps[k[0]] for k in keys])
        rotations = [look_rotation(k[1], k[2]) for k in keys]
        order = _order_tour(positions, rotations)
        keys = [keys[i] for i in order]
        rotations = [rotations[i] for i in order]
        segments = [_segment_waypoints(graph, vps, keys[i][0], keys[i + 1][0]) for i in range(len(keys) - 1)]
        if not segments:
            segments = [vps[[keys[0][0]]]]
        poses = interpolate_path(segments, rotations, cfg.frames_per_agent)
        # round the grid path's corners (a few centimetres; the viewpoints keep clearance_m from obstacles)
        poses[:, :3, 3] = gaussian_filter1d(poses[:, :3, 3], sigma=cfg.smoothing_frames, axis=0, mode="nearest")
        paths.append(poses)
    return paths
