"""The collaborative learner: messages, channel, consistency algorithms, eq. 13, arrival, rounds."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from mapping.model.field import OBJECT_FIELD, InstanceFieldBank
from mapping.model.optim import AdamConfig, StackedAdam
from mapping.model.render import RayBundle
from mapping.team import (Channel, ChannelConfig, ConsistencyConfig, InstancePayload, MessageError, ParameterMessage,
                          PlanError, RayMessage, RoundPlan, Team, TeamConfig, from_bytes, to_bytes)
from mapping.team.arrival import InstanceView, align_arrivals
from tests.team_helpers import CountingStream, rewrite_header, tiny_team
from mapping.team.consistency import (ConsistencyPairs, consensus_penalty, dinno_dual_update, dinno_penalty,
                                      metropolis_mix)
from mapping.team.cross_rendering import instance_render_consistency_loss, peer_render_targets, render_consistency_loss


def _payload(iid=3, cloud=True, dtype=np.float32):
    rng = np.random.default_rng(iid)
    return InstancePayload(iid, "object", rng.normal(size=50).astype(dtype), np.zeros(3, np.float32),
                           np.ones(3, np.float32), np.full(3, 0.5, np.float32), 0.75, 1, 2, "a red mug",
                           rng.normal(size=8).astype(dtype), 0.4, rng.normal(size=(20, 3)).astype(np.float32) if cloud else None)


# ---- messages and channel ----------------------------------------------------------------------------
def test_messages_round_trip_and_bytes_are_their_serialised_length():
    msg = ParameterMessage(0, 1, 5, [_payload(3), _payload(4, cloud=False, dtype=np.float16)], degree=2)
    back = from_bytes(to_bytes(msg))
    assert back.sender == 0 and back.receiver == 1 and back.round == 5 and back.degree == 2
    assert np.array_equal(back.instances[0].params, msg.instances[0].params)
    assert back.instances[1].params.dtype == np.float16 and back.instances[1].cloud is None
    assert np.array_equal(back.instances[0].cloud, msg.instances[0].cloud) and back.instances[0].caption == "a red mug"
    rays = RayMessage(1, 0, 5, np.stack([np.eye(4)] * 2).astype(np.float32), (100.0, 100.0, 80.0, 60.0, 160, 120), 7, 32)
    channel = Channel(2)
    d1, d2 = channel.transmit(msg), channel.transmit(rays)
    assert d1.bytes == len(to_bytes(msg)) and d2.bytes == len(to_bytes(rays))
    assert channel.bytes_sent.tolist() == [d1.bytes, d2.bytes] and channel.link_bytes[0, 1] == d1.bytes
    assert len(to_bytes(ParameterMessage(0, 1, 5, [_payload(3, dtype=np.float16)]))) < len(to_bytes(
        ParameterMessage(0, 1, 5, [_payload(3)])))


def test_corrupt_messages_are_refused():
    data = to_bytes(ParameterMessage(0, 1, 0, [_payload()]))
    with pytest.raises(MessageError, match="magic"):
        from_bytes(b"junk" + data)
    with pytest.raises(MessageError, match="truncated"):
        from_bytes(data[:-10])




def _set_array(name: str, field: int, value):
    def change(header):
        next(entry for entry in header["arrays"] if entry[0] == name)[field] = value
        return header
    return change


@pytest.mark.parametrize("name, field, value, error", [
    ("0.cloud", 2, [-1, 3], "0.cloud: shape \\[-1, 3\\] is not a list of at most 4 non-negative integers"),
    ("0.params", 1, "object", "0.params: dtype 'object' cannot travel"),
    ("0.box", 2, [3, 3], "0.box: shape \\(3, 3\\), expected \\(9\\)"),
    ("0.params", 3, -4, "0.params: offset -4"),
])
def test_malformed_messages_are_refused_naming_the_field(name, field, value, error):
    data = to_bytes(ParameterMessage(0, 1, 0, [_payload(cloud=True)]))
    with pytest.raises(MessageError, match=error):
        from_bytes(rewrite_header(data, _set_array(name, field, value)))


def test_non_finite_parameters_and_bad_scalars_are_refused():
    bad = _payload()
    bad.params = bad.params.copy()
    bad.params[0] = np.nan
    with pytest.raises(MessageError, match="0.params: expected finite floats"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 0, [bad])))
    data = to_bytes(ParameterMessage(0, 1, 0, [_payload()]))
    with pytest.raises(MessageError, match="field sender"):
        from_bytes(rewrite_header(data, lambda h: {**h, "scalars": {**h["scalars"], "sender": "x"}}))
    with pytest.raises(MessageError, match="poses: shape"):
        rays = to_bytes(RayMessage(0, 1, 0, np.eye(4, dtype=np.float32)[None], (1.0, 1.0, 0.5, 0.5, 2, 2), 3, 4))
        from_bytes(rewrite_header(rays, _set_array("poses", 2, [2, 8])))


def test_the_channel_counts_a_malformed_message_as_dropped_and_never_applies_it():
    channel = Channel(2)
    data = rewrite_header(to_bytes(ParameterMessage(0, 1, 0, [_payload()])), _set_array("0.box", 2, [3, 3]))
    with pytest.warns(UserWarning, match="refused: array 0.box"):
        d = channel.transmit_bytes(0, 1, "params", data)
    assert d.status == "dropped" and d.message is None
    assert channel.bytes_sent[0] == len(data) and channel.bytes_received[1] == 0


def test_channel_drops_by_probability_and_enforces_the_budget():
    msg = ParameterMessage(0, 1, 0, [_payload()])
    size = len(to_bytes(msg))
    lossy = Channel(2, success_probability=0.0)
    d = lossy.transmit(msg)
    assert d.status == "dropped" and d.message is None and lossy.bytes_sent[0] == size and lossy.bytes_received[1] == 0
    budget = Channel(2, budget_bytes=1.5 * size)
    assert budget.transmit(msg).status == "delivered"
    assert budget.transmit(msg).status == "over_budget" and budget.bytes_sent[0] == size
    draws = [Channel(2, 0.5, seed=3).transmit(msg).status for _ in range(1)]
    assert draws == [Channel(2, 0.5, seed=3).transmit(msg).status]
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        Channel(2, success_probability=1.5)


# ---- eq. 12: the three algorithms ------------------------------------------------------------------
def _pairs(rows, vectors, peer_deg, own_deg):
    """Pairs with the Metropolis weight 1 / (max(own, peer degree) + 1) of each."""
    weights = [1.0 / (max(p, o) + 1.0) for p, o in zip(peer_deg, own_deg)]
    return ConsistencyPairs(torch.tensor(rows), torch.tensor(vectors, dtype=torch.float32), torch.tensor(weights))


def test_dinno_and_dsgd_updates_match_hand_computed_values():
    theta = torch.tensor([[1.0, 2.0], [0.0, -1.0]])
    pairs = _pairs([0, 0], [[3.0, 0.0], [1.0, 4.0]], [1, 2], [2, 2])
    # DiNNO dual: p_0 += rho * ((1-3, 2-0) + (1-1, 2-4)) = 0.5 * (-2, 0) ; row 1 untouched
    duals = dinno_dual_update(torch.zeros(2, 2), theta, pairs, rho=0.5)
    assert torch.allclose(duals, torch.tensor([[-1.0, 0.0], [0.0, 0.0]]))
    # penalty: theta.p + rho * sum ||theta - (theta0 + theta_j)/2||^2 with theta0 = theta
    # mids (2, 1) and (1, 3): ||(-1, 1)||^2 + ||(0, -1)||^2 = 3; linear -1 -> -1 + 0.5 * 3
    assert torch.allclose(dinno_penalty(theta, theta, duals, pairs, 0.5), torch.tensor(0.5))
    # consensus: (rho/2) * 3
    assert torch.allclose(consensus_penalty(theta, theta, pairs, 0.3), torch.tensor(0.45))
    # DSGD Metropolis: W = 1/(max(2,1)+1) = 1/3 and 1/(max(2,2)+1) = 1/3; W_00 = 1/3
    mixed = metropolis_mix(theta, pairs)
    assert torch.allclose(mixed[0], torch.tensor([(1 + 3 + 1) / 3, (2 + 0 + 4) / 3]))
    assert torch.equal(mixed[1], theta[1])


def test_consensus_pulls_two_agents_parameters_together():
    torch.manual_seed(0)
    a = torch.nn.Parameter(torch.randn(1, 20))
    b = torch.nn.Parameter(torch.randn(1, 20) + 3.0)
    start = float((a - b).detach().norm())
    for _ in range(50):
        pa = _pairs([0], b.detach().tolist(), [1], [1])
        pb = _pairs([0], a.detach().tolist(), [1], [1])
        la = consensus_penalty(a, a.detach(), pa, 0.3)
        lb = consensus_penalty(b, b.detach(), pb, 0.3)
        ga, gb = torch.autograd.grad(la, a)[0], torch.autograd.grad(lb, b)[0]
        with torch.no_grad():
            a -= 0.5 * ga
            b -= 0.5 * gb
    assert float((a - b).detach().norm()) < 0.05 * start


# ---- eq. 13 ----------------------------------------------------------------------------------------
def _plane_bank(seed: int, train_steps: int) -> InstanceFieldBank:
    """One instance in the box [-0.5, 0.5]^2 x [1, 2]: trained to be solid below z = 1.5."""
    g = torch.Generator().manual_seed(seed)
    bank = InstanceFieldBank(OBJECT_FIELD, "cpu")
    bank.add_instances(1, torch.tensor([[-0.5, -0.5, 1.0]]), torch.tensor([[0.5, 0.5, 2.0]]), generator=g)
    opt = StackedAdam(bank, AdamConfig(lr=3e-3))
    for _ in range(train_steps):
        x = torch.rand(1, 512, 3, generator=g) * torch.tensor([1.0, 1.0, 1.0]) + torch.tensor([-0.5, -0.5, 1.0])
        target = (x[..., 2] > 1.5).float()
        loss = (bank(x, with_colour=False).occupancy - target).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
    return bank


def _down_rays(n: int = 256) -> RayBundle:
    """Rays from z = 0 looking along +z through the box (unit z, so t is the depth)."""
    g = torch.Generator().manual_seed(1)
    xy = torch.rand(n, 2, generator=g) * 0.8 - 0.4
    return RayBundle(torch.cat([xy, torch.zeros(n, 1)], 1), torch.tensor([[0.0, 0.0, 1.0]]).expand(n, 3).contiguous())


def test_render_consistency_fits_a_blind_zone_where_parameter_consistency_alone_does_not():
    peer = _plane_bank(0, 400)  # the peer saw the surface
    rays = _down_rays()
    with torch.no_grad():
        from mapping.model.render import CompositeConfig, composite_instances
        target = composite_instances([peer], rays, CompositeConfig(samples_per_box=32), with_colour=False).depth

    def blind_error(use_render: bool) -> float:
        me = _plane_bank(5, 0)  # never saw it: a random network in the same frame
        opt = StackedAdam(me, AdamConfig(lr=3e-3))
        pairs = _pairs([0], peer.params.detach().tolist(), [1], [1])
        for _ in range(60):
            anchor = me.params.detach().clone()
            loss = consensus_penalty(me.params, anchor, pairs, 0.3)
            if use_render:
                loss = loss + render_consistency_loss([me], peer_render_targets([peer], None, rays, samples_per_box=32),
                                                      samples_per_box=32)
            opt.zero_grad()
            loss.backward()
            opt.step()
        with torch.no_grad():
            depth = composite_instances([me], rays, CompositeConfig(samples_per_box=32), with_colour=False).depth
        return float((depth - target).abs().mean())

    parameter_only, with_render = blind_error(False), blind_error(True)
    assert with_render < 0.05, with_render  # within 5 cm of the peer's surface
    assert parameter_only > 3 * with_render, (parameter_only, with_render)


def test_instance_form_of_eq13_fits_a_blind_zone_and_keeps_free_space_free():
    peer = _plane_bank(0, 400)  # the peer saw the surface at z = 1.5
    rays = _down_rays()
    labels = [torch.tensor([7])]
    me = _plane_bank(5, 0)  # never saw it
    opt = StackedAdam(me, AdamConfig(lr=3e-3))
    g = torch.Generator().manual_seed(3)
    for _ in range(60):
        targets = peer_render_targets([peer], labels, rays, {7: 7})
        loss, used = instance_render_consistency_loss([me], labels, targets, generator=g), len(targets)
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert used == len(rays)
    with torch.no_grad():
        from mapping.model.render import CompositeConfig, composite_instances
        depth = composite_instances([me], rays, CompositeConfig(samples_per_box=64), with_colour=False).depth
        column = torch.stack([torch.zeros(20), torch.zeros(20), torch.linspace(1.0, 1.35, 20)], 1)
        in_front = me(column[None], with_colour=False).occupancy
    assert float((depth - 1.5).abs().mean()) < 0.05
    assert float(in_front.max()) < 0.1  # no occluder in front of the peer's surface


def test_eq13_skips_rays_whose_surface_i_observed():
    peer, me = _plane_bank(0, 200), _plane_bank(5, 0)
    rays, labels = _down_rays(64), [torch.tensor([0])]
    everywhere = lambda points: torch.ones(points.shape[0], dtype=torch.bool)  # noqa: E731
    targets = peer_render_targets([peer], labels, rays, {0: 0}, observed=everywhere)
    assert len(targets) == 0 and float(instance_render_consistency_loss([me], labels, targets)) == 0.0
    targets = peer_render_targets([peer], None, rays, observed=everywhere)
    assert len(targets) == 0 and float(render_consistency_loss([me], targets)) == 0.0


def test_eq13_trusts_a_surface_i_saw_in_front_of_the_peers():
    """The peer's map misses a surface at z = 1.5 that I observed (its ray runs on to z = 1.8): that ray is
    not mine to learn from, since following it would erase what I saw."""
    me = _plane_bank(0, 400)  # solid from z = 1.5

    class Far:  # the peer's map: a surface at z = 1.8 only
        bound_min, bound_max, num_instances = torch.tensor([[-0.5, -0.5, 1.0]]), torch.tensor([[0.5, 0.5, 2.0]]), 1

        def query(self, points, rows, with_colour=True, block_size=4096):
            from mapping.model.field import FieldOutput
            return FieldOutput((points[:, 2] > 1.8).float(), None)

    rays, labels = _down_rays(64), [torch.tensor([0])]
    saw_the_plane = lambda p: (p[:, 2] - 1.5).abs() < 0.05  # noqa: E731
    assert len(peer_render_targets([Far()], labels, rays, {0: 0}, [me], saw_the_plane)) == 0
    assert len(peer_render_targets([Far()], labels, rays, {0: 0}, [me], None)) == 64  # without the test: all


def test_an_unaligned_peer_surface_does_not_empty_my_instance_there():
    """The peer's surface is its instance 3, which alignment tied to none of mine: my instance 0 may well
    be that surface (alignment missed it), so only the space in front of it is taught to be free."""
    peer, me = _plane_bank(0, 400), _plane_bank(1, 400)  # both know the surface
    rays = _down_rays()
    opt = StackedAdam(me, AdamConfig(lr=3e-3))
    g = torch.Generator().manual_seed(3)
    for _ in range(40):
        targets = peer_render_targets([peer], [torch.tensor([3])], rays, {})
        loss = instance_render_consistency_loss([me], [torch.tensor([0])], targets, generator=g)
        opt.zero_grad()
        loss.backward()
        opt.step()
    with torch.no_grad():
        behind = torch.stack([torch.zeros(20), torch.zeros(20), torch.linspace(1.55, 1.9, 20)], 1)
        assert float(me(behind[None], with_colour=False).occupancy.min()) > 0.9


# ---- alignment on arrival --------------------------------------------------------------------------
def _box_cloud(lo, hi, step=0.02):
    axes = [np.arange(a, b + 1e-9, step) for a, b in zip(lo, hi)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    on_surface = np.any([(np.isclose(g[:, k], lo[k]) | np.isclose(g[:, k], hi[k])) for k in range(3)], axis=0)
    return g[on_surface]


def _unit(v):
    v = np.asarray(v, np.float32)
    return v / np.linalg.norm(v)


def test_arrival_merges_two_halves_of_one_sofa_but_not_a_mug_against_a_book():
    sofa_feature, mug, book = _unit([1, 0, 0, 0.1]), _unit([0, 1, 0, 0]), _unit([0, 0, 1, 0])
    left, right = _box_cloud((0, 0, 0), (1.0, 0.8, 0.8)), _box_cloud((1.0, 0, 0), (2.0, 0.8, 0.8))
    own = {1: InstanceView(left, sofa_feature, 0.5), 2: InstanceView(right, sofa_feature, 0.5)}
    whole = np.concatenate([left, right])
    [d] = align_arrivals(own, {9: InstanceView(whole, sofa_feature, 0.9)})
    assert d.kind == "match" and d.own_id == 1 and d.merged == (2,) and d.take_meaning
    mug_cloud, book_cloud = _box_cloud((0, 0, 0), (0.1, 0.1, 0.12)), _box_cloud((0.1, 0, 0), (0.3, 0.2, 0.05))
    own = {1: InstanceView(mug_cloud, mug, 0.6), 2: InstanceView(book_cloud, book, 0.6)}
    coarse = np.concatenate([mug_cloud, book_cloud])  # a peer's under-segmented mask of both
    [d] = align_arrivals(own, {4: InstanceView(coarse, _unit(mug + book), 0.3)})
    assert d.kind == "match" and d.merged == () and not d.take_meaning
    [d] = align_arrivals(own, {5: InstanceView(_box_cloud((3, 3, 0), (3.2, 3.2, 0.2)), mug, 0.9)})
    assert d.kind == "adopt"


# ---- rounds on the tiny world ----------------------------------------------------------------------




def test_bad_plans_get_a_clear_error(tiny_world):
    team, _ = tiny_team(tiny_world)
    with pytest.raises(PlanError, match="must be \\(2, 2\\)"):
        team.round(RoundPlan(np.ones((3, 3), bool), np.zeros((2, 2), bool)))
    with pytest.raises(PlanError, match="self-links"):
        team.round(RoundPlan(np.eye(2, dtype=bool), np.zeros((2, 2), bool)))
    with pytest.raises(PlanError, match="booleans"):
        team.round(RoundPlan(np.full((2, 2), 0.5), np.zeros((2, 2), bool)))


def test_rounds_are_causal_exchange_adopts_and_a_dropped_message_changes_nothing(tiny_world):
    team, streams = tiny_team(tiny_world)
    silent, _ = tiny_team(tiny_world)
    lossy = Team([CountingStream(s.inner) for s in streams], team.config, team.members[0].vocabulary, seed=0,
                 channel=ChannelConfig(success_probability=0.0), device="cpu")
    for r in range(2):
        report = team.round(RoundPlan.always(2))
        silent.round(RoundPlan.never(2))
        dropped = lossy.round(RoundPlan.always(2))
        for s in streams:  # never a frame beyond the round's
            assert s.max_read < (r + 1) * team.config.frames_per_round
        assert report.delivered == 4 and sum(report.bytes_sent) == int(report.bytes_per_link.sum()) > 0
        assert dropped.dropped == 4 and dropped.delivered == 0
    # what arrived was adopted or matched, and is rendered by the receiver
    a0 = team.members[0]
    assert a0.held[1] and set(a0.matches[1].values()) <= set(a0.mapper.slots)
    # dropped messages leave every receiver exactly as if nothing had been sent
    for m_lossy, m_silent in zip(lossy.members, silent.members):
        assert not m_lossy.held
        for name in m_lossy.mapper.banks:
            assert torch.equal(m_lossy.mapper.banks[name].params, m_silent.mapper.banks[name].params)


def test_team_checkpoint_round_trip(tiny_world, tmp_path):
    team, _ = tiny_team(tiny_world)
    team.round(RoundPlan.always(2))
    path = team.save(tmp_path / "team.pt", extra={"policy": "always"})
    resumed, _ = tiny_team(tiny_world)
    assert resumed.load(path) == {"policy": "always"} and resumed.round_index == 1
    a, b = team.round(RoundPlan.always(2)), resumed.round(RoundPlan.always(2))
    assert a.bytes_sent == b.bytes_sent
    for ma, mb in zip(team.members, resumed.members):
        for name in ma.mapper.banks:
            assert torch.equal(ma.mapper.banks[name].params, mb.mapper.banks[name].params)


def test_an_unknown_form_of_eq13_is_refused_by_name():
    with pytest.raises(ValueError, match="cross_rendering_form 'depth'.*instance"):
        ConsistencyConfig(cross_rendering_form="depth")


@pytest.mark.parametrize("ray_poses", ["current", "mapped"])
def test_ray_messages_carry_the_views_they_are_asked_for(tiny_world, ray_poses):
    team, streams = tiny_team(tiny_world, consistency=ConsistencyConfig(iterations=2, rays_per_pose=64,
                                                                          ray_poses=ray_poses))
    for _ in range(2):
        team.round(RoundPlan.never(2))
    member, per_round = team.members[0], team.config.frames_per_round
    poses = np.stack([streams[0].read(i)[0].pose for i in range(2 * per_round)]).astype(np.float32)
    message = member.ray_message(1, team.round_index, seed=5)
    frames = {int(np.argmin(np.abs(poses - p).sum((1, 2)))) for p in message.poses}
    if ray_poses == "current":  # this round's views
        assert frames <= set(range(per_round, 2 * per_round))
    else:  # views read in earlier rounds, which the sender's map has trained on
        assert frames <= set(range(per_round)) and len(frames) == team.config.consistency.poses_per_message
    assert member.ray_message(1, team.round_index, seed=5).poses.tobytes() == message.poses.tobytes()  # replayable


def _paired_distance(team) -> float:
    """Mean distance between agent 0's parameters and the ones it holds from agent 1, over its pairs."""
    m = team.members[0]
    dists = []
    for name, bank in m.mapper.banks.items():
        pairs, _ = m._pairs(name)
        if len(pairs):
            dists.append((bank.params.detach()[pairs.rows] - pairs.vectors).norm(dim=1))
    return float(torch.cat(dists).mean())


