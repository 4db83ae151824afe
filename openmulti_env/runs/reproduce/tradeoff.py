"""The trade-off table's files: final completion ratio (mesh-based, the run's protocol) against the MB the
team sent, per communication policy, with the Pareto front.

A policy's cell is the mean over its runs (scenes x seeds) with the sample standard deviation; "of
always" compares with ``always`` on the same scenes and seeds. A trained policy's reward, budget and
training worlds (from its file's record) are written under the table.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic


def policy_means(rows: list[dict]) -> list[dict]:
    """Per policy (first appearance order): runs, mean and sd of completion and MB, share of ``always``."""
    always = {(r["scene"], r["seed"]): r for r in rows if r["policy"] == "always"}
    out = []
    for policy in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == policy]
        comp, mb = np.array([r["comp_ratio"] for r in mine]), np.array([r["mb_total"] for r in mine])
        paired = [(r, always[(r["scene"], r["seed"])]) for r in mine if (r["scene"], r["seed"]) in always]
        out.append({"policy": policy, "runs": len(mine), "comp_ratio": float(comp.mean()),
                    "comp_sd": float(comp.std(ddof=1)) if len(mine) > 1 else None, "mb": float(mb.mean()),
                    "mb_sd": float(mb.std(ddof=1)) if len(mine) > 1 else None,
                    "delta_vs_always": float(np.mean([r["comp_ratio"] - a["comp_ratio"] for r, a in paired]))
                    if paired else None,
                    "bytes_vs_always": float(sum(r["mb_total"] for r, _ in paired) /
                                             max(sum(a["mb_total"] for _, a in paired), 1e-12)) if paired else None})
    return out


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the (MB, completion) points no other point beats on both (fewer MB, more completion)."""
    front = []
    for i, (mb, comp) in enumerate(points):
        if not any((m <= mb and c >= comp) and (m < mb or c > comp) for j, (m, c) in enumerate(points) if j != i):
            front.append(i)
    return sorted(front, key=lambda i: points[i][0])


def learned_note() -> str:
    """What the shipped policy was trained with (its file's record), or that none ships."""
    from policies.learned import SHIPPED  # noqa: PLC0415

    if not SHIPPED.is_file():
        return "No trained policy ships with this version: `learned` is not in the table."
    training = json.loads(SHIPPED.read_text()).get("training", {})
    env = training.get("env", {})
    return (f"`learned`: {SHIPPED.name}, trained with `{training.get('command', '?')}` for "
            f"{training.get('env_steps', '?')} env steps on {len(training.get('scenes', []))} worlds "
            f"({', '.join(training.get('scenes', [])[:4])}, ...), preset `{env.get('preset')}`, reward "
            f"`{env.get('reward')}`, cost {env.get('comm_cost_per_mb')} per MB, budget {env.get('comm_budget_mb')} MB.")


def write_tradeoff(out: Path, rows: list[dict], notes: str = "") -> dict[str, Path]:
    """``tradeoff.json`` (rows and per-policy means), ``tradeoff.md`` and ``tradeoff.png``."""
    out.mkdir(parents=True, exist_ok=True)
    means = policy_means(rows)
    paths = {"json": out / "tradeoff.json", "md": out / "tradeoff.md", "png": out / "tradeoff.png"}
    write_json_atomic(paths["json"], {"table": "tradeoff", "rows": rows, "policies": means})
    front = set(pareto_front([(m["mb"], m["comp_ratio"]) for m in means]))
    lines = ["| policy | runs | comp ratio [%] | MB sent (team) | of always's bytes | vs always [points] | Pareto |",
             "|---|---|---|---|---|---|---|"]
    for k, m in enumerate(means):
        sd = f" ± {m['comp_sd']:.1f}" if m["comp_sd"] is not None else ""
        mb_sd = f" ± {m['mb_sd']:.1f}" if m["mb_sd"] is not None else ""
        share = f"{100 * m['bytes_vs_always']:.0f} %" if m["bytes_vs_always"] is not None else "-"
        delta = f"{m['delta_vs_always']:+.1f}" if m["delta_vs_always"] is not None else "-"
        lines.append(f"| {m['policy']} | {m['runs']} | {m['comp_ratio']:.1f}{sd} | {m['mb']:.1f}{mb_sd} | {share} "
                     f"| {delta} | {'yes' if k in front else ''} |")
    text = "\n".join(["## tradeoff: completion ratio against bytes", "", *lines, "", learned_note(), "", notes, ""])
    tmp = paths["md"].with_name("tradeoff.md.tmp")
    tmp.write_text(text)
    tmp.replace(paths["md"])
    save_tradeoff_plot(paths["png"], rows, means, front)
    return paths


def save_tradeoff_plot(path: Path, rows: list[dict], means: list[dict], front: set[int]) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(7.5, 5))
    colours = plt.get_cmap("tab10")
    for k, m in enumerate(means):
        mine = [r for r in rows if r["policy"] == m["policy"]]
        colour = colours(k % 10)
        ax.scatter([r["mb_total"] for r in mine], [r["comp_ratio"] for r in mine], s=12, alpha=0.35, color=colour)
        ax.scatter([m["mb"]], [m["comp_ratio"]], s=60, color=colour, edgecolor="black", label=m["policy"], zorder=3)
    ordered = [means[i] for i in sorted(front, key=lambda i: means[i]["mb"])]
    ax.plot([m["mb"] for m in ordered], [m["comp_ratio"] for m in ordered], "k--", lw=1, label="Pareto front")
    ax.set_xlabel("MB sent by the team over the run")
    ax.set_ylabel("completion ratio [%] (5 cm, mesh-based)")
    scenes = sorted({r["scene"] for r in rows})
    ax.set_title(f"Completion against bytes: {', '.join(scenes)}; means (large) and runs (small)", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
