import numpy as np
import pytest

from openmulti_env.experiment.presets import world_config
from openmulti_env.world import REPLICA_LIKE_PRESETS, World
from openmulti_env.world.visibility import compute_observable_surface, free_space_viewpoints


def test_culling_drops_hidden_faces(tiny_scene):
    surface = compute_observable_surface(tiny_scene, max_edge_m=0.1)
    assert 0.3 < surface.visible_fraction < 0.95
    centres = surface.mesh.triangles_center
    # the outside of the walls is never observable; the floor in the open is
    vis_floor = surface.visible[(surface.face_instance_ids == 1)]
    assert vis_floor.mean() > 0.6
    # faces under the furniture footprint on the floor are culled
    cab = next(i for i in tiny_scene.instances if i.category == "cabinet")
    lo, hi = cab.bounds
    under = (surface.face_instance_ids == 1) & np.all((centres[:, :2] > lo[:2] + 0.1) & (centres[:, :2] < hi[:2] - 0.1), axis=1)
    assert under.any() and not surface.visible[under].any()


def test_viewpoints_stay_in_free_space(tiny_scene):
    vps = free_space_viewpoints(tiny_scene)
    for inst in tiny_scene.instances:
        if not inst.is_structure:
            inside = np.all((vps > inst.bounds[0]) & (vps < inst.bounds[1]), axis=1)
            assert not inside.any()


def test_paths_are_smooth_valid_poses(tiny_world):
    for poses in tiny_world.agent_poses:
        assert poses.shape == (24, 4, 4)
        r = poses[:, :3, :3]
        assert np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-6)
        assert np.allclose(np.linalg.det(r), 1.0)
        steps = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1)
        assert steps.max() < 1.0
        sx, sy, sz = tiny_world.scene.size_m
        assert np.all(poses[:, :3, 3] > 0) and np.all(poses[:, :3, 3] < [sx, sy, sz])


def test_one_agent_follows_all_region_paths(tiny_scene):
    one = World.build(tiny_scene, seed=0, config=world_config("tiny", 1))
    four = World.build(tiny_scene, seed=0, config=world_config("tiny", 4))
    assert one.num_agents == 1
    assert np.allclose(one.agent_poses[0], np.concatenate(four.agent_poses))


def test_same_seed_same_paths(tiny_scene):
    a = World.build(tiny_scene, seed=3, config=world_config("tiny", 2))
    b = World.build(tiny_scene, seed=3, config=world_config("tiny", 2))
    assert all(np.array_equal(x, y) for x, y in zip(a.agent_poses, b.agent_poses))


def test_too_many_agents_is_refused(tiny_scene):
    with pytest.raises(ValueError, match="between 1 and 8"):
        World.build(tiny_scene, seed=0, config=world_config("tiny", 9))


@pytest.mark.parametrize("name", REPLICA_LIKE_PRESETS)
def test_team_covers_95_percent_while_each_agent_leaves_blind_zones(name):
    """The issue's property, at the default settings, on every preset."""
    world = World.build(name, seed=0, config=world_config("fast", 4))
    report = world.coverage()
    assert report.union >= 0.95, report.as_dict()
    assert max(report.per_agent) <= 0.75, report.as_dict()
    # agents overlap: every agent shares surface with at least one other
    overlap = np.array(report.pairwise_overlap)
    np.fill_diagonal(overlap, 0)
    assert np.all(overlap.max(axis=1) > 0.02), report.as_dict()
