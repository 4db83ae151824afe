"""Pictures of a world: the room from above with the agents' paths, the coverage map, sample frames."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from mapping.data import Frame  # noqa: E402
from mapping.figures import save_figure  # noqa: E402
from openmulti_env.world.coverage import covered_mask, observed_points  # noqa: E402
from openmulti_env.world.scene import Scene  # noqa: E402

AGENT_COLORS = plt.get_cmap("tab10").colors


def draw_top_down(ax, scene: Scene) -> None:
    """Room seen from above: faces drawn lowest first in their own colours (ceiling left out)."""
    polys, colors, heights = [], [], []
    for inst in scene.instances:
        if inst.category == "ceiling":
            continue
        tri = np.asarray(inst.mesh.triangles)
        up = np.asarray(inst.mesh.face_normals)[:, 2] > 0.2
        polys.append(tri[up][:, :, :2])
        colors.append(np.asarray(inst.mesh.visual.face_colors)[up, :3] / 255.0)
        heights.append(tri[up][:, :, 2].max(axis=1))
    polys, colors, heights = np.concatenate(polys), np.concatenate(colors), np.concatenate(heights)
    order = np.argsort(heights, kind="stable")
    ax.add_collection(PolyCollection(polys[order], facecolors=colors[order], edgecolors="none"))
    sx, sy, _ = scene.size_m
    ax.set_xlim(-0.1, sx + 0.1)
    ax.set_ylim(-0.1, sy + 0.1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")


def draw_paths(ax, agent_poses: list[np.ndarray], arrow_every: int = 12) -> None:
    """Each agent's camera path with its viewing direction every ``arrow_every`` frames."""
    for a, poses in enumerate(agent_poses):
        c = AGENT_COLORS[a % len(AGENT_COLORS)]
        xy = poses[:, :2, 3]
        ax.plot(xy[:, 0], xy[:, 1], "-", color=c, lw=1.6, label=f"agent_{a}")
        ax.plot(xy[0, 0], xy[0, 1], "o", color=c, ms=5)
        fwd = poses[::arrow_every, :2, 2]
        ax.quiver(xy[::arrow_every, 0], xy[::arrow_every, 1], fwd[:, 0], fwd[:, 1], color=c, scale=18, width=0.004)
    ax.legend(loc="upper right", fontsize=7)


def save_world_overview(path: str | Path, scene: Scene, agent_poses: list[np.ndarray], gt_points: np.ndarray,
                        caster, intrinsics, stride: int = 2) -> Path:
    """Two panels: the room with paths, and which agents saw each ground-truth point (blind zones)."""
    fig, axes = plt.subplots(1, 2, figsize=(13, 6))
    draw_top_down(axes[0], scene)
    draw_paths(axes[0], agent_poses)
    axes[0].set_title(f"{scene.name}: {len(scene.instances)} instances, {len(agent_poses)} agent paths")
    masks = np.stack([covered_mask(gt_points, observed_points(caster, p, intrinsics, stride)) for p in agent_poses])
    count = masks.sum(axis=0)
    low = gt_points[:, 2] < 2.0  # the ceiling would hide everything below it
    order = np.argsort(gt_points[low, 2])
    pts, cnt, msk = gt_points[low][order], count[low][order], masks[:, low][:, order]
    first = np.argmax(msk, axis=0)
    col = np.array([AGENT_COLORS[i % len(AGENT_COLORS)] for i in first])
    col[cnt >= 2] = (0.55, 0.55, 0.55)
    col[cnt == 0] = (0.85, 0.0, 0.0)
    axes[1].scatter(pts[:, 0], pts[:, 1], c=col, s=1.5, linewidths=0)
    axes[1].set_aspect("equal")
    sx, sy, _ = scene.size_m
    axes[1].set_xlim(-0.1, sx + 0.1)
    axes[1].set_ylim(-0.1, sy + 0.1)
    axes[1].set_title("coverage: agent colour = seen by that agent only, grey = 2+, red = nobody")
    return save_figure(fig, path, dpi=110)


def save_frames(path: str | Path, frames: list[Frame], title: str = "") -> Path:
    """A grid of frames: RGB, depth and instance ids side by side, one row per frame."""
    fig, axes = plt.subplots(len(frames), 3, figsize=(9, 2.4 * len(frames)), squeeze=False)
    for row, f in zip(axes, frames):
        row[0].imshow(f.rgb)
        row[1].imshow(np.where(f.depth > 0, f.depth, np.nan), cmap="viridis")
        inst = f.instance if f.instance is not None else np.zeros_like(f.depth, dtype=int)
        row[2].imshow(inst % 20, cmap="tab20", vmin=0, vmax=19, interpolation="nearest")
        row[0].set_ylabel(f"frame {f.index}")
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0][0].set_title("RGB")
    axes[0][1].set_title("depth [m]")
    axes[0][2].set_title("instance id")
    return save_figure(fig, path, title)
