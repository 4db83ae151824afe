"""Write a simulated world as an RGB-D data set, so other systems (vMAP, NICE-SLAM, OpenObj) can run on
the same worlds and ``openmulti run --data`` can read them back.

The agents' frames are written one after the other as one sequence (agent 0's path, then agent 1's,
...); every agent has the same number of frames, so ``--agents K`` cuts the sequence back into the
same K paths. Layouts (``mapping.data`` reads all three):

replica (vMAP)::

    rgb/rgb_<i>.png  depth/depth_<i>.png (uint16, mm)  semantic_instance/semantic_instance_<i>.png
    traj_w_c.txt  cam_params.json  info_semantic.json  mesh.ply (observable ground truth)

scannet (SensReader export)::

    color/<i>.jpg  depth/<i>.png (uint16, mm)  pose/<i>.txt  intrinsic/intrinsic_{color,depth}.txt
    instance-filt/<i>.png (objectId + 1)  <name>.aggregation.json  <name>_vh_clean_2.ply

nice_slam (no instance images)::

    results/frame<i:06d>.jpg  results/depth<i:06d>.png (uint16, metres * 6553.5)  traj.txt  cam_params.json

``openmulti_export.json`` records the scene, seed, agents and each agent's frame range.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image
from tqdm import tqdm

from mapping.data import Frame, Intrinsics
from openmulti_env.world.world import World

LAYOUTS = ("replica", "scannet", "nice_slam")
DEPTH_SCALE = {"replica": 1000.0, "scannet": 1000.0, "nice_slam": 6553.5}
"""Raw depth units per metre written by each layout (the layouts' own conventions)."""
MAX_DEPTH_M = 65535 / 6553.5
"""Deepest reading every layout can store in 16 bits (10 m); deeper readings are written as missing."""


def export_world(world: World, out: str | Path, layout: str = "replica", frame_stride: int = 1,
                 progress: bool = True) -> Path:
    """Render every agent's frames and write them, with poses, camera, masks, labels and the
    observable ground-truth mesh, in ``layout``; returns the data set folder.

    Args:
        world: the built world (its agents' paths are the frames written).
        out: the folder to write (created; files of an earlier export are overwritten).
        layout: ``replica``, ``scannet`` or ``nice_slam``.
        frame_stride: write every n-th frame of each path (small fixtures).
    """
    if layout not in LAYOUTS:
        raise ValueError(f"unknown layout {layout!r}; choose one of {LAYOUTS}")
    if int(frame_stride) != frame_stride or frame_stride < 1:
        raise ValueError(f"frame_stride must be a positive integer, got {frame_stride}")
    root = Path(out)
    root.mkdir(parents=True, exist_ok=True)
    per_agent = [list(range(0, len(p), frame_stride)) for p in world.agent_poses]
    total = sum(len(f) for f in per_agent)
    poses, ranges, n = [], [], 0
    with tqdm(total=total, desc=f"exporting {layout}", unit="frame", disable=not progress) as bar:
        for a, indices in enumerate(per_agent):
            ranges.append([n, n + len(indices)])
            for i in indices:
                frame = world.render(a, i)
                _write_frame(root, layout, n, frame)
                poses.append(frame.pose)
                n += 1
                bar.update(1)
    _write_camera(root, layout, world.intrinsics, np.stack(poses))
    _write_labels_and_mesh(root, layout, world)
    (root / "openmulti_export.json").write_text(json.dumps({
        "scene": world.scene.name, "seed": world.seed, "layout": layout, "agents": world.num_agents,
        "agent_frames": ranges, "frame_stride": frame_stride, "depth_scale": DEPTH_SCALE[layout],
        "gt_mesh": _mesh_name(layout, root.name)}, indent=2))
    return root


def _depth_png(depth: np.ndarray, scale: float) -> np.ndarray:
    d = np.where(np.isfinite(depth) & (depth > 0) & (depth < MAX_DEPTH_M), depth, 0.0)
    return np.round(d * scale).astype(np.uint16)


def _save(path: Path, array: np.ndarray, **kw) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(array).save(path, **kw)


def _write_frame(root: Path, layout: str, i: int, frame: Frame) -> None:
    depth = _depth_png(frame.depth, DEPTH_SCALE[layout])
    inst = None if frame.instance is None else frame.instance.astype(np.uint16)
    if layout == "replica":
        _save(root / "rgb" / f"rgb_{i}.png", frame.rgb)
        _save(root / "depth" / f"depth_{i}.png", depth)
        if inst is not None:
            _save(root / "semantic_instance" / f"semantic_instance_{i}.png", inst)
    elif layout == "scannet":
        _save(root / "color" / f"{i}.jpg", frame.rgb, quality=95)
        _save(root / "depth" / f"{i}.png", depth)
        (root / "pose").mkdir(exist_ok=True)
        (root / "pose" / f"{i}.txt").write_text(_matrix_text(frame.pose))
        if inst is not None:
            _save(root / "instance-filt" / f"{i}.png", inst)
    else:
        _save(root / "results" / f"frame{i:06d}.jpg", frame.rgb, quality=95)
        _save(root / "results" / f"depth{i:06d}.png", depth)


def _matrix_text(m: np.ndarray) -> str:
    return "".join(" ".join(f"{v:.17g}" for v in row) + "\n" for row in m)


def _write_camera(root: Path, layout: str, k: Intrinsics, poses: np.ndarray) -> None:
    lines = "".join(" ".join(f"{v:.17g}" for v in p.ravel()) + "\n" for p in poses)
    if layout == "scannet":
        (root / "intrinsic").mkdir(exist_ok=True)
        k4 = np.eye(4)
        k4[:3, :3] = k.matrix
        for name in ("intrinsic_color.txt", "intrinsic_depth.txt"):
            (root / "intrinsic" / name).write_text(_matrix_text(k4))
        return
    (root / ("traj_w_c.txt" if layout == "replica" else "traj.txt")).write_text(lines)
    camera = {"w": k.width, "h": k.height, "fx": float(k.fx), "fy": float(k.fy), "cx": float(k.cx),
              "cy": float(k.cy), "scale": DEPTH_SCALE[layout]}
    (root / "cam_params.json").write_text(json.dumps({"camera": camera}, indent=2))


def _mesh_name(layout: str, name: str) -> str | None:
    return {"replica": "mesh.ply", "scannet": f"{name}_vh_clean_2.ply", "nice_slam": "mesh.ply"}[layout]


def _write_labels_and_mesh(root: Path, layout: str, world: World) -> None:
    instances = world.scene.instances
    if layout == "replica":
        classes = sorted({inst.category for inst in instances})
        (root / "info_semantic.json").write_text(json.dumps({
            "classes": [{"id": c, "name": name} for c, name in enumerate(classes, start=1)],
            "objects": [{"id": inst.instance_id, "class_id": classes.index(inst.category) + 1,
                         "class_name": inst.category, "caption": inst.caption} for inst in instances]}, indent=2))
    elif layout == "scannet":
        (root / f"{root.name}.aggregation.json").write_text(json.dumps({
            "sceneId": root.name, "appId": "openmulti.export",
            "segGroups": [{"id": inst.instance_id - 1, "objectId": inst.instance_id - 1, "label": inst.category,
                           "segments": []} for inst in instances]}, indent=2))
    world.surface.culled_mesh().export(root / _mesh_name(layout, root.name))
