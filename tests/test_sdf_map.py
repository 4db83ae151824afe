"""MACIM's scene SDF (the published form of the global baselines): network, samples, losses, training."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from mapping.model.agent import MappingAgent, SdfBatch
from mapping.model.agent_config import MappingConfig
from mapping.data import Frame, Intrinsics
from mapping.model.field import STRUCTURE_FIELD, InstanceFieldBank
from mapping.model.fleet import fleet_train
from mapping.model.optim import AdamConfig, StackedAdam
from mapping.model.sdf_field import SdfFieldBank
from mapping.model.sdf_loss import SdfConfig, batch_bounds, eikonal_loss, sdf_loss, sdf_samples, sdf_step_loss
from mapping.model.sdf_network import SDF_ENCODING_DIM, init_sdf_params, sdf_param_layout
from mapping.team.global_map import published_mapping

SMALL = SdfConfig(width=32, rays=64, n_stratified=6, n_surface=3, iterations_first=2, iterations_after=4)


def _bank(config: SdfConfig = SMALL, half: float = 2.0) -> SdfFieldBank:
    field = replace(STRUCTURE_FIELD, hidden_width=config.width, encoding_scale=1.0 / (half * config.encoding_per_m),
                    occupancy_sharpness=config.occupancy_sharpness)
    bank = SdfFieldBank(field, config, device="cpu")
    bank.add_instances(1, torch.tensor([[-half] * 3]), torch.tensor([[half] * 3]),
                       generator=torch.Generator().manual_seed(0), frame_centre=torch.zeros(1, 3),
                       frame_half=torch.tensor([half]))
    return bank


def test_the_network_has_macims_shape():
    """E = 255 inputs, width 256: in, two hidden, skip with the encoding, two hidden, out (460,033 parameters)."""
    assert SDF_ENCODING_DIM == 255
    assert sum(int(np.prod(shape)) for _, shape in sdf_param_layout(256)) == 460_033
    a = init_sdf_params(64, 2, torch.Generator().manual_seed(3))
    b = init_sdf_params(64, 2, torch.Generator().manual_seed(3))
    assert torch.equal(a, b) and not torch.equal(a[0], a[1])


def test_occupancy_is_one_half_on_the_zero_level_set_and_colour_is_grey():
    bank = _bank()
    points = torch.rand(1, 50, 3) * 2 - 1
    sdf = bank.sdf(points, torch.tensor([0]))
    out = bank(points, torch.tensor([0]))
    assert torch.allclose(out.occupancy, torch.sigmoid(-SMALL.occupancy_sharpness * sdf), atol=1e-6)
    assert torch.all((out.occupancy > 0.5) == (sdf < 0))
    assert torch.all(out.colour == 0.5)


def test_samples_lie_on_their_rays_between_the_near_bound_and_behind_the_surface():
    origins = torch.zeros(10, 3)
    directions = torch.nn.functional.pad(torch.rand(10, 2) - 0.5, (0, 1), value=1.0)  # unit camera z
    depth = torch.linspace(0.5, 3.0, 10)
    s = sdf_samples(origins, directions, depth, SMALL, torch.Generator().manual_seed(0))
    assert s.depths.shape == (10, SMALL.n_stratified + SMALL.n_surface) and s.positions.shape == (10, 9, 3)
    assert torch.equal(s.depths[:, 0], depth)
    assert torch.all(s.depths >= SMALL.min_depth_m - 1e-6)
    assert torch.all(s.depths <= depth[:, None] + SMALL.behind_surface_m + 1e-6)
    assert torch.allclose(s.positions, directions[:, None] * s.depths[..., None])
    assert torch.all(s.bounds[:, 0] == 0)  # the surface sample itself
    behind = s.depths > depth[:, None]
    assert torch.all(s.bounds[behind] <= 0) and torch.all(s.bounds[~behind] >= 0)


def test_bounds_are_distances_to_the_nearest_surface_point_of_any_ray():
    surface = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    positions = torch.tensor([[[0.0, 0.0, 0.5], [0.0, 0.0, 1.2]], [[1.0, 0.0, 0.2], [0.9, 0.0, 1.0]]])
    depths = torch.tensor([[0.5, 1.2], [0.2, 1.0]])
    bounds = batch_bounds(positions, surface, depths, torch.tensor([1.0, 1.0]))
    assert torch.allclose(bounds, torch.tensor([[0.5, -0.2], [0.8, 0.1]]), atol=1e-6)


def test_the_sdf_loss_follows_isdf():
    cfg = SdfConfig()
    sdf = torch.tensor([0.05, 1.5, 0.5, -1.0, 0.0])
    bounds = torch.tensor([0.1, 1.0, 1.0, 1.0, 0.0])
    loss = sdf_loss(sdf, bounds, cfg)
    expected = torch.tensor([
        0.05 * cfg.truncation_weight,  # truncation band: weighted L1 to the bound
        0.5,  # free space above the bound: relu(sdf - bound)
        0.0,  # free space below the bound and positive: no loss
        cfg.loss_cap,  # free space, negative: exp(5) - 1, capped
        0.0])
    assert torch.allclose(loss, expected, atol=1e-5)
    gradient = torch.tensor([[0.0, 0.0, 2.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    eik = eikonal_loss(gradient, torch.tensor([0.5, 0.5, 0.05]), cfg)
    assert torch.allclose(eik, torch.tensor([cfg.eikonal_weight, 0.0, 0.0]))


def test_a_scene_sdf_learns_a_wall_from_depth_rays():
    """A wall at z = 1.5 m seen head on: after training, the SDF crosses zero at the wall and is about the
    distance to it in front."""
    torch.manual_seed(0)
    bank = _bank()
    optimiser = StackedAdam(bank, AdamConfig(lr=SMALL.lr, weight_decay=SMALL.weight_decay))
    generator = torch.Generator().manual_seed(1)
    rows = torch.tensor([0])
    for _ in range(250):
        xy = torch.rand(SMALL.rays, 2, generator=generator) - 0.5
        directions = torch.cat([xy, torch.ones(SMALL.rays, 1)], dim=1)
        origins = torch.zeros(SMALL.rays, 3)
        samples = sdf_samples(origins, directions, torch.full((SMALL.rays,), 1.5), SMALL, generator)
        loss = sdf_step_loss(lambda p: bank.sdf(p.reshape(1, -1, 3), rows).reshape(p.shape[:-1]), samples, SMALL)
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
    probe = torch.tensor([[[0.1, -0.1, 1.5], [0.0, 0.0, 1.0], [0.0, 0.1, 1.2]]])
    with torch.no_grad():
        sdf = bank.sdf(probe, rows)[0]
    assert abs(float(sdf[0])) < 0.05
    assert 0.3 < float(sdf[1]) < 0.7 and 0.15 < float(sdf[2]) < 0.45


def _frames(n: int = 3) -> list[Frame]:
    intrinsics = Intrinsics(32, 24, 30.0, 30.0, 16.0, 12.0)
    frames = []
    for i in range(n):
        pose = np.eye(4)
        pose[0, 3] = 0.1 * i
        frames.append(Frame(np.full((24, 32, 3), 128, np.uint8), np.full((24, 32), 1.5, np.float32), pose,
                            intrinsics, np.ones((24, 32), np.int32), index=i))
    return frames


def _agent(seed: int = 0) -> MappingAgent:
    mapping = published_mapping(MappingConfig(), (0.0, 0.0, 1.0, 2.0), SMALL)
    return MappingAgent(mapping, is_structure=lambda _: True, device="cpu", seed=seed)


def test_an_agent_with_the_published_form_trains_its_scene_sdf_on_every_frame():
    agent = _agent()
    assert isinstance(agent.banks["structure"], SdfFieldBank)
    assert agent.optimisers["structure"].config.lr == SMALL.lr
    assert agent.config.keyframe_every == 1 and agent.config.iterations_per_keyframe == SMALL.iterations_per_frame
    for frame in _frames():
        assert agent.ingest(frame)
    (batch,) = agent.training_batches()
    assert isinstance(batch, SdfBatch) and batch.samples.depths.shape == (SMALL.rays, 9)
    before = agent.banks["structure"].params.detach().clone()
    loss = agent.train(3)
    assert np.isfinite(loss) and not torch.equal(before, agent.banks["structure"].params.detach())


def test_the_fleet_trains_scene_sdfs_as_each_agent_alone():
    pairs = [(_agent(s), _agent(s)) for s in (0, 1)]
    for a, b in pairs:
        for frame in _frames():
            a.ingest(frame)
            b.ingest(frame)
    losses = fleet_train([a for a, _ in pairs], [3, 2])
    for (a, b), n, loss in zip(pairs, [3, 2], losses):
        assert loss == pytest.approx(b.train(n), rel=1e-4)
        assert torch.allclose(a.banks["structure"].params, b.banks["structure"].params, atol=1e-5)


def test_checkpoints_of_one_network_kind_are_refused_by_the_other(tmp_path):
    agent = _agent()
    for frame in _frames(1):
        agent.ingest(frame)
    state = agent.banks["structure"].state_dict()
    plain = InstanceFieldBank(replace(STRUCTURE_FIELD, hidden_width=SMALL.width), device="cpu")
    with pytest.raises(ValueError, match="holds a 'sdf' bank"):
        plain.load_state_dict(state)
    plain.add_instances(1, torch.zeros(1, 3), torch.ones(1, 3))
    with pytest.raises(ValueError, match="vMAP occupancy bank, this is a MACIM SDF bank"):
        _bank().load_state_dict(plain.state_dict())


def test_bad_sdf_settings_are_refused():
    with pytest.raises(ValueError, match="SdfConfig.rays must be >= 1"):
        SdfConfig(rays=0)


def test_the_published_form_sets_macims_budget_and_rho():
    from dataclasses import replace

    from openmulti_env.experiment import experiment, resolved_team

    tree = experiment("fast", global_map=True, global_form="published", cross_rendering=False)
    mapping = published_mapping(tree.team.mapping, (2.0, 2.0, 1.5, 2.6))
    assert mapping.structure_sdf == SdfConfig() and mapping.structure_width == 256
    assert mapping.keyframe_every == 1 and mapping.iterations_per_keyframe == 3
    assert mapping.iterations_after_stream == 200 and mapping.iterations_first_keyframe == 200
    assert mapping.structure_encoding_scale == pytest.approx(1.0 / (2.6 * SdfConfig().encoding_per_m))
    team = resolved_team(tree, mapping)
    assert team.consistency.rho == 0.3 and team.global_map
    # a full path gets exactly 3 iterations per frame before the 200 after it
    assert team.min_local_steps == tree.world.path.frames_per_agent * 3
    crossing = replace(tree, team=replace(tree.team, consistency=replace(tree.team.consistency, cross_rendering=True)))
    with pytest.raises(ValueError, match="Cross Rendering .* MACIM's scene SDF"):
        resolved_team(crossing, mapping)


def test_an_unknown_global_form_is_refused(tmp_path):
    from openmulti_env.runs.reproduce.methods import Method
    from openmulti_env.runs.run import run

    with pytest.raises(ValueError, match="global_map.form must be one of .* got 'macim'"):
        run("tiny", 2, "always", "tiny", 0, tmp_path, global_map=True, global_form="macim", progress=False)
    with pytest.raises(ValueError, match="unknown global_form 'x'"):
        Method("m", "M", "d", global_map=True, global_form="x")


def test_a_study_budget_reaches_the_published_map(tmp_path):
    from openmulti_env.experiment import experiment
    from openmulti_env.runs.run import map_structure, run
    from openmulti_env.world import World

    longer = SdfConfig(iterations_after=2000)
    tree = experiment("tiny", agents=1, global_map=True, global_form="published", cross_rendering=False, sdf=longer)
    world = World.build("tiny", seed=0, config=tree.world)
    try:
        mapping, info = map_structure(world, tree)
        assert mapping.iterations_after_stream == 2000 and info["iterations_after"] == 2000
        default, info = map_structure(world, experiment("tiny", agents=1, global_map=True, global_form="published"))
        assert default.iterations_after_stream == 200 and info["iterations_after"] == 200
    finally:
        world.close()
    with pytest.raises(ValueError, match="global map only"):
        run("tiny", 1, "never", "tiny", 0, tmp_path, progress=False, shared_global_init=False)


def test_softplus_is_isdfs_with_exact_first_and_second_derivatives():
    from mapping.model.sdf_network import softplus

    x = torch.linspace(-3, 3, 20001, dtype=torch.float64, requires_grad=True)
    y = softplus(x)
    (g,) = torch.autograd.grad(y.sum(), x, create_graph=True)
    (h,) = torch.autograd.grad(g.sum(), x)
    s = torch.sigmoid(100 * x)
    assert torch.allclose(y, torch.nn.functional.softplus(x, beta=100), atol=1e-9)
    assert torch.allclose(g, s, atol=1e-12) and torch.allclose(h, 100 * s * (1 - s), atol=1e-9)
    small = (torch.randn(30, dtype=torch.float64) * 0.05).requires_grad_()
    assert torch.autograd.gradgradcheck(softplus, (small,))


def test_a_published_row_is_keyed_on_macims_settings_and_other_rows_are_not():
    from openmulti_env.runs.reproduce.runner import run_settings
    from openmulti_env.runs.reproduce.tables import RunSpec

    published = run_settings(RunSpec("macim_global", "room0", 0, 4), "fast", False, None)
    assert published["published_map"]["rays"] == 200 and published["published_map"]["iterations_first"] == 200
    assert "published_map" not in run_settings(RunSpec("macim_global_equal_compute", "room0", 0, 4), "fast", False, None)
    assert "published_map" not in run_settings(RunSpec("openmulti", "room0", 0, 4), "fast", False, None)
    # every global row is keyed on whether its agents start alike; instance-level rows keep their keys
    for method in ("macim_global", "dinerf_global_equal_compute", "openmulti_global"):
        assert run_settings(RunSpec(method, "room0", 0, 4), "fast", False, None)["shared_global_init"] is True
    assert "shared_global_init" not in run_settings(RunSpec("openmulti", "room0", 0, 4), "fast", False, None)


def test_a_step_whose_rays_have_no_depth_trains_nothing_and_does_not_fail():
    agent = _agent()
    frame = _frames(1)[0]
    agent.ingest(Frame(frame.rgb, np.zeros_like(frame.depth), frame.pose, frame.intrinsics, frame.instance))
    assert agent.training_batches() == []
    before = agent.banks["structure"].params.detach().clone()
    assert agent.train(2) == 0.0 and torch.equal(before, agent.banks["structure"].params.detach())
