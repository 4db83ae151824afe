"""Pictures of a run, for any source: the maps from above beside the ground truth, the sensor beside the
map rendered from the same pose, per-class IoU, bytes and compute per round."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from mapping.figures import save_figure  # noqa: E402

SURFACE_CLASS_COLOURS = {"missed": "tab:blue", "right": "tab:green", "invented": "tab:red"}


def save_reconstruction_views(path: str | Path, gt_mesh, agent_meshes: list, reference: str = "ground truth",
                              seed: int = 0) -> Path:
    """Seen from above: the ground truth coloured by height, then per agent where its map (as scored) is
    right, what it misses and what it invents, against ``gt_mesh`` within the completion ratio's 5 cm.
    ``reference`` names what ``gt_mesh`` is (ground truth, or a reference fused from the observations)."""
    from mapping.evaluate.geometry import COMPLETION_RATIO_THRESHOLD_M, sample_points, surface_classes  # noqa: PLC0415

    n = 1 + len(agent_meshes)
    fig, axes = plt.subplots(1, n, figsize=(4.2 * n, 5.0), squeeze=False)
    lo, hi = gt_mesh.bounds
    below_ceiling = hi[2] - 0.15  # leave the ceiling out: it hides the room (a recording's z need not be up)

    def top_down(ax, points, by_height: bool = False, **style):
        points = points[points[:, 2] < below_ceiling]
        points = points[np.argsort(points[:, 2])]  # the highest surface on top
        if by_height:
            style.update(c=points[:, 2], cmap="viridis", vmin=lo[2], vmax=hi[2])
        return ax.scatter(points[:, 0], points[:, 1], s=0.2, rasterized=True, **style)

    shown = top_down(axes[0, 0], sample_points(gt_mesh, 100_000, seed=seed + 1), by_height=True)
    fig.colorbar(shown, ax=axes[0, 0], orientation="horizontal", fraction=0.05, pad=0.02, label="height [m]")
    axes[0, 0].set_title(f"{reference}, looking down z (top 15 cm cut)")
    for a, (ax, mesh) in enumerate(zip(axes[0, 1:], agent_meshes)):
        classes = surface_classes(mesh, gt_mesh, seed=seed)
        for name in ("missed", "right", "invented"):  # what the map invents on top
            top_down(ax, getattr(classes, name), color=SURFACE_CLASS_COLOURS[name])
        ax.set_title(f"agent_{a}")
    for ax in axes[0]:
        ax.set_xlim(lo[0] - 0.1, hi[0] + 0.1)
        ax.set_ylim(lo[1] - 0.1, hi[1] + 0.1)
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
    cm = round(COMPLETION_RATIO_THRESHOLD_M * 100)
    labels = {"right": f"map within {cm} cm of the {reference}", "missed": f"{reference} the map misses (> {cm} cm)",
              "invented": f"map surface the {reference} lacks (> {cm} cm)"}
    handles = [plt.Line2D([], [], ls="", marker="o", color=SURFACE_CLASS_COLOURS[k], label=v) for k, v in labels.items()]
    if agent_meshes:
        axes[0, 1].legend(handles=handles, loc="upper left", bbox_to_anchor=(0.0, -0.02), frameon=False, fontsize=8)
    return save_figure(fig, path)


DEPTH_CLASS_COLOURS = ("white", "tab:green", "tab:red", "black")
DEPTH_CLASS_NAMES = ("no sensor depth", "within 5 cm", "off > 5 cm", "no surface")


def save_view_comparison(path: str | Path, views: list, stride: int, title: str = "") -> Path:
    """Rows of (sensor RGB, map colour, sensor depth, map depth, and where the meshed map is right against
    the sensor); ``views`` holds (Frame, colour (h, w, 3), depth (h, w), classes (h, w) of
    ``mapping.evaluate.depth_check.depth_classes`` or None) with the map rendered at every ``stride``-th pixel."""
    from matplotlib.colors import ListedColormap  # noqa: PLC0415
    from matplotlib.patches import Patch  # noqa: PLC0415

    fig, axes = plt.subplots(len(views), 5, figsize=(15, 2.6 * len(views)), squeeze=False)
    for row, (frame, colour, depth, classes) in zip(axes, views):
        if classes is not None:
            row[4].imshow(classes, cmap=ListedColormap(DEPTH_CLASS_COLOURS), vmin=-0.5, vmax=3.5,
                          interpolation="nearest")
        vmax = float(frame.depth.max()) or 1.0
        row[0].imshow(frame.rgb)
        row[1].imshow(np.clip(colour, 0, 1), interpolation="nearest")
        row[2].imshow(frame.depth[::stride, ::stride], cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
        row[3].imshow(depth, cmap="viridis", vmin=0, vmax=vmax, interpolation="nearest")
        row[0].set_ylabel(f"frame {frame.index}")
        for ax in row:
            ax.set_xticks([])
            ax.set_yticks([])
    for ax, name in zip(axes[0], ("sensor RGB", "map colour", "sensor depth", "map depth", "meshed map vs sensor")):
        ax.set_title(name)
    fig.legend(handles=[Patch(facecolor=c, edgecolor="grey", label=n) for c, n in zip(DEPTH_CLASS_COLOURS, DEPTH_CLASS_NAMES)],
               loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.subplots_adjust(bottom=0.12)
    return save_figure(fig, path, title)


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
    return save_figure(fig, path, f"{title}\nF-mIoU {metrics.f_miou:.1f}, F-mAcc {metrics.f_macc:.1f} "
                                   "(class: share of ground-truth points)")


def save_round_bytes(path: str | Path, reports: list[dict], title: str = "") -> Path:
    """Bytes each agent sent per round (stacked) with the links that were up (when some went down or had a
    capacity), and each agent's own compute seconds per round."""
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
        links = [r.get("links") for r in reports]
        up = np.array([np.sum(x["up"]) if x else np.nan for x in links], np.float64)
        limited = any(x and (any(v is not None for row in x["room_bytes"] for v in row)) for x in links)
        n = sent.shape[1]
        if np.any(np.isfinite(up)) and (limited or np.nanmin(up) < n * (n - 1)):
            ax_links = ax_bytes.twinx()
            ax_links.step(rounds, up, where="mid", color="k", lw=1.2, label="links up")
            ax_links.set_ylim(0, n * (n - 1) + 0.5)
            ax_links.set_ylabel(f"links up (of {n * (n - 1)})")
            ax_links.legend(fontsize=7, loc="upper right")
        ax_bytes.legend(fontsize=7, loc="upper left")
        ax_time.legend(fontsize=7)
    ax_bytes.set_xlabel("round")
    ax_bytes.set_ylabel("MB sent")
    ax_time.set_xlabel("round")
    ax_time.set_ylabel("compute s")
    fig.tight_layout()
    return save_figure(fig, path, title)