def test_local_consensus_pulls_paired_instances_together_in_the_local_iterations(tiny_world):
    # rho large enough that the pull shows within the few iterations of a tiny run
    rho = 30.0
    plain, _ = tiny_team(tiny_world, consistency=ConsistencyConfig(iterations=2, rays_per_pose=64, rho=rho,
                                                                    local_consensus=False))
    local, _ = tiny_team(tiny_world, consistency=ConsistencyConfig(iterations=2, rays_per_pose=64, rho=rho,
                                                                    local_consensus=True))
    plan = RoundPlan.always(2)
    for _ in range(2):
        plain.round(plan), local.round(plan)
    # the same first round: the penalty only starts once parameters were held
    assert plain.members[0].matches and local.members[0].matches
    plain.round(RoundPlan.never(2)), local.round(RoundPlan.never(2))  # local iterations only, same held vectors
    assert _paired_distance(local) < _paired_distance(plain)


def test_a_lost_first_message_is_sent_again_with_its_clouds(tiny_world):
    # round 0: every parameter message is lost; round 1: all arrive. The receiver must get each
    # instance's cloud then (only a delivered message books what the peer holds), and align them.
    team, _ = tiny_team(tiny_world)
    team.channel.success = np.zeros((2, 2))
    lost = team.round(RoundPlan(~np.eye(2, dtype=bool), np.zeros((2, 2), bool)))
    assert lost.delivered == 0 and lost.dropped == 2
    assert not team.members[0].sent_vectors.get(1) and not team.members[0].sent_cloud_points.get(1)
    team.channel.success = np.ones((2, 2))
    team.round(RoundPlan(~np.eye(2, dtype=bool), np.zeros((2, 2), bool)))
    for m in team.members:
        peer = 1 - m.index
        held = m.held[peer]
        assert held and all(p.cloud is not None for p in held.values())  # every instance came with its cloud
        assert set(m.matches[peer]) == set(held)  # and was aligned (matched or adopted)


