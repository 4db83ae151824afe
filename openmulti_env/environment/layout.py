"""The env's observation contract: names and positions of an observation's parts, and helpers that read
them by name.

The env (``observation.py``, ``parallel_env.py``) writes observations in this layout; policies read them by
these names, importing this module and nothing else of ``openmulti_env``. It imports only numpy and the
standard library, so a policy that reads observations does not load the simulator. An observation is a
``Dict`` of these entries:

``map``: (S, S, C) uint8 in [0, 255], channels last, rows along +y of the room and columns along +x (the
room's floor box fills the square with a margin). Channels ``MAP_CHANNELS``:

0. ``map_height``: the top of what the agent's own map holds in the column (its fields queried on a fixed
   voxel grid over the room's box, the ceiling band left out); 0 where it holds nothing, 1..255 from the
   floor up to the room's height;
1. ``map_decided``: share of the column's voxels whose occupancy the agent's fields decide (far from 0.5);
2. ``observed``: cells its own depth frames have hit;
3. ``received``: footprints of the object instances it holds from peers;
4. ``own_path``: its path so far (128) and its current position (255);
5. ``peer_poses``: peers' last known positions, from the ray messages it received (255, fading by 32 per
   round of age, at least 64).

``comm``: (N - 1) x ``LINK_FEATURES`` then ``AGENT_FEATURES``, float32 in [0, 1]; peer k is the k-th peer in
action order (ascending index, skipping the agent itself). Per peer, from the agent's own side of the link
(what its messages did, as the link acknowledged them) and what it received:

- ``holds``: share of its shareable instances the peer holds in some version;
- ``up_to_date``: share the peer holds within 5 % (relative L2) of their parameters now;
- ``change``: mean relative change of its instances since the peer's copy (1 for one the peer lacks);
- ``since_params`` / ``since_rays``: rounds since its last parameter / ray message reached the peer,
  divided by ``AGE_SCALE`` (1: never, or that long ago);
- ``since_received``: rounds since the peer's parameters last reached it, the same way;
- ``held_from_peer``: instances of the peer it holds, as a share of its map's instances (at most 1);
- ``bytes_share``: share of its bytes sent that went to the peer.

Then ``budget_left`` (share of its byte budget left; 1 without a budget) and ``progress`` (share of its
path's frames read).

``links``: (N - 1, ``LINK_STATE``) float32 in [0, 1], peers in action order, what its radio reports of each
link in the last round: ``up`` (1: the peer was within ``link_range_m``; every link before the first round)
and ``room`` (the share of its map's network bytes the link carries in one round: 1 without a capacity
limit, 0 when down).

``instances`` (only with ``action_form="instances"``): (N - 1, M, ``INSTANCE_FEATURES``) float32 in [0, 1],
peers in action order, M = ``instance_slots`` slots each. Slot m of peer k holds the m-th of the agent's
shareable instances in the link's priority order (those the peer lacks first, then by change since the
peer's copy, largest first, then those the peer maps too, then by id); the action's entry for that slot
sends that instance. Per slot:

- ``present``: 1 when the slot holds an instance (an agent with fewer than M has empty slots, all zeros);
- ``lacks``: the peer holds no copy of it (as the link acknowledged);
- ``change``: relative L2 change since the peer's copy (1 when it lacks it);
- ``copy_age``: rounds since its copy reached the peer, divided by ``AGE_SCALE`` (1: never or that long ago);
- ``shared``: the peer maps it too (one of the peer's own instances matched it over the Instance
  Collaborative Graph): the instances parameter consistency (eq. 12) works on;
- ``confidence``: its confidence (eq. 1-2);
- ``size``: its box diagonal / ``SIZE_SCALE_M`` (at most 1);
- ``age``: rounds since it appeared in the agent's map / ``AGE_SCALE`` (at most 1);
- ``bytes``: its network's bytes as a share of what the link carries in a round (of its whole map's network
  bytes without a capacity limit), at most 1.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

MAP_CHANNELS = ("map_height", "map_decided", "observed", "received", "own_path", "peer_poses")
LINK_FEATURES = ("holds", "up_to_date", "change", "since_params", "since_rays", "since_received", "held_from_peer",
                 "bytes_share")
AGENT_FEATURES = ("budget_left", "progress")
LINK_STATE = ("up", "room")
INSTANCE_FEATURES = ("present", "lacks", "change", "copy_age", "shared", "confidence", "size", "age", "bytes")
OBSERVATION_VERSION = 2
"""1: ``map`` and ``comm``; 2 (2026-12-06): ``links`` added, and ``instances`` with the instance action form.
``map`` and ``comm`` are unchanged, so a policy that reads only them (the shipped network) reads either."""
OBSERVATION_VERSIONS = tuple(range(1, OBSERVATION_VERSION + 1))
"""Every observation version there has been: a policy file records one of these (another was written by a
newer release, or by hand)."""
AGE_SCALE = 16.0
"""Rounds after which an age feature reads 1."""
SIZE_SCALE_M = 4.0
"""Box diagonal at which ``size`` reads 1."""


def comm_size(num_agents: int) -> int:
    """Length of the ``comm`` vector for a team of ``num_agents``."""
    return (num_agents - 1) * len(LINK_FEATURES) + len(AGENT_FEATURES)


def num_agents_of(comm_length: int) -> int:
    """The team size a ``comm`` vector of this length belongs to (ValueError if none)."""
    peers, rest = divmod(comm_length - len(AGENT_FEATURES), len(LINK_FEATURES))
    if rest or peers < 1:
        raise ValueError(f"a comm vector of length {comm_length} fits no team: it must be (N - 1) x "
                         f"{len(LINK_FEATURES)} + {len(AGENT_FEATURES)}")
    return peers + 1


def link_feature(observation: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """(N - 1,) values of one ``LINK_FEATURES`` entry, peers in action order."""
    comm = np.asarray(observation["comm"])
    peers = num_agents_of(comm.shape[-1]) - 1
    return comm[..., :peers * len(LINK_FEATURES)].reshape(*comm.shape[:-1], peers, len(LINK_FEATURES))[
        ..., LINK_FEATURES.index(name)]


def agent_feature(observation: Mapping[str, np.ndarray], name: str) -> np.ndarray | float:
    """One ``AGENT_FEATURES`` entry."""
    comm = np.asarray(observation["comm"])
    return comm[..., comm.shape[-1] - len(AGENT_FEATURES) + AGENT_FEATURES.index(name)]


def age_feature(rounds_done: int, last_round: int | None) -> float:
    """An age in [0, 1]: 0 for a message of the round just done, 1 for none or ``AGE_SCALE`` rounds back."""
    if last_round is None:
        return 1.0
    return float(min(max(rounds_done - 1 - last_round, 0) / AGE_SCALE, 1.0))


def link_state(observation: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """(N - 1,) values of one ``LINK_STATE`` entry, peers in action order."""
    return np.asarray(observation["links"])[..., LINK_STATE.index(name)]


def instance_feature(observation: Mapping[str, np.ndarray], name: str) -> np.ndarray:
    """(N - 1, M) values of one ``INSTANCE_FEATURES`` entry, peers in action order, slots in priority order."""
    if "instances" not in observation:
        raise KeyError("this observation has no 'instances' entry: make the env with action_form='instances'")
    return np.asarray(observation["instances"])[..., INSTANCE_FEATURES.index(name)]
