"""Env steps per hour of ``openmulti train``, side by side: code checkouts x presets, alternated.

Issue 47's headline target is training throughput as a user sees it: the whole ``openmulti train`` command (PPO
updates, resets, world changes, the text encoder's first load), not one env's step. Each ``--run LABEL=CHECKOUT:PRESET``
runs the same command with the same PPO settings from CHECKOUT's code (``PYTHONPATH``: a git worktree of an older
commit, or ``.``), in a fresh run folder, and reports env steps per hour and the ratio to the first run. Every
training world is built into the world cache once before timing (``--no-warm`` skips that), so no run pays for
building what another run built.

    git worktree add /tmp/base 6892348
    .venv/bin/python benchmarks/bench_train_rate.py --run base=/tmp/base:rl_small --run head=.:rl_small \\
        --run lite=.:rl_lite --env-steps 512 --repeats 1 --out runs/bench_train_rate

Rows are appended to ``--out/rows.jsonl`` as each run ends (a rerun skips what is there).

Figures: docs/profile.md#openmulti-trains-env-steps-per-hour-side-by-side-with-main-at-6892348-issue-47s-headline-target
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from studies.settings import parse_setting

ROOT = Path(__file__).resolve().parents[1]
TRAIN_SCENES = tuple(f"random:{k}" for k in range(100, 116))
"""``openmulti train``'s default worlds (``openmulti_env.runs.train.DEFAULT_TRAIN_SCENES``)."""


@dataclass(frozen=True)
class RunSpec:
    label: str
    checkout: Path
    preset: str
    """A preset with overrides, ``rl_lite,episode=recorded,recordings=2`` (``studies.settings``)."""

    @classmethod
    def parse(cls, text: str) -> "RunSpec":
        label, sep, rest = text.partition("=")
        checkout, sep2, preset = rest.rpartition(":")
        if not (sep and sep2 and label and preset):
            raise SystemExit(f"--run {text!r}: expected LABEL=CHECKOUT:PRESET[,FIELD=VALUE...], e.g. head=.:rl_small "
                             "or rec=.:rl_lite,episode=recorded,recordings=2")
        path = Path(checkout).resolve()
        if not (path / "openmulti_env").is_dir():
            raise SystemExit(f"--run {text!r}: {path} holds no openmulti_env package")
        return cls(label, path, preset)

    def environ(self) -> dict:
        return {**os.environ, "PYTHONPATH": str(self.checkout)}


def warm(spec: RunSpec) -> None:
    """Build (or find cached) every training world with the checkout's own code, and with recorded episodes every
    recording (made once, like the worlds: not what a training rate measures); check it imports that code."""
    preset, overrides = parse_setting(spec.preset)
    code = ("import openmulti_env, sys; from openmulti_env import parallel_env\n"
            f"assert openmulti_env.__file__.startswith({str(spec.checkout)!r}), openmulti_env.__file__\n"
            f"for s in {list(TRAIN_SCENES)!r}:\n"
            f"    e = parallel_env(preset={preset!r}, scene=s, **{overrides!r}); e.reset(seed=0)\n"
            "    for k in range(e.config.env.recordings if e.recorded_episodes is not None else 0):\n"
            "        e.recorded_episodes.recording(k)\n"
            "    e.close()\n")
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=spec.environ(), check=True, cwd=spec.checkout,
                   stdout=subprocess.DEVNULL)
    print(f"[bench_train_rate] {spec.label}: worlds ready in {time.perf_counter() - start:.0f} s", flush=True)


