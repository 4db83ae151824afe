"""Fixed-rate fronts and a policy's margin over them: the yardstick every schedule study reads.

A policy is worth its bytes only if it completes more than the fixed-rate schedules (``never``, ``every:K``,
``rate:Q``, ``always``) do at the same bytes. Two readings of the front are used:

- ``reward_front.front`` (the env's front reward, and ``learned_vs_fixed``): the Pareto points, straight lines
  between them, flat past the last; margins per cell and paired differences below are read on it;
- ``concave_front_at`` (the held-out comparison, ``schedules_tradeoff``): the concave upper envelope, which
  credits a schedule that mixes two others round by round.
"""

from __future__ import annotations

import numpy as np

from openmulti_env.environment.reward_front import FRONT_SCHEDULES, front

FIXED_RATE = ("never",) + FRONT_SCHEDULES + ("always",)
"""The fixed-rate front's schedules (the front reward's, ``reward_front.FRONT_SCHEDULES``, between the ends)."""


def is_fixed_rate(policy: str) -> bool:
    """Whether ``policy`` is a fixed-rate schedule (``never``, ``always``, ``every:K``, ``rate:Q``)."""
    return policy in ("always", "never") or policy.startswith(("every:", "rate:"))


def concave_front_at(points: list[tuple[float, float]], mb: float) -> float:
    """The upper envelope of (MB, completion) points, linear between them, read at ``mb`` (the envelope is
    non-decreasing: spending more can always repeat a cheaper schedule's choice of rounds)."""
    pts = sorted(points)
    xs, ys = [pts[0][0]], [pts[0][1]]
    for x, y in pts[1:]:
        if y <= ys[-1]:
            continue  # dominated: more bytes for no more completion
        while len(xs) >= 2 and (ys[-1] - ys[-2]) * (x - xs[-2]) <= (y - ys[-2]) * (xs[-1] - xs[-2]):
            xs.pop(), ys.pop()  # keep the envelope concave
        xs.append(x), ys.append(y)
    return float(np.interp(mb, xs, ys))


def cell_margins(rows: list[dict], policy: str, family: tuple[str, ...]) -> dict[str, float]:
    """Per cell with every needed row (``cell``, ``policy``, ``mb``, ``completion``): the policy's completion
    minus the family's front at its MB."""
    out = {}
    for cell in dict.fromkeys(r["cell"] for r in rows):
        mine = {r["policy"]: r for r in rows if r["cell"] == cell}
        if policy not in mine or not all(p in mine for p in family):
            continue
        f = front([(mine[p]["mb"], mine[p]["completion"]) for p in family])
        out[cell] = mine[policy]["completion"] - f(mine[policy]["mb"])
    return out


def margins(rows: list[dict], policy: str, family: tuple[str, ...]) -> np.ndarray:
    """The per-cell margins as an array (cells in the rows' order)."""
    return np.array(list(cell_margins(rows, policy, family).values()))


def paired(rows: list[dict], a: str, b: str, family: tuple[str, ...] = FIXED_RATE) -> np.ndarray:
    """Per cell both were played on: a's margin over the family's front minus b's (points). Each is measured
    against the front at its own bytes, so two policies that send different amounts compare fairly."""
    ma, mb = cell_margins(rows, a, family), cell_margins(rows, b, family)
    return np.array([ma[cell] - mb[cell] for cell in ma if cell in mb])


def mean_se(values: np.ndarray) -> str:
    """``+1.23 ± 0.45``, marked when the mean is beyond two standard errors either way."""
    se = values.std(ddof=1) / np.sqrt(len(values))
    verdict = " **> 2 SE**" if values.mean() > 2 * se else (" < -2 SE" if values.mean() < -2 * se else "")
    return f"{values.mean():+.2f} ± {se:.2f}{verdict}"
