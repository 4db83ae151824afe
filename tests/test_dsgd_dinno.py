"""DSGD's Metropolis weights (symmetric, doubly stochastic, agreed through ``DegreeMessage``) and DiNNO /
DSGD acting only on vectors that arrived this round (``ConsistencyConfig.missing_edges``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from mapping.team import Channel, ChannelConfig, ConsistencyConfig, MessageError, Team, TeamConfig
from mapping.team.consistency import ConsistencyPairs, PairKey, degree_listing, metropolis_mix, metropolis_weights
from mapping.team.messages import DegreeMessage, from_bytes, to_bytes
from mapping.team.team import RoundPlan
from tests.team_helpers import rewrite_header


def _random_pairing(rng: np.random.Generator, n: int, objects: int = 6) -> list[list[PairKey]]:
    """Each agent's pairs: agent k's instance (10 k + g) sees object g with probability 0.7; a pair (k, j, g)
    exists at k when both see g, except that k misses it now and then (e.g. a frame it has not agreed
    on yet) and k sometimes pairs a second instance of its own with j's (alignment is not one-to-one)."""
    sees = rng.random((n, objects)) < 0.7
    keys: list[list[PairKey]] = [[] for _ in range(n)]
    for k in range(n):
        for j in range(n):
            if j == k:
                continue
            for g in range(objects):
                if sees[k, g] and sees[j, g] and rng.random() < 0.85:
                    keys[k].append(PairKey(j, 10 * k + g, 10 * j + g))
                if sees[k, g] and sees[j, g] and rng.random() < 0.1:  # a duplicate of mine paired with j's
                    keys[k].append(PairKey(j, 10 * k + g + 100, 10 * j + g))
    return keys