def test_each_algorithm_takes_its_own_penalty_weight():
    assert ConsistencyConfig().penalty_rho == 3.0 and ConsistencyConfig(algorithm="dinno").penalty_rho == 0.3
    assert ConsistencyConfig(algorithm="consensus", rho=0.5).penalty_rho == 0.5
    assert ConsistencyConfig(algorithm="dinno", dinno_rho=0.4, rho=9.0).penalty_rho == 0.4
    for bad in ({"rho": -1.0}, {"dinno_rho": float("nan")}):
        with pytest.raises(ValueError, match="rho must be >= 0"):
            ConsistencyConfig(**bad)


def test_a_message_over_budget_books_nothing(tiny_world):
    team, _ = tiny_team(tiny_world, channel=ChannelConfig(budget_mb=1e-5))
    report = team.round(RoundPlan(~np.eye(2, dtype=bool), np.zeros((2, 2), bool)))
    assert report.over_budget == 2 and report.delivered == 0
    for m in team.members:
        assert not m.sent_vectors.get(1 - m.index) and not m.sent_cloud_points.get(1 - m.index)
        assert not m._unacknowledged


def test_merging_a_piece_into_an_instance_without_a_network_keeps_ids_in_step(tiny_world):
    # an arrival can merge my piece (with a network) into an instance seen in no keyframe yet (none):
    # the piece's network must move to the surviving id, never stay alive under a retired one
    team, _ = tiny_team(tiny_world)
    team.round(RoundPlan.never(2))
    m = team.members[0]
    piece = next(i for i in m.mapper.live_ids() if m.mapper.keyframes.has_pixels(i))
    inst = m.fusion.instances[piece]
    target = m.fusion.add_instance(inst.points, inst.caption, inst.caption_feature, inst.confidence)
    assert target not in m.mapper.slots
    m._merge(piece, target)
    assert piece not in m.fusion.instances and piece not in m.mapper.live_ids()
    assert target in m.mapper.live_ids() and m.mapper.keyframes.has_pixels(target)
    assert set(m.mapper.live_ids()) <= set(m.fusion.instances)
    m.parameter_message(1, 1, 1)  # every live instance has its code-book entry


