"""Instance-level messages, links that come and go, the instance action form and ``instance_novelty``."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.team import ChannelConfig, RoundPlan
from mapping.team.links import closest_approach_m, links_in_range, round_limits
from mapping.team.team import PlanError
from openmulti_env import parallel_env
from openmulti_env.environment.observation import slot_instances
from openmulti_env.experiment import ConfigError
from policies import PolicyError, make_policy, parse_policy
from policies.instance_novelty import InstanceNoveltyPolicy, InstanceNoveltySettings, last_round
from openmulti_env.environment.layout import AGENT_FEATURES, INSTANCE_FEATURES, LINK_FEATURES, LINK_STATE


@pytest.fixture(scope="module")
def cache(shared_world_cache):
    return str(shared_world_cache)  # the run's one world cache: worlds other modules built are read, not built


def test_range_and_capacity_make_the_round_links():
    positions = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [5.0, 0.0, 1.0]])
    up = links_in_range(positions, 2.0)
    assert up.tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    assert links_in_range(positions, None).sum() == 6
    limits = round_limits(positions, 2.0, 0.5e6)
    assert limits.room_bytes[0, 1] == 0.5e6 and limits.room_bytes[0, 2] == 0.0
    assert limits.as_dict()["up"][0] == [0, 1, 0]
    paths = [np.array([[0.0, 0, 0], [1, 0, 0]]), np.array([[3.0, 0, 0], [1.5, 0, 0], [1.5, 0, 0]])]
    assert closest_approach_m(paths)[0, 1] == pytest.approx(0.5)


@pytest.mark.parametrize("bad", [dict(link_range_m=0.0), dict(link_range_m=float("nan")), dict(link_mb_per_round=-1.0),
                                 dict(link_range_m=True)])
def test_bad_link_limits_are_refused(bad):
    with pytest.raises(ValueError, match="must be a finite number > 0"):
        ChannelConfig(**bad)


def test_a_success_probability_per_link(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, link_success=[[1.0, 0.0], [1.0, 1.0]])
    e.reset(seed=0)
    for _ in range(2):
        *_, infos = e.step({a: np.ones(2, np.int8) for a in e.agents})
    assert infos["agent_0"]["messages_delivered"] == 0 and infos["agent_0"]["messages_dropped"] == 2
    assert infos["agent_1"]["messages_delivered"] == 2
    for bad, message in (([[1.0, 0.5, 1.0]] * 3, "the team has 2 agents"), ([[1.0, 2.0], [1.0, 1.0]], "probabilities"),
                         ([1.0, 0.5], "channel.link_success takes a list of a list")):
        with pytest.raises(ValueError, match=message):
            parallel_env(preset="rl_tiny", cache_dir=cache, link_success=bad)


def test_bernoulli_and_a_success_per_link_are_refused_together(cache):
    with pytest.raises(ValueError, match="one success probability for every link"):
        parallel_env(preset="rl_tiny", cache_dir=cache, policy="bernoulli:0.5", link_success=[[1, 1], [1, 1]])


def test_a_resumed_team_observes_the_links_of_its_last_round(cache, tmp_path):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, link_range_m=0.01)
    e.reset(seed=0)
    e.step({a: np.ones(2, np.int8) for a in e.agents})
    e.team.save(tmp_path / "team.pt")
    before = [s.links_up for s in e.team.snapshots()]
    assert before[0] == {1: False}
    f = parallel_env(preset="rl_tiny", cache_dir=cache, link_range_m=0.01)
    f.reset(seed=0)
    f.team.load(tmp_path / "team.pt")
    assert [s.links_up for s in f.team.snapshots()] == before


def test_plan_instance_choices_are_checked():
    full = ~np.eye(2, dtype=bool)
    assert RoundPlan(full, full, {(0, 1): [3, 4]}).validate(2).send_instances == {(0, 1): (3, 4)}
    with pytest.raises(PlanError, match="distinct agents"):
        RoundPlan(full, full, {(0, 0): [1]}).validate(2)
    with pytest.raises(PlanError, match="instance ids"):
        RoundPlan(full, full, {(0, 1): [-1]}).validate(2)
    with pytest.raises(PlanError, match="send_new"):
        RoundPlan(full, full, {}, np.ones((3, 3))).validate(2)


@pytest.mark.parametrize("bad, message", [(dict(action_form="slots"), "env.action_form must be one of"),
                                          (dict(action_form="instances", instance_slots=0), "env.instance_slots"),
                                          (dict(link_range_m=-2.0), "link_range_m")])
def test_bad_env_settings_name_the_problem(bad, message, cache):
    with pytest.raises((ConfigError, ValueError), match=message):
        parallel_env(preset="rl_tiny", cache_dir=cache, **bad)


def _run(e, act):
    obs, _ = e.reset(seed=3)
    reports, step = [], 0
    while e.agents:
        obs, rewards, terminations, truncations, infos = e.step({a: act(obs[a], step) for a in e.agents})
        reports.append(e._last_report)
        step += 1
    return reports, infos, terminations, truncations


def test_every_slot_and_the_new_entry_send_what_the_entries_form_sends(cache):
    """The instance form with everything chosen is the entries form's `always`, to the byte and the map."""
    entries = parallel_env(preset="rl_tiny", cache_dir=cache, comm_cost_per_mb=0.0, max_cycles=5)
    full, full_infos, _, _ = _run(entries, lambda o, s: np.ones(2, np.int8))
    e = parallel_env(preset="rl_tiny", cache_dir=cache, comm_cost_per_mb=0.0, action_form="instances",
                     instance_slots=64, max_cycles=5)
    assert e.action_space("agent_0").shape == (66,)
    assert e.observation_space("agent_0")["instances"].shape == (1, 64, len(INSTANCE_FEATURES))
    chosen, chosen_infos, _, _ = _run(e, lambda o, s: np.ones(66, np.int8))
    assert [r.bytes_sent for r in chosen] == [r.bytes_sent for r in full]
    assert [i["completion_ratio"] for i in chosen_infos.values()] == [i["completion_ratio"] for i in full_infos.values()]


