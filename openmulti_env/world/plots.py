"""Pictures of a world: the room from above with the agents' paths, the coverage map, sample frames."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import PolyCollection  # noqa: E402

from mapping.data import Frame  # noqa: E402
from openmulti_env.world.coverage import covered_mask, observed_points  # noqa: E402
from openmulti_env.world.scene import Scene  # noqa: E402

AGENT_COLORS = plt.get_cmap("tab10").colors


def _save_figure(fig, path: str | Path, title: str = "", dpi: int = 100) -> Path:
    """Title, tighten, write the PNG (creating its folder) and free the figure."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


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
    return _save_figure(fig, path, dpi=110)


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
    return _save_figure(fig, path, title)


def save_reconstruction_views(path: str | Path, gt_mesh, agent_meshes: list) -> Path:
    """Ground truth beside each agent's reconstruction, seen from above (vertices coloured by height)."""
    n = 1 + len(agent_meshes)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 4.2), squeeze=False)
    lo, hi = gt_mesh.bounds
    for ax, (title, mesh) in zip(axes[0], [("ground truth (observable)", gt_mesh)]
                                 + [(f"agent_{a}", m) for a, m in enumerate(agent_meshes)]):
        if mesh is not None and len(mesh.vertices):
            v = np.asarray(mesh.vertices)
            v = v[v[:, 2] < hi[2] - 0.15]  # leave the ceiling out
            order = np.argsort(v[:, 2])
            ax.scatter(v[order, 0], v[order, 1], c=v[order, 2], s=0.2, cmap="viridis", vmin=lo[2], vmax=hi[2])
        ax.set_title(title)
        ax.set_xlim(lo[0] - 0.1, hi[0] + 0.1)
        ax.set_ylim(lo[1] - 0.1, hi[1] + 0.1)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    return _save_figure(fig, path)


def save_view_comparison(path: str | Path, views: list, stride: int, title: str = "") -> Path:
    """Rows of (sensor RGB, map colour, sensor depth, map depth); ``views`` holds (Frame, colour (h, w, 3),
    depth (h, w)) with the map rendered at every ``stride``-th pixel."""
    fig, axes = plt.subplots(len(views), 4, figsize=(12, 2.6 * len(views)), squeeze=False)
    for row, (frame, colour, depth) in zip(axes, views):
        vmax = float(frame.depth.max()) or 1.0
        row[0].imshow(frame.rgb)
        row[1].imshow(np.clip(colour, 0, 1), interpolation="nearest")
        row[2].imshow(frame.depth[::stride, ::stride], cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
        row[3].imshow(depth, cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
        row[0].set_ylabel(f"frame {frame.index}")
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    for ax, name in zip(axes[0], ("sensor RGB", "map colour", "sensor depth", "map depth")):
        ax.set_title(name)
    return _save_figure(fig, path, title)


def save_semantic_classes(path: str | Path, metrics, title: str, top: int = 20) -> Path:
    """Bar chart of per-class IoU and accuracy (the ``top`` most frequent classes), F-mIoU in the title.

    ``metrics`` is a ``mapping.evaluate.semantic.SemanticMetrics``.
    """
    rows = metrics.per_class[:top]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.45 * len(rows) + 2), 4))
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [100 * r.iou for r in rows], 0.4, label="IoU")
    ax.bar(x + 0.2, [100 * r.acc for r in rows], 0.4, label="accuracy")
    ax.set_xticks(x, [f"{r.class_name}\n{100 * r.frequency:.0f}%" for r in rows], rotation=60, fontsize=7)
    ax.set_ylabel("%")
    ax.set_ylim(0, 100)
    ax.legend(loc="upper right")
    return _save_figure(fig, path, f"{title}\nF-mIoU {metrics.f_miou:.1f}, F-mAcc {metrics.f_macc:.1f} "
                                   "(class: share of ground-truth points)")


def save_round_bytes(path: str | Path, reports: list[dict], title: str = "") -> Path:
    """Bytes each agent sent per round (stacked), and each agent's own compute seconds per round."""
    fig, (ax_bytes, ax_time) = plt.subplots(1, 2, figsize=(11, 3.8))
    if reports:
        rounds = np.arange(len(reports))
        sent = np.array([r["bytes_sent"] for r in reports], np.float64) / 1e6  # (T, N)
        bottom = np.zeros(len(reports))
        for a in range(sent.shape[1]):
            ax_bytes.bar(rounds, sent[:, a], bottom=bottom, label=f"agent_{a}")
            bottom += sent[:, a]
        compute = np.array([r["compute_s"] for r in reports], np.float64)
        for a in range(compute.shape[1]):
            ax_time.plot(rounds, compute[:, a], label=f"agent_{a}")
        ax_time.plot(rounds, [r["fleet_s"] for r in reports], "k--", label="fleet")
        ax_bytes.legend(fontsize=7)
        ax_time.legend(fontsize=7)
    ax_bytes.set_xlabel("round")
    ax_bytes.set_ylabel("MB sent")
    ax_time.set_xlabel("round")
    ax_time.set_ylabel("compute s")
    fig.tight_layout()
    return _save_figure(fig, path, title)
