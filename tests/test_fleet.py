"""The fleet-batched learner (``mapping.model.fleet``, ``Team(learner="fleet")``): the same maps and bytes as every
agent training on its own, whatever the iteration counts; bad input refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from mapping.model.agent import MappingAgent
from mapping.model.fleet import fleet_train, joint_evaluation
from mapping.team import ConsistencyConfig, RoundPlan, Team, TeamConfig


def _team(tiny_world, learner: str, algorithm: str) -> Team:
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.world.stream import world_streams, world_vocabulary

    streams = world_streams(tiny_world, seed=0, segmentation_errors=False)
    mapping = replace(mapping_config("tiny"), iterations_per_keyframe=2, refit_steps=10)
    consistency = ConsistencyConfig(algorithm=algorithm, iterations=2, rays_per_pose=64,
                                    local_consensus=algorithm == "consensus")
    config = TeamConfig(mapping=mapping, frames_per_round=4, consistency=consistency)
    return Team(streams, config, world_vocabulary(tiny_world), seed=0, device="cpu", learner=learner)


def _maps(team: Team) -> dict:
    return {(m.index, name): bank.params.detach().clone() for m in team.members for name, bank in m.mapper.banks.items()}


@pytest.mark.parametrize("algorithm", ["consensus", "dsgd"])
def test_a_fleet_round_gives_the_maps_and_bytes_of_per_agent_rounds(tiny_world, algorithm):
    plans = [RoundPlan.always(2), RoundPlan(np.array([[False, True], [False, False]]), np.zeros((2, 2), bool)),
             RoundPlan.always(2)]
    apart, fleet = _team(tiny_world, "per_agent", algorithm), _team(tiny_world, "fleet", algorithm)
    for plan in plans:
        a, b = apart.round(plan), fleet.round(plan)
        assert a.bytes_sent == b.bytes_sent and a.delivered == b.delivered and a.keyframes == b.keyframes
        assert [s.instances for s in a.agents] == [s.instances for s in b.agents]
        for name in a.losses:  # eq. 8-11, eq. 12's local term, the consistency objective: each agent's own
            la, lb = a.losses[name], b.losses[name]
            assert lb.data == pytest.approx(la.data, rel=1e-5) and lb.local_parameter == pytest.approx(
                la.local_parameter, rel=1e-5, abs=1e-9)
            assert (la.consistency.loss is None) == (lb.consistency.loss is None)
            if la.consistency.loss is not None:
                assert lb.consistency.loss == pytest.approx(la.consistency.loss, rel=1e-5)
            assert lb.consistency.pairs == la.consistency.pairs
    maps_apart, maps_fleet = _maps(apart), _maps(fleet)
    assert maps_apart.keys() == maps_fleet.keys()
    assert sum(p.shape[0] for p in maps_apart.values()) > 4  # several instances were learned
    for key, params in maps_apart.items():
        assert maps_fleet[key].shape == params.shape
        torch.testing.assert_close(maps_fleet[key], params, rtol=1e-5, atol=1e-6)
    assert [m.mapper.steps for m in fleet.members] == [m.mapper.steps for m in apart.members]


def _trained_pair(tiny_world) -> list[MappingAgent]:
    """Two agents that each took two rounds of their own stream (instances of both banks)."""
    team = _team(tiny_world, "per_agent", "none")
    team.round(RoundPlan.never(2))
    team.round(RoundPlan.never(2))
    return [m.mapper for m in team.members]


def _copy(agent: MappingAgent) -> MappingAgent:
    twin = MappingAgent(agent.config, agent.is_structure, device="cpu", seed=agent.seed, agent_index=agent.agent_index)
    twin.keyframes = agent.keyframes
    twin.restore(agent.state())
    return twin


def test_fleet_train_runs_each_agents_own_count_of_steps(tiny_world):
    agents = _trained_pair(tiny_world)
    alone = [_copy(a) for a in agents]
    together = [_copy(a) for a in agents]
    expected = [alone[0].train(3), alone[1].train(5)]  # the second agent goes on alone for two steps
    got = fleet_train(together, [3, 5])
    assert got == pytest.approx(expected, rel=1e-5)
    idle = _copy(agents[1])
    assert fleet_train([_copy(agents[0]), idle], [2, 0])[1] == 0.0 and idle.steps == agents[1].steps
    torch.testing.assert_close(idle.banks["object"].params, agents[1].banks["object"].params, rtol=0, atol=0)
    assert [a.steps for a in together] == [a.steps for a in alone]
    for mine, ref in zip(together, alone):
        for name in ref.banks:
            torch.testing.assert_close(mine.banks[name].params.detach(), ref.banks[name].params.detach(),
                                       rtol=1e-5, atol=1e-6)
            torch.testing.assert_close(mine.optimisers[name].exp_avg, ref.optimisers[name].exp_avg, rtol=1e-5, atol=1e-7)


def test_joint_evaluation_stacks_same_kind_banks_and_splits_back(tiny_world):
    agents = [_copy(a) for a in _trained_pair(tiny_world)]
    batches = [a.training_batches() for a in agents]
    assert all(len(b) == 2 for b in batches)  # objects and structure
    outputs = joint_evaluation(agents, batches)
    with torch.no_grad():
        for agent, own, outs in zip(agents, batches, outputs):
            for batch, out in zip(own, outs):
                ref = agent.banks[batch.bank](batch.positions, batch.rows)
                assert out.occupancy.shape == ref.occupancy.shape and out.colour.shape == ref.colour.shape
                torch.testing.assert_close(out.occupancy, ref.occupancy, rtol=1e-5, atol=1e-6)


def test_fleet_bad_input_is_refused(tiny_world):
    agents = [_copy(a) for a in _trained_pair(tiny_world)]
    with pytest.raises(ValueError, match="2 agents but 1 iteration counts"):
        fleet_train(agents, [1])
    with pytest.raises(ValueError, match=">= 0"):
        fleet_train(agents, [1, -1])
    with pytest.raises(ValueError, match="twice"):
        fleet_train([agents[0], agents[0]], [1, 1])
    with pytest.raises(ValueError, match="2 agents but 3 extra losses"):
        fleet_train(agents, [1, 1], [None] * 3)
    streams = [object(), object()]
    with pytest.raises(ValueError, match="learner must be one of"):
        Team(streams, TeamConfig(), None, learner="batched")
    with pytest.raises(ValueError, match="cannot train members in processes"):
        Team(streams, TeamConfig(), None, learner="fleet", processes="ray")
