"""The transfer check: does the cheap training episode rank communication schedules as the real one does?

A cheap episode is worth training on only if the schedule it prefers is the one a `fast` run prefers. For each
scene-seed cell never used for a choice (``studies.cells.HEADROOM_CELLS``) and each scripted schedule, the final
completion ratio of
- the cheap episode: one env episode at ``--cheap`` (a preset with overrides, e.g. ``rl_small``), the env's own
  estimate (the reward's view), the cell's scene and seed;
- the real one: ``openmulti run --preset fast`` on the same cell, the mesh metric (the headroom study's runs and
  rows, shared: ``--fast-root``, ``--fast-rows``).
Per cell the Spearman rank correlation of the two completions over the schedules both sides have; the report
gives each cell's, their mean, and a scatter picture (``--out/transfer_<setting>.png``).

    .venv/bin/python -m studies.transfer_check                   # cheap episodes that are missing, then report
    .venv/bin/python -m studies.transfer_check --run-fast        # also the missing fast runs (about 10 min each)
    .venv/bin/python -m studies.transfer_check --report          # only the table and the picture

Rows are appended as each episode or run ends (a rerun skips what it has). On a Ray cluster the fast runs are
independent: give each its own task (``studies.fast_runs.command`` builds the command line).

Figures: docs/transfer.md
"""

from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from studies.cells import HEADROOM_CELLS
from studies.episodes import episode
from studies.fast_runs import command, row_of, run_folder
from studies.rows import append_row, read_rows
from studies.settings import parse_setting

POLICIES = ("always", "never", "every:2", "every:3", "every:4", "rate:0.25", "rate:0.5", "novelty",
            "instance_novelty")
"""The issue's eight plus the instance-level heuristic."""
SEPARATED = 2.0
"""Points by which the reference must separate two schedules for their order to count in the pair agreement."""


def cheap_episodes(setting: str, policies: list[str], rows_file: Path) -> list[dict]:
    """Run the cheap episodes this file lacks (one env per cell and action form), appending each row."""
    from openmulti_env import parallel_env  # noqa: PLC0415
    from openmulti_env.environment.config import env_config  # noqa: PLC0415
    from policies import make_policy  # noqa: PLC0415

    rows = read_rows(rows_file)
    done = {(r["setting"], r["scene"], r["seed"], r["policy"]) for r in rows}
    preset, overrides = parse_setting(setting)
    for scene, seed in HEADROOM_CELLS:
        envs: dict[str, object] = {}
        n = env_config(preset, **{**overrides, "scene": scene}).num_agents
        for name in policies:
            if (setting, scene, seed, name) in done:
                continue
            policy = make_policy(name, n, seed)
            form = getattr(policy, "action_form", "entries")
            if form not in envs:
                envs[form] = parallel_env(preset=preset, seed=seed, **{**overrides, "scene": scene, "action_form": form})
            row = {"setting": setting, "scene": scene, "seed": seed, "policy": name,
                   **episode(envs[form], policy, seed)}
            rows.append(row)
            append_row(rows_file, row)
            print(f"[transfer] {setting} {scene} s{seed} {name}: {row['completion']:.2f} % {row['mb']:.1f} MB "
                  f"{row['s_per_step']:.2f} s/step", flush=True)
        for env in envs.values():
            env.close()
    return rows


def fast_runs(policies: list[str], root: Path, rows_file: Path) -> list[dict]:
    """Run the `fast` cells this file lacks (the unlimited scenario), appending each row."""
    rows = read_rows(rows_file)
    done = {(r["scene"], r["seed"], r["scenario"], r["policy"]) for r in rows}
    for scene, seed in HEADROOM_CELLS:
        for name in policies:
            if (scene, seed, "unlimited", name) in done:
                continue
            folder = run_folder(root, scene, seed, "unlimited", name)
            if row_of(folder, scene, seed, "unlimited", name) is None:
                print(f"[transfer] fast {scene} s{seed} {name}", flush=True)
                subprocess.run(command(scene, seed, "unlimited", name, folder), check=True)
            row = row_of(folder, scene, seed, "unlimited", name)
            if row is not None:
                rows.append(row)
                append_row(rows_file, row)
    return rows


def rank_agreement(cheap: list[dict], fast: list[dict], setting: str, against: str | None = None) -> list[dict]:
    """Per cell: the schedules both sides have, their completions, and the Spearman correlation (``against``: a
    second cheap setting in place of the fast runs, e.g. whether a cheaper episode ranks as ``rl_small`` does)."""
    out = []
    for scene, seed in HEADROOM_CELLS:
        c = {r["policy"]: r["completion"] for r in cheap if (r["setting"], r["scene"], r["seed"]) == (setting, scene, seed)}
        f = {r["policy"]: r["comp_ratio"] for r in fast
             if (r["scene"], r["seed"], r["scenario"]) == (scene, seed, "unlimited")} if against is None else \
            {r["policy"]: r["completion"] for r in cheap if (r["setting"], r["scene"], r["seed"]) == (against, scene, seed)}
        both = [p for p in c if p in f]
        rho = float(spearmanr([c[p] for p in both], [f[p] for p in both]).statistic) if len(both) >= 3 else None
        pairs = [(a, b) for k, a in enumerate(both) for b in both[k + 1:] if abs(f[a] - f[b]) > SEPARATED]
        agree = [np.sign(c[a] - c[b]) == np.sign(f[a] - f[b]) for a, b in pairs]
        out.append({"scene": scene, "seed": seed, "policies": both, "cheap": [c[p] for p in both],
                    "fast": [f[p] for p in both], "spearman": rho, "pairs": len(pairs),
                    "agree": float(np.mean(agree)) if agree else None})
    return out


