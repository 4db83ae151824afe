"""Scripted policies and the env-action -> round-plan conversion."""

import numpy as np
import pytest

from openmulti_env.environment.actions import ActionError, actions_to_plan, peers_of
from policies.scripted import PolicyError, ScriptedPolicy, parse_policy

AGENTS = ["agent_0", "agent_1", "agent_2"]


def test_policy_names_parse_with_their_link_success():
    assert parse_policy("always").rule == "always"
    spec = parse_policy("bernoulli:0.2")
    assert spec.rule == "always" and spec.success_probability == pytest.approx(0.2)
    for bad in ("sometimes", "bernoulli:2", "bernoulli:x"):
        with pytest.raises(PolicyError):
            parse_policy(bad)


def test_scripted_actions_become_the_expected_plans():
    always = actions_to_plan(ScriptedPolicy("always", 3)(None, None, 0), AGENTS)
    assert np.array_equal(always.send_params, ~np.eye(3, dtype=bool)) and np.array_equal(always.share_rays,
                                                                                         always.send_params)
    never = actions_to_plan(ScriptedPolicy("never", 3)(None, None, 0), AGENTS)
    assert not never.send_params.any() and not never.share_rays.any()
    rr = ScriptedPolicy("round_robin", 3)
    for step in range(4):
        plan = actions_to_plan(rr(None, None, step), AGENTS)
        assert plan.send_params.sum(axis=1).tolist() == [1, 1, 1]  # one peer each
        for i in range(3):
            assert plan.send_params[i, peers_of(i, 3)[step % 2]]
    budget = ScriptedPolicy("budget", 3)
    infos = {"agent_0": {"budget_left_mb": 0.0}, "agent_1": {"budget_left_mb": 2.0}, "agent_2": {"budget_left_mb": 1.0}}
    plan = actions_to_plan(budget(None, infos, 0), AGENTS)
    assert plan.send_params.sum(axis=1).tolist() == [0, 2, 2]


def test_bad_actions_name_the_agent_and_the_problem():
    good = ScriptedPolicy("always", 3)(None, None, 0)
    with pytest.raises(ActionError, match="missing \\['agent_2'\\]"):
        actions_to_plan({k: v for k, v in good.items() if k != "agent_2"}, AGENTS)
    with pytest.raises(ActionError, match="unknown \\['agent_9'\\]"):
        actions_to_plan({**good, "agent_9": good["agent_0"]}, AGENTS)
    with pytest.raises(ActionError, match="agent_1: action must have shape \\(4,\\)"):
        actions_to_plan({**good, "agent_1": np.ones(3)}, AGENTS)
    with pytest.raises(ActionError, match="agent_0: action entries must be 0 or 1"):
        actions_to_plan({**good, "agent_0": np.full(4, 2)}, AGENTS)
    with pytest.raises(PolicyError, match="not a fixed schedule"):
        ScriptedPolicy(parse_policy(__file__), 3)
