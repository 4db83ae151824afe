"""The held-out comparison's arithmetic: the fixed-rate front at equal bytes and the paired summary."""

from __future__ import annotations

import json

import pytest

from studies.schedules_tradeoff import load_rows, short, summary


def test_summary_pairs_each_policy_with_always_and_the_front(tmp_path):
    rows = []
    for seed, scale in ((0, 1.0), (1, 0.9)):
        for policy, comp, mb in (("always", 60, 100), ("never", 10, 0), ("every:2", 55, 50), ("p.json", 58, 50)):
            rows.append({"setting": "s", "policy": policy, "seed": seed, "completion": comp * scale, "mb": mb})
    path = tmp_path / "rows.jsonl"
    path.write_text("\n".join(json.dumps(r) for r in rows))
    text = summary(load_rows(path))
    assert short("runs/a/best.json:mode") == "a/best:mode" and short("runs/b/best.json") == "b/best"  # runs apart
    line = next(ln for ln in text.splitlines() if ln.startswith("| p |"))
    assert "50 %" in line and "+2.9 (min +2.7" in line  # 58 vs 55 and 52.2 vs 49.5 at the same bytes
    assert text.startswith("2 episodes")
