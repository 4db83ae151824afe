import numpy as np
import pytest
import trimesh

from openmulti_env.world import REPLICA_LIKE_PRESETS, make_scene
from openmulti_env.world.collision import find_interpenetrations
from openmulti_env.world.scene import Instance


def _signature(scene):
    return [(i.category, i.caption, np.round(i.mesh.vertices, 6).tobytes()) for i in scene.instances]


def test_same_name_and_seed_give_the_same_scene():
    assert _signature(make_scene("room1", 0)) == _signature(make_scene("room1", 0))
    assert _signature(make_scene("random:7")) == _signature(make_scene("random:7"))


def test_other_seeds_give_other_layouts():
    assert _signature(make_scene("room1", 0)) != _signature(make_scene("room1", 1))
    assert _signature(make_scene("random:1")) != _signature(make_scene("random:2"))


@pytest.mark.parametrize("name", REPLICA_LIKE_PRESETS)
def test_presets_are_rooms_of_15_to_40_instances_without_interpenetration(name):
    scene = make_scene(name)
    assert 15 <= len(scene.instances) <= 40
    cats = [i.category for i in scene.instances]
    assert cats.count("floor") == 1 and cats.count("ceiling") == 1 and cats.count("wall") == 4
    for inst in scene.instances:
        assert inst.caption and inst.material and inst.color_name, inst.describe()
        assert np.all(inst.mesh.bounds[0] >= -0.11) and np.all(inst.mesh.bounds[1] <= np.add(scene.size_m, 0.11))
        if not inst.is_structure:  # furniture stays inside the room box
            assert np.all(inst.mesh.bounds[0] >= -1e-6) and np.all(inst.mesh.bounds[1] <= np.add(scene.size_m, 1e-6))
    assert find_interpenetrations(scene.instances) == []


def test_presets_together_use_at_least_15_furniture_categories():
    cats = set()
    for name in REPLICA_LIKE_PRESETS:
        cats |= {i.category for i in make_scene(name).instances if not i.is_structure}
    assert len(cats) >= 15, sorted(cats)


def test_small_objects_rest_on_their_support():
    scene = make_scene("office0")
    small = [i for i in scene.instances if i.support_id]
    assert small, "expected objects on desks and shelves"
    for inst in small:
        host = scene.instance(inst.support_id)
        below = inst.mesh.bounds[0, 2]
        assert host.mesh.bounds[0, 2] < below <= host.mesh.bounds[1, 2] + 0.01


def test_interpenetration_is_detected():
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.box(extents=(1, 1, 1))
    b.apply_translation((0.5, 0.3, 0.2))
    c = trimesh.creation.box(extents=(1, 1, 1))
    c.apply_translation((1.0, 0.0, 0.0))  # touching a, not penetrating
    inst = [Instance(k + 1, "box", "a box", (1, 0, 0), "red", "wooden", m, [m]) for k, m in enumerate((a, b, c))]
    assert find_interpenetrations(inst) == [(1, 2), (2, 3)]


def test_unknown_scene_names_the_choices():
    with pytest.raises(ValueError, match="room0"):
        make_scene("kitchen9")
    with pytest.raises(ValueError, match="random:<integer seed>"):
        make_scene("random:abc")


def test_export_writes_scene_and_instance_plys(tmp_path, tiny_scene):
    out = tiny_scene.export(tmp_path)
    assert (out / "scene.ply").stat().st_size > 0
    files = sorted((out / "instances").glob("*.ply"))
    assert len(files) == len(tiny_scene.instances)
    back = trimesh.load(out / "scene.ply")
    assert len(back.faces) == len(tiny_scene.mesh().faces)
