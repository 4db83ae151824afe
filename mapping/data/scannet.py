"""ScanNet loader (the layout written by ScanNet's SensReader export)::

    color/0.jpg ...   (1296x968)        depth/0.png ... (640x480, uint16 millimetres)
    pose/0.txt ...    (4x4 camera-to-world, OpenCV axes; some frames are all -inf/nan)
    intrinsic/intrinsic_depth.txt, intrinsic/intrinsic_color.txt  (4x4 text, K in the top-left)
    instance-filt/0.png ... (optional, instance ids, 0 = none)

Frames are produced at the depth resolution: colour is resized to it (bilinear) and instance images
with nearest neighbour, which is what vMAP and NICE-SLAM do, since depth is what gets back-projected.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from mapping.data.files import (
    DatasetError,
    DatasetWarning,
    check_pose,
    image_size,
    intrinsics_for_images,
    match_indices,
    numbered_files,
    read_matrix_file,
    require_dir,
)
from mapping.data.frame import Intrinsics
from mapping.data.dataset import FrameFiles, ReadSpec, RGBDDataset, check_depth_scale, select

IntrinsicsLike = Intrinsics | Mapping[str, float] | Sequence[float]


def read_intrinsic_file(path: Path, width: int, height: int) -> Intrinsics:
    """Camera of a ScanNet ``intrinsic_*.txt`` (4x4, K top-left) for images of ``width`` x ``height``."""
    m = read_matrix_file(path)
    fx, fy, cx, cy = m[0, 0], m[1, 1], m[0, 2], m[1, 2]
    if not np.all(np.isfinite([fx, fy, cx, cy])) or fx <= 0 or fy <= 0:
        raise DatasetError(f"{path}: not a camera matrix (fx={fx}, fy={fy}, cx={cx}, cy={cy})")
    return Intrinsics(width, height, float(fx), float(fy), float(cx), float(cy))


def scannet_intrinsics(root: Path, depth_size: tuple[int, int], color_path: Path,
                       given: IntrinsicsLike | None = None) -> Intrinsics:
    """The depth camera: ``given`` (rescaled to the depth size), else ``intrinsic_depth.txt``, else
    ``intrinsic_color.txt`` rescaled from the colour image size (the two cameras share a centre)."""
    w, h = depth_size
    if given is not None:
        k = intrinsics_for_images(given, depth_size)
        return k if (k.width, k.height) == (w, h) else k.scaled(w, h)
    depth_file = root / "intrinsic" / "intrinsic_depth.txt"
    color_file = root / "intrinsic" / "intrinsic_color.txt"
    if depth_file.is_file():
        return read_intrinsic_file(depth_file, w, h)
    if color_file.is_file():
        cw, ch = image_size(color_path)
        return read_intrinsic_file(color_file, cw, ch).scaled(w, h)
    raise DatasetError(f"{root}: no intrinsics: looked for {depth_file} and {color_file}; pass intrinsics=")


def _valid_poses(
    pose_files: dict[int, Path], indices: list[int], invalid_pose: str
) -> tuple[dict[int, np.ndarray], list[int]]:
    """Read the pose files of ``indices``; ScanNet marks lost tracking with non-finite matrices."""
    poses, skipped = {}, []
    for i in indices:
        pose = read_matrix_file(pose_files[i])
        if not np.all(np.isfinite(pose)):
            if invalid_pose == "error":
                raise DatasetError(f"{pose_files[i]}: invalid pose (non-finite entries; tracking lost)")
            skipped.append(i)
            continue
        check_pose(pose, pose_files[i])
        poses[i] = pose
    return poses, skipped


def load_scannet(
    path: str | Path,
    *,
    depth_scale: float | None = None,
    intrinsics: IntrinsicsLike | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    instances: bool | None = None,
    invalid_pose: str = "skip",
) -> RGBDDataset:
    """Load an exported ScanNet scene.

    Args:
        path: the scene folder (``scene0000_00``).
        depth_scale: raw depth units per metre (None: 1000, ScanNet stores millimetres).
        intrinsics: override the depth camera (any resolution of it, rescaled to the depth images; or
            (fx, fy, cx, cy) of the depth images).
        stride: keep every ``stride``-th source frame.
        max_frames: keep at most this many frames (after ``stride`` and skipping invalid poses).
        instances: read ``instance-filt/``: None = if present, True = required, False = never.
        invalid_pose: ``"skip"`` frames with non-finite poses (one DatasetWarning with the count) or
            ``"error"``.
    """
    if invalid_pose not in ("skip", "error"):
        raise ValueError(f"invalid_pose must be 'skip' or 'error', got {invalid_pose!r}")
    root = require_dir(Path(path), "a ScanNet scene")
    folders = {
        "color/": numbered_files(root / "color"),
        "depth/": numbered_files(root / "depth", exts=(".png",)),
        "pose/": numbered_files(root / "pose", exts=(".txt",)),
    }
    inst_dir = root / "instance-filt"
    if (inst_dir.is_dir() if instances is None else instances):
        folders["instance-filt/"] = numbered_files(inst_dir, exts=(".png",))
    indices = match_indices(root, folders)
    poses, skipped = _valid_poses(folders["pose/"], select(indices, stride), invalid_pose)
    if skipped:
        warnings.warn(
            f"{root}: skipped {len(skipped)} frame(s) with invalid poses, e.g. {folders['pose/'][skipped[0]]}",
            DatasetWarning,
            stacklevel=2,
        )
    kept = select(list(poses), 1, max_frames)
    if not kept:
        raise DatasetError(f"{root / 'pose'}: every selected frame has an invalid pose")
    depth_size = image_size(folders["depth/"][kept[0]])
    k = scannet_intrinsics(root, depth_size, folders["color/"][kept[0]], intrinsics)
    inst = folders.get("instance-filt/")
    files = [
        FrameFiles(i, folders["color/"][i], folders["depth/"][i], poses[i], None if inst is None else inst[i])
        for i in kept
    ]
    spec = ReadSpec(k, check_depth_scale(1000.0 if depth_scale is None else depth_scale), resize_rgb=True, resize_instance=True)
    return RGBDDataset(files, spec, "scannet", root, skipped=skipped)
