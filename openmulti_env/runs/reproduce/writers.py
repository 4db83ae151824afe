"""Writing a table: ``DIR/T.json`` (every row), ``DIR/T.md`` (means over seeds with their spread,
beside the paper's figures) and ``DIR/T.png``.

Rows are grouped by method (and link success rate, and number of agents); a cell is "mean +- sd" over
the group's runs (scenes x seeds; sd is the sample standard deviation, omitted for a single run).
Geometric tables give each of the three cullings (``mapping.pipeline.scoring``).
"""

from __future__ import annotations

import math
from pathlib import Path

from openmulti_env.runs.reproduce.orderings import ordering_lines
from openmulti_env.runs.reproduce.tables import HELD_OUT_SCENES, PAPER, TUNING_SCENES
from mapping.pipeline.records import write_json_atomic

CULLING_COLUMNS = (("free space", ""), ("NICE-SLAM", "_nice"), ("unculled", "_unculled"))
COLUMNS = {  # table -> (header, row key, scale) after method / n
    "geometric": [(f"{m} [{name}]", f"{m}{s}", 1.0) for name, s in CULLING_COLUMNS
                  for m in ("acc_cm", "comp_cm", "comp_ratio")] + [("MB/round/agent", "bytes_per_round", 1e-6),
                                                                    ("s/round", "time_per_round_s", 1.0)],
    "multi-vs-single": [("acc_cm", "acc_cm", 1.0), ("comp_cm", "comp_cm", 1.0), ("comp_ratio", "comp_ratio", 1.0),
                        ("fleet time [s]", "fleet_s", 1.0), ("s/round", "time_per_round_s", 1.0)],
    "semantic": [("F-mIoU (agent)", "f_miou", 1.0), ("F-mAcc (agent)", "f_macc", 1.0),
                 ("F-mIoU (all maps)", "team_f_miou", 1.0), ("F-mAcc (all maps)", "team_f_macc", 1.0)],
    "ablation": [("acc_cm", "acc_cm", 1.0), ("comp_cm", "comp_cm", 1.0), ("comp_ratio", "comp_ratio", 1.0),
                 ("s/round", "time_per_round_s", 1.0), ("MB/round/agent", "bytes_per_round", 1e-6)],
    "comm-failure": [("comp_ratio", "comp_ratio", 1.0), ("acc_cm", "acc_cm", 1.0), ("comp_cm", "comp_cm", 1.0)],
    "transmission": [("MB/round/agent", "bytes_per_round", 1e-6), ("first round MB", "first_mb", 1.0),
                     ("last round MB", "last_mb", 1.0), ("instances", "instances", 1.0)],
}


def write_table(out: Path, table: str, rows: list[dict], notes: str = "") -> dict[str, Path]:
    """Write the three files of ``table``; returns their paths."""
    out.mkdir(parents=True, exist_ok=True)
    paths = {"json": out / f"{table}.json", "md": out / f"{table}.md", "png": out / f"{table}.png"}
    write_json_atomic(paths["json"], {"table": table, "rows": rows})
    tmp = paths["md"].with_name(paths["md"].name + ".tmp")
    tmp.write_text(markdown_table(table, rows, notes))
    tmp.replace(paths["md"])
    save_plot(paths["png"], table, rows)
    return paths


def _with_derived(row: dict) -> dict:
    series = row.get("bytes_per_round_series") or []
    return {**row, "first_mb": series[0] / 1e6 if series else None, "last_mb": series[-1] / 1e6 if series else None}


def group_rows(rows: list[dict]) -> dict[tuple, list[dict]]:
    """Rows by (method, success rate, agents), in their first appearance order."""
    groups: dict[tuple, list[dict]] = {}
    for row in rows:
        groups.setdefault((row["method"], row.get("success_rate", 1.0), row.get("agents")), []).append(_with_derived(row))
    return groups


