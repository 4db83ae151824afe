"""A simulated world exported as a data set loads back through the loaders (round trip)."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from mapping.data import load_dataset
from mapping.data.labels import dataset_categories
from openmulti_env.runs.cli import main
from openmulti_env.experiment.presets import world_config
from openmulti_env.world import World
from openmulti_env.world.export import export_world
from openmulti_env.world.sensor import SensorConfig


@pytest.fixture(scope="module")
def world():
    w = World.build("tiny", seed=0, config=replace(world_config("tiny", 2), sensor=SensorConfig(width=64, height=48)))
    yield w
    w.close()


@pytest.mark.parametrize("layout", ["replica", "scannet", "nice_slam"])
def test_export_round_trip(world, tmp_path, layout):
    root = export_world(world, tmp_path / "scene0001_00", layout, frame_stride=8, progress=False)
    ds = load_dataset(root)
    assert ds.kind == layout and len(ds) == 6  # 3 frames of each of the 2 agents, agent 0 first
    assert ds.intrinsics == world.intrinsics
    originals = [world.render(a, i) for a in range(2) for i in (0, 8, 16)]
    for got, want in zip(ds, originals):
        np.testing.assert_allclose(got.pose, want.pose, atol=1e-6)
        ok = want.depth > 0
        np.testing.assert_array_equal(got.depth > 0, ok)
        np.testing.assert_allclose(got.depth[ok], want.depth[ok], atol=1e-3)  # mm (or 1/6553.5 m) steps
        if layout == "replica":
            np.testing.assert_array_equal(got.rgb, want.rgb)
        else:  # JPEG
            assert np.abs(got.rgb.astype(int) - want.rgb).mean() < 8
        if layout == "nice_slam":
            assert got.instance is None
        else:
            np.testing.assert_array_equal(got.instance, want.instance)
    meta = json.loads((root / "openmulti_export.json").read_text())
    assert meta["agent_frames"] == [[0, 3], [3, 6]] and meta["scene"] == "tiny"
    # the split gives back the agents' paths
    parts = ds.split(2)
    np.testing.assert_allclose(parts[1].poses[0], world.agent_poses[1][0], atol=1e-6)
    categories, _ = dataset_categories(root, layout)
    if layout != "nice_slam":
        assert categories == {i.instance_id: i.category for i in world.scene.instances}
        mesh = trimesh.load(root / meta["gt_mesh"], force="mesh")
        assert len(mesh.faces) == len(world.surface.culled_mesh().faces)
    else:
        assert categories == {}


def test_scenes_export_command(tmp_path, capsys):
    out = tmp_path / "exported"
    assert main(["scenes", "tiny", "--agents", "1", "--preset", "tiny", "--json", "--export", str(out),
                 "--layout", "scannet"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["export_dir"] == str(out)
    assert len(load_dataset(out, "scannet")) == 24 * 4  # one agent follows the four region paths
