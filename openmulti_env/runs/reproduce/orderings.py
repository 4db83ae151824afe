"""The paper's orderings, weighed over the runs a table has: holds, missed or within noise.

Each ordering is a set of paired differences, one per (scene, seed) both sides ran (the same world and
episode), so that the layout's own spread cancels. An ordering **holds** when every difference has the
paper's sign and their mean is more than two standard errors from zero, is **missed** when every
difference has the other sign by that margin, and is **within noise** otherwise; one pair is reported as
**one run** (no spread to weigh it by). The verdict is given under the run's culling and NICE-SLAM's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

COMPLETION_KEYS = (("comp_ratio", "run's culling"), ("comp_ratio_nice", "NICE-SLAM"))


@dataclass(frozen=True)
class Ordering:
    """One of the paper's claims as "``better`` scores higher than ``worse``" on ``key``."""

    claim: str
    table: str
    differences: Callable[[list[dict], str], list[float]]
    """Paired differences (paper's sign positive) from the table's rows and a completion key."""


@dataclass(frozen=True)
class Verdict:
    """An ordering weighed over its pairs under one completion key."""

    claim: str
    key: str
    pairs: int
    mean: float | None
    sd: float | None
    low: float | None
    high: float | None
    verdict: str
    """``holds``, ``missed``, ``within noise``, ``one run`` or ``not run``."""


def _by_run(rows: list[dict], method: str, rate: float = 1.0) -> dict[tuple, dict]:
    return {(r["scene"], r["seed"]): r for r in rows
            if r["method"] == method and abs(r.get("success_rate", 1.0) - rate) < 1e-9}


def higher(better: str, worse: str) -> Callable[[list[dict], str], list[float]]:
    """Differences ``better - worse`` on the same scene and seed."""
    def differences(rows: list[dict], key: str) -> list[float]:
        a, b = _by_run(rows, better), _by_run(rows, worse)
        return [a[k][key] - b[k][key] for k in sorted(a.keys() & b.keys())
                if a[k].get(key) is not None and b[k].get(key) is not None]
    return differences


def smaller_loss(better: str, worse: str, rate: float) -> Callable[[list[dict], str], list[float]]:
    """Differences of the share of completion lost from 100 % link success to ``rate`` [points of %],
    ``worse``'s loss minus ``better``'s, on the same scene and seed."""
    def loss(rows: list[dict], method: str, key: str) -> dict[tuple, float]:
        full, failing = _by_run(rows, method), _by_run(rows, method, rate)
        return {k: 100.0 * (full[k][key] - failing[k][key]) / full[k][key] for k in full.keys() & failing.keys()
                if full[k].get(key) and failing[k].get(key) is not None}

    def differences(rows: list[dict], key: str) -> list[float]:
        a, b = loss(rows, better, key), loss(rows, worse, key)
        return [b[k] - a[k] for k in sorted(a.keys() & b.keys())]
    return differences


ORDERINGS = (
    *(Ordering(f"instance-level beats global: `{inst}` above `{glob}`", "geometric", higher(inst, glob))
      for inst, glob in (("openmulti", "macim_global"), ("openmulti", "dinerf_global"),
                         ("dinno_instance", "dinerf_global"), ("dsgd_instance", "macim_global"))),
    *(Ordering("removing Cross Rendering worsens completion: `openmulti` above `openmulti_no_cross`", table,
               higher("openmulti", "openmulti_no_cross")) for table in ("geometric", "ablation")),
    *(Ordering(f"OpenMulti best: `openmulti` above `{other}`", "geometric", higher("openmulti", other))
      for other in ("single", "dsgd_instance", "dinno_instance")),
    Ordering("OpenMulti loses the smallest share at 20 % link success: `openmulti` below `dinerf_global`",
             "comm-failure", smaller_loss("openmulti", "dinerf_global", 0.2)),
)
"""The paper's orderings (issue: the tables over scenes and seeds); "OpenMulti best" against the global
maps is the instance-level ones above."""


def weigh(values: list[float]) -> tuple[str, float | None, float | None]:
    """(verdict, mean, sd) of paired differences (the module's rule)."""
    if not values:
        return "not run", None, None
    mean = sum(values) / len(values)
    if len(values) == 1:
        return "one run", mean, None
    sd = math.sqrt(sum((v - mean) ** 2 for v in values) / (len(values) - 1))
    margin = 2.0 * sd / math.sqrt(len(values))
    if all(v > 0 for v in values) and mean > margin:
        return "holds", mean, sd
    if all(v < 0 for v in values) and -mean > margin:
        return "missed", mean, sd
    return "within noise", mean, sd


def verdicts(table: str, rows: list[dict]) -> list[Verdict]:
    """Every ordering of ``table`` under each completion key the rows have."""
    out = []
    for ordering in (o for o in ORDERINGS if o.table == table):
        for key, _ in COMPLETION_KEYS:
            values = ordering.differences(rows, key)
            verdict, mean, sd = weigh(values)
            out.append(Verdict(ordering.claim, key, len(values), mean, sd, min(values, default=None),
                               max(values, default=None), verdict))
    return out


def ordering_lines(table: str, rows: list[dict]) -> list[str]:
    """A Markdown table of the verdicts (empty when ``table`` has no ordering)."""
    found = verdicts(table, rows)
    if not found:
        return []
    names = dict(COMPLETION_KEYS)
    lines = ["The paper's orderings (paired over scene and seed; completion ratio [points], or for link failures "
             "the share of completion lost [points of %]; holds / missed: every pair agrees and the mean is over "
             "two standard errors from 0):", "",
             "| ordering | culling | pairs | mean difference ± sd | range | verdict |", "|---|---|---|---|---|---|"]
    for v in found:
        diff = "-" if v.mean is None else f"{v.mean:+.2f}" + ("" if v.sd is None else f" ± {v.sd:.2f}")
        span = "-" if v.low is None else f"{v.low:+.2f} .. {v.high:+.2f}"
        lines.append(f"| {v.claim} | {names[v.key]} | {v.pairs} | {diff} | {span} | **{v.verdict}** |")
    return lines