def mean_sd(values: list) -> tuple[float | None, float | None]:
    """Mean and sample standard deviation of the non-None values (sd None below two values)."""
    vals = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if not vals:
        return None, None
    m = sum(vals) / len(vals)
    if len(vals) < 2:
        return m, None
    return m, math.sqrt(sum((v - m) ** 2 for v in vals) / (len(vals) - 1))


def _cell(values: list, scale: float) -> str:
    m, sd = mean_sd(values)
    if m is None:
        return "-"
    return f"{m * scale:.2f}" if sd is None else f"{m * scale:.2f} ± {sd * scale:.2f}"


def _paper(table: str, method: str, rate: float) -> str:
    ref = PAPER.get(table, {}).get(method)
    if ref is None:
        return "-"
    if isinstance(ref, dict):
        return f"{ref.get(rate, '-')}"
    if isinstance(ref, tuple):
        return " / ".join("-" if v is None else f"{v:g}" for v in ref)
    return str(ref)


def markdown_table(table: str, rows: list[dict], notes: str = "") -> str:
    """The Markdown of ``table``: one line per (method, success rate, agents), means +- sd over runs; the
    scenes never used for a choice (``HELD_OUT_SCENES``) in a table of their own."""
    held = [r for r in rows if r["scene"] in HELD_OUT_SCENES]
    chosen = [r for r in rows if r["scene"] not in HELD_OUT_SCENES]
    lines = [f"# {table}", ""]
    if chosen:
        lines += method_lines(table, chosen)
    paper_note = {"geometric": "paper: Acc / Comp / Comp ratio (Table I)",
                  "ablation": "paper: Acc / Comp / s per round / MB (Table IV)",
                  "comm-failure": "paper: comp ratio at this success rate (Table V, room_0)",
                  "transmission": "paper: MB per frame (Table VI)",
                  "semantic": "paper: F-mIoU / F-mAcc (Table II)",
                  "multi-vs-single": "paper: mapping time (Table III)"}[table]
    lines += ["", paper_note + "."]
    orderings = ordering_lines(table, chosen)
    if orderings:
        lines += ["", *orderings]
    scenes = sorted({r["scene"] for r in chosen})
    if len(scenes) > 1:
        lines += ["", *per_scene_lines(table, chosen, scenes)]
    if held:
        lines += ["", f"## Scenes never used for a choice ({', '.join(sorted({r['scene'] for r in held}))})", "",
                  *method_lines(table, held)]
        held_orderings = ordering_lines(table, held)
        if held_orderings:
            lines += ["", *held_orderings]
    if notes:
        lines += ["", notes]
    return "\n".join(lines) + "\n"


