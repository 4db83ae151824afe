"""Issue 44 end to end: an agent's observed spaces decide where its meshes, views, observation and reward may
hold surface; they travel with the parameters, merge on arrival, survive checkpoints; bad ones are refused."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from mapping.model.agent import MappingAgent
from mapping.model.agent_config import MappingConfig
from mapping.model.banks import param_counts
from mapping.model.observed import FREE, SURFACE, UNKNOWN, ObservedSpace
from mapping.model.topdown import ColumnGrid, column_map
from mapping.evaluate.probe import surface_probe_coverage
from mapping.team import Channel, InstancePayload, MessageError, MessageRules, ParameterMessage, from_bytes, to_bytes


def _book_agent(world, config: MappingConfig, seed: int = 0, steps: int = 150) -> tuple[MappingAgent, int]:
    """An agent that maps only the first book of the tiny scene (other pixels masked out), trained."""
    book = next(i for i in world.scene.instances if i.category == "book")
    torch.manual_seed(seed)
    agent = MappingAgent(config, device="cpu", seed=seed)
    for i in range(len(world.agent_poses[0])):
        frame = world.render(0, i)
        agent.ingest(frame, np.where(frame.instance == book.instance_id, book.instance_id, 0))
    agent.train(steps)
    return agent, book.instance_id


@pytest.fixture(scope="module")
def book_agent(tiny_world):
    return _book_agent(tiny_world, MappingConfig(keyframe_every=2))


def test_keyframes_mark_the_book_surface_where_its_depth_fell_and_free_in_front(tiny_world, book_agent):
    agent, iid = book_agent
    space = agent.observed.get(iid)
    assert space is not None and space.cell_m == MappingConfig().observed_cell_m
    frame = tiny_world.render(0, 0)
    points = frame.backproject(mask=frame.instance == iid)
    assert np.mean(space.state_at(points) == SURFACE) > 0.99  # every depth point of the book lies in a surface cell
    camera = frame.pose[:3, 3]
    towards = (camera - points[::20]) / np.linalg.norm(camera - points[::20], axis=1)[:, None]
    in_front = np.concatenate([points[::20] + d * towards for d in (0.08, 0.12, 0.2, 0.3)])
    inside = np.all((in_front >= space.lo) & (in_front < space.lo + np.array(space.states.shape) * space.cell_m), axis=1)
    assert inside.any() and (space.states == FREE).any()
    assert np.mean(space.state_at(in_front[inside]) > UNKNOWN) > 0.9  # rays to the camera crossed these cells
    assert 0.0 < space.observed_share < 1.0
    bound = agent.slots[iid].bound
    assert np.all(space.lo <= bound.lo + 1e-9) and np.all(space.lo + np.array(space.states.shape) * space.cell_m >= bound.hi)


def test_no_space_at_all_means_no_surface_anywhere_in_mesh_view_observation_and_probe(tiny_world, book_agent):
    agent, iid = book_agent
    assert agent.instance_meshes(), "the book is meshed where it was seen"
    pose = tiny_world.agent_poses[0][0]
    seen = agent.render_view(pose, tiny_world.intrinsics, stride=8)
    assert (seen.depth > 0).any()
    lo, hi = agent.slots[iid].bound.lo, agent.slots[iid].bound.hi
    grid = ColumnGrid(np.arange(lo[0], hi[0], 0.02), np.arange(lo[1], hi[1], 0.02), np.arange(lo[2], hi[2], 0.02))
    assert np.isfinite(column_map(agent, grid).top).any()
    own = agent.observed.spaces[iid]
    try:  # nobody looked anywhere: the same networks draw nothing
        agent.observed.spaces[iid] = ObservedSpace(own.cell_m, own.origin.copy(), np.full_like(own.states, FREE))
        assert agent.instance_meshes() == {}
        blind = agent.render_view(pose, tiny_world.intrinsics, stride=8)
        assert not (blind.depth > 0).any()
        columns = column_map(agent, grid)
        assert not np.isfinite(columns.top).any()
        centre = np.array([(lo + hi) / 2])
        assert not surface_probe_coverage(agent, centre, np.array([[0.0, 0.0, 1.0]])).any()
        agent.observed.spaces[iid] = ObservedSpace(own.cell_m, own.origin.copy(), np.zeros_like(own.states))
        assert column_map(agent, grid).decided.max() == 0.0  # unknown space is undecided, not empty
    finally:
        agent.observed.spaces[iid] = own


def test_mesh_faces_lie_only_near_observed_surface_and_the_setting_off_draws_as_before(tiny_world, book_agent):
    agent, iid = book_agent
    mesh = agent.instance_meshes()[iid]
    assert agent.observed.get(iid).near_surface(mesh.triangles_center).all()
    plain, _ = _book_agent(tiny_world, MappingConfig(keyframe_every=2, observed_cell_m=None))
    assert plain.observed.spaces == {} and plain.export_instance(iid).observed is None
    assert torch.equal(plain.banks["object"].params, agent.banks["object"].params)  # the mask never touches training
    assert len(plain.instance_meshes()[iid].faces) >= len(mesh.faces)


def test_a_space_travels_with_the_instance_merges_on_adoption_and_survives_a_checkpoint(tiny_world, book_agent,
                                                                                        tmp_path):
    agent, iid = book_agent
    exported = agent.export_instance(iid)
    assert exported.observed is not None and np.array_equal(exported.observed.states[exported.observed.states > 0],
                                                            agent.observed.get(iid).states[agent.observed.get(iid).states > 0])
    peer = MappingAgent(agent.config, device="cpu", seed=1)
    peer.adopt_instance(7, exported)
    assert np.array_equal(peer.observed.get(7).states, exported.observed.states)
    peer.adopt_instance(8, exported)
    peer.merge_instances(8, 7)  # a piece joins: its observations with it
    assert 8 not in peer.observed.spaces and peer.observed.get(7).observed_share == exported.observed.observed_share
    path = peer.save(tmp_path / "peer.pt")
    restored = MappingAgent(agent.config, device="cpu", seed=5)
    restored.load(path)
    assert np.array_equal(restored.observed.get(7).states, peer.observed.get(7).states)
    with pytest.raises(ValueError, match="observed_cell_m"):
        MappingConfig(observed_cell_m=0.0)
    with pytest.raises(ValueError, match="observed_ray_stride"):
        MappingConfig(observed_ray_stride=0)


def _payload_with(space: ObservedSpace, lo=np.zeros(3), hi=np.ones(3)) -> InstancePayload:
    rng = np.random.default_rng(0)
    return InstancePayload(3, "object", rng.normal(size=50).astype(np.float32), np.asarray(lo, np.float32),
                           np.asarray(hi, np.float32), np.full(3, 0.5, np.float32), 0.75, 0, 0, "a red mug",
                           rng.normal(size=8).astype(np.float32), 0.4, None, space)


def _box_space(cell_m: float = 0.05, lo=np.zeros(3), hi=np.ones(3)) -> ObservedSpace:
    space = ObservedSpace.empty(cell_m)
    space.cover(np.asarray(lo, float), np.asarray(hi, float))
    space.mark(np.array([[0.5, 0.5, 0.5]]), SURFACE)
    return space


def test_a_space_round_trips_on_the_wire_and_a_mismatched_one_is_refused_naming_the_field():
    rules = MessageRules(observed_cell_m=0.05)
    message = ParameterMessage(0, 1, 0, [_payload_with(_box_space())])
    back = from_bytes(to_bytes(message), rules)
    assert np.array_equal(back.instances[0].observed.states, message.instances[0].observed.states)
    params_only = len(to_bytes(ParameterMessage(0, 1, 0, [replace(message.instances[0], observed=None)])))
    assert len(to_bytes(message)) - params_only < 0.05 * 4 * param_counts(MappingConfig())["object"]  # < 5 % of one
    with pytest.raises(MessageError, match="0.observed: observed space: cell size"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 0, [_payload_with(_box_space(0.1))])), rules)
    shifted = _box_space(lo=np.full(3, 2.0), hi=np.full(3, 3.0))
    with pytest.raises(MessageError, match="0.observed: a grid of cells .* does not match the instance's box"):
        from_bytes(to_bytes(ParameterMessage(0, 1, 0, [_payload_with(shifted)])), rules)
    channel = Channel(2, rules=rules)
    with pytest.warns(UserWarning, match="refused: array 0.observed"):
        d = channel.transmit(ParameterMessage(0, 1, 0, [_payload_with(shifted)]))
    assert d.status == "dropped" and d.message is None


def test_a_matched_instance_takes_the_peers_observations(tiny_world):
    from mapping.team import RoundPlan, Team, TeamConfig, ConsistencyConfig
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.world.stream import world_streams, world_vocabulary

    streams = world_streams(tiny_world, seed=0, segmentation_errors=False)
    mapping = replace(mapping_config("tiny"), iterations_per_keyframe=2, refit_steps=10)
    team = Team(streams, TeamConfig(mapping=mapping, frames_per_round=4,
                                    consistency=ConsistencyConfig(iterations=1, rays_per_pose=32)),
                world_vocabulary(tiny_world), seed=0, device="cpu")
    quiet = RoundPlan(np.zeros((2, 2), bool), np.zeros((2, 2), bool))
    team.round(quiet)
    receiver = team.members[1]
    before = {iid: s.copy() for iid, s in receiver.mapper.observed.spaces.items()}
    send = np.array([[False, True], [False, False]])
    team.round(RoundPlan(send, np.zeros((2, 2), bool)))
    matched = receiver.matches.get(0, {})
    assert matched, "agent 1 aligned some of agent 0's instances"
    grown = 0
    for own in set(matched.values()):
        space = receiver.mapper.observed.get(own)
        assert space is not None
        if own in before:
            was = before[own]
            assert np.count_nonzero(space.states) >= np.count_nonzero(was)
            grown += np.count_nonzero(space.states) > np.count_nonzero(was)
    assert grown or any(own not in before for own in matched.values())


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_the_masked_view_answers_on_the_points_device():
    from mapping.model.observed_field import ObservedRows

    class Full:  # occupancy 1 everywhere
        num_instances, bound_min, bound_max = 1, torch.zeros(1, 3), torch.ones(1, 3)

        def query(self, points, rows, with_colour=True, block_size=4096):
            from mapping.model.field import FieldOutput
            return FieldOutput(torch.ones(len(points), device=points.device), None)

    points = torch.tensor([[0.5, 0.5, 0.5], [0.05, 0.05, 0.05]], device="cuda")
    out = ObservedRows(Full(), {0: _box_space()}).query(points, torch.zeros(2, dtype=torch.long, device="cuda"))
    assert out.occupancy.device.type == "cuda" and out.occupancy.tolist() == [1.0, 0.0]


@pytest.mark.parametrize("voxel_m", [0.01, 0.02, 0.06])
def test_meshing_only_the_reach_gives_the_faces_of_meshing_everything_then_cutting(voxel_m):
    """``ReachSamples`` skips the samples whose faces ``observed_faces`` would drop: the kept faces are the same,
    bit for bit, for margins under a cell (eight corners) and over one (the dilated reach)."""
    from mapping.evaluate import extract_instance_mesh
    from mapping.model.observed_field import ReachSamples, observed_faces

    centre, radius = np.array([0.31, 0.27, 0.22]), 0.17

    def occupancy(points: torch.Tensor) -> torch.Tensor:  # a ball with a bump, evaluated in float32
        d = torch.linalg.norm(points - torch.tensor(centre, dtype=torch.float32), dim=1)
        return torch.sigmoid(40 * (radius + 0.02 * torch.sin(25 * points[:, 0]) - d))

    space = ObservedSpace.empty(0.025)
    lo, hi = centre - 0.3, centre + 0.3
    space.cover(lo, hi)
    angles = np.random.default_rng(0).uniform(0, np.pi / 2, (400, 2))  # one octant of the ball seen
    seen = centre + radius * np.stack([np.cos(angles[:, 0]) * np.sin(angles[:, 1]),
                                       np.sin(angles[:, 0]) * np.sin(angles[:, 1]), np.cos(angles[:, 1])], 1)
    space.mark(seen, SURFACE)
    full = observed_faces(extract_instance_mesh(occupancy, lo, hi, voxel_size_m=voxel_m), space)
    calls = []
    counted = lambda pts: (calls.append(len(pts)), occupancy(pts))[1]  # noqa: E731
    part = observed_faces(extract_instance_mesh(counted, lo, hi, voxel_size_m=voxel_m,
                                                needed=ReachSamples(space)), space)
    assert full is not None and part is not None and len(full.faces) > 20
    assert np.array_equal(np.asarray(full.triangles), np.asarray(part.triangles))
    grid = int(np.prod(np.floor((hi - lo) / voxel_m + 1e-9) + 1))
    assert sum(calls) < 0.6 * grid  # an octant's reach: far fewer samples than the box


@pytest.mark.parametrize("voxel_m", [0.02, 0.04])
def test_meshing_only_the_reach_is_exact_where_the_box_runs_past_the_observed_grid(voxel_m):
    """Surface in the grid's last layer and a box (and its meshing grid) reaching past the grid: samples outside
    the grid but within a voxel of its edge are still needed (a review found them dropped at voxels over a
    cell); and at voxels between half a cell and a cell, a box spans three cells per axis."""
    from mapping.evaluate import extract_instance_mesh
    from mapping.model.observed_field import ReachSamples, observed_faces

    space = ObservedSpace.empty(0.025)
    space.cover(np.zeros(3), np.array([1.0, 0.5, 0.5]))
    xs = np.linspace(0.0, 0.5, 20)
    face = np.stack(np.meshgrid([0.99], xs, xs, indexing="ij"), -1).reshape(-1, 3)  # the grid's last x layer
    space.mark(face, SURFACE)

    def occupancy(points: torch.Tensor) -> torch.Tensor:  # a slab whose face lies just past the grid
        return torch.sigmoid(200 * (1.03 - points[:, 0]))

    lo, hi = np.zeros(3), np.array([1.05, 0.5, 0.5])
    full = observed_faces(extract_instance_mesh(occupancy, lo, hi, voxel_size_m=voxel_m), space)
    part = observed_faces(extract_instance_mesh(occupancy, lo, hi, voxel_size_m=voxel_m, needed=ReachSamples(space)),
                          space)
    assert (full is None) == (part is None)
    if full is not None:
        assert np.array_equal(np.asarray(full.triangles), np.asarray(part.triangles))


def test_reach_samples_of_a_space_without_surface_need_nothing():
    from mapping.model.observed_field import ReachSamples

    space = ObservedSpace.empty(0.025)
    space.cover(np.zeros(3), np.ones(3) * 0.2)
    assert not ReachSamples(space)(np.zeros(3), 0.01, (20, 20, 20)).any()


def test_the_one_gather_mask_equals_each_rows_own_lookup():
    """``ObservedRows.mask`` lays every row's grid end to end and gathers once; it must say what each space's own
    lookup says (``reach_mask`` / ``looked_mask``), rows without a space True, points off a grid False."""
    from mapping.model.observed_field import ObservedRows, looked_grid

    def own_lookup(grid: np.ndarray, space: ObservedSpace, pts: torch.Tensor) -> torch.Tensor:
        """One space's grid at each point's cell, False off the grid (the per-row form the gather replaced)."""
        out = torch.zeros(len(pts), dtype=torch.bool)
        if not grid.size:
            return out
        idx = torch.floor(pts.double() / space.cell_m).long() - torch.as_tensor(space.origin)
        inside = ((idx >= 0) & (idx < torch.as_tensor(grid.shape))).all(dim=1)
        out[inside] = torch.as_tensor(grid)[tuple(idx[inside].T)]
        return out

    def reach_mask(space, pts):
        return own_lookup(space.surface_reach(), space, pts)

    def looked_mask(space, pts):
        return own_lookup(looked_grid(space), space, pts)

    rng = np.random.default_rng(4)
    spaces = {}
    for row, origin in {0: (-3, 2, 0), 2: (5, -4, 1), 3: (0, 0, 0)}.items():
        states = rng.choice([UNKNOWN, FREE, SURFACE], size=(6, 5, 7), p=[0.5, 0.3, 0.2]).astype(np.uint8)
        spaces[row] = ObservedSpace(0.05, np.array(origin, np.int64), states)
    spaces[4] = ObservedSpace.empty(0.05)  # an instance that saw nothing: False everywhere
    points = torch.as_tensor(rng.uniform(-0.3, 0.6, size=(4000, 3)), dtype=torch.float32)
    rows = torch.as_tensor(rng.integers(0, 5, size=4000))  # row 1 has no space
    view = ObservedRows(object(), spaces)
    for grid_of, single in ((None, reach_mask), (looked_grid, looked_mask)):
        expected = torch.ones(len(points), dtype=torch.bool)
        for row, space in spaces.items():
            expected[rows == row] = single(space, points[rows == row])
        got = view.mask(points, rows, grid_of)
        assert torch.equal(got, expected)
        assert got[rows == 1].all() and not got[rows == 4].any() and 0 < int(got[rows != 1].sum()) < int((rows != 1).sum())
    assert view.mask(points[:3], torch.tensor([-1, 0, -1])).tolist() == [True, bool(reach_mask(spaces[0], points[1:2])), True]


def test_the_cached_reach_is_kept_through_free_marks_and_redone_after_new_surface():
    from scipy.ndimage import binary_dilation  # noqa: PLC0415

    rng = np.random.default_rng(0)
    space = ObservedSpace.empty(0.05)
    space.cover(np.zeros(3), np.ones(3))
    space.mark(rng.uniform(0.3, 0.7, (40, 3)), SURFACE)

    def fresh() -> np.ndarray:
        return binary_dilation(space.states == SURFACE, np.ones((3, 3, 3), bool))

    first = space.surface_reach()
    assert np.array_equal(first, fresh())
    space.mark(rng.uniform(0, 1, (500, 3)), FREE)  # free marks never touch the surface cells
    assert space.surface_reach() is first
    space.mark(space.lo + (np.argwhere(space.states == SURFACE)[:5] + 0.5) * 0.05, SURFACE)  # already surface
    assert space.surface_reach() is first
    before_new = space.states == SURFACE
    space.mark(np.array([[0.05, 0.05, 0.05], [0.0, 0.5, 0.99]]), SURFACE)  # new cells, one on the grid's edge
    again = space.surface_reach()
    assert again is not first and np.array_equal(again, fresh()) and again.sum() > first.sum()
    assert np.array_equal(first, binary_dilation(before_new, np.ones((3, 3, 3), bool)))  # the old array kept
    for _ in range(5):  # many small marks, each grown onto the cached reach, agree with one dilation at the end
        space.mark(rng.uniform(0, 1, (7, 3)), SURFACE)
        space.mark(rng.uniform(0, 1, (50, 3)), FREE)
    assert np.array_equal(space.surface_reach(), fresh())
