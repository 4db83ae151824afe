"""Plausibility checks of a loaded sequence that a loader cannot make from file headers alone.

A wrong depth scale or poses in the wrong direction load without error and then map to garbage;
these checks read a few frames and warn (``DatasetWarning``) naming the file and the way out:

- depth unit: the median valid depth of indoor RGB-D data lies between 0.2 and 15 m; outside that
  the depth scale (raw units per metre, ``--depth-scale``) is almost surely wrong;
- pose direction: consecutive frames of a real trajectory see the same surface, so frame i's depth
  carried into frame j through the poses must agree with frame j's depth. Poses that are
  world-to-camera (or otherwise not camera-to-world, OpenCV axes) make that agreement collapse.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from mapping.data.files import DatasetWarning
from mapping.data.frame import Frame, backproject_depth

PLAUSIBLE_MEDIAN_DEPTH_M = (0.2, 15.0)
"""Median depth of indoor RGB-D frames (hand-held, robot and Replica/ScanNet data all fall inside)."""
AGREEMENT_TOLERANCE = 0.05
"""Relative depth difference under which a reprojected point agrees with the other frame's depth."""
MIN_AGREEMENT = 0.3
"""Share of the overlapping reprojected points that must agree for neighbouring frames to look
consistent (occlusion and sensor noise keep correct poses well above it; wrong poses land points at
unrelated depths, far below it)."""
FREE_SPACE_CONFLICT_M = 0.05
"""A point carried into the neighbour's view more than this in front of the neighbour's depth lies where the
neighbour saw free space: one of the two frames' poses (or its depth's timing) is off, and no single map
can match both frames there (the depth check's 5 cm)."""
CONFLICT_NOTE_SHARE = 0.03
"""Above this median share of conflicting points the run's notes say so (7-Scenes: 0.5 %; a TUM sequence
with motion-capture poses: about 11 %)."""
MIN_OVERLAP = 0.1
"""A pair counts only when this share of the first frame's points lands inside the second frame."""


@dataclass(frozen=True)
class PoseCheck:
    """Reprojection agreement of neighbouring frames under the poses as given and inverted."""

    as_given: float
    inverted: float
    pairs: int
    free_space_conflict: float = float("nan")
    """Median share of the overlapping points that land more than ``FREE_SPACE_CONFLICT_M`` in front of the
    neighbour's depth, poses as given: a point one frame saw where the other saw free space."""


def median_depth_m(frames: Sequence[Frame]) -> float:
    """Median of the valid depth readings of ``frames`` (NaN when none is valid)."""
    values = [f.depth[(f.depth > 0) & np.isfinite(f.depth)][::7] for f in frames]
    values = np.concatenate(values) if values else np.zeros(0)
    return float(np.median(values)) if len(values) else float("nan")


def check_depth_unit(frames: Sequence[Frame], where: str, depth_scale: float) -> float:
    """Warn when the median depth of ``frames`` is implausible for indoor data; returns the median."""
    median = median_depth_m(frames)
    lo, hi = PLAUSIBLE_MEDIAN_DEPTH_M
    if not np.isfinite(median):
        warnings.warn(f"{where}: no valid depth in the frames checked (all zero, missing or non-finite)",
                      DatasetWarning, stacklevel=2)
    elif not lo <= median <= hi:
        guess = depth_scale * median / 2.5  # the scale that would put the median at a typical 2.5 m
        warnings.warn(f"{where}: median depth is {median:.3g} m with depth scale {depth_scale:g} raw units per "
                      f"metre, implausible for indoor data ({lo}-{hi} m); the depth unit is probably wrong: "
                      f"pass --depth-scale (e.g. about {guess:.4g})", DatasetWarning, stacklevel=2)
    return median


