"""Where a map's depth check is off, and whose surface it is (issue: real data as clean as the simulator).

The depth check (``mapping.evaluate.depth_check``) says what share of a camera's view of the map is off by
more than 5 cm; this script says how. For every agent of a finished ``openmulti run --data`` and each of its
frames (every ``--stride``-th pixel), a valid sensor pixel is *right* (within 5 cm), *in front* (the map's
surface more than 5 cm nearer than the sensor's: surface the map invents in observed free space), *behind*
(farther: the map misses the surface) or *none* (no surface), split by sensor depth. For the in-front pixels
it names the instance whose surface the ray hit and the instance that owns the sensed point (the map's
nearest vertex): when they differ, one instance's network put surface in front of another's, inside its own
box, where only the other instance's rays looked.

``--cull-free-space`` also scores each map with the faces its agent's own frames saw as free space removed
(in front of a frame's valid depth by more than max(5 cm, 3 x Kinect noise)), trained frames against
held-out ones (every 10th): the bound of meshing only where no frame saw free space, without retraining;
and the share of the frames' own sensed points that another frame saw as free space (the data's own
disagreement, which no single map can undo). ``--icp`` aligns each pair of consecutive frames' clouds
(open3d point-to-plane ICP from the given relative pose) and prints how far it moves them: what the poses
are off by, relative to the depth.

Run: ``.venv/bin/python -m studies.depth_off --data DIR --run RUN_DIR --agents 2``

Figures: docs/real_data.md#surface-in-front-of-other-instances-free-space-rays-that-cross-the-box
"""

from __future__ import annotations

import argparse
import collections
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from mapping.data.frame import Frame

from mapping.pipeline.data_source import load_agents
from mapping.evaluate.depth_check import OFF_TOLERANCE_M, depth_check
from mapping.evaluate.meshing import load_scene_mesh
from mapping.evaluate.raycast import MeshRaycaster

CLASSES = ("right", "in front", "behind", "none")


def pixel_classes(raycaster: MeshRaycaster, frame: Frame, stride: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                         np.ndarray]:
    """Per strided pixel: class index (``CLASSES``, -1 = no sensor depth), sensor depth, the face hit, and
    the sensed point in world coordinates (for the in-front pixels' owners)."""
    k, pose = frame.intrinsics, np.asarray(frame.pose, np.float64)
    sensor = np.asarray(frame.depth, np.float32)[::stride, ::stride]
    v, u = np.mgrid[0:k.height:stride, 0:k.width:stride]
    cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(u.shape)], -1).reshape(-1, 3)
    t, face = raycaster.cast(pose[:3, 3], cam @ pose[:3, :3].T)
    t, face = np.where(np.isfinite(t), t, 0.0).reshape(sensor.shape), face.reshape(sensor.shape)
    error = t - sensor
    classes = np.where(t <= 0, 3, np.where(np.abs(error) <= OFF_TOLERANCE_M, 0, np.where(error < 0, 1, 2)))
    classes = np.where(np.isfinite(sensor) & (sensor > 0), classes, -1)
    points = (cam.reshape(*sensor.shape, 3) * sensor[..., None]) @ pose[:3, :3].T + pose[:3, 3]
    return classes, sensor, face, points


def seen_as_free_space(points: np.ndarray, frames: list[Frame], margin_m: float = OFF_TOLERANCE_M,
                       noise_m_per_m2: float = 0.0015) -> np.ndarray:
    """(n,) bool: some frame saw the point in front of its valid depth by more than max(margin, 3 x noise)."""
    free = np.zeros(len(points), bool)
    for frame in frames:
        k, world_to_cam = frame.intrinsics, np.linalg.inv(np.asarray(frame.pose, np.float64))
        cam = points @ world_to_cam[:3, :3].T + world_to_cam[:3, 3]
        z = cam[:, 2]
        ahead = z > 0.01
        u, v = np.full(len(z), -1), np.full(len(z), -1)
        u[ahead] = np.rint(k.fx * cam[ahead, 0] / z[ahead] + k.cx)
        v[ahead] = np.rint(k.fy * cam[ahead, 1] / z[ahead] + k.cy)
        inside = ahead & (u >= 0) & (u < k.width) & (v >= 0) & (v < k.height)
        depth = np.zeros(len(z))
        depth[inside] = np.asarray(frame.depth, np.float64)[v[inside], u[inside]]
        free |= inside & (depth > 0) & (z < depth - np.maximum(margin_m, 3 * noise_m_per_m2 * depth**2))
    return free


def culled_scores(mesh: trimesh.Trimesh, frames: list[Frame], holdout_every: int = 10) -> str:
    """The depth check (off %) of ``mesh`` as it is and with the faces the trained frames saw as free space removed."""
    trained = [f for i, f in enumerate(frames) if i % holdout_every != holdout_every - 1]
    held = [f for i, f in enumerate(frames) if i % holdout_every == holdout_every - 1]
    keep = np.flatnonzero(~seen_as_free_space(np.asarray(mesh.triangles_center), trained))
    culled = mesh.submesh([keep], append=True, repair=False)

    def scores(m: trimesh.Trimesh) -> str:
        held_out = f"{depth_check(m, held).off_pct:.1f} %" if held else f"none (fewer than {holdout_every} frames)"
        return f"trained {depth_check(m, trained).off_pct:.1f} %, held out {held_out}"
    return "; ".join(f"{what}: {scores(m)}" for what, m in (("as is", mesh), ("free-space faces removed", culled)))


