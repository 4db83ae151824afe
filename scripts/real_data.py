"""Write public real RGB-D sequences in the NICE-SLAM layout ``openmulti run --data`` reads.

The frames are not in this repository (they are other people's data, tens of MB): clone the source
repository, then convert. Two sources, both real sensors with their holes and noise:

- ``7scenes50``: 50 Kinect v1 frames of a Microsoft 7-Scenes sequence (640x480, depth in millimetres,
  camera-to-world poses from KinectFusion, fx = fy = 585) as shipped in ``andyzeng/tsdf-fusion``
  (``data/rgbd-frames``; 7-Scenes' terms: non-commercial research use).
  ``git clone --depth 1 https://github.com/andyzeng/tsdf-fusion``
- ``tum_cabinet58``: 58 keyframes of TUM RGB-D ``freiburg3_cabinet`` (Asus Xtion, 640x480, depth x 5000,
  motion-capture ground-truth poses, JPEG colour recompressed by the repository) as shipped in
  ``benchun123/cuboid_slam_with_bbox_constraints`` (``data/``; TUM RGB-D: CC BY 4.0).
  ``git clone --depth 1 https://github.com/benchun123/cuboid_slam_with_bbox_constraints``

Run: ``python scripts/real_data.py 7scenes50 tsdf-fusion/ data/real/7scenes50`` (the source folder is the
clone's root). Writes ``results/frame<i:06d>.<png|jpg>`` (colour bytes copied, not re-encoded),
``results/depth<i:06d>.png`` (16-bit, copied; 7-Scenes' 65535 "no depth" rewritten as 0), ``traj.txt`` (one
row-major camera-to-world 4x4 per line, OpenCV axes) and ``cam_params.json`` (camera and depth scale).
"""

from __future__ import annotations

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
from PIL import Image
from scipy.spatial.transform import Rotation


def seven_scenes(src: Path) -> tuple[list[tuple[Path, Path, np.ndarray]], dict]:
    """(colour, depth, pose) per frame and the camera of andyzeng/tsdf-fusion's ``data/rgbd-frames``."""
    folder = src / "data" / "rgbd-frames"
    stems = sorted(p.name[: -len(".pose.txt")] for p in folder.glob("frame-*.pose.txt"))
    if not stems:
        raise SystemExit(f"{folder}: no frame-*.pose.txt (give the root of a clone of andyzeng/tsdf-fusion)")
    frames = [(folder / f"{s}.color.png", folder / f"{s}.depth.png", np.loadtxt(folder / f"{s}.pose.txt"))
              for s in stems]
    k = np.loadtxt(src / "data" / "camera-intrinsics.txt")
    return frames, {"w": 640, "h": 480, "fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], "scale": 1000.0}


def tum_cabinet(src: Path) -> tuple[list[tuple[Path, Path, np.ndarray]], dict]:
    """(colour, depth, pose) per frame and the camera of benchun123/cuboid_slam_with_bbox_constraints'
    ``data/`` (TUM fr3 cabinet keyframes; poses ``t tx ty tz qx qy qz qw``, one row per frame in order)."""
    data = src / "data"
    rows = np.loadtxt(data / "truth_cam_poses.txt")
    if rows.ndim != 2 or rows.shape[1] != 8:
        raise SystemExit(f"{data / 'truth_cam_poses.txt'}: expected rows of t tx ty tz qx qy qz qw")
    frames = []
    for i, row in enumerate(rows):
        pose = np.eye(4)
        pose[:3, :3] = Rotation.from_quat(row[4:8]).as_matrix()  # scipy's order is x, y, z, w as TUM's
        pose[:3, 3] = row[1:4]
        frames.append((data / "raw_imgs" / f"{i:04d}_rgb_raw.jpg", data / "depth_imgs" / f"{i:04d}_depth_raw.png", pose))
    return frames, {"w": 640, "h": 480, "fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6, "scale": 5000.0}


SOURCES = {"7scenes50": seven_scenes, "tum_cabinet58": tum_cabinet}


def convert(kind: str, src: Path, out: Path) -> int:
    """Write ``kind``'s frames from the clone at ``src`` into ``out``; returns the number of frames."""
    frames, camera = SOURCES[kind](src)
    results = out / "results"
    results.mkdir(parents=True, exist_ok=True)
    poses = []
    for i, (colour, depth, pose) in enumerate(frames):
        for part in (colour, depth):
            if not part.is_file():
                raise SystemExit(f"{part} is missing")
        shutil.copyfile(colour, results / f"frame{i:06d}{colour.suffix}")
        raw = np.asarray(Image.open(depth))
        if raw.dtype != np.uint16 and raw.dtype != np.int32:
            raise SystemExit(f"{depth}: expected 16-bit depth, got {raw.dtype}")
        raw = np.where(raw >= 65535, 0, raw).astype(np.uint16)  # 7-Scenes marks missing depth 65535
        Image.fromarray(raw).save(results / f"depth{i:06d}.png")
        if not np.all(np.isfinite(pose)) or pose.shape != (4, 4):
            raise SystemExit(f"frame {i}: pose is not a finite 4x4 matrix")
        poses.append(pose.reshape(-1))
    np.savetxt(out / "traj.txt", np.stack(poses), fmt="%.9f")
    (out / "cam_params.json").write_text(json.dumps({"camera": {k: float(v) for k, v in camera.items()}}, indent=2))
    return len(frames)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("kind", choices=sorted(SOURCES))
    parser.add_argument("src", type=Path, help="root of a clone of the source repository")
    parser.add_argument("out", type=Path, help="folder to write (NICE-SLAM layout)")
    args = parser.parse_args()
    n = convert(args.kind, args.src, args.out)
    print(f"wrote {n} frames of {args.kind} to {args.out} (openmulti run --data {args.out} --kind nice_slam)")


if __name__ == "__main__":
    main()
