"""One `openmulti run --preset fast` per (cell, link scenario, policy): the real runs a cheap episode is
checked against.

The headroom study makes these runs and the transfer check reads them (and fills in missing ones), so both
must name a run's folder and read its row the same way. Each run is an independent command: on a Ray
cluster give each its own task (``command`` builds it).
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

SCENARIOS = {"unlimited": [], "range": ["--link-range-m", "2.0"], "bandwidth": ["--link-mb-per-round", "0.25"]}
"""Range 2 m: every pair of these paths comes within 1.6 m at some frame; 0.25 MB a link and round is about a
quarter of what `always` sends over one at `fast`."""


def command(scene: str, seed: int, scenario: str, policy: str, out: Path) -> list[str]:
    """The `openmulti run` of one cell, scenario and policy."""
    return [sys.executable, "-m", "openmulti_env.runs.cli", "run", "--preset", "fast", "--scene", scene, "--seed",
            str(seed), "--policy", policy, "--out", str(out), *SCENARIOS[scenario]]


def run_folder(root: Path, scene: str, seed: int, scenario: str, policy: str) -> Path:
    """``ROOT/<scene>-s<seed>/<scenario>/<policy>`` (the policy's ``:``, ``,`` and ``=`` made path-safe)."""
    return Path(root) / f"{scene}-s{seed}" / scenario / policy.replace(":", "_").replace(",", "_").replace("=", "")


def row_of(folder: Path, scene: str, seed: int, scenario: str, policy: str) -> dict | None:
    """The finished run's row (None when it has not finished or kept no scores)."""
    metrics = Path(folder) / "metrics.json"
    if not metrics.is_file():
        return None
    m = json.loads(metrics.read_text())
    if "mean" not in m:
        return None
    return {"scene": scene, "seed": seed, "scenario": scenario, "policy": policy,
            "comp_ratio": m["mean"]["comp_ratio"], "acc_cm": m["mean"]["acc_cm"], "mb": m["bytes_sent_total"] / 1e6,
            "wall_s": m.get("wall_s")}
