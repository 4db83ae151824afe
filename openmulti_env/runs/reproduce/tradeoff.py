"""The trade-off table's files: final completion ratio (mesh-based, the run's protocol) against the MB the
team sent, per communication policy, with the Pareto front.

A policy's cell is the mean over its runs (scenes x seeds) with the sample standard deviation, over the
scene-seed cells every policy has run; "of always" and "vs always" compare with ``always`` on the same scenes
and seeds (paired: the sd there is the paired differences'). The completion ratio is given under two
cullings: the run's (free-space viewpoints with the map's own occlusion, so a floater or a bumpy surface
hides the surface behind it and costs completion) and NICE-SLAM's (the agents' frustums and depth, as vMAP
and MACIM score). They can rank schedules differently (docs/schedules.md). A trained policy's reward,
budget and training worlds (from its file's record) are written under the table.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mapping.pipeline.records import write_json_atomic
from mapping.safe_parse import load_json

CULLINGS = {"comp_ratio": "", "comp_ratio_nice": "_nice"}
"""Completion-ratio key per culling, and the suffix of its fields in a policy's means."""


def policy_means(rows: list[dict]) -> list[dict]:
    """Per policy (first appearance order): runs, mean and sd of completion (under each culling every run
    has) and MB, and both against ``always`` on the same scenes and seeds."""
    always = {(r["scene"], r["seed"]): r for r in rows if r["policy"] == "always"}
    out = []
    for policy in dict.fromkeys(r["policy"] for r in rows):
        mine = [r for r in rows if r["policy"] == policy]
        mb = np.array([r["mb_total"] for r in mine])
        paired = [(r, always[(r["scene"], r["seed"])]) for r in mine if (r["scene"], r["seed"]) in always]
        means = {"policy": policy, "runs": len(mine), "mb": float(mb.mean()),
                 "mb_sd": float(mb.std(ddof=1)) if len(mine) > 1 else None,
                 "bytes_vs_always": float(sum(r["mb_total"] for r, _ in paired) /
                                          max(sum(a["mb_total"] for _, a in paired), 1e-12)) if paired else None}
        for key, suffix in CULLINGS.items():
            if any(r.get(key) is None for r in mine):
                continue
            comp = np.array([r[key] for r in mine])
            both = [(r, a) for r, a in paired if a.get(key) is not None]
            deltas = np.array([r[key] - a[key] for r, a in both])
            means |= {key: float(comp.mean()), f"comp{suffix}_sd": float(comp.std(ddof=1)) if len(mine) > 1 else None,
                      f"delta{suffix}_vs_always": float(deltas.mean()) if both else None,
                      f"delta{suffix}_sd": float(deltas.std(ddof=1)) if len(both) > 1 else None}
        out.append(means)
    return out


def common_cells(rows: list[dict]) -> tuple[list[dict], list[dict]]:
    """(rows on the scene-seed cells every policy has run, the other rows): means over unequal cells would
    compare policies on different worlds."""
    cells = [{(r["scene"], r["seed"]) for r in rows if r["policy"] == p} for p in dict.fromkeys(r["policy"] for r in rows)]
    shared = set.intersection(*cells) if cells else set()
    return ([r for r in rows if (r["scene"], r["seed"]) in shared],
            [r for r in rows if (r["scene"], r["seed"]) not in shared])


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
    training = load_json(SHIPPED).get("training", {})
    env = training.get("env", {})
    total = training.get("train", {}).get("total_env_steps", "?")
    return (f"`learned`: {SHIPPED.name}, trained with `{training.get('command', '?')}` (the snapshot at env step "
            f"{training.get('env_steps', '?')} of {total}) on {len(training.get('scenes', []))} worlds "
            f"({', '.join(training.get('scenes', [])[:4])}, ...), preset `{env.get('preset')}`, reward "
            f"`{env.get('reward')}`, cost {env.get('comm_cost_per_mb')} per MB, budget {env.get('comm_budget_mb')} MB.")


def write_tradeoff(out: Path, rows: list[dict], notes: str = "") -> dict[str, Path]:
    """``tradeoff.json`` (rows and per-policy means), ``tradeoff.md`` and ``tradeoff.png``."""
    out.mkdir(parents=True, exist_ok=True)
    complete, _, _ = compared_rows(rows)
    means = policy_means(complete)
    paths = {"json": out / "tradeoff.json", "md": out / "tradeoff.md", "png": out / "tradeoff.png"}
    write_json_atomic(paths["json"], {"table": "tradeoff", "rows": rows, "policies": means})
    fronts = {key: _front(means, key) for key in CULLINGS}
    text = "\n".join(["## tradeoff: completion ratio against bytes", "", *tradeoff_lines(rows), "", learned_note(), "",
                       notes, ""])
    tmp = paths["md"].with_name("tradeoff.md.tmp")
    tmp.write_text(text)
    tmp.replace(paths["md"])
    save_tradeoff_plot(paths["png"], complete, means, fronts)
    return paths


def compared_rows(rows: list[dict]) -> tuple[list[dict], list[dict], bool]:
    """(the rows the means are over, the rows left out, whether those compare unequal cells): the cells every
    policy has run, or every row when no cell has every policy yet (said rather than showing nothing)."""
    complete, pending = common_cells(rows)
    if not complete:
        return rows, [], True
    return complete, pending, False


