"""Env benchmark: steps per second (and where a step's time goes), reset time with a cold and a warm
world cache, memory over many episodes, and how closely the probe estimate of completion ratio tracks
the mesh-based metric over whole episodes.

Run: `.venv/bin/python benchmarks/bench_env.py [--presets rl_tiny rl] [--episodes 3] [--memory-episodes 20]
[--correlation-every 2]`. Random actions (each entry 1 with probability 1/2). Prints Markdown tables and
writes `--out/bench_env.json`, `--out/estimate_vs_mesh.png` and `--out/render_<preset>.png`.

Figures: docs/env.md#speed, docs/env.md#how-well-the-estimate-tracks-the-meshes
"""

from __future__ import annotations

import argparse
import os
import platform
import resource
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from openmulti_env import parallel_env
from mapping.pipeline.records import write_json_atomic

PARTS = ("local_s", "consistency_s", "exchange_s", "reward_s", "observation_s")


def rss_mb() -> float:
    with open(f"/proc/{os.getpid()}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def random_actions(e, rng):
    return {a: rng.integers(0, 2, e.action_space(a).shape).astype(np.int8) for a in e.agents}


def speed(preset: str, episodes: int, cache: str, threads: int) -> dict:
    """Steps/s per episode (the first renders its frames; later ones read the render cache)."""
    e = parallel_env(preset=preset, cache_dir=cache, threads=threads, render_mode="rgb_array")
    rng = np.random.default_rng(0)
    per_episode, parts, render_s = [], {k: 0.0 for k in PARTS}, []
    for k in range(episodes):
        e.reset(seed=k)
        steps, start = 0, time.perf_counter()
        while e.agents:
            e.step(random_actions(e, rng))
            steps += 1
            if k > 0:
                for p in PARTS:
                    parts[p] += e.timings[p]
        per_episode.append(steps / (time.perf_counter() - start))
        t = time.perf_counter()
        frame = e.render()
        render_s.append(time.perf_counter() - t)
    later_steps = steps * max(episodes - 1, 1)
    from PIL import Image  # noqa: PLC0415

    Image.fromarray(frame).save(OUT / f"render_{preset}.png")
    e.close()
    return {"preset": preset, "steps_per_episode": steps, "steps_per_s": per_episode,
            "steps_per_s_warm": float(np.mean(per_episode[1:])) if episodes > 1 else per_episode[0],
            "ms_per_step": {p: 1000 * parts[p] / later_steps for p in PARTS},
            "render_ms": 1000 * float(np.mean(render_s))}


def resets(preset: str, threads: int) -> dict:
    """Reset of a new env on an empty cache (cold) and on the entry it left (warm, a new env again)."""
    folder = tempfile.mkdtemp(prefix="openmulti-worlds-")
    try:
        out = {}
        for label in ("cold", "warm"):
            e = parallel_env(preset=preset, cache_dir=folder, threads=threads)
            t = time.perf_counter()
            e.reset(seed=0)
            out[f"{label}_s"] = time.perf_counter() - t
            assert e.last_cache_hit == (label == "warm")
            e.close()
        e = parallel_env(preset=preset, cache_dir=folder, threads=threads)
        e.reset(seed=0)
        t = time.perf_counter()
        e.reset(seed=1)
        out["same_env_s"] = time.perf_counter() - t
        e.close()
        out["entry_mb"] = sum(p.stat().st_size for p in Path(folder).glob("*.npz")) / 1e6
        return out
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def memory(preset: str, episodes: int, cache: str, threads: int) -> dict:
    """RSS after each episode of one env (growth from reset to reset would show here)."""
    e = parallel_env(preset=preset, cache_dir=cache, threads=threads)
    rng = np.random.default_rng(1)
    rss = []
    for k in range(episodes):
        e.reset(seed=100 + k)
        while e.agents:
            e.step(random_actions(e, rng))
        rss.append(rss_mb())
    e.close()
    half = len(rss) // 2
    return {"preset": preset, "rss_mb": rss, "growth_second_half_mb": rss[-1] - rss[half] if half else 0.0}


def correlation(preset: str, seeds: list[int], every: int, cache: str, threads: int) -> dict:
    """Probe estimate against the mesh-based completion ratio (the run's protocol: culled meshes against
    the observable ground truth) for every agent every ``every`` steps of whole episodes."""
    from mapping.evaluate import evaluate_mesh, merge_instance_meshes  # noqa: PLC0415
    from mapping.evaluate.visibility import cull_to_viewpoints  # noqa: PLC0415

    e = parallel_env(preset=preset, cache_dir=cache, threads=threads)
    rng = np.random.default_rng(2)
    estimate, measured, unculled = [], [], []
    for seed in seeds:
        e.reset(seed=seed)
        gt = e.world.surface.culled_mesh()
        step = 0
        while e.agents:
            _, _, _, _, infos = e.step(random_actions(e, rng))
            step += 1
            if step % every and e.agents:
                continue
            for i, member in enumerate(e.team.members):
                mesh, _ = merge_instance_meshes(member.mapper.instance_meshes())
                culled = cull_to_viewpoints(mesh, e.world.surface.viewpoints) if len(mesh.faces) else None
                metrics = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=0)
                raw = evaluate_mesh(mesh if len(mesh.faces) else None, gt, seed=0)
                estimate.append(infos[f"agent_{i}"]["completion_ratio"])
                measured.append(float(metrics.comp_ratio))
                unculled.append(float(raw.comp_ratio))
    e.close()
    r = float(np.corrcoef(estimate, measured)[0, 1]) if len(estimate) > 2 else float("nan")
    r_raw = float(np.corrcoef(estimate, unculled)[0, 1]) if len(estimate) > 2 else float("nan")
    slope, intercept = np.polyfit(measured, estimate, 1) if len(estimate) > 2 else (float("nan"),) * 2
    return {"preset": preset, "seeds": seeds, "points": len(estimate), "pearson_r": r, "estimate": estimate,
            "mesh": measured, "mesh_unculled": unculled, "pearson_r_unculled": r_raw, "fit_slope": float(slope), "fit_intercept": float(intercept),
            "mean_abs_diff": float(np.mean(np.abs(np.subtract(estimate, measured))))}