def test_a_global_map_covers_the_boxes_its_peers_mapped(tiny_world):
    """A global map is meshed and cross-rendered inside its box: after an exchange it must reach as far
    as any peer's frames did, not stop where its own frames did."""
    from mapping.team.global_map import GLOBAL_INSTANCE_ID, scene_frame

    team, _ = tiny_team(tiny_world, global_map=True, global_frame=scene_frame(tiny_world.scene.size_m))
    team.round(RoundPlan.never(2))
    boxes = [m.mapper.slots[GLOBAL_INSTANCE_ID].bound for m in team.members]
    union_lo, union_hi = np.minimum(boxes[0].lo, boxes[1].lo), np.maximum(boxes[0].hi, boxes[1].hi)
    assert not all(np.allclose(b.lo, union_lo) and np.allclose(b.hi, union_hi) for b in boxes)  # they differ
    team.round(RoundPlan.always(2))
    for member in team.members:
        bound = member.mapper.slots[GLOBAL_INSTANCE_ID].bound
        assert np.all(bound.lo <= union_lo + 1e-6) and np.all(bound.hi >= union_hi - 1e-6)


def test_a_global_maps_agents_start_from_one_network_and_instance_maps_from_their_own(tiny_world):
    """MACIM deep-copies robot 0's map to every robot: consensus averages networks of one origin."""
    from mapping.team.global_map import GLOBAL_INSTANCE_ID, scene_frame

    def init_states(team):
        return [m.mapper.init_generator.get_state() for m in team.members]

    frame = scene_frame(tiny_world.scene.size_m)
    shared, _ = tiny_team(tiny_world, global_map=True, global_frame=frame)
    own, _ = tiny_team(tiny_world, global_map=True, global_frame=frame, shared_global_init=False)
    instance, _ = tiny_team(tiny_world)
    assert torch.equal(*init_states(shared))
    assert not torch.equal(*init_states(own)) and not torch.equal(*init_states(instance))
    assert torch.equal(init_states(shared)[0], init_states(own)[0])  # agent 0's draw is as before
    shared.round(RoundPlan.never(2))  # each agent's first frame draws the scene network, then trains it
    rows = [m.mapper.slots[GLOBAL_INSTANCE_ID].row for m in shared.members]
    assert rows[0] == rows[1]
    assert torch.equal(*init_states(shared))  # both drew the same network from the same state
    from mapping.team.remote import MemberProcess  # what a Ray actor holds: the seed travels there too

    remote = [MemberProcess(i, 24, shared.config, shared.members[0].vocabulary, 100 + i, "cpu", None, 0)
              for i in range(2)]
    assert torch.equal(*[p.member.mapper.init_generator.get_state() for p in remote])


