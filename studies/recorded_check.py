"""The recorded episode against the real one at the same setting: the same fixed schedules played on both.

For each cell (a scene at a world seed) and link scenario, one recording (the world's first) and its episode seed;
each schedule is played twice from that seed, on the real team and on the ``RecordedTeam`` of the recording
(``environment.rewards.play_fixed``: the reward's probes after every round), and a row keeps both final
completions (team mean, percent), both MB and the seconds each took. With the same seed both sides draw the same
channel, so what differs is the model (``mapping.team.recorded``): how far its completion is from the real one,
and whether it ranks the schedules as the real one does. ``--shares`` sets the share of an adopted copy's probes beyond
the receiver's own that count (``RecordedTeam(copy_share=...)``), to fit it on validation cells.

    .venv/bin/python -m studies.recorded_check --setting rl_lite --cells room0:6 office0:6
    .venv/bin/python -m studies.recorded_check --report

Figures: docs/recorded.md
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from studies.cells import parse_cell
from studies.rows import append_row, read_rows
from studies.settings import parse_setting

SCHEDULES = ("never", "always", "every:2", "every:3", "every:4", "rate:0.25", "rate:0.5")
SCENARIOS = {"unlimited": {}, "range": {"link_range_m": 2.0}, "capacity": {"link_mb_per_round": 0.25}}
"""The link-limited scenarios play ``LIMITED`` schedules (the fast runs' range and capacity, studies.fast_runs)."""
LIMITED = ("always", "every:2", "rate:0.5")
MODEL = 3
"""The version of the recorded episode's model a row was played with. 3 (in force): 1 with a review's fixes (a
match to an instance its mapper does not hold adopts the copy, a copy without a cloud is held unaligned, live
instances without keyframe pixels count in the map, ray positions drawn with the real message seed, float32
storage). 1: every copy aligned against the receiver's own instances only. 2 (e1131f5, tried and not kept: 2.15
points mean absolute error and 0.89 mean Spearman on the validation worlds against 1.81 and 0.90): a copy matched
to one adopted from a third agent is not adopted again."""


def play_cell(setting: str, cell: str, shares: list[float], rows_file: Path, cache_dir: str | None) -> None:
    """Every schedule and scenario of one cell this file lacks, appending a row each."""
    from mapping.team.recorded import RecordedTeam  # noqa: PLC0415
    from openmulti_env import parallel_env  # noqa: PLC0415
    from openmulti_env.environment.rewards import play_fixed  # noqa: PLC0415
    from openmulti_env.runs.made_at import made_at  # noqa: PLC0415

    done = {(r["setting"], r["cell"], r["scenario"], r["schedule"], r["share"]) for r in read_rows(rows_file)
            if r.get("model", 1) == MODEL}
    preset, overrides = parse_setting(setting)
    scene, world_seed = parse_cell(cell)
    for scenario, links in SCENARIOS.items():
        schedules = SCHEDULES if scenario == "unlimited" else LIMITED
        if all((setting, cell, scenario, s, share) in done for s in schedules for share in shares):
            continue
        env = parallel_env(preset=preset, seed=world_seed, **{**overrides, "scene": scene, "episode": "recorded",
                                                                "recordings": 1, "cache_dir": cache_dir, **links})
        env.reset(seed=0)
        episodes = env.recorded_episodes
        recording = episodes.recording(0)
        seed, tree = int(recording.meta["episode_seed"]), env.config
        n, horizon = tree.num_agents, tree.env.horizon
        for schedule in schedules:
            real = None
            for share in shares:
                if (setting, cell, scenario, schedule, share) in done:
                    continue
                if real is None:
                    start = time.perf_counter()
                    real = play_fixed(lambda: episodes.real_team(seed), n, horizon, episodes.points, episodes.normals,
                                      schedule, seed)
                    real_s = time.perf_counter() - start
                start = time.perf_counter()
                model = play_fixed(lambda: RecordedTeam(recording, tree.team, tree.channel, seed, share), n, horizon,
                                   episodes.points, episodes.normals, schedule, seed)
                row = {"setting": setting, "cell": cell, "scenario": scenario, "schedule": schedule, "share": share,
                       "real": 100 * float(real[0][-1].mean()), "recorded": 100 * float(model[0][-1].mean()),
                       "real_mb": float(real[1].sum()), "recorded_mb": float(model[1].sum()),
                       "real_s": real_s, "recorded_s": time.perf_counter() - start,
                       "record_s": episodes.record_s, "episode_seed": seed, "made_at": made_at(), "model": MODEL}
                append_row(rows_file, row)
                print(f"[recorded] {cell} {scenario} {schedule} share {share}: real {row['real']:.2f} % "
                      f"{row['real_mb']:.1f} MB ({real_s:.0f} s), recorded {row['recorded']:.2f} % "
                      f"{row['recorded_mb']:.1f} MB ({row['recorded_s']:.2f} s)", flush=True)
        env.close()


def summary(rows: list[dict], setting: str, share: float, model: int = MODEL) -> list[dict]:
    """Per cell: completion error (recorded - real, points) mean and largest, MB ratio, Spearman over every
    (scenario, schedule) point, and the share of pairs the real side separates by > 2 points ranked alike."""
    out = []
    for cell in sorted({r["cell"] for r in rows if r["setting"] == setting}):
        mine = [r for r in rows if r["setting"] == setting and r["cell"] == cell and r["share"] == share
                and r.get("model", 1) == model]
        if len(mine) < 3:
            continue
        real = np.array([r["real"] for r in mine])
        recorded = np.array([r["recorded"] for r in mine])
        pairs = [(a, b) for a in range(len(mine)) for b in range(a + 1, len(mine)) if abs(real[a] - real[b]) > 2]
        agree = [np.sign(real[a] - real[b]) == np.sign(recorded[a] - recorded[b]) for a, b in pairs]
        mb = [r["recorded_mb"] / r["real_mb"] for r in mine if r["real_mb"] > 0]
        out.append({"cell": cell, "points": len(mine), "error_mean": float(np.mean(recorded - real)),
                    "error_max": float(np.max(np.abs(recorded - real))),
                    "spearman": float(spearmanr(real, recorded).statistic),
                    "pairs": len(pairs), "agree": float(np.mean(agree)) if agree else None,
                    "mb_ratio": float(np.mean(mb)) if mb else None,
                    "speedup": float(np.sum([r["real_s"] for r in mine]) / max(np.sum([r["recorded_s"] for r in mine]), 1e-9))})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--setting", default="rl_lite")
    parser.add_argument("--cells", nargs="+", default=["room0:6"])
    parser.add_argument("--shares", nargs="+", type=float, default=[0.0])
    parser.add_argument("--rows", default="docs/recorded/rows.jsonl")
    parser.add_argument("--cache-dir", default=None)
    parser.add_argument("--report", action="store_true")
    args = parser.parse_args()
    rows_file = Path(args.rows)
    if not args.report:
        for cell in args.cells:
            play_cell(args.setting, cell, args.shares, rows_file, args.cache_dir)
    rows = read_rows(rows_file)
    for model in sorted({r.get("model", 1) for r in rows}):
        for share in sorted({r["share"] for r in rows if r["setting"] == args.setting}):
            for s in summary(rows, args.setting, share, model):
                print(f"model {model}, share {share}: {s}")


if __name__ == "__main__":
    main()
