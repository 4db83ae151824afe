import json

import numpy as np
import pytest
import trimesh
import yaml

from openmulti_env.world import make_scene
from openmulti_env.world.manifest import ManifestError, load_manifest_scene


def _write_meshes(folder):
    folder.mkdir()
    # a "chair" modelled in centimetres with y up (as many asset packs are)
    chair = trimesh.creation.box(extents=(45.0, 90.0, 50.0))
    chair.export(folder / "chair_cm_yup.obj")
    # an open mesh: a box with its bottom faces removed (not watertight), few faces
    box = trimesh.creation.box(extents=(0.6, 0.4, 0.7))
    keep = box.face_normals[:, 2] > -0.5
    open_box = trimesh.Trimesh(box.vertices, box.faces[keep])
    assert not open_box.is_watertight
    open_box.export(folder / "open_box.ply")


def _manifest(objects):
    return {"name": "my_room", "room": {"size_m": [4.0, 3.5, 2.6]}, "up_axis": "y", "objects": objects}


def test_manifest_builds_a_room_from_messy_meshes(tmp_path):
    _write_meshes(tmp_path / "meshes")
    data = _manifest([
        {"mesh": "meshes/chair_cm_yup.obj", "category": "chair", "caption": "a wooden chair",
         "position_m": [1.2, 0.8], "yaw_deg": 90, "height_m": 0.9, "color": [0.6, 0.4, 0.2]},
        {"mesh": "meshes/open_box.ply", "category": "cabinet", "position_m": [3.0, 2.5], "height_m": 0.7},
    ])
    path = tmp_path / "room.json"
    path.write_text(json.dumps(data))
    scene = make_scene(str(path))
    assert scene.name == "my_room" and len(scene.instances) == 8
    chair = next(i for i in scene.instances if i.category == "chair")
    assert chair.caption == "a wooden chair"
    assert chair.mesh.extents[2] == pytest.approx(0.9)  # 90 units tall along y -> 0.9 m along z
    assert chair.mesh.bounds[0, 2] == pytest.approx(0.0, abs=1e-9)  # rests on the floor
    assert np.allclose(chair.mesh.bounds.mean(axis=0)[:2], [1.2, 0.8])
    assert np.allclose(chair.color, (0.6, 0.4, 0.2))
    cabinet = next(i for i in scene.instances if i.category == "cabinet")
    assert cabinet.caption == "a cabinet"
    # YAML gives the same scene
    ypath = tmp_path / "room.yaml"
    ypath.write_text(yaml.safe_dump(data))
    assert len(load_manifest_scene(ypath).instances) == 8


def test_manifest_scene_renders_and_culls(tmp_path):
    from openmulti_env.experiment.presets import world_config
    from openmulti_env.world import World

    _write_meshes(tmp_path / "meshes")
    path = tmp_path / "room.json"
    path.write_text(json.dumps(_manifest([
        {"mesh": "meshes/open_box.ply", "category": "cabinet", "position_m": [2.0, 1.7], "height_m": 0.7}])))
    world = World.build(str(path), seed=0, config=world_config("tiny", 2))
    frame = world.render(0, 0)
    assert (frame.depth > 0).mean() > 0.95
    assert world.coverage(n_points=3000).union > 0.8


def test_overlapping_objects_are_refused_naming_both(tmp_path):
    _write_meshes(tmp_path / "meshes")
    path = tmp_path / "room.json"
    path.write_text(json.dumps(_manifest([
        {"mesh": "meshes/open_box.ply", "category": "cabinet", "position_m": [2.0, 1.7], "height_m": 0.7},
        {"mesh": "meshes/chair_cm_yup.obj", "category": "chair", "position_m": [2.1, 1.8], "height_m": 0.9},
    ])))
    with pytest.raises(ManifestError, match=r"objects\[1\].*chair.*overlaps cabinet"):
        load_manifest_scene(path)


@pytest.mark.parametrize("change, message", [
    (lambda d: d["objects"][0].update(mesh="meshes/nope.obj"), "mesh file not found"),
    (lambda d: d["objects"][0].pop("category"), "missing 'category'"),
    (lambda d: d["objects"][0].update(position_m=[9.0, 1.0]), "outside the room"),
    (lambda d: d["objects"][0].update(position_m="left"), "position_m"),
    (lambda d: d.update(up_axis="w"), "up_axis"),
    (lambda d: d.pop("room"), "'room'"),
    (lambda d: d["objects"][0].pop("height_m"), "larger than the room"),
    # every wrong type names its field (each gave a bare ValueError, a traceback or a silent NaN before)
    (lambda d: d["objects"][0].update(height_m="tall"), r"objects\[0\]\.height_m: expected a positive number"),
    (lambda d: d["objects"][0].update(height_m=[1]), r"objects\[0\]\.height_m: expected a positive number"),
    (lambda d: d["objects"][0].update(height_m=True), r"objects\[0\]\.height_m: expected a positive number"),
    (lambda d: d["objects"][0].update(yaw_deg={}), r"objects\[0\]\.yaw_deg: expected a finite number"),
    (lambda d: d["objects"][0].update(yaw_deg=float("nan")), r"objects\[0\]\.yaw_deg: expected a finite number"),
    (lambda d: d["objects"][0].update(color=[2.0, 0.5, 0.5]), r"objects\[0\]\.color: expected three numbers in"),
    (lambda d: d["objects"][0].update(color=[0.5, 0.5]), r"objects\[0\]\.color"),
    (lambda d: d["objects"][0].update(category={"a": 1}), r"objects\[0\]\.category: expected a non-empty string"),
    (lambda d: d["objects"][0].update(category=""), r"objects\[0\]\.category: expected a non-empty string"),
    (lambda d: d["objects"][0].update(caption=["a", "chair"]), r"objects\[0\]\.caption: expected a non-empty"),
    (lambda d: d["objects"][0].update(material=3), r"objects\[0\]\.material: expected a string"),
    (lambda d: d["objects"][0].update(mesh=["a.obj"]), r"objects\[0\]\.mesh: expected a non-empty string"),
    (lambda d: d.update(name=["x"]), r"room.json\.name: expected a non-empty string"),
    (lambda d: d.update(up_axis=3), r"room.json\.up_axis: expected a non-empty string"),
])
def test_bad_manifests_give_clear_errors(tmp_path, change, message):
    _write_meshes(tmp_path / "meshes")
    data = _manifest([{"mesh": "meshes/chair_cm_yup.obj", "category": "chair", "position_m": [1.0, 1.0],
                       "height_m": 0.9}])
    change(data)
    path = tmp_path / "room.json"
    path.write_text(json.dumps(data))
    with pytest.raises(ManifestError, match=message):
        load_manifest_scene(path)


def test_corrupt_manifest_and_mesh_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ManifestError, match="cannot parse"):
        load_manifest_scene(bad)
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "broken.obj").write_text("this is not a mesh\n")
    path = tmp_path / "room.json"
    path.write_text(json.dumps(_manifest([{"mesh": "m/broken.obj", "category": "x", "position_m": [1, 1]}])))
    with pytest.raises(ManifestError, match="broken.obj"):
        load_manifest_scene(path)
    with pytest.raises(ManifestError, match="not found"):
        load_manifest_scene(tmp_path / "missing.yaml")