def timed_run(spec: RunSpec, env_steps: int, workers: int, extra: list[str]) -> dict:
    """One whole ``openmulti train`` in a fresh folder: wall seconds and env steps per hour."""
    with tempfile.TemporaryDirectory(prefix="train_rate_") as out:
        preset, overrides = parse_setting(spec.preset)
        options = [x for k, v in overrides.items() for x in (f"--{k.replace('_', '-')}", str(v))]
        command = [sys.executable, "-c", "from openmulti_env.runs.cli import main; raise SystemExit(main())", "train",
                   "--preset", preset, *options, "--env-steps", str(env_steps), "--workers", str(workers),
                   "--out", out, *extra]
        # a wrapper process waits for the run: its children's peak resident set is the largest process's of this run
        peak = Path(out) / "peak_kb"
        wrapper = [sys.executable, "-c", "import resource, subprocess, sys; code = subprocess.run(sys.argv[2:]).returncode; "
                   "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)); "
                   "raise SystemExit(code)", str(peak)]
        start = time.perf_counter()
        done = subprocess.run(wrapper + command, env=spec.environ(), cwd=spec.checkout, capture_output=True, text=True)
        wall = time.perf_counter() - start
        if done.returncode:
            raise SystemExit(f"{spec.label}: openmulti train failed ({done.returncode}):\n{done.stderr[-3000:]}")
        peak_mb = int(peak.read_text()) / 1024 if peak.exists() else None
        log = Path(out) / "log.csv"
        episodes = max(0, len(log.read_text().splitlines()) - 1) if log.exists() else 0
        ran = steps_run(Path(out) / "latest.json")
    if ran is None:
        raise SystemExit(f"{spec.label}: the run wrote no env step count in latest.json")
    return {"label": spec.label, "checkout": str(spec.checkout), "preset": spec.preset, "env_steps": env_steps,
            "env_steps_run": ran, "workers": workers, "episodes": episodes, "wall_s": wall,
            "env_steps_per_hour": ran * 3600 / wall, "peak_process_mb": peak_mb}


def steps_run(policy_file: Path) -> int | None:
    """The env steps the run made (its record in the policy file): PPO learns whole rollouts in chunks
    (``--chunk-env-steps``), so a run may make more than it was asked for."""
    if not policy_file.exists():
        return None
    stack = [json.loads(policy_file.read_text())]
    while stack:
        node = stack.pop()
        if isinstance(node, dict):
            if isinstance(node.get("env_steps"), int):
                return node["env_steps"]
            stack.extend(node.values())
        elif isinstance(node, list):
            stack.extend(node)
    return None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="LABEL=CHECKOUT:PRESET (repeatable; the first "
                        "is the reference of the ratios)")
    parser.add_argument("--env-steps", type=int, default=512, help="asked of each run (it makes whole PPO "
                        "rollouts in chunks of --chunk-env-steps, 512 by default: the rate uses what it made)")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--no-warm", action="store_true")
    parser.add_argument("--out", default="runs/bench_train_rate")
    parser.add_argument("extra", nargs="*", help="after --: more options for every openmulti train")
    args = parser.parse_args()
    if args.env_steps < 1 or args.repeats < 1:
        raise SystemExit("--env-steps and --repeats must be at least 1")
    specs = [RunSpec.parse(r) for r in args.run]
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_file = out / "rows.jsonl"
    rows = [json.loads(x) for x in rows_file.read_text().splitlines() if x.strip()] if rows_file.exists() else []
    if not args.no_warm:
        for spec in specs:
            warm(spec)
    def same(row: dict, spec: RunSpec) -> bool:
        """A row of this spec under this command's settings (another --workers or extra option is another run)."""
        return (row["label"], row["checkout"], row["preset"], row["env_steps"], row["workers"], row.get("extra", [])) \
            == (spec.label, str(spec.checkout), spec.preset, args.env_steps, args.workers, args.extra)

    for repeat in range(args.repeats):
        for spec in specs:  # alternated: each repeat runs every spec once, in order
            if any(same(r, spec) and r["repeat"] == repeat for r in rows):
                continue
            row = {**timed_run(spec, args.env_steps, args.workers, args.extra), "repeat": repeat,
                   "extra": args.extra}
            rows.append(row)
            with rows_file.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"[bench_train_rate] {spec.label} ({spec.preset}) repeat {repeat}: {row['wall_s']:.0f} s, "
                  f"{row['env_steps_per_hour']:.0f} env steps/h, peak process {row['peak_process_mb'] or 0:.0f} MB",
                  flush=True)
    ref = [r["env_steps_per_hour"] for r in rows if same(r, specs[0])]
    print("| run | setting | env steps/h (each repeat) | ratio to " + specs[0].label + " | peak process MB |\n"
          "|---|---|---|---|---|")
    for spec in specs:
        mine = [r for r in rows if same(r, spec)]
        rates = [r["env_steps_per_hour"] for r in mine]
        peaks = [r["peak_process_mb"] for r in mine if r.get("peak_process_mb")]
        ratio = (sum(rates) / len(rates)) / (sum(ref) / len(ref)) if rates and ref else float("nan")
        print(f"| {spec.label} | {spec.preset} | {' / '.join(f'{x:.0f}' for x in rates)} | {ratio:.2f} | "
              f"{max(peaks) if peaks else float('nan'):.0f} |")


if __name__ == "__main__":
    main()