def tradeoff_lines(rows: list[dict]) -> list[str]:
    """The Markdown table of ``rows`` (one line per policy, means over the common cells) and which cells it is over."""
    complete, pending, unequal = compared_rows(rows)
    means = policy_means(complete)
    fronts = {key: _front(means, key) for key in CULLINGS}
    lines = ["| policy | runs | comp ratio [%] | MB sent (team) | of always's bytes | vs always [points] | Pareto "
             "| comp ratio, NICE-SLAM culling [%] | vs always [points] | Pareto |", "|---|---|---|---|---|---|---|---|---|---|"]
    for k, m in enumerate(means):
        mb_sd = f" ± {m['mb_sd']:.1f}" if m["mb_sd"] is not None else ""
        share = f"{100 * m['bytes_vs_always']:.0f} %" if m["bytes_vs_always"] is not None else "-"
        comp, delta, front = _completion_cells(m, "comp_ratio", "", k in fronts["comp_ratio"])
        nice = " | ".join(_completion_cells(m, "comp_ratio_nice", "_nice", k in fronts["comp_ratio_nice"]))
        lines.append(f"| {m['policy']} | {m['runs']} | {comp} | {m['mb']:.1f}{mb_sd} | {share} | {delta} | {front} "
                     f"| {nice} |")
    cells = sorted({(r["scene"], r["seed"]) for r in complete})
    said = [f"Means over the {len(cells)} scene-seed cells {'some' if unequal else 'every'} policy has run: "
            f"{', '.join(f'{scene} seed {seed}' for scene, seed in cells)}"
            f"{' (no cell has every policy yet: the means compare different worlds)' if unequal else ''}."]
    if pending:
        waiting = sorted({(r["scene"], r["seed"]) for r in pending})
        said.append(f"Left out until every policy has run its cell: {len(pending)} runs on "
                    f"{', '.join(f'{scene} seed {seed}' for scene, seed in waiting)} (in tradeoff.json's rows).")
    return [*lines, "", *said]


def _front(means: list[dict], key: str) -> set[int]:
    """Pareto members among the policies that have ``key``."""
    have = [k for k, m in enumerate(means) if key in m]
    return {have[i] for i in pareto_front([(means[k]["mb"], means[k][key]) for k in have])}


def _completion_cells(m: dict, key: str, suffix: str, on_front: bool) -> tuple[str, str, str]:
    """(mean ± sd, vs always, Pareto) of one culling, or dashes when a run lacks it."""
    if key not in m:
        return "-", "-", ""
    sd, delta, delta_sd = m[f"comp{suffix}_sd"], m[f"delta{suffix}_vs_always"], m[f"delta{suffix}_sd"]
    return (f"{m[key]:.1f}{f' ± {sd:.1f}' if sd is not None else ''}",
            "-" if delta is None else f"{delta:+.1f}" + (f" ± {delta_sd:.1f}" if delta_sd else ""),
            "yes" if on_front else "")


def save_tradeoff_plot(path: Path, rows: list[dict], means: list[dict], fronts: dict[str, set[int]]) -> None:
    """One panel per culling: every run (small), each policy's mean (large) and the Pareto front."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    keys = [key for key in CULLINGS if any(key in m for m in means)]
    fig, axes = plt.subplots(1, len(keys), figsize=(6.5 * len(keys), 5), squeeze=False)
    colours = plt.get_cmap("tab10")
    names = {"comp_ratio": "the run's culling (free-space viewpoints)", "comp_ratio_nice": "NICE-SLAM culling"}
    for ax, key in zip(axes[0], keys):
        for k, m in enumerate(means):
            if key not in m:
                continue
            mine = [r for r in rows if r["policy"] == m["policy"]]
            colour = colours(k % 10)
            ax.scatter([r["mb_total"] for r in mine], [r[key] for r in mine], s=12, alpha=0.35, color=colour)
            ax.scatter([m["mb"]], [m[key]], s=60, color=colour, edgecolor="black", label=m["policy"], zorder=3,
                       marker="os^Dv<>pPX*"[k % 11])
        ordered = [means[i] for i in sorted(fronts[key], key=lambda i: means[i]["mb"])]
        ax.plot([m["mb"] for m in ordered], [m[key] for m in ordered], "k--", lw=1, label="Pareto front")
        sending = [r[key] for r in rows if r["mb_total"] > 0 and r.get(key) is not None]
        silent = [m for m in means if key in m and m["mb"] == 0]
        if sending and silent and min(m[key] for m in silent) < min(sending) - 10:  # zoom in on the sending ones
            ax.set_ylim(min(sending) - 2, max(sending) + 1)
            ax.text(0.02, 0.02, "; ".join(f"{m['policy']} (0 MB): {m[key]:.1f} %, below" for m in silent),
                    transform=ax.transAxes, fontsize=8)
        ax.set_xlabel("MB sent by the team over the run")
        ax.set_ylabel("completion ratio [%] (5 cm, mesh-based)")
        ax.set_title(names[key], fontsize=10)
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7, loc="lower right")
    scenes = sorted({r["scene"] for r in rows})
    fig.suptitle(f"Completion against bytes: {', '.join(scenes)}, seeds {sorted({r['seed'] for r in rows})}; "
                 "means (large) and runs (small)", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