def test_one_slot_sends_one_instance_and_the_rest_wait(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, action_form="instances", instance_slots=4)
    obs, _ = e.reset(seed=3)
    e.step({a: np.zeros(6, np.int8) for a in e.agents})  # round 0: nothing observed yet, nothing sent
    obs, *_ = e.step({a: np.zeros(6, np.int8) for a in e.agents})
    present = obs["agent_0"]["instances"][0, :, INSTANCE_FEATURES.index("present")]
    lacks = obs["agent_0"]["instances"][0, :, INSTANCE_FEATURES.index("lacks")]
    assert present.sum() == 4 and lacks.sum() == 4  # more instances than slots, none held by the peer
    first = e.team.members[0].instance_priority(1, [e._snapshots[0].instance_links[1][0].instance_id])[0]
    action = np.zeros(6, np.int8)
    action[0] = 1
    e.step({"agent_0": action, "agent_1": np.zeros(6, np.int8)})
    assert set(e.team.members[0].sent_vectors[1]) == {first}
    obs = e._observe(0)
    assert obs["comm"][LINK_FEATURES.index("holds")] > 0  # the peer holds the one instance sent
    assert first not in slot_instances(e._snapshots[0], 2, 4)[0]  # lacked ones come first: it left the slots
    assert obs["instances"][0, :, INSTANCE_FEATURES.index("lacks")].sum() == 4


def test_slot_instance_ids_name_what_each_slot_holds(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, action_form="instances", instance_slots=32)
    e.reset(seed=3)
    e.step({a: np.zeros(e.action_space(a).shape, np.int8) for a in e.agents})
    obs, *_ = e.step({a: np.zeros(e.action_space(a).shape, np.int8) for a in e.agents})
    ids = e.slot_instance_ids("agent_0")
    present = obs["agent_0"]["instances"][0, :, INSTANCE_FEATURES.index("present")] > 0
    assert ids.shape == (1, 32) and present.any() and not present.all()
    assert np.array_equal(ids[0] >= 0, present)  # an id where a slot holds an instance, -1 where it is empty
    assert set(ids[0][present]) <= set(e.team.members[0].mapper.live_ids())
    entries = parallel_env(preset="rl_tiny", cache_dir=cache)
    entries.reset(seed=3)
    with pytest.raises(ValueError, match="action_form='instances'"):
        entries.slot_instance_ids("agent_0")
    with pytest.raises(KeyError, match="unknown agent"):
        e.slot_instance_ids("agent_9")


def test_a_link_capacity_bounds_every_message_and_what_waits_goes_later(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, link_mb_per_round=0.15)
    reports, infos, terminations, truncations = _run(e, lambda o, s: np.ones(2, np.int8))
    assert all(r.bytes_per_link.max() <= 0.15e6 for r in reports)
    assert all(r.links.as_dict()["room_bytes"][0][1] == 150000 for r in reports)
    member = e.team.members[0]
    sent_rounds = sorted(set(member.sent_rounds[1].values()))
    assert len(sent_rounds) > 3  # what did not fit in one round went in later ones
    assert all(terminations.values()) and not any(truncations.values())  # the paths' end is termination
    links = e._observe(0)["links"]
    assert links[0, LINK_STATE.index("up")] == 1.0 and 0 < links[0, LINK_STATE.index("room")] < 1


def test_a_link_out_of_range_carries_nothing_and_costs_nothing(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, link_range_m=0.01)
    reports, infos, _, _ = _run(e, lambda o, s: np.ones(2, np.int8))
    assert all(i["bytes_sent_total"] == 0 for i in infos.values())
    assert all(not r.links.up.any() for r in reports)
    assert e._observe(0)["links"][0].tolist() == [0.0, 0.0]


def test_the_horizon_truncates_and_the_paths_end_terminates(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, max_cycles=2)
    e.reset(seed=0)
    for _ in range(2):
        _, _, terminations, truncations, _ = e.step({a: np.zeros(2, np.int8) for a in e.agents})
    assert not any(terminations.values()) and all(truncations.values())


