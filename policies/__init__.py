"""Communication policies: scripted and learned. Of ``openmulti_env`` they import only the env's observation
contract, ``openmulti_env.environment.layout`` (a leaf: numpy and the standard library); nothing of ``mapping``.

``make_policy(name, num_agents)`` gives any policy by name (``policies.scripted.POLICY_FORMS``); every
policy is called as ``policy(observations, infos, step) -> {agent: action}`` and says whether it reads
observations (``reads_observations``: the layout is ``openmulti_env.environment.layout``) and, when not
``entries``, its action form (``action_form``: ``instances`` for ``instance_novelty``).
"""

from __future__ import annotations

from policies.scripted import POLICY_FORMS, PolicyError, PolicySpec, ScriptedPolicy, parse_policy

__all__ = ["POLICY_FORMS", "PolicyError", "PolicySpec", "ScriptedPolicy", "make_policy", "parse_policy"]


def make_policy(name: str | PolicySpec, num_agents: int, seed: int = 0):
    """The policy called ``name`` for a team of ``num_agents`` (PolicyError naming the problem)."""
    spec = parse_policy(name) if isinstance(name, str) else name
    if spec.rule == "novelty":
        from policies.novelty import NoveltyPolicy  # noqa: PLC0415

        policy = NoveltyPolicy(spec.settings["novelty"])
    elif spec.rule == "instance_novelty":
        from policies.instance_novelty import InstanceNoveltyPolicy  # noqa: PLC0415

        policy = InstanceNoveltyPolicy(spec.settings["instance_novelty"])
    elif spec.rule in ("learned", "file"):
        from policies.learned import LearnedPolicy  # noqa: PLC0415

        policy = LearnedPolicy.load(spec.settings["path"], num_agents, seed if spec.settings["act"] == "sample" else None)
    else:
        return ScriptedPolicy(spec, num_agents, seed)
    policy.spec = spec
    return policy
