"""Env actions <-> the team's round plan (``mapping.team.RoundPlan``), with errors that name the agent.

Three action forms (``env.action_form``), peers always in ascending index order skipping the agent itself:

- ``entries``: ``MultiBinary(2 (N - 1))``: entry k < N - 1 sends its parameters (every shareable instance) to
  peer k, entry N - 1 + k shares its rays with peer k (DESIGN.md's action);
- ``round``: ``MultiBinary(1)``: one decision per round, parameters and rays to every peer or to none;
- ``instances``: ``MultiBinary((N - 1)(M + 2))``: entry k M + m sends the instance in slot m of peer k (the
  ``instances`` observation's slots, M = ``instance_slots``); then N - 1 entries "also send peer k the
  instances that appear in this round" (the observation was made before the round's frames, so it cannot
  name them: without this entry an instance seen first in the last round never travels, and everything
  travels a round late); then N - 1 entries share rays with each peer. Rays go per peer: a ray message is a
  few poses and a seed (kilobytes against 45 kB per object network), so choosing them per instance would
  buy nothing worth an action entry.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from mapping.team import RoundPlan

ACTION_FORMS = ("entries", "round", "instances")


class ActionError(ValueError):
    """A bad action dict: a missing or unknown agent, or an action of the wrong shape or values."""


def peers_of(i: int, n: int) -> list[int]:
    """Agent ``i``'s peers in action order: ascending index, skipping itself."""
    return [j for j in range(n) if j != i]


def action_size(form: str, num_agents: int, slots: int = 0) -> int:
    """Length of one agent's MultiBinary action in ``form``."""
    if form not in ACTION_FORMS:
        raise ValueError(f"unknown action form {form!r}; choose one of {ACTION_FORMS}")
    peers = num_agents - 1
    return {"entries": 2 * peers, "round": 1, "instances": peers * (slots + 2)}[form]


def actions_to_plan(actions: Mapping[str, object], agents: Sequence[str], form: str = "entries", slots: int = 0,
                    slot_ids: Sequence[Sequence[Sequence[int]]] | None = None) -> RoundPlan:
    """Turn ``{agent: action}`` into the round's plan (see the module docstring for each form).

    ``slot_ids[i][k]`` (the instance form): the instance ids in agent i's slots for its k-th peer, as its
    observation showed them; a slot past the agent's instances sends nothing."""
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
    size = action_size(form, n, slots)
    meaning = {"entries": f"MultiBinary: send parameters to each of {n - 1} peers, then share rays with each",
               "round": "MultiBinary: one decision for the round, everything to every peer or nothing",
               "instances": f"MultiBinary: {slots} instance slots for each of {n - 1} peers, then send new instances "
                            "to each, then share rays with each"}
    send, rays, new = np.zeros((n, n), bool), np.zeros((n, n), bool), np.zeros((n, n), bool)
    chosen: dict[tuple[int, int], tuple[int, ...]] = {}
    for i, agent in enumerate(agents):
        a = np.asarray(actions[agent])
        if a.shape != (size,):
            raise ActionError(f"{agent}: action must have shape ({size},) ({meaning[form]}), got {a.shape}")
        if not np.all(np.isin(a, (0, 1))):
            raise ActionError(f"{agent}: action entries must be 0 or 1, got {np.unique(a)[:6].tolist()}")
        for k, j in enumerate(peers_of(i, n)):
            if form == "entries":
                send[i, j], rays[i, j] = bool(a[k]), bool(a[n - 1 + k])
            elif form == "round":
                send[i, j] = rays[i, j] = bool(a[0])
            else:
                ids = list(slot_ids[i][k]) if slot_ids is not None else []
                picked = tuple(ids[m] for m in np.flatnonzero(a[k * slots:(k + 1) * slots]) if m < len(ids))
                new[i, j] = bool(a[(n - 1) * slots + k])
                send[i, j], rays[i, j] = bool(picked) or new[i, j], bool(a[(n - 1) * (slots + 1) + k])
                chosen[(i, j)] = picked
    if form != "instances":
        return RoundPlan(send, rays)
    return RoundPlan(send, rays, chosen, new)
