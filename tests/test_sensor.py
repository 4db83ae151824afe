import numpy as np
import pytest
import trimesh

from openmulti_env.world.sensor import RGBDSensor, SensorConfig, decode_instance_image, encode_instance_color


def test_instance_colour_code_round_trips():
    ids = np.array([[0, 1, 255], [256, 1000, 65535]])
    rgb = np.stack([[encode_instance_color(int(i)) for i in row] for row in ids])
    assert np.array_equal(decode_instance_image(rgb), ids)


def test_backprojected_depth_lands_on_the_instance_of_its_pixel(tiny_world):
    scene = tiny_world.scene
    checked = 0
    for agent in range(tiny_world.num_agents):
        for index in (0, len(tiny_world.agent_poses[agent]) // 2):
            frame = tiny_world.render(agent, index)
            assert frame.rgb.dtype == np.uint8 and frame.depth.dtype == np.float32
            valid = frame.depth > 0
            assert valid.mean() > 0.95  # a closed room: every pixel sees a surface
            pts = frame.backproject(stride=3)
            ids = frame.instance[::3, ::3][valid[::3, ::3]]
            assert set(np.unique(ids)) <= {i.instance_id for i in scene.instances}
            for iid in np.unique(ids):
                mesh = scene.instance(int(iid)).mesh
                sel = pts[ids == iid][::5]
                _, dist, _ = trimesh.proximity.closest_point(mesh, sel)
                assert dist.max() < 0.01, (iid, dist.max())
                checked += len(sel)
    assert checked > 1000


def test_sensor_depth_equals_ray_cast_depth(tiny_world):
    pose = tiny_world.agent_poses[0][5]
    frame = tiny_world.render(0, 5)
    depth, labels = tiny_world.caster.render_depth(pose, tiny_world.intrinsics)
    both = (frame.depth > 0) & (depth > 0)
    assert np.median(np.abs(frame.depth[both] - depth[both])) < 1e-3
    assert np.mean(frame.instance[both] == labels[both]) > 0.99


def test_depth_noise_and_dropout(tiny_scene, tiny_world):
    pose = tiny_world.agent_poses[0][3]
    clean = RGBDSensor(tiny_scene, SensorConfig(width=160, height=120)).render(pose)
    noisy = RGBDSensor(tiny_scene, SensorConfig(width=160, height=120, depth_noise_std_m=0.01,
                                                missing_depth_prob=0.2), seed=3).render(pose)
    dropped = (clean.depth > 0) & (noisy.depth == 0)
    assert 0.15 < dropped.mean() < 0.25
    both = (clean.depth > 0) & (noisy.depth > 0)
    err = noisy.depth[both] - clean.depth[both]
    assert 0.002 < err.std() < 0.1 and abs(err.mean()) < 0.005


def test_bad_pose_and_image_size_are_refused(tiny_scene):
    with pytest.raises(ValueError, match="at least 8x8"):
        SensorConfig(width=4, height=4).intrinsics()
    sensor = RGBDSensor(tiny_scene, SensorConfig(width=32, height=24))
    with pytest.raises(ValueError, match="finite 4x4"):
        sensor.render(np.full((4, 4), np.nan))