def contradicted_share(frames: list, stride: int = 8) -> float:
    """Share [%] of the frames' sensed points (every ``stride``-th pixel) that another frame saw as free
    space: what no single surface can match in every frame (pose or depth disagreement between frames)."""
    contradicted = total = 0
    for i, frame in enumerate(frames):
        k, pose = frame.intrinsics, np.asarray(frame.pose, np.float64)
        sensor = np.asarray(frame.depth, np.float64)[::stride, ::stride]
        v, u = np.mgrid[0:k.height:stride, 0:k.width:stride]
        valid = np.isfinite(sensor) & (sensor > 0)
        cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(u.shape)], -1)[valid] * sensor[valid, None]
        points = cam @ pose[:3, :3].T + pose[:3, 3]
        contradicted += int(seen_as_free_space(points, frames[:i] + frames[i + 1:]).sum())
        total += len(points)
    return 100.0 * contradicted / max(total, 1)


def icp_corrections(frames: list, max_depth_m: float = 3.5) -> np.ndarray:
    """(n - 1, 2): translation [cm] and rotation [deg] by which point-to-plane ICP moves each consecutive
    pair's given relative pose (clouds of every 2nd pixel within ``max_depth_m``, 1 cm voxels)."""
    import open3d as o3d  # noqa: PLC0415

    def cloud(frame) -> o3d.geometry.PointCloud:
        k, depth = frame.intrinsics, np.asarray(frame.depth, np.float64)[::2, ::2]
        v, u = np.mgrid[0:k.height:2, 0:k.width:2]
        ok = (depth > 0) & (depth < max_depth_m)
        cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones(u.shape)], -1)[ok] * depth[ok, None]
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cam)).voxel_down_sample(0.01)
        pc.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=0.05, max_nn=30))
        return pc

    clouds, out = [cloud(f) for f in frames], []
    for i in range(1, len(frames)):
        given = np.linalg.inv(np.asarray(frames[i - 1].pose)) @ np.asarray(frames[i].pose)
        fit = o3d.pipelines.registration.registration_icp(
            clouds[i], clouds[i - 1], 0.05, given, o3d.pipelines.registration.TransformationEstimationPointToPlane())
        delta = np.linalg.inv(given) @ fit.transformation
        angle = np.degrees(np.arccos(np.clip((np.trace(delta[:3, :3]) - 1) / 2, -1, 1)))
        out.append((100 * np.linalg.norm(delta[:3, 3]), angle))
    return np.array(out).reshape(-1, 2)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, help="the data set folder the run mapped")
    parser.add_argument("--run", required=True, help="the run's folder (meshes/agent_K.ply)")
    parser.add_argument("--agents", type=int, required=True, help="the run's --agents")
    parser.add_argument("--stride", type=int, default=4)
    parser.add_argument("--icp", action="store_true", help="also print how far ICP moves consecutive frames")
    parser.add_argument("--cull-free-space", action="store_true", help="also score the maps without the faces "
                        "their own frames saw as free space")
    args = parser.parse_args()
    for name, seq in load_agents(args.data, "auto", args.agents).items():
        mesh, vertex_ids = load_scene_mesh(Path(args.run) / "meshes" / f"{name}.ply")
        face_ids = vertex_ids[mesh.faces[:, 0]]
        raycaster, tree = MeshRaycaster(mesh), cKDTree(mesh.vertices)
        by_depth = np.zeros((7, len(CLASSES)))
        hit_ids, other = collections.Counter(), 0
        for frame in seq:
            classes, sensor, face, points = pixel_classes(raycaster, frame, args.stride)
            valid = classes >= 0
            np.add.at(by_depth, (np.clip(sensor[valid].astype(int), 0, 6), classes[valid]), 1)
            front = classes == 1
            hit, owner = face_ids[face[front]], vertex_ids[tree.query(points[front])[1]]
            hit_ids.update(hit.tolist())
            other += int((hit != owner).sum())
        total = by_depth.sum()
        if not total:
            print(f"{name}: {len(seq)} frames, no pixel with valid sensor depth: nothing to split")
            continue
        shares = ", ".join(f"{c} {100 * by_depth[:, i].sum() / total:.1f}" for i, c in enumerate(CLASSES))
        print(f"{name}: {len(seq)} frames, % of valid pixels: {shares}")
        for metres, row in enumerate(by_depth):
            if row.sum():
                band = f"{metres}-{metres + 1} m" if metres < len(by_depth) - 1 else f">= {metres} m"
                print(f"  sensor depth {band} ({100 * row.sum() / total:.1f} % of pixels): "
                      + ", ".join(f"{c} {100 * x / row.sum():.1f}" for c, x in zip(CLASSES, row)))
        n_front = sum(hit_ids.values())
        if n_front:
            print(f"  in front: {100 * other / n_front:.1f} % hit another instance than the sensed point's; "
                  f"the instances hit most (id: pixels): {dict(hit_ids.most_common(4))}")
        if args.icp and len(seq) > 1:
            c = icp_corrections(list(seq))
            print(f"  ICP moves consecutive frames by a median {np.median(c[:, 0]):.1f} cm and {np.median(c[:, 1]):.2f} "
                  f"deg (90th percentile {np.percentile(c[:, 0], 90):.1f} cm, {np.percentile(c[:, 1], 90):.2f} deg)")
        if args.cull_free_space:
            print(f"  off: {culled_scores(mesh, list(seq))}; sensed points another frame saw as free space: "
                  f"{contradicted_share(list(seq)):.1f} %")


if __name__ == "__main__":
    main()
