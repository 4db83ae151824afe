"""Env actions <-> the team's round plan (``mapping.team.RoundPlan``), with errors that name the agent."""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from mapping.team import RoundPlan


class ActionError(ValueError):
    """A bad action dict: a missing or unknown agent, or an action of the wrong shape or values."""


def peers_of(i: int, n: int) -> list[int]:
    """Agent ``i``'s peers in action order: ascending index, skipping itself."""
    return [j for j in range(n) if j != i]


def actions_to_plan(actions: Mapping[str, object], agents: Sequence[str]) -> RoundPlan:
    """Turn ``{agent: MultiBinary(2 * (N - 1))}`` into the round's two (N, N) matrices.

    Entry k < N - 1 of agent i's action: send parameters to ``peers_of(i)[k]``; entry N - 1 + k: share
    rays with it."""
    n = len(agents)
    if not isinstance(actions, Mapping):
        raise ActionError(f"actions must be a dict {{agent: action}} for the agents {list(agents)}, got "
                          f"{type(actions).__name__}")
    missing = [a for a in agents if a not in actions]
    unknown = [a for a in actions if a not in agents]
    if missing or unknown:
        raise ActionError(f"actions must hold exactly the agents {list(agents)}: "
                          + (f"missing {missing}" if missing else "") + (" " if missing and unknown else "")
                          + (f"unknown {unknown}" if unknown else ""))
    send, rays = np.zeros((n, n), bool), np.zeros((n, n), bool)
    for i, agent in enumerate(agents):
        a = np.asarray(actions[agent])
        if a.shape != (2 * (n - 1),):
            raise ActionError(f"{agent}: action must have shape ({2 * (n - 1)},) (MultiBinary: send parameters to "
                              f"each of {n - 1} peers, then share rays with each), got {a.shape}")
        if not np.all(np.isin(a, (0, 1))):
            raise ActionError(f"{agent}: action entries must be 0 or 1, got {np.unique(a)[:6].tolist()}")
        for k, j in enumerate(peers_of(i, n)):
            send[i, j], rays[i, j] = bool(a[k]), bool(a[n - 1 + k])
    return RoundPlan(send, rays)
