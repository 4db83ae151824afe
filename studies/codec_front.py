"""The codec's study (issue 63): completion against MB at `fast` for `always` and `instance_novelty` under each
codec setting and today's float32, one `openmulti run --preset fast` per (cell, policy, setting), one at a time;
the settings are picked on validation cells and reported on cells never used for a choice.

    python -m studies.codec_front --cells room0:0 --policies always --settings float32 8d10 4d5 \\
        --rows docs/codec/validation.jsonl --out runs/study_codec
    python -m studies.codec_front --cells room1:3 office1:4 office2:5 --policies always instance_novelty \\
        --settings float32 --pick-from docs/codec/validation.jsonl --within 0.5 1.0 --rows docs/codec/test.jsonl
    python -m studies.codec_front --rows docs/codec/test.jsonl --plot docs/codec/test.png   # the picture only

Each finished run appends its row (completion, accuracy, MB, wall time, ``made_at``) to ``--rows`` at once; a
rerun plays only the missing ones and resumes an interrupted run from its checkpoint. Prints each cell's table
(share of float32 `always`'s bytes, points against it) and draws completion against MB with each cell's front.

Figures: docs/codec.md
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from studies.cells import parse_cell
from studies.fast_runs import SCENARIOS
from studies.rows import append_row, read_rows

SETTINGS: dict[str, tuple[str, ...]] = {
    "float32": (),
    "16": ("bits=16", "feature_bits=16"),
    "8": ("bits=8", "feature_bits=8"),
    "8d": ("bits=8", "feature_bits=8", "delta=true", "lossless=zstd"),
    "8d10": ("bits=8", "feature_bits=8", "delta=true", "keep=0.1", "lossless=zstd"),
    "4d10": ("bits=4", "feature_bits=8", "delta=true", "keep=0.1", "lossless=zstd"),
    "4d5": ("bits=4", "feature_bits=8", "delta=true", "keep=0.05", "lossless=zstd"),
    "4d2": ("bits=4", "feature_bits=8", "delta=true", "keep=0.02", "lossless=zstd"),
    "8d10c16": ("bits=8", "feature_bits=8", "delta=true", "keep=0.1", "cloud_bits=16", "lossless=zstd"),
    "4d5c16": ("bits=4", "feature_bits=8", "delta=true", "keep=0.05", "cloud_bits=16", "lossless=zstd"),
    "4d5c8": ("bits=4", "feature_bits=8", "delta=true", "keep=0.05", "cloud_bits=8", "lossless=zstd"),
}
"""Named codec settings: ``team.exchange.codec`` fields (``float32``: the codec off, today's format). Rows made
before 5b3c8b6's successor coded neither clouds nor left out held observed spaces (their ``made_at`` says which
code made them)."""


def codec_options(setting: str) -> list[str]:
    """The ``openmulti run`` options of a named setting."""
    out = []
    for item in SETTINGS[setting]:
        key, _, value = item.partition("=")
        out += [f"--team.exchange.codec.{key.replace('_', '-')}", value]
    return out


def run_command(scene: str, seed: int, policy: str, setting: str, scenario: str, out: Path) -> list[str]:
    """The `openmulti run` of one cell, policy, codec setting and link scenario."""
    return [sys.executable, "-m", "openmulti_env.runs.cli", "run", "--preset", "fast", "--scene", scene, "--seed",
            str(seed), "--policy", policy, "--out", str(out), *SCENARIOS[scenario], *codec_options(setting)]


def run_folder(root: Path, scene: str, seed: int, scenario: str, policy: str, setting: str) -> Path:
    return Path(root) / f"{scene}-s{seed}" / scenario / policy.replace(":", "_").replace(",", "_").replace("=", "") / setting


def row_of(folder: Path) -> dict | None:
    """The finished run's figures (None while it has not finished scoring)."""
    path = folder / "metrics.json"
    if not path.is_file():
        return None
    m = json.loads(path.read_text())
    if "mean" not in m:
        return None
    return {"comp_ratio": m["mean"]["comp_ratio"], "acc_cm": m["mean"]["acc_cm"], "mb": m["bytes_sent_total"] / 1e6,
            "wall_s": m.get("wall_s"), "made_at": m.get("made_at")}


def key(row: dict) -> tuple:
    return row["scene"], row["seed"], row["scenario"], row["policy"], row["setting"]


def play(cells: list[str], policies: list[str], settings: list[str], scenario: str, rows_path: Path,
         root: Path) -> None:
    """Every missing run, one after another, its row appended as it ends."""
    done = {key(r) for r in read_rows(rows_path)}
    for cell in cells:
        scene, seed = parse_cell(cell)
        for policy in policies:
            for setting in settings:
                if (scene, seed, scenario, policy, setting) in done:
                    continue
                folder = run_folder(root, scene, seed, scenario, policy, setting)
                print(f"[codec] {scene} s{seed} {scenario} {policy} {setting}", flush=True)
                if row_of(folder) is None:
                    subprocess.run(run_command(scene, seed, policy, setting, scenario, folder), check=True)
                figures = row_of(folder)
                append_row(rows_path, {"scene": scene, "seed": seed, "scenario": scenario, "policy": policy,
                                       "setting": setting, "codec": list(SETTINGS[setting]), **figures})