class _ShortStream(CountingStream):
    """The first ``n`` frames of a stream: a recording shorter than the preset's path."""

    def __init__(self, inner, n):
        super().__init__(inner)
        self.n = n

    def __len__(self):
        return self.n


def test_a_short_stream_trains_the_missing_local_steps_after_its_last_frame_and_a_full_one_does_not(tiny_world):
    full_path = 6 * 2  # tiny: 24 frames, a keyframe every 4th, 2 iterations each in _tiny_team
    short, streams = tiny_team(tiny_world, min_local_steps=full_path)
    short = Team([_ShortStream(s.inner, 8) for s in streams], short.config, short.members[0].vocabulary, seed=0,
                 device="cpu")
    plain, _ = tiny_team(tiny_world)
    plain = Team([_ShortStream(s.inner, 8) for s in streams], plain.config, plain.members[0].vocabulary, seed=0,
                 device="cpu")
    short.round(RoundPlan.never(2))
    plain.round(RoundPlan.never(2))
    assert [m.mapper.steps for m in short.members] == [m.mapper.steps for m in plain.members] == [2, 2]
    assert not short.done
    short.round(RoundPlan.never(2))
    plain.round(RoundPlan.never(2))
    assert short.done and [m.steps_after_stream() for m in short.members] == [8, 8]
    assert [m.mapper.steps for m in short.members] == [full_path, full_path]  # 2 keyframes x 2, then 8 more
    assert [m.mapper.steps for m in plain.members] == [4, 4]
    # streams that end in different rounds: the first to end trains the rest once, not every later round
    uneven = Team([_ShortStream(streams[0].inner, 8), _ShortStream(streams[1].inner, 12)], short.config,
                  short.members[0].vocabulary, seed=0, device="cpu")
    for _ in range(2):
        uneven.round(RoundPlan.never(2))
    assert uneven.members[0].done and not uneven.members[1].done
    assert [m.mapper.steps for m in uneven.members] == [full_path, 4]
    uneven.round(RoundPlan.never(2))
    assert uneven.done and [m.mapper.steps for m in uneven.members] == [full_path, full_path]
    # a stream as long as the preset's path had all its steps: the setting changes nothing
    whole, _ = tiny_team(tiny_world, min_local_steps=full_path, min_keyframes=6)
    base, _ = tiny_team(tiny_world)
    while not whole.done:
        whole.round(RoundPlan.always(2))
        base.round(RoundPlan.always(2))
    for a, b in zip(whole.members, base.members):
        assert a.mapper.steps == b.mapper.steps
        for name in a.mapper.banks:
            assert torch.equal(a.mapper.banks[name].params, b.mapper.banks[name].params)


