"""The depth check: a map ray cast from the input poses against the sensor depth."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from mapping.data import Frame, Intrinsics
from mapping.evaluate.depth_check import depth_check
from mapping.evaluate.raycast import MeshRaycaster


def _frame(depth: np.ndarray, pose: np.ndarray, k: Intrinsics) -> Frame:
    return Frame(np.zeros((k.height, k.width, 3), np.uint8), depth.astype(np.float32), pose, k)


def _scene():
    """A 4 m wall 2 m in front of a camera that looks along +z (OpenCV axes)."""
    wall = trimesh.creation.box(extents=(4.0, 4.0, 0.1))
    wall.apply_translation((0.0, 0.0, 2.05))
    k = Intrinsics(64, 48, 40.0, 40.0, 32.0, 24.0)
    pose = np.eye(4)
    sensor, _ = MeshRaycaster(wall).render_depth(pose, k)
    return wall, k, pose, sensor


def test_a_map_equal_to_the_sensor_is_clean_and_errors_are_counted():
    wall, k, pose, sensor = _scene()
    assert np.all(sensor > 0)
    clean = depth_check(wall, [_frame(sensor, pose, k)], stride=1)
    assert clean.median_cm == pytest.approx(0.0, abs=1e-3) and clean.off_pct == 0.0 and clean.pixels == 64 * 48
    shifted = sensor.copy()
    shifted[:, :32] += 0.10  # half the image 10 cm behind the map: off
    shifted[:, 32:40] += 0.02  # within the 5 cm tolerance
    shifted[0, 0] = 0.0  # a hole in the sensor: not compared
    check = depth_check(wall, [_frame(shifted, pose, k)], stride=1)
    assert check.pixels == 64 * 48 - 1 and check.off_pct == pytest.approx(100 * (32 * 48 - 1) / (64 * 48 - 1))
    assert check.no_surface_pct == 0.0


def test_missing_surface_counts_as_off():
    wall, k, pose, sensor = _scene()
    half = trimesh.creation.box(extents=(2.0, 4.0, 0.1))  # covers x in [-2, 0]: the image's left half
    half.apply_translation((-1.0, 0.0, 2.05))
    check = depth_check(half, [_frame(sensor, pose, k)], stride=2)
    assert 45 < check.no_surface_pct < 55 and check.off_pct >= check.no_surface_pct
    assert check.median_cm == pytest.approx(0.0, abs=1e-3) and check.views == 1
    nothing = depth_check(None, [_frame(sensor, pose, k)] * 2, stride=4)
    assert nothing.off_pct == 100.0 and nothing.median_cm is None and nothing.views == 2
    assert depth_check(wall, []).off_pct is None
    with pytest.raises(ValueError, match="stride must be >= 1"):
        depth_check(wall, [_frame(sensor, pose, k)], stride=0)


def test_held_out_frames_stay_out_of_the_map_and_are_scored(tmp_path, tiny_world):
    from dataclasses import replace

    from mapping.team import RoundPlan, Team, TeamConfig
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.runs.run import run
    from openmulti_env.world.stream import world_streams, world_vocabulary

    with pytest.raises(ValueError, match="holdout_every must be >= 2"):
        TeamConfig(holdout_every=1)
    config = TeamConfig(holdout_every=3)
    assert [p for p in range(9) if config.held_out(p)] == [2, 5, 8] and not TeamConfig().held_out(2)
    streams = world_streams(tiny_world, seed=0, segmentation_errors=False)
    team = Team(streams, TeamConfig(mapping=replace(mapping_config("tiny"), iterations_per_keyframe=1),
                                    frames_per_round=6, holdout_every=3), world_vocabulary(tiny_world), device="cpu")
    team.round(RoundPlan.never(2))
    assert all(m.fusion.frames_seen == 4 and m.mapper.frames_seen == 4 and m.next_frame == 6 for m in team.members)
    metrics = run("tiny", 2, "always", "tiny", 0, tmp_path / "run", device="cpu", holdout_every=3, plots=False,
                  threads=1)
    assert metrics["config"]["team"]["holdout_every"] == 3
    for m in metrics["agents"].values():
        assert m["depth_heldout_median_cm"] is not None and 0 <= m["depth_heldout_off_pct"] <= 100
    assert "depth_heldout_off_pct" in metrics["mean"]