def pick_setting(rows: list[dict], within: float) -> str:
    """The setting that sends the fewest bytes while staying within ``within`` points of float32 `always` on every
    validation cell it was played on (mean MB share over cells); float32 when none does. Only `always` rows count."""
    always = [r for r in rows if r["policy"] == "always"]
    cells = {(r["scene"], r["seed"], r["scenario"]) for r in always}
    ref = {c: next((r for r in always if (r["scene"], r["seed"], r["scenario"]) == c and r["setting"] == "float32"), None)
           for c in cells}
    best, best_share = "float32", 1.0
    for setting in sorted({r["setting"] for r in always} - {"float32"}):
        mine = [r for r in always if r["setting"] == setting and ref[(r["scene"], r["seed"], r["scenario"])]]
        if not mine:
            continue
        refs = [ref[(r["scene"], r["seed"], r["scenario"])] for r in mine]
        if all(r["comp_ratio"] >= f["comp_ratio"] - within for r, f in zip(mine, refs)):
            share = sum(r["mb"] / f["mb"] for r, f in zip(mine, refs)) / len(mine)
            if share < best_share:
                best, best_share = setting, share
    return best


def cell_table(rows: list[dict]) -> str:
    """Per cell: each (policy, setting) with completion, MB, its share of float32 `always`'s bytes, points
    against float32 `always` (missing reference: blank)."""
    lines = ["| cell | policy | codec | completion % | MB | of float32 always's bytes | vs float32 always [points] |",
             "|---|---|---|---|---|---|---|"]
    for cell in sorted({(r["scene"], r["seed"], r["scenario"]) for r in rows}):
        mine = [r for r in rows if (r["scene"], r["seed"], r["scenario"]) == cell]
        ref = next((r for r in mine if r["policy"] == "always" and r["setting"] == "float32"), None)
        for r in sorted(mine, key=lambda r: -r["mb"]):
            share = f"{100 * r['mb'] / ref['mb']:.1f} %" if ref else ""
            diff = f"{r['comp_ratio'] - ref['comp_ratio']:+.2f}" if ref else ""
            lines.append(f"| {cell[0]} s{cell[1]}{'' if cell[2] == 'unlimited' else ' ' + cell[2]} | `{r['policy']}` | "
                         f"{r['setting']} | {r['comp_ratio']:.2f} | {r['mb']:.1f} | {share} | {diff} |")
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    """Completion against MB (log scale) per cell, a marker per policy, labelled by setting."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.ticker import FormatStrFormatter, LogLocator, NullFormatter  # noqa: PLC0415

    cells = sorted({(r["scene"], r["seed"]) for r in rows})
    fig, axes = plt.subplots(1, len(cells), figsize=(5 * len(cells), 4), squeeze=False)
    for ax, cell in zip(axes[0], cells):
        for policy, marker in (("always", "o"), ("instance_novelty", "s")):
            mine = sorted((r for r in rows if (r["scene"], r["seed"]) == cell and r["policy"] == policy),
                          key=lambda r: r["mb"])
            if not mine:
                continue
            ax.plot([r["mb"] for r in mine], [r["comp_ratio"] for r in mine], marker=marker, linestyle="",
                    label=policy)
            for r in mine:
                ax.annotate(r["setting"], (r["mb"], r["comp_ratio"]), fontsize=7, xytext=(3, 3),
                            textcoords="offset points")
        ax.set_xscale("log")
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))  # 10, 20, 50, 100, ... MB written out
        ax.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("MB sent by the team (log scale)")
        ax.set_ylabel("completion ratio %")
        ax.set_title(f"{cell[0]} seed {cell[1]} (fast)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--cells", nargs="*", default=[], help="SCENE:SEED, e.g. room1:3")
    parser.add_argument("--policies", nargs="*", default=["always"])
    parser.add_argument("--settings", nargs="*", default=["float32"], choices=sorted(SETTINGS))
    parser.add_argument("--pick-from", type=Path, default=None,
                        help="validation rows: also play the setting pick_setting chooses there within each of --within")
    parser.add_argument("--within", type=float, nargs="*", default=[0.5, 1.0], help="points below float32 always")
    parser.add_argument("--scenario", default="unlimited", choices=sorted(SCENARIOS))
    parser.add_argument("--rows", type=Path, required=True)
    parser.add_argument("--out", type=Path, default=Path("runs/study_codec"))
    parser.add_argument("--plot", type=Path, default=None, help="draw completion against MB here (PNG)")
    args = parser.parse_args(argv)
    settings = list(args.settings)
    if args.pick_from is not None:
        validation = read_rows(args.pick_from)
        for within in args.within:
            chosen = pick_setting(validation, within)
            print(f"[codec] chosen on {args.pick_from} within {within} points of float32: {chosen}", flush=True)
            settings += [chosen] if chosen not in settings else []
    play(args.cells, args.policies, settings, args.scenario, args.rows, args.out)
    rows = read_rows(args.rows)
    if rows:
        print(cell_table(rows))
        if args.plot is not None:
            plot(rows, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
