"""Collaborative-learner study: the team under several policies and options on one scene.

Run: `.venv/bin/python -m studies.team [--scene room0] [--preset fast] [--configs always never ...]`.
Each configuration is one `openmulti run` (its directory under --out); a finished one is not run again
while its settings and the library's defaults it learns with are unchanged (`bench_key.json` beside its
metrics; delete its folder to re-measure). Prints a Markdown table and writes `--out/bench_team.json` and
`--out/bench_team.png`.

Configurations (names): always, never, bernoulli:P, round_robin, no_cross (always without eq. 13),
dinno, dsgd, compact (always with float16 and changed-only sending at 1 %), single (one agent that
follows every region's path, policy never).

Figures: docs/learner.md#measured-at-fast-and-full
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import torch

from openmulti_env.runs.reproduce.runner import library_defaults
from mapping.pipeline.records import write_json_atomic
from openmulti_env.runs.run import run

CONFIGS = {
    "always": {"policy": "always"},
    "never": {"policy": "never"},
    "round_robin": {"policy": "round_robin"},
    "no_cross": {"policy": "always", "cross_rendering": False},
    "dinno": {"policy": "always", "consistency": "dinno"},
    "dsgd": {"policy": "always", "consistency": "dsgd"},
    "compact": {"policy": "always", "float16": True, "changed_only": 0.01},
    "single": {"policy": "never", "agents": 1},
}


def settings_of(name: str) -> dict:
    if name.startswith("bernoulli:"):
        return {"policy": name}
    if name not in CONFIGS:
        raise SystemExit(f"unknown configuration {name!r}; known: {sorted(CONFIGS)} or bernoulli:P")
    return dict(CONFIGS[name])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--agents", type=int, default=4)
    parser.add_argument("--configs", nargs="+", default=["always", "never", "bernoulli:0.2", "no_cross", "compact"])
    parser.add_argument("--out", default="runs/bench_team")
    parser.add_argument("--threads", type=int, default=None, help="torch threads (default: all cores)")
    args = parser.parse_args()
    out = Path(args.out)
    rows = []
    for name in args.configs:
        s = settings_of(name)
        agents = s.pop("agents", args.agents)
        policy = s.pop("policy")
        folder = out / f"{args.scene}_{args.preset}_s{args.seed}_{name.replace(':', '_')}"
        done, key_file = folder / "metrics.json", folder / "bench_key.json"
        key = {"scene": args.scene, "preset": args.preset, "seed": args.seed, "agents": agents, "policy": policy,
               "options": s, "defaults": library_defaults(args.preset)}
        if not (done.is_file() and key_file.is_file() and json.loads(key_file.read_text()) == key):
            start = time.perf_counter()
            run(args.scene, agents, policy, args.preset, args.seed, folder, device="cpu", threads=args.threads, **s)
            write_json_atomic(key_file, key)
            print(f"[bench_team] {name}: {time.perf_counter() - start:.0f} s")
        m = json.loads(done.read_text())
        rows.append({"config": name, "agents": agents, **{k: m["mean"][k] for k in ("acc_cm", "comp_cm", "comp_ratio",
                                                                                    "f_miou")},
                     "mb_per_round_per_agent": m["bytes_per_round_per_agent_mean"] / 1e6,
                     "mb_total": m["bytes_sent_total"] / 1e6, "fleet_s": m["fleet_s"], "wall_s": m["wall_s"],
                     "rounds": m["rounds"], "compute_s_max": max(m["compute_s"].values()),
                     "threads": m["config"].get("run", m["config"]).get("threads")})
    header = ("| config | agents | acc [cm] | comp [cm] | comp ratio [%] | F-mIoU | MB/round/agent | MB total | "
              "fleet [s] | wall [s] |")
    lines = [header, "|" + "---|" * 10]
    for r in rows:
        lines.append(f"| {r['config']} | {r['agents']} | {r['acc_cm']:.2f} | {r['comp_cm']:.2f} | {r['comp_ratio']:.1f} "
                     f"| {r['f_miou']:.1f} | {r['mb_per_round_per_agent']:.2f} | {r['mb_total']:.1f} | "
                     f"{r['fleet_s']:.0f} | {r['wall_s']:.0f} |")
    print(f"\n{args.scene}, preset {args.preset}, seed {args.seed}; machine {platform.machine()}, "
          f"{os.cpu_count()} cores, torch {torch.__version__}, CPU")
    print("\n".join(lines))
    write_json_atomic(out / "bench_team.json", {"scene": args.scene, "preset": args.preset, "seed": args.seed,
                                                 "rows": rows})
    _plot(out / "bench_team.png", rows, f"{args.scene} preset {args.preset} seed {args.seed}")


def _plot(path: Path, rows: list[dict], title: str) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6))
    names = [r["config"] for r in rows]
    for ax, key, label in zip(axes, ("comp_ratio", "acc_cm", "mb_per_round_per_agent"),
                              ("completion ratio [%]", "accuracy [cm]", "MB per round per agent")):
        ax.bar(names, [r[key] for r in rows], color="tab:blue")
        ax.set_ylabel(label)
        ax.tick_params(axis="x", rotation=40, labelsize=8)
    fig.suptitle(title)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