def report(cells: list[dict], setting: str, out: Path, against: str | None = None) -> None:
    """Markdown table (per cell: schedules compared, Spearman) and the scatter picture, named after the setting
    (``transfer_<setting>.md`` / ``.png``; ``..._vs_<against>`` for two cheap settings)."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    rhos = [c["spearman"] for c in cells if c["spearman"] is not None and np.isfinite(c["spearman"])]
    other = "`fast` (mesh metric)" if against is None else f"the cheap episode `{against}`"
    lines = [f"Cheap episode `{setting}` against {other}, unlimited links.", "",
             f"| cell | schedules on both sides | Spearman | pairs the reference separates by > {SEPARATED:g} points: "
             "ordered alike |", "|---|---|---|---|"]
    for c in cells:
        rho = "-" if c["spearman"] is None else f"{c['spearman']:.2f}"
        agree = "-" if c["agree"] is None else f"{c['pairs']}: {100 * c['agree']:.0f} %"
        lines.append(f"| {c['scene']} s{c['seed']} | {len(c['policies'])} ({', '.join(c['policies'])}) | {rho} | {agree} |")
    pairs = sum(c["pairs"] for c in cells)
    agreed = sum(c["pairs"] * c["agree"] for c in cells if c["agree"] is not None)
    total = f"{pairs}: {100 * agreed / pairs:.0f} %" if pairs else "-"
    lines.append(f"| mean over {len(rhos)} cell(s) | | {np.mean(rhos):.2f} | {total} |" if rhos else "| mean | | - | - |")
    fig, axes = plt.subplots(1, len(cells), figsize=(5 * len(cells), 4.2), squeeze=False)
    for ax, c in zip(axes[0], cells):
        # `never` lies 50-60 points under the rest on both sides: said in a corner, not drawn, so the schedules
        # whose order matters fill the axes
        shown = [(p, x, y) for p, x, y in zip(c["policies"], c["cheap"], c["fast"]) if p != "never"]
        ax.scatter([x for _, x, _ in shown], [y for _, _, y in shown])
        for k, (p, x, y) in enumerate(shown):
            ax.annotate(p.replace("instance_novelty", "inst_nov"), (x, y), fontsize=7,
                        xytext=(4, 4 if k % 2 else -9), textcoords="offset points")
        never = ""
        if "never" in c["policies"]:
            k = c["policies"].index("never")
            never = f"\n(never, not drawn: {c['cheap'][k]:.1f} / {c['fast'][k]:.1f})"
        rho = "-" if c["spearman"] is None else f"{c['spearman']:.2f}"
        ax.set_title(f"{c['scene']} seed {c['seed']}: Spearman {rho}{never}", fontsize=10)
        ax.set_xlabel(f"cheap episode ({setting}) completion %")
        ax.set_ylabel("fast run completion % (mesh, 5 cm)" if against is None else f"{against} completion %")
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    name = "transfer_" + setting.replace(",", "_").replace("=", "") + ("" if against is None else f"_vs_{against}")
    fig.savefig(out / f"{name}.png", dpi=110)
    plt.close(fig)
    (out / f"{name}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cheap", default="rl_small", help="the cheap episode: preset[,field=value...]")
    parser.add_argument("--policies", nargs="+", default=list(POLICIES))
    parser.add_argument("--cheap-rows", default="docs/schedules/transfer/cheap_rows.jsonl")
    parser.add_argument("--fast-root", default="runs/headroom_fast")
    parser.add_argument("--fast-rows", default="docs/schedules/headroom_fast/rows.jsonl")
    parser.add_argument("--run-fast", action="store_true", help="also run the missing fast cells")
    parser.add_argument("--report", action="store_true", help="only the table and the picture")
    parser.add_argument("--against", help="with --report: rank against this second cheap setting instead of fast")
    parser.add_argument("--out", default="docs/schedules/transfer")
    args = parser.parse_args()
    cheap_file, fast_file = Path(args.cheap_rows), Path(args.fast_rows)
    cheap = read_rows(cheap_file) if args.report else cheap_episodes(args.cheap, args.policies, cheap_file)
    fast = fast_runs(args.policies, Path(args.fast_root), fast_file) if args.run_fast and not args.report \
        else read_rows(fast_file)
    report(rank_agreement(cheap, fast, args.cheap, args.against), args.cheap, Path(args.out), args.against)


if __name__ == "__main__":
    main()
