"""A whole env episode's fingerprint: a SHA-256 over every observation, reward and info of every step,
with seeded random actions, plus the final completion estimate and bytes in plain figures.

A refactor that must keep behaviour bit for bit runs this before and after and compares the hashes
(``--expect`` does it and exits 1 on a difference)::

    python -m studies.episode_fingerprint --preset rl_tiny --seed 11 --action-seed 2
    python -m studies.episode_fingerprint --preset rl --seed 0 --action-seed 0 --json out.json

Figures: docs/benchmarks.md#refactor-check-episode_fingerprintpy
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
import time

import numpy as np

from openmulti_env import parallel_env


def episode_fingerprint(preset: str, seed: int, action_seed: int, **overrides) -> dict:
    """Run one episode with random 0/1 actions drawn from ``action_seed``; hash everything it returned."""
    e = parallel_env(preset=preset, **overrides)
    digest = hashlib.sha256()
    start = time.perf_counter()
    obs, infos = e.reset(seed=seed)
    rng = np.random.default_rng(action_seed)

    def feed(value) -> None:
        """Every array's bytes and every other value's JSON, dicts in key order (observations are Dicts)."""
        if isinstance(value, np.ndarray):
            digest.update(str(value.dtype).encode() + str(value.shape).encode() + value.tobytes())
        elif isinstance(value, dict):
            for key in sorted(value):
                digest.update(str(key).encode())
                feed(value[key])
        elif isinstance(value, (list, tuple)):
            for item in value:
                feed(item)
        else:
            digest.update(json.dumps(value, sort_keys=True, default=lambda o: o.tolist()).encode())

    def absorb(d: dict) -> None:
        for agent in sorted(d):
            digest.update(agent.encode())
            feed(d[agent])

    absorb(obs)
    absorb(infos)
    steps, returns = 0, 0.0
    while e.agents:
        actions = {a: rng.integers(0, 2, e.action_space(a).shape).astype(np.int8) for a in e.agents}
        obs, rewards, terms, truncs, infos = e.step(actions)
        for d in (obs, rewards, terms, truncs, infos):
            absorb(d)
        returns += float(np.mean(list(rewards.values())))
        steps += 1
    final = {a: infos[a] for a in sorted(infos)}
    e.close()
    return {"preset": preset, "seed": seed, "action_seed": action_seed, "overrides": overrides, "steps": steps,
            "sha256": digest.hexdigest(), "mean_return": returns,
            "completion_ratio": {a: final[a]["completion_ratio"] for a in final},
            "bytes_sent_total": {a: final[a]["bytes_sent_total"] for a in final},
            "wall_s": time.perf_counter() - start}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default="rl_tiny", help="env preset (default: rl_tiny)")
    parser.add_argument("--seed", type=int, default=11, help="episode seed given to reset (default: 11)")
    parser.add_argument("--action-seed", type=int, default=2, help="seed of the random actions (default: 2)")
    parser.add_argument("--learner", default="per_agent", choices=("per_agent", "fleet"),
                        help="the env's learner (fleet: every agent's steps batched; default per_agent)")
    parser.add_argument("--json", help="also write the fingerprint to this JSON file")
    parser.add_argument("--expect", help="a fingerprint JSON to compare with; exit 1 when the hash differs")
    args = parser.parse_args()
    overrides = {"learner": args.learner} if args.learner != "per_agent" else {}
    result = episode_fingerprint(args.preset, args.seed, args.action_seed, **overrides)
    print(json.dumps(result, indent=2))
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(result, fh, indent=2)
    if args.expect:
        with open(args.expect) as fh:
            expected = json.load(fh)
        same = expected["sha256"] == result["sha256"]
        print("same episode as" if same else "DIFFERENT episode from", args.expect)
        return 0 if same else 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
