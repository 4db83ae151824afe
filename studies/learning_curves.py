"""Learning curves of several training runs, grouped (e.g. one action form over three seeds), with their spread.

Each run folder's ``log.csv`` (one row per finished episode: env steps, return, final completion, MB) is binned
by env steps; per group the picture draws the mean over its runs of each bin's mean and the band between the
runs' lowest and highest, for the return, the final completion and the MB sent. The table gives each run's
first and last bins and the group's mean, so "did it learn" and "do the seeds agree" read off one page.

Run: `.venv/bin/python -m studies.learning_curves --group "team, central critic" runs/learn/team_central_s0
runs/learn/team_central_s1 runs/learn/team_central_s2 --group ... --out docs/schedules/learning/curves.png`

Figures: docs/learning.md#training-people-can-follow
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

KEYS = (("return", "episode return (normalised)"), ("completion", "final completion %"), ("mb", "MB sent by the team"))


def run_name(run) -> str:
    """A run folder's name, with its parent's when the folder is a copy at some length (``gate_s0/steps_3072``)."""
    path = Path(run)
    return f"{path.parent.name}/{path.name}" if path.name.startswith("steps_") else path.name


def read_log(folder: Path) -> dict[str, np.ndarray]:
    path = Path(folder) / "log.csv"
    if not path.is_file():
        raise FileNotFoundError(f"{path} is missing: not a training run folder (openmulti train --out)")
    rows = list(csv.DictReader(path.open()))
    return {k: np.array([float(r[k]) for r in rows]) for k in ("env_steps", "return", "completion", "mb")}


def binned(log: dict[str, np.ndarray], key: str, edges: np.ndarray) -> np.ndarray:
    which = np.digitize(log["env_steps"], edges[1:-1])
    return np.array([np.mean(log[key][which == b]) if np.any(which == b) else np.nan for b in range(len(edges) - 1)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--group", nargs="+", action="append", required=True, metavar=("LABEL", "RUN"),
                        help="a label and its run folders (repeatable)")
    parser.add_argument("--bin", type=int, default=256, help="env steps per bin")
    parser.add_argument("--out", default="runs/learning_curves.png")
    args = parser.parse_args()
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    groups = {g[0]: [read_log(Path(r)) for r in g[1:]] for g in args.group}
    last = max(float(log["env_steps"].max()) for logs in groups.values() for log in logs)
    edges = np.arange(0, last + args.bin, args.bin, dtype=float)
    centres = 0.5 * (edges[1:] + edges[:-1])
    fig, axes = plt.subplots(1, 3, figsize=(14, 3.8))
    lines = [f"Bins of {args.bin} env steps; per run the mean of its first and last bins.", "",
             "| group | run | episodes | first-bin return | last-bin return | last-bin completion % | last-bin MB |",
             "|---|---|---|---|---|---|---|"]
    for k, (label, logs) in enumerate(groups.items()):
        for ax, (key, title) in zip(axes, KEYS):
            curves = np.array([binned(log, key, edges) for log in logs])
            ax.plot(centres, np.nanmean(curves, axis=0), color=f"C{k}", label=f"{label} ({len(logs)} runs)")
            ax.fill_between(centres, np.nanmin(curves, axis=0), np.nanmax(curves, axis=0), color=f"C{k}", alpha=0.2)
            ax.set_title(title, fontsize=10)
            ax.set_xlabel("env steps")
            ax.grid(alpha=0.3)
        cells = []
        for run, log in zip(args.group[k][1:], logs):
            ret = binned(log, "return", edges)
            valid = np.flatnonzero(~np.isnan(ret))
            first, final = valid[0], valid[-1]
            cells.append((len(log["return"]), ret[first], ret[final], binned(log, "completion", edges)[final],
                          binned(log, "mb", edges)[final]))
            lines.append(f"| {label} | {run_name(run)} | {cells[-1][0]} | {cells[-1][1]:.3f} | {cells[-1][2]:.3f} | "
                         f"{cells[-1][3]:.1f} | {cells[-1][4]:.1f} |")
        if len(cells) > 1:
            mean = np.mean(np.array(cells), axis=0)
            lines.append(f"| {label} | **mean of {len(cells)}** | {mean[0]:.0f} | {mean[1]:.3f} | {mean[2]:.3f} | "
                         f"{mean[3]:.1f} | {mean[4]:.1f} |")
    axes[0].legend(fontsize=8, loc="best")
    fig.suptitle("mean over runs, band: lowest to highest run", fontsize=10)
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