def test_a_short_stream_takes_keyframes_more_often_down_to_every_frame(tiny_world):
    config = TeamConfig(mapping=replace(TeamConfig().mapping, keyframe_every=5), min_keyframes=24)
    assert [config.keyframe_every(n) for n in (200, 120, 100, 50, 29, 3)] == [5, 5, 4, 2, 1, 1]
    assert replace(config, min_keyframes=0).keyframe_every(29) == 5
    team, streams = tiny_team(tiny_world, min_keyframes=6)  # tiny: a keyframe every 4th of 24 frames
    short = Team([_ShortStream(s.inner, 12) for s in streams], team.config, team.members[0].vocabulary, seed=0,
                 device="cpu")
    assert [m.mapper.config.keyframe_every for m in short.members] == [2, 2]
    assert [m.mapper.config.keyframe_every for m in team.members] == [4, 4]


@pytest.mark.parametrize("name", ["min_local_steps", "min_keyframes"])
def test_minimums_must_not_be_negative(name):
    with pytest.raises(ValueError, match=f"{name} must be >= 0"):
        TeamConfig(**{name: -1})


def test_first_keyframe_and_after_stream_iterations_are_added_once(tiny_world):
    """MACIM's budget: extra iterations in the round of an agent's first keyframe and after its last frame."""
    team, streams = tiny_team(tiny_world)
    mapping = replace(team.config.mapping, iterations_first_keyframe=5, iterations_after_stream=3)
    short = Team([_ShortStream(s.inner, 8) for s in streams], replace(team.config, mapping=mapping),
                 team.members[0].vocabulary, seed=0, device="cpu")
    short.round(RoundPlan.never(2))
    assert [m.mapper.steps for m in short.members] == [2 + 5, 2 + 5]  # one keyframe x 2, then the first's 5
    short.round(RoundPlan.never(2))
    assert short.done and [m.mapper.steps for m in short.members] == [7 + 2 + 3, 7 + 2 + 3]