def _agreement(src: Frame, dst: Frame, src_pose: np.ndarray, dst_pose: np.ndarray,
               stride: int) -> tuple[float, float] | None:
    """Shares of ``src``'s points, carried into ``dst`` by the poses, whose depth agrees with ``dst``'s and
    that land more than ``FREE_SPACE_CONFLICT_M`` in front of it (of those ``dst`` has depth for)."""
    points = backproject_depth(src.depth, src.intrinsics, src_pose, stride=stride)
    if len(points) == 0:
        return None
    world_to_cam = np.linalg.inv(dst_pose)
    cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
    k = dst.intrinsics
    z = cam[:, 2]
    front = z > 1e-3
    u = np.round(k.fx * cam[front, 0] / z[front] + k.cx).astype(np.int64)
    v = np.round(k.fy * cam[front, 1] / z[front] + k.cy).astype(np.int64)
    inside = (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
    seen = dst.depth[v[inside], u[inside]]
    zz = z[front][inside]
    ok = seen > 0
    if ok.sum() < MIN_OVERLAP * len(points):
        return 0.0, float("nan")  # the neighbour does not look at the same place
    agree = np.abs(seen[ok] - zz[ok]) < AGREEMENT_TOLERANCE * zz[ok]
    return float(agree.mean()), float((zz[ok] < seen[ok] - FREE_SPACE_CONFLICT_M).mean())


def pose_agreement(pairs: Sequence[tuple[Frame, Frame]], stride: int = 8) -> PoseCheck:
    """Median agreement of pairs of neighbouring frames with the poses as given and inverted."""
    given, inverted, conflict = [], [], []
    for a, b in pairs:
        g = _agreement(a, b, a.pose, b.pose, stride)
        i = _agreement(a, b, np.linalg.inv(a.pose), np.linalg.inv(b.pose), stride)
        if g is not None and i is not None:
            given.append(g[0])
            inverted.append(i[0])
            conflict.append(g[1])
    if not given:
        return PoseCheck(float("nan"), float("nan"), 0)
    conflict = [c for c in conflict if np.isfinite(c)]
    return PoseCheck(float(np.median(given)), float(np.median(inverted)), len(given),
                     float(np.median(conflict)) if conflict else float("nan"))


def check_poses(pairs: Sequence[tuple[Frame, Frame]], where: str) -> PoseCheck:
    """Warn when neighbouring frames disagree under their poses (poses not camera-to-world)."""
    result = pose_agreement(pairs)
    if result.pairs and result.as_given < MIN_AGREEMENT:
        hint = (" but agree with the poses inverted: the file probably holds world-to-camera matrices; "
                "invert them" if result.inverted >= max(MIN_AGREEMENT, result.as_given + 0.2) else
                "; the poses may not be camera-to-world with OpenCV axes (x right, y down, z forward), or "
                "the frames are too far apart (--frames with a smaller step)")
        warnings.warn(f"{where}: neighbouring frames disagree under the given poses (median "
                      f"{100 * result.as_given:.0f} % of reprojected depth agrees, over {result.pairs} pairs)"
                      f"{hint}", DatasetWarning, stacklevel=2)
    return result


def pose_conflict_note(checks: list[PoseCheck], where: str) -> str | None:
    """A note when neighbouring frames contradict each other's free space on more than
    ``CONFLICT_NOTE_SHARE`` of their points (median over the pairs checked), else None."""
    shares = [c.free_space_conflict for c in checks  # inverted or wrong poses get check_poses' warning instead
              if c.pairs and c.as_given >= MIN_AGREEMENT and np.isfinite(c.free_space_conflict)]
    if not shares or np.median(shares) <= CONFLICT_NOTE_SHARE:
        return None
    return (f"{where}: under the given poses, {100 * np.median(shares):.1f} % of a frame's points land more than "
            f"{100 * FREE_SPACE_CONFLICT_M:.0f} cm in front of what the next frame measured there (median over "
            f"{len(shares)} agents' pairs): the poses (or the depth's timing) are off by centimetres there, "
            "no map can be right in both frames, and the depth check's off share stays above about that figure")