def method_lines(table: str, rows: list[dict], columns: list[tuple[str, str, float]] | None = None) -> list[str]:
    """The scenes and seeds line and the method table of ``rows``: ``columns`` (header, row key, scale; default the
    table's ``COLUMNS``) after method / success / agents / n, the paper's figures last."""
    columns = COLUMNS[table] if columns is None else columns
    scenes = sorted({r["scene"] for r in rows})
    marked = [f"{s} (settings chosen here)" if s in TUNING_SCENES else s for s in scenes]
    seeds = sorted({r["seed"] for r in rows})
    head = ["method", "success", "agents", "n"] + [c[0] for c in columns] + ["paper"]
    lines = [f"Scenes {', '.join(marked)}; seeds {', '.join(map(str, seeds))}; "
             "cells: mean ± sd over the runs (scenes x seeds).", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for (method, rate, agents), group in group_rows(rows).items():
        cells = [_cell([r.get(key) for r in group], scale) for _, key, scale in columns]
        lines.append("| " + " | ".join([method, f"{rate * 100:g} %", str(agents), str(len(group))] + cells
                                       + [_paper(table, method, rate)]) + " |")
    return lines


HEADLINE = {"geometric": ("comp_ratio", "comp_ratio_nice", "comp_ratio_unculled"), "semantic": ("f_miou",),
            "transmission": ("bytes_per_round",)}
"""The figure(s) a table's per-scene section gives (default: its first column's)."""


def per_scene_lines(table: str, rows: list[dict], scenes: list[str]) -> list[str]:
    """A method x scene table of the headline figure (mean +- sd over seeds): the held-back scenes'
    figures stay visible instead of disappearing into a mean over scenes."""
    keys = HEADLINE.get(table, (COLUMNS[table][0][1],))
    scale = 1e-6 if keys == ("bytes_per_round",) else 1.0
    names = {"comp_ratio": "comp ratio [free space]", "comp_ratio_nice": "[NICE-SLAM]",
             "comp_ratio_unculled": "[unculled]", "bytes_per_round": "MB/round/agent"}
    lines = [f"Per scene: {' / '.join(names.get(k, k) for k in keys)}, mean ± sd over seeds.", "",
             "| method | success | agents | " + " | ".join(f"{s} (settings chosen here)" if s in TUNING_SCENES else s
                                                     for s in scenes) + " |", "|" + "---|" * (3 + len(scenes))]
    for (method, rate, agents), group in group_rows(rows).items():
        cells = [" / ".join(_cell([r.get(k) for r in group if r["scene"] == scene], scale) for k in keys)
                 for scene in scenes]
        lines.append("| " + " | ".join([method, f"{rate * 100:g} %", str(agents)] + cells) + " |")
    return lines


def save_plot(path: Path, table: str, rows: list[dict]) -> None:
    """One picture per table: completion ratio (or F-mIoU) per method; CR against link success for
    comm-failure; bytes per round over the rounds for transmission."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(8, 4))
    groups = group_rows(rows)
    if table == "transmission":
        for (method, _, _), group in groups.items():
            series = group[0].get("bytes_per_round_series") or []
            ax.plot(range(1, len(series) + 1), [b / 1e6 for b in series], marker=".", label=method)
        ax.set_xlabel("round")
        ax.set_ylabel("MB sent per agent")
        ax.legend(fontsize=8)
    elif table == "comm-failure":
        by_method: dict[str, list[tuple[float, float]]] = {}
        for (method, rate, _), group in groups.items():
            m, _ = mean_sd([r.get("comp_ratio") for r in group])
            if m is not None:
                by_method.setdefault(method, []).append((rate * 100, m))
        for method, pts in by_method.items():
            pts.sort()
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", label=method)
        ax.set_xlabel("link success [%]")
        ax.set_ylabel("completion ratio [%]")
        ax.legend(fontsize=8)
    else:
        key = "f_miou" if table == "semantic" else "comp_ratio"
        names = [method if table != "multi-vs-single" else f"{method} ({agents})" for method, _, agents in groups]
        scenes = sorted({r["scene"] for r in rows})
        width = 0.8 / len(scenes)
        for k, scene in enumerate(scenes):  # one bar per method and scene (mean +- sd over seeds)
            values = [[r.get(key) for r in group if r["scene"] == scene] for group in groups.values()]
            stats = [mean_sd(v) for v in values]
            xs = [i + (k - (len(scenes) - 1) / 2) * width for i in range(len(names))]
            ax.bar(xs, [m or 0.0 for m, _ in stats], width, yerr=[sd or 0.0 for _, sd in stats], capsize=2, label=scene)
            for x, v, (m, sd) in zip(xs, values, stats):  # how many seeds each bar is
                if m is not None:
                    ax.text(x, m + (sd or 0.0) + 1, f"n={sum(u is not None for u in v)}", ha="center", fontsize=6)
        ax.set_ylim(top=ax.get_ylim()[1] * 1.06)  # room for the n= labels
        if len(scenes) > 1:
            ax.legend(fontsize=8)
        ax.set_xticks(range(len(names)), names, rotation=30, ha="right", fontsize=8)
        ax.set_ylabel("F-mIoU" if key == "f_miou" else "completion ratio [%] (free-space culling)")
    ax.set_title(table)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)