@pytest.mark.parametrize("seed", range(20))
def test_metropolis_weights_are_symmetric_and_doubly_stochastic_for_any_delivery(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    keys = _random_pairing(rng, n)
    delivered = rng.random((n, n)) < rng.uniform(0.2, 1.0)  # listing i -> j arrived
    listings = {k: {j: degree_listing(keys[j], k) for j in range(n) if j != k and delivered[j, k]} for k in range(n)}
    acknowledged = {k: {j for j in range(n) if j != k and delivered[k, j]} for k in range(n)}
    nodes = sorted({(k, key.own_id) for k in range(n) for key in keys[k]}
                   | {(key.peer, key.peer_id) for k in range(n) for key in keys[k]})
    index = {node: i for i, node in enumerate(nodes)}
    w = np.zeros((len(nodes), len(nodes)))
    for k in range(n):
        for key, weight in zip(keys[k], metropolis_weights(keys[k], listings[k], acknowledged[k])):
            if weight > 0:
                assert delivered[k, key.peer] and delivered[key.peer, k]  # both listings arrived
                w[index[(k, key.own_id)], index[(key.peer, key.peer_id)]] += weight
    np.fill_diagonal(w, 1.0 - w.sum(axis=1))
    assert np.allclose(w, w.T)  # both ends weigh every edge alike
    assert np.allclose(w.sum(axis=0), 1.0) and np.allclose(w.sum(axis=1), 1.0)
    assert np.all(np.diag(w) > 0) and np.all(w >= 0)


def test_metropolis_weights_follow_the_listed_degrees():
    # agent 0 pairs its instance 5 with agent 1's 7 and agent 2's 9; agent 1 pairs 7 with 0's 5 only
    keys = [PairKey(1, 5, 7), PairKey(2, 5, 9)]
    assert degree_listing(keys, 1) == ([5], [7], [2])
    listing_1 = ([7], [5], [1])
    assert metropolis_weights(keys, {1: listing_1}, {1, 2}) == [1.0 / 3.0, 0.0]  # 2 listed nothing back
    assert metropolis_weights(keys, {1: listing_1}, {2}) == [0.0, 0.0]  # my listing never reached 1
    assert metropolis_weights(keys, {1: ([7], [6], [1])}, {1}) == [0.0, 0.0]  # 1 pairs 7 with another of mine
    pairs = ConsistencyPairs(torch.tensor([0]), torch.tensor([[4.0, 4.0]]), torch.tensor([1.0 / 3.0]))
    mixed = metropolis_mix(torch.tensor([[1.0, 1.0], [0.0, 2.0]]), pairs)
    assert torch.allclose(mixed, torch.tensor([[2.0, 2.0], [0.0, 2.0]]))
    with pytest.raises(ValueError, match="Metropolis weights"):
        metropolis_mix(torch.zeros(1, 2), ConsistencyPairs(torch.tensor([0]), torch.zeros(1, 2)))


def _edit(header: dict, name: str, field: int, value) -> dict:
    next(entry for entry in header["arrays"] if entry[0] == name)[field] = value
    return header


def test_degree_messages_round_trip_and_malformed_ones_are_refused():
    message = DegreeMessage(2, 0, 4, np.array([3, 8]), np.array([1, 1]), np.array([2, 1]))
    back = from_bytes(to_bytes(message))
    assert isinstance(back, DegreeMessage) and (back.sender, back.receiver, back.round) == (2, 0, 4)
    assert back.own_ids.tolist() == [3, 8] and back.peer_ids.tolist() == [1, 1] and back.degrees.tolist() == [2, 1]
    ids = np.array([1, 2])
    bad = {"lengths": (DegreeMessage(2, 0, 4, ids, ids, np.array([1])), None, "lengths"),
           "negative": (DegreeMessage(2, 0, 4, -ids, ids, ids), None, "non-negative integers"),
           "zero degree": (DegreeMessage(2, 0, 4, ids, ids, 0 * ids), None, ">= 1"),
           "floats": (message, lambda h: _edit(h, "own_ids", 1, "float32"), "non-negative integers"),
           "missing": (message, lambda h: {**h, "arrays": h["arrays"][:2]}, "degrees is missing")}
    for m, change, match in bad.values():
        data = to_bytes(m) if change is None else rewrite_header(to_bytes(m), change)
        with pytest.raises(MessageError, match=match):
            from_bytes(data)
    channel = Channel(3)
    d = channel.transmit(message)
    assert d.status == "delivered" and d.kind == "degrees" and channel.bytes_sent[2] == len(to_bytes(message))


def _team(tiny_world, consistency: ConsistencyConfig, success: float = 1.0) -> Team:
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.world.stream import world_streams, world_vocabulary

    streams = world_streams(tiny_world, seed=0, segmentation_errors=False)
    mapping = replace(mapping_config("tiny"), iterations_per_keyframe=2, refit_steps=10)
    config = TeamConfig(mapping=mapping, frames_per_round=4, consistency=consistency)
    return Team(streams, config, world_vocabulary(tiny_world), seed=0, channel=ChannelConfig(success), device="cpu")


def test_dsgd_rounds_mix_with_the_same_weight_at_both_ends_of_every_edge(tiny_world):
    team = _team(tiny_world, ConsistencyConfig(algorithm="dsgd", iterations=1, rays_per_pose=32, cross_rendering=False),
                 success=0.8)
    mixed_rounds, listings, lossy_rounds = 0, 0, 0
    while not team.done:
        report = team.round(RoundPlan.always(team.num_agents))
        kinds = [d.kind for d in report.deliveries]
        listings += kinds.count("degrees")
        lossy_rounds += report.dropped > 0
        a, b = team.members
        for member, other in ((a, b), (b, a)):
            for key, weight in member.mixing_weights.items():
                mirror = PairKey(member.index, key.peer_id, key.own_id)
                assert other.mixing_weights.get(mirror) == weight  # symmetric W
                assert 0 < weight <= 0.5
        mixed_rounds += bool(a.mixing_weights)
    assert listings > 0 and mixed_rounds > 0 and lossy_rounds > 0  # listings travelled, some rounds mixed, some lost


def test_dsgd_sends_listings_only_where_the_plan_sent_parameters(tiny_world):
    team = _team(tiny_world, ConsistencyConfig(algorithm="dsgd", iterations=1, cross_rendering=False, missing_edges="last"))
    team.round(RoundPlan.always(2))
    first = team.round(RoundPlan.always(2))
    assert [d.kind for d in first.deliveries].count("degrees") == 2  # both ends listed their pairs
    quiet = team.round(RoundPlan.never(2))  # the stale form still holds pairs, but nothing was sent
    assert quiet.deliveries == [] and all(not m.mixing_weights for m in team.members)
    one_way = RoundPlan(np.array([[False, True], [False, False]]), np.zeros((2, 2), bool))
    report = team.round(one_way)  # 0 -> 1 only: agent 0 lists to 1, agent 1's parameters never reached 0
    assert [(d.sender, d.kind) for d in report.deliveries] == [(0, "params"), (0, "degrees")]
    assert all(not m.mixing_weights for m in team.members)  # an edge with one end is not mixed


def test_dinno_skips_an_edge_whose_vector_did_not_arrive_this_round(tiny_world):
    never = RoundPlan.never(2)
    for missing in ("skip", "last"):
        team = _team(tiny_world, ConsistencyConfig(algorithm="dinno", iterations=1, cross_rendering=False,
                                                   missing_edges=missing))
        team.round(RoundPlan.always(2))
        team.round(RoundPlan.always(2))
        m = team.members[0]
        assert m.held_at[1] and set(m.held_at[1].values()) == {1}  # every vector arrived in round 1
        before = {k: v.clone() for k, v in m.duals.items()}
        report = team.round(never)  # nothing arrives in round 2
        terms = report.losses[m.name].consistency
        after = m.duals
        if missing == "skip":
            assert terms.pairs == 0 and all(torch.equal(before[k], after[k][:len(before[k])]) for k in before)
        else:  # the stale form keeps pushing the duals from the last vectors held
            assert terms.pairs > 0 and any(not torch.equal(before[k], after[k][:len(before[k])]) for k in before)
    with pytest.raises(ValueError, match="missing_edges"):
        ConsistencyConfig(missing_edges="sometimes")