def plot_correlation(rows: list[dict], path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, ax = plt.subplots(figsize=(5, 5))
    for row in rows:
        ax.scatter(row["mesh"], row["estimate"], s=14, label=f"{row['preset']}, culled mesh: r = {row['pearson_r']:.3f} "
                                                               f"({row['points']} agent-steps)")
        ax.scatter(row["mesh_unculled"], row["estimate"], s=14, marker="x",
                   label=f"{row['preset']}, unculled mesh: r = {row['pearson_r_unculled']:.3f}")
    top = max(max(r["mesh"] + r["estimate"] + r["mesh_unculled"]) for r in rows) * 1.05
    ax.plot([0, top], [0, top], "k--", lw=0.8, label="estimate = mesh")
    ax.set(xlabel="completion ratio from meshes [%]", ylabel="probe estimate [%]",
           title="Completion-ratio estimate vs mesh metric", xlim=(0, top), ylim=(0, top))
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    global OUT
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--presets", nargs="+", default=["rl_tiny", "rl"])
    parser.add_argument("--episodes", type=int, default=3, help="episodes per preset for steps/s")
    parser.add_argument("--memory-episodes", type=int, default=20, help="tiny episodes for the memory check")
    parser.add_argument("--correlation-seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--correlation-every", type=int, default=1, help="mesh every this many steps")
    parser.add_argument("--skip", nargs="*", default=[], choices=["speed", "resets", "memory", "correlation"])
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="runs/bench_env")
    args = parser.parse_args()
    OUT = Path(args.out)
    OUT.mkdir(parents=True, exist_ok=True)
    cache = str(OUT / "world-cache")
    result = {"machine": f"{platform.machine()}, {os.cpu_count()} cores, {platform.python_version()}",
              "threads": args.threads}
    if "speed" not in args.skip:
        result["speed"] = [speed(p, args.episodes, cache, args.threads) for p in args.presets]
        print("\n| preset | steps/episode | steps/s (1st episode) | steps/s (later) | " +
              " | ".join(f"{p} ms" for p in PARTS) + " | render ms |")
        print("|---" * (5 + len(PARTS)) + "|")
        for r in result["speed"]:
            print(f"| {r['preset']} | {r['steps_per_episode']} | {r['steps_per_s'][0]:.2f} | {r['steps_per_s_warm']:.2f} | "
                  + " | ".join(f"{r['ms_per_step'][p]:.0f}" for p in PARTS) + f" | {r['render_ms']:.0f} |")
    if "resets" not in args.skip:
        result["resets"] = {p: resets(p, args.threads) for p in args.presets}
        print("\n| preset | cold reset s | warm reset s (new env) | reset s (same env) | cache entry MB |\n|---|---|---|---|---|")
        for p, r in result["resets"].items():
            print(f"| {p} | {r['cold_s']:.2f} | {r['warm_s']:.2f} | {r['same_env_s']:.2f} | {r['entry_mb']:.1f} |")
    if "memory" not in args.skip:
        result["memory"] = memory("rl_tiny", args.memory_episodes, cache, args.threads)
        m = result["memory"]
        print(f"\nmemory (tiny, {len(m['rss_mb'])} episodes): RSS {m['rss_mb'][0]:.0f} -> {m['rss_mb'][-1]:.0f} MB, "
              f"second half growth {m['growth_second_half_mb']:+.1f} MB")
    if "correlation" not in args.skip:
        result["correlation"] = [correlation(p, args.correlation_seeds, args.correlation_every, cache, args.threads)
                                 for p in args.presets]
        for r in result["correlation"]:
            print(f"\ncorrelation ({r['preset']}, seeds {r['seeds']}, {r['points']} agent-steps): Pearson r = "
                  f"{r['pearson_r']:.3f} against culled meshes (the run's protocol), {r['pearson_r_unculled']:.3f} "
                  f"against unculled; estimate = {r['fit_slope']:.2f} x culled + {r['fit_intercept']:.1f}, "
                  f"mean |difference| {r['mean_abs_diff']:.1f} points")
        plot_correlation(result["correlation"], OUT / "estimate_vs_mesh.png")
    write_json_atomic(OUT / "bench_env.json", result)


OUT = Path("runs/bench_env")

if __name__ == "__main__":
    main()
