"""Replica loaders: the vMAP layout and the NICE-SLAM layout.

vMAP (``vmap/room_0/imap/00``)::

    rgb/rgb_0.png ...  depth/depth_0.png ... (uint16, metres * 1000)
    semantic_instance/semantic_instance_0.png ... (instance ids, optional)
    traj_w_c.txt       (one row-major 4x4 camera-to-world per line)

NICE-SLAM (``Replica/room0``)::

    results/frame000000.jpg ...  results/depth000000.png ... (uint16, metres * 6553.5)
    traj.txt           (one row-major 4x4 camera-to-world per line)

Both store OpenCV camera-to-world poses, line ``i`` for frame ``i``, and use the same 1200x680
camera, so no axis conversion is needed.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mapping.data.files import (
    DatasetError,
    as_intrinsics,
    check_pose,
    image_size,
    intrinsics_for_images,
    match_indices,
    numbered_files,
    read_cam_params,
    read_trajectory,
    require_dir,
)
from mapping.data.frame import Intrinsics
from mapping.data.dataset import FrameFiles, ReadSpec, RGBDDataset, check_depth_scale, select

#: The camera of the Replica renderings used by vMAP, iMAP and NICE-SLAM.
REPLICA_INTRINSICS = Intrinsics(width=1200, height=680, fx=600.0, fy=600.0, cx=599.5, cy=339.5)

IntrinsicsLike = Intrinsics | Mapping[str, float] | Sequence[float]


def _check_trajectory(traj_path: Path, poses: np.ndarray, indices: list[int], images: Path) -> None:
    """Pose ``i`` belongs to frame ``i``: counts and numbering must agree, and every pose be rigid."""
    if len(poses) != len(indices):
        raise DatasetError(f"{traj_path}: has {len(poses)} poses but {images} has {len(indices)} frames")
    if indices != list(range(len(indices))):
        gap = next(i for i, j in enumerate(indices) if i != j)
        raise DatasetError(
            f"{images}: frame numbers must run 0..{len(indices) - 1} to match the lines of {traj_path.name}; "
            f"frame {gap} is missing"
        )
    for i, pose in enumerate(poses):
        check_pose(pose, traj_path, f"pose {i}")


def _check_first_size(path: Path, k: Intrinsics) -> None:
    """Fail at load time, not 30 minutes into a run, when the camera does not fit the images."""
    w, h = image_size(path)
    if (w, h) != (k.width, k.height):
        raise DatasetError(f"{path}: image is {w}x{h} but the intrinsics are {k.width}x{k.height}; pass intrinsics=")


def _trajectory_dataset(
    root: Path,
    kind: str,
    rgb: dict[int, Path],
    depth: dict[int, Path],
    instance: dict[int, Path] | None,
    labels: tuple[str, str, str],
    traj_path: Path,
    depth_scale: float | None,
    default_scale: float,
    intrinsics: IntrinsicsLike | None,
    stride: int,
    max_frames: int | None,
) -> RGBDDataset:
    folders = {labels[0]: rgb, labels[1]: depth}
    if instance is not None:
        folders[labels[2]] = instance
    indices = match_indices(root, folders)
    poses = read_trajectory(traj_path)
    _check_trajectory(traj_path, poses, indices, rgb[indices[0]].parent)
    cam, _ = read_cam_params(root)
    if intrinsics is not None:
        k = intrinsics_for_images(intrinsics, image_size(rgb[indices[0]]))
    elif cam is not None:
        k = as_intrinsics((cam["w"], cam["h"], cam["fx"], cam["fy"], cam["cx"], cam["cy"]))
    else:
        k = REPLICA_INTRINSICS
    if depth_scale is None:
        depth_scale = cam["scale"] if cam is not None and "scale" in cam else default_scale
    _check_first_size(rgb[indices[0]], k)
    files = [
        FrameFiles(i, rgb[i], depth[i], poses[i], None if instance is None else instance[i])
        for i in select(indices, stride, max_frames)
    ]
    return RGBDDataset(files, ReadSpec(k, check_depth_scale(depth_scale)), kind, root)


def load_replica(
    path: str | Path,
    *,
    depth_scale: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    instances: bool | None = None,
) -> RGBDDataset:
    """Load a Replica sequence in vMAP's layout (``rgb/``, ``depth/``, ``semantic_instance/``, ``traj_w_c.txt``).

    Args:
        path: the sequence folder.
        depth_scale: raw depth units per metre; None = ``cam_params.json``'s ``scale`` if there is one,
            else 1000 (vMAP) / 6553.5 (NICE-SLAM).
        intrinsics: camera (Intrinsics, vMAP-style mapping, 6-sequence, or (fx, fy, cx, cy) for the
            images' size); None = ``cam_params.json`` in the folder or its parent, else Replica's 1200x680.
        stride: keep every ``stride``-th frame.
        max_frames: keep at most this many frames (after ``stride``).
        instances: read ``semantic_instance/``: None = if present, True = required, False = never.
    """
    root = require_dir(Path(path), "a vMAP Replica sequence")
    rgb = numbered_files(root / "rgb", "rgb_")
    depth = numbered_files(root / "depth", "depth_", (".png",))
    inst_dir = root / "semantic_instance"
    use_inst = inst_dir.is_dir() if instances is None else instances
    inst = numbered_files(inst_dir, "semantic_instance_", (".png",)) if use_inst else None
    labels = ("rgb/", "depth/", "semantic_instance/")
    return _trajectory_dataset(root, "replica", rgb, depth, inst, labels, root / "traj_w_c.txt",
                               depth_scale, 1000.0, intrinsics, stride, max_frames)


def load_nice_slam(
    path: str | Path,
    *,
    depth_scale: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    instances: bool | None = None,
) -> RGBDDataset:
    """Load a Replica scene in NICE-SLAM's layout (``results/frame*.jpg``, ``results/depth*.png``, ``traj.txt``).

    Arguments as :func:`load_replica`; this layout has no instance images, so ``instances=True`` is an error.
    """
    root = require_dir(Path(path), "a NICE-SLAM Replica scene")
    if instances:
        raise DatasetError(f"{root}: the NICE-SLAM Replica layout has no instance images")
    results = root / "results"
    rgb = numbered_files(results, "frame")
    depth = numbered_files(results, "depth", (".png",))
    labels = ("results/frame*", "results/depth*", "")
    return _trajectory_dataset(root, "nice_slam", rgb, depth, None, labels, root / "traj.txt",
                               depth_scale, 6553.5, intrinsics, stride, max_frames)
