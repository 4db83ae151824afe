"""Tiny on-disk scenes in the vMAP Replica, NICE-SLAM Replica and ScanNet layouts, for loader tests.

Each writer returns the ground truth it wrote so tests can check the round trip.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

W, H = 16, 12
#: (width, height, fx, fy, cx, cy) of the tiny test camera.
TINY_CAM = (W, H, 10.0, 11.0, 7.5, 5.5)


@dataclass
class Truth:
    """What a writer put on disk: (n, H, W, 3) rgb, (n, H, W) raw depth, (n, 4, 4) poses, ids."""

    rgb: np.ndarray
    depth_raw: np.ndarray
    poses: np.ndarray
    instance: np.ndarray | None


def rigid_poses(n: int, seed: int = 0) -> np.ndarray:
    """(n, 4, 4) random camera-to-world rigid transforms."""
    rng = np.random.default_rng(seed)
    out = np.tile(np.eye(4), (n, 1, 1))
    for i in range(n):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        out[i, :3, :3] = q * np.sign(np.linalg.det(q))
        out[i, :3, 3] = rng.uniform(-2, 2, size=3)
    return out


def images(n: int, w: int = W, h: int = H, seed: int = 0) -> Truth:
    """Random colour, raw uint16 depth (some zeros = missing) and instance ids for ``n`` frames."""
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, size=(n, h, w, 3), dtype=np.uint8)
    depth = rng.integers(0, 60000, size=(n, h, w)).astype(np.uint16)
    depth[:, 0, 0] = 0
    inst = np.zeros((n, h, w), dtype=np.int32)
    inst[:, h // 2 :, : w // 2] = 3
    inst[:, : h // 2, w // 2 :] = 7
    return Truth(rgb, depth, rigid_poses(n, seed), inst)


def save_png(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path)


def save_jpg(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path, quality=95)


def write_trajectory(path: Path, poses: np.ndarray) -> None:
    path.write_text("".join(" ".join(f"{v:.17g}" for v in p.ravel()) + "\n" for p in poses))


def write_replica(root: Path, n: int = 6, instances: bool = True) -> Truth:
    """vMAP layout: rgb/rgb_i.png, depth/depth_i.png, semantic_instance/..., traj_w_c.txt."""
    t = images(n)
    for i in range(n):
        save_png(root / "rgb" / f"rgb_{i}.png", t.rgb[i])
        save_png(root / "depth" / f"depth_{i}.png", t.depth_raw[i])
        if instances:
            save_png(root / "semantic_instance" / f"semantic_instance_{i}.png", t.instance[i].astype(np.uint8))
    write_trajectory(root / "traj_w_c.txt", t.poses)
    return t if instances else Truth(t.rgb, t.depth_raw, t.poses, None)


def write_nice_slam(root: Path, n: int = 6) -> Truth:
    """NICE-SLAM layout: results/frame000000.jpg, results/depth000000.png, traj.txt."""
    t = images(n, seed=1)
    for i in range(n):
        save_jpg(root / "results" / f"frame{i:06d}.jpg", t.rgb[i])
        save_png(root / "results" / f"depth{i:06d}.png", t.depth_raw[i])
    write_trajectory(root / "traj.txt", t.poses)
    return Truth(t.rgb, t.depth_raw, t.poses, None)


def _matrix_text(m: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.17g}" for v in row) + "\n" for row in m)


def write_scannet(
    root: Path,
    n: int = 6,
    invalid: tuple[int, ...] = (),
    color_scale: int = 2,
    depth_intrinsics: bool = True,
    instances: bool = True,
) -> Truth:
    """ScanNet export: colour ``color_scale`` times the depth size, pose/i.txt, intrinsic/*.txt.

    Frames in ``invalid`` get ScanNet's all ``-inf`` pose. Instance images are at colour size.
    """
    t = images(n, seed=2)
    cw, ch = W * color_scale, H * color_scale
    for i in range(n):
        big = np.asarray(Image.fromarray(t.rgb[i]).resize((cw, ch), Image.Resampling.NEAREST))
        save_jpg(root / "color" / f"{i}.jpg", big)
        save_png(root / "depth" / f"{i}.png", t.depth_raw[i])
        pose = np.full((4, 4), -np.inf) if i in invalid else t.poses[i]
        (root / "pose").mkdir(exist_ok=True)
        (root / "pose" / f"{i}.txt").write_text(_matrix_text(pose))
        if instances:
            ids = np.asarray(Image.fromarray(t.instance[i].astype(np.uint8)).resize((cw, ch), Image.Resampling.NEAREST))
            save_png(root / "instance-filt" / f"{i}.png", ids)
    _, _, fx, fy, cx, cy = TINY_CAM
    k_depth = np.array([[fx, 0, cx, 0], [0, fy, cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=float)
    s = float(color_scale)
    k_color = np.array([[fx * s, 0, cx * s, 0], [0, fy * s, cy * s, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    (root / "intrinsic").mkdir(exist_ok=True)
    (root / "intrinsic" / "intrinsic_color.txt").write_text(_matrix_text(k_color))
    if depth_intrinsics:
        (root / "intrinsic" / "intrinsic_depth.txt").write_text(_matrix_text(k_depth))
    return t if instances else Truth(t.rgb, t.depth_raw, t.poses, None)