def _observation(slots: int, lacks, change, shared, up=1.0, progress=0.5, holds=1.0):
    n_peers = 1
    instances = np.zeros((n_peers, slots, len(INSTANCE_FEATURES)), np.float32)
    instances[0, :len(lacks), INSTANCE_FEATURES.index("present")] = 1
    instances[0, :len(lacks), INSTANCE_FEATURES.index("lacks")] = lacks
    instances[0, :len(lacks), INSTANCE_FEATURES.index("change")] = change
    instances[0, :len(lacks), INSTANCE_FEATURES.index("shared")] = shared
    comm = np.zeros(n_peers * len(LINK_FEATURES) + len(AGENT_FEATURES), np.float32)
    comm[LINK_FEATURES.index("holds")] = holds
    comm[-len(AGENT_FEATURES) + AGENT_FEATURES.index("budget_left")] = 1.0
    comm[-len(AGENT_FEATURES) + AGENT_FEATURES.index("progress")] = progress
    return {"comm": comm, "links": np.array([[up, 1.0]], np.float32), "instances": instances}


def test_instance_novelty_sends_what_the_peer_lacks_what_moved_and_what_it_maps_too():
    policy = InstanceNoveltyPolicy(InstanceNoveltySettings(change=0.1, shared=0.02, final=1.0))
    obs = _observation(5, lacks=[1, 0, 0, 0], change=[1.0, 0.2, 0.05, 0.05], shared=[0, 0, 1, 0])
    action = policy.act(obs, step=1)
    assert action.tolist() == [1, 1, 1, 0, 0, 1, 1]  # 5 slots, then new instances, then rays
    # a link down last round may be up this one, and a down link costs nothing: it still asks
    assert policy.act(_observation(5, [1], [1.0], [0], up=0.0), step=1).tolist() == [1, 0, 0, 0, 0, 1, 1]
    last = _observation(5, lacks=[0, 0], change=[0.05, 0.0], shared=[0, 0], progress=0.75)
    assert last_round(last, step=3)  # 3 rounds read 3/4 of the path: the 4th is the last
    assert not last_round(_observation(5, [0], [0.0], [0], progress=0.5), step=2)
    assert not last_round(_observation(5, [0], [0.0], [0], progress=0.0), step=0)
    final = InstanceNoveltyPolicy(InstanceNoveltySettings(change=0.1, final=0.01)).act(last, step=3)
    assert final[:2].tolist() == [1, 0]  # the final push sends what moved at all
    late = InstanceNoveltyPolicy(InstanceNoveltySettings.parse("change=0.1,start=2"))
    assert not late.act(obs, step=1).any() and late.act(obs, step=2).tolist() == action.tolist()  # silent before round 2


def test_instance_novelty_names_and_bad_settings():
    assert parse_policy("instance_novelty:change=0.2,rays=never").settings["instance_novelty"].change == 0.2
    assert make_policy("instance_novelty", 4).action_form == "instances"
    for bad in ("instance_novelty:change=-1", "instance_novelty:speed=2", "instance_novelty:rays=sometimes",
                "instance_novelty:change=x", "instance_novelty:after=-1", "instance_novelty:start=-2"):
        with pytest.raises(PolicyError):
            parse_policy(bad)
    with pytest.raises(KeyError, match="action_form='instances'"):
        InstanceNoveltyPolicy().act({"comm": np.zeros(10, np.float32), "links": np.ones((1, 2), np.float32)})


def test_coplanar_faces_render_the_same_in_any_insertion_order():
    """pyrender keeps nodes in sets: the draw order of faces two instances share follows their names."""
    import trimesh

    from openmulti_env.world.gl import load_pyrender

    pyrender = load_pyrender()
    renderer = pyrender.OffscreenRenderer(32, 32)
    images = []
    for order in (("a", "b"), ("b", "a")):
        scene = pyrender.Scene()
        nodes = {}
        for name in order:
            nodes[name] = scene.add(pyrender.Mesh.from_trimesh(trimesh.creation.box((1.0, 1.0, 0.01))), name=name)
        pose = np.eye(4)
        pose[2, 3] = 2.0
        scene.add(pyrender.IntrinsicsCamera(30, 30, 16, 16), pose=pose)
        seg, _ = renderer.render(scene, flags=pyrender.RenderFlags.SEG,
                                 seg_node_map={nodes["a"]: (255, 0, 0), nodes["b"]: (0, 255, 0)})
        images.append(seg.copy())
    renderer.delete()
    np.testing.assert_array_equal(images[0], images[1])


def test_the_round_form_is_one_decision_for_every_peer(cache):
    e = parallel_env(preset="rl_tiny", cache_dir=cache, num_agents=3, action_form="round", max_cycles=2)
    assert e.action_space("agent_0").shape == (1,)
    e.reset(seed=0)
    e.step({"agent_0": np.ones(1, np.int8), "agent_1": np.zeros(1, np.int8), "agent_2": np.zeros(1, np.int8)})
    report = e._last_report
    assert report.bytes_per_link[0, 1] > 0 and report.bytes_per_link[0, 2] > 0
    assert report.bytes_per_link[1:].sum() == 0
