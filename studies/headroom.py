"""The headroom of communication schedules at `fast`: completion ratio (the mesh metric) against megabytes,
per scene-seed cell and link scenario, on cells never used for a choice.

Each (cell, scenario, policy) is one `openmulti run --preset fast` into `OUT/<scene>-s<seed>/<scenario>/<policy>/`
(a run resumes by itself; a finished one is skipped), run one after another, cell by cell, so that whole cells
finish first. Rows (the run's mean completion ratio, accuracy, MB sent by the team, the share of `always`'s
bytes) go to `OUT/rows.jsonl` as each run ends; `--report` writes `OUT/headroom.md` and `OUT/headroom.png`
(completion against MB per cell, the Pareto front of each scenario drawn).

    .venv/bin/python -m studies.headroom --out runs/headroom_fast            # run what is missing
    .venv/bin/python -m studies.headroom --out runs/headroom_fast --report   # table and picture

On a Ray cluster the runs are independent: give each (cell, scenario, policy) its own task (the command line
``studies.fast_runs.command`` builds), e.g. with `openmulti reproduce --ray` or Ray Tune's function trainable.

Figures: docs/schedules.md#at-fast-on-cells-never-used-for-a-choice-studiesheadroompy
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

from studies.cells import HEADROOM_CELLS
from studies.fast_runs import SCENARIOS, command, row_of, run_folder
from studies.rows import append_row, read_rows

POLICIES = ("always", "every:4", "instance_novelty", "instance_novelty:change=1,after=999,final=0", "at:23")


def report(root: Path, rows: list[dict]) -> None:
    """Markdown table (per cell and scenario, each policy's completion and MB against that scenario's `always`)
    and PNG."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    lines = ["| cell | scenario | policy | completion % | vs always [points] | MB (team) | of always's bytes |",
             "|---|---|---|---|---|---|---|"]
    groups = sorted({(r["scene"], r["seed"], r["scenario"]) for r in rows})
    fig, axes = plt.subplots(1, max(len({(g[0], g[1]) for g in groups}), 1), figsize=(5 * 3, 4), squeeze=False)
    cells = sorted({(g[0], g[1]) for g in groups})
    for scene, seed, scenario in groups:
        mine = [r for r in rows if (r["scene"], r["seed"], r["scenario"]) == (scene, seed, scenario)]
        base = next((r for r in mine if r["policy"] == "always"), None)  # the scenario's own always
        for r in mine:
            vs = f"{r['comp_ratio'] - base['comp_ratio']:+.2f}" if base else "-"
            share = f"{100 * r['mb'] / base['mb']:.1f} %" if base and base["mb"] else "-"
            lines.append(f"| {scene} s{seed} | {scenario} | `{r['policy']}` | {r['comp_ratio']:.2f} | {vs} | "
                         f"{r['mb']:.1f} | {share} |")
        ax = axes[0][cells.index((scene, seed))]
        points = sorted((r["mb"], r["comp_ratio"], r["policy"]) for r in mine)
        ax.scatter([p[0] for p in points], [p[1] for p in points], label=scenario)
        for mb, cr, name in points:
            ax.annotate(name.replace("instance_novelty", "inst"), (mb, cr), fontsize=6)
        front, best = [], -1.0
        for mb, cr, _ in points:
            if cr > best:
                front.append((mb, cr))
                best = cr
        ax.plot([p[0] for p in front], [p[1] for p in front], lw=1)
        ax.set_title(f"{scene} seed {seed} (fast, 4 agents)")
        ax.set_xlabel("MB sent by the team")
        ax.set_ylabel("completion ratio % (5 cm)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(root / "headroom.png", dpi=120)
    (root / "headroom.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", default="runs/headroom_fast")
    parser.add_argument("--scenarios", nargs="+", default=["unlimited"], choices=sorted(SCENARIOS))
    parser.add_argument("--policies", nargs="+", default=list(POLICIES))
    parser.add_argument("--rows", help="also append each finished row to this JSONL (e.g. in docs/)")
    parser.add_argument("--report", action="store_true", help="only write the table and the picture")
    args = parser.parse_args()
    root = Path(args.out)
    root.mkdir(parents=True, exist_ok=True)
    rows_file = Path(args.rows) if args.rows else root / "rows.jsonl"
    rows = read_rows(rows_file)
    done = {(r["scene"], r["seed"], r["scenario"], r["policy"]) for r in rows}
    if not args.report:
        for scene, seed in HEADROOM_CELLS:
            for scenario in args.scenarios:
                for policy in args.policies:
                    if (scene, seed, scenario, policy) in done:
                        continue
                    folder = run_folder(root, scene, seed, scenario, policy)
                    if row_of(folder, scene, seed, scenario, policy) is None:
                        print(f"[headroom] {scene} seed {seed} {scenario} {policy}", flush=True)
                        subprocess.run(command(scene, seed, scenario, policy, folder), check=True)
                    row = row_of(folder, scene, seed, scenario, policy)
                    if row is None:
                        print(f"[headroom] {folder}/metrics.json holds no scores: run it again without "
                              "--no-evaluation", flush=True)
                        continue
                    rows.append(row)
                    append_row(rows_file, row)
    report(root, rows)


if __name__ == "__main__":
    main()
