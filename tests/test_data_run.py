"""``openmulti run --data`` end to end on the tiny committed data sets (tests/fixtures): the team under
scripted policies, resuming, and bad input."""

from __future__ import annotations

import json
import re
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest

from scipy.spatial.transform import Rotation

import mapping.pipeline.data_source as source
from mapping.model.agent_config import MappingConfig, for_recordings
from mapping.data import DatasetError, DatasetWarning
from mapping.data.checks import CONFLICT_NOTE_SHARE, pose_conflict_note
from mapping.pipeline.data_source import check_sequence, load_agents, load_gt_mesh, parse_frames, parse_intrinsics
from mapping.model.losses import DataLossWeights
from mapping.perception.geometric_segmenter import RANGE_AWARE, segmenter_settings
from mapping.pipeline.records import forget_stale_checkpoints
from openmulti_env.runs.cli import main
from openmulti_env.runs.run import run_data

FIXTURES = Path(__file__).parent / "fixtures"
REPLICA, SCANNET, NICE_SLAM = FIXTURES / "replica_tiny", FIXTURES / "scene0000_00", FIXTURES / "nice_slam_tiny"
KEYS = {"acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc"}


def _run(out: Path, data: Path, *extra: str, policy: str = "never") -> dict:
    args = ["run", "--data", str(data), "--preset", "tiny", "--policy", policy, "--device", "cpu", "--out", str(out)]
    assert main(args + list(extra)) == 0
    return json.loads((out / "metrics.json").read_text())


def _query(capsys, out: Path, text: str) -> dict:
    capsys.readouterr()
    assert main(["query", "--run", str(out), text, "--top", "3"]) == 0
    printed = capsys.readouterr().out
    return json.loads(printed[printed.index("{"):])


def test_replica_team_always_writes_the_run_contract_and_answers_queries(tmp_path, capsys):
    out = tmp_path / "replica"
    metrics = _run(out, REPLICA, "--agents", "2", "--gt-mesh", str(REPLICA / "mesh.ply"), policy="always")
    text = capsys.readouterr().out
    assert "given ground-truth mesh" in text and "TSDF" not in text and "fleet time" in text
    assert set(metrics["agents"]) == {"agent_0", "agent_1"} and KEYS <= set(metrics["mean"])
    for m in metrics["agents"].values():
        assert KEYS <= set(m) and 0 < m["comp_ratio"] <= 100 and m["acc_cm"] > 0
        assert 0 < m["f_miou"] <= 100 and 0 < m["f_macc"] <= 100
        assert m["depth_median_cm"] is not None and 0 <= m["depth_off_pct"] <= 100  # against the data's own depth
    assert metrics["ground_truth"] == "given" and metrics["masks"] == "dataset"
    assert metrics["resolved"]["frames_per_agent"] == {"agent_0": 6, "agent_1": 6}
    team = metrics["resolved"]["team"]  # a recording gets empty-space carving and crossing free-space rays;
    assert team["mapping"]["loss_weights"]["free_space"] == 10.0 and team["min_keyframes"] == 6  # all keyframes
    assert team["mapping"]["free_space_rays"] == "crossing" and team["mapping"]["own_ray_fraction"] == 0.5
    # the team ran its rounds (6 frames per agent, 4 per round on tiny) and talked in every one
    assert metrics["config"]["run"]["policy"] == "always" and metrics["config"]["team"]["alignment"] is True
    assert metrics["rounds"] == len(metrics["bytes_per_round"]) == 2 and metrics["fleet_s"] > 0
    assert metrics["bytes_sent_total"] == sum(metrics["bytes_per_round"]) > 0 and min(metrics["bytes_per_round"]) > 0
    assert metrics["messages"] == {"delivered": 2 * 2 * 2, "dropped": 0, "over_budget": 0} and metrics["wall_s"] > 0
    assert len(json.loads((out / "rounds.json").read_text())["rounds"]) == 2
    for name in ("meshes/gt_observable.ply", "meshes/agent_1.ply", "codebook/agent_0.json",
                 "plots/reconstruction_top_down.png", "plots/rendered_views_agent_1.png", "plots/semantic_per_class.png",
                 "plots/bytes_per_round.png"):
        assert (out / name).stat().st_size > 0, name
    classes = {o["class_name"] for o in json.loads((REPLICA / "info_semantic.json").read_text())["objects"]}
    book = json.loads((out / "codebook" / "agent_0.json").read_text())["instances"]
    assert book and {e["caption"] for e in book} <= classes  # captions = the data set's names
    hits = _query(capsys, out, "the floor")
    assert hits["results"][0]["category"] == "floor"
    # the team's checkpoint is kept for the same settings only
    assert (out / "checkpoints" / "team.pt").exists()
    settings = json.loads((out / "checkpoints" / "run_settings.json").read_text())
    forget_stale_checkpoints(out, settings)
    assert (out / "checkpoints" / "team.pt").exists()
    forget_stale_checkpoints(out, {**settings, "policy": "never"})
    assert not (out / "checkpoints" / "team.pt").exists()


def test_bernoulli_team_run_interrupted_after_a_round_resumes(tmp_path, capsys, monkeypatch):
    import mapping.pipeline.runner as pipeline

    out, mesh = tmp_path / "lossy", str(REPLICA / "mesh.ply")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    with monkeypatch.context() as m:  # the run stops after round 1 was checkpointed, before evaluating
        m.setattr(pipeline, "evaluate_team", interrupted)
        with pytest.raises(KeyboardInterrupt):
            run_data(REPLICA, 2, "bernoulli:0.5", "tiny", 0, out, gt_mesh=mesh, device="cpu", progress=False,
                     max_rounds=1)
    assert (out / "checkpoints" / "team.pt").exists() and not (out / "metrics.json").exists()
    capsys.readouterr()
    metrics = _run(out, REPLICA, "--agents", "2", "--gt-mesh", mesh, policy="bernoulli:0.5")
    assert "resumed the team after round 1" in capsys.readouterr().out
    assert metrics["rounds"] == len(metrics["bytes_per_round"]) == 2
    msgs = metrics["messages"]
    assert msgs["delivered"] + msgs["dropped"] == 2 * 2 * 2 and msgs["dropped"] > 0 and msgs["delivered"] > 0
    assert metrics["bytes_sent_total"] > 0  # a dropped message costs its sender
    assert KEYS <= set(metrics["mean"]) and metrics["config"]["run"]["policy"] == "bernoulli:0.5"


def test_scannet_with_masks_without_mesh_is_scored_against_a_tsdf_reference(tmp_path, capsys):
    metrics = _run(tmp_path / "scannet", SCANNET, "--agents", "1")
    text = capsys.readouterr().out
    assert "TSDF REFERENCE" in text and "not ground truth" in text
    assert metrics["ground_truth"] == "tsdf_reference" and "not against ground truth" in metrics["notes"]
    assert metrics["masks"] == "dataset" and metrics["mean"]["f_miou"] is not None
    assert 0 < metrics["mean"]["comp_ratio"] <= 100
    assert (tmp_path / "scannet" / "meshes" / "gt_reference.ply").stat().st_size > 0


def test_plain_rgbd_without_masks_uses_the_geometric_segmenter_and_never_talks(tmp_path, capsys):
    out = tmp_path / "plain"
    metrics = _run(out, NICE_SLAM, "--agents", "2", "--gt-mesh", str(REPLICA / "mesh.ply"))
    text = capsys.readouterr().out
    assert "semantics are geometric only" in text
    assert metrics["masks"] == "geometric" and metrics["ground_truth"] == "given"
    assert metrics["bytes_sent_total"] == 0 and metrics["rounds"] >= 1 and not any(metrics["bytes_per_round"])
    assert metrics["messages"]["delivered"] == 0 and set(metrics["agents"]) == {"agent_0", "agent_1"}
    assert metrics["mean"]["f_miou"] is None and metrics["mean"]["comp_ratio"] > 0
    assert metrics["timings_s"]["segmenter_per_frame"] > 0
    book = json.loads((out / "codebook" / "agent_0.json").read_text())["instances"]
    captions = [e["caption"] for e in book]
    assert captions and all(c.split()[-1].isdigit() and c.rsplit(" ", 1)[0] in ("planar surface", "object")
                            for c in captions)
    assert _query(capsys, out, "a planar surface")["results"]


def test_no_masks_no_mesh_and_a_frame_selection(tmp_path, capsys):
    metrics = _run(tmp_path / "bare", NICE_SLAM, "--agents", "1", "--frames", "0:12:3")
    assert metrics["resolved"]["frames_per_agent"] == {"agent_0": 4}
    assert metrics["masks"] == "geometric" and metrics["ground_truth"] == "tsdf_reference"


def test_bad_policies_and_options_are_refused_naming_the_problem(tmp_path, capsys):
    base = ["run", "--data", str(REPLICA), "--preset", "tiny", "--out", str(tmp_path)]
    for extra, message in ((["--policy", "sometimes"], "unknown policy 'sometimes'"),
                           (["--policy", "bernoulli:1.5"], "[0, 1]"),
                           (["--policy", "budget"], "policy 'budget' needs a budget: --comm-budget-mb MB"),
                           (["--policy", "budget", "--comm-budget-mb", "-1"], "--comm-budget-mb (channel.budget_mb) must be >= 0"),
                           (["--perception.segmentation-errors", "false"],
                            "--perception.segmentation-errors false is for --scene")):
        assert main(base + extra) == 2, extra
        assert message in capsys.readouterr().err, extra
    with pytest.raises(ValueError, match="no ground-truth 'oracle' alignment"):
        run_data(REPLICA, 2, "always", "tiny", 0, tmp_path, alignment="oracle")
    with pytest.raises(ValueError, match=r"team.consistency.algorithm must be one of \(.*\), got .gossip."):
        run_data(REPLICA, 2, "always", "tiny", 0, tmp_path, consistency="gossip")
    assert not (tmp_path / "metrics.json").exists()


def test_segmenter_settings_reach_the_geometric_segmenter_and_bad_ones_are_named(tmp_path, monkeypatch, capsys):
    seen = []

    class Spy(source.GeometricSegmenter):
        def __init__(self, config=None):
            seen.append(config)
            super().__init__(config)

    monkeypatch.setattr(source, "GeometricSegmenter", Spy)
    inputs = source.prepare_inputs(NICE_SLAM, agents=1, frames="0:6:3", segmenter_config=RANGE_AWARE, progress=False)
    assert seen == [RANGE_AWARE] and any("geometric segmenter" in n for n in inputs.notes)
    inputs = source.prepare_inputs(REPLICA, agents=1, frames="0:6:3", segmenter_config=RANGE_AWARE, progress=False)
    assert seen == [RANGE_AWARE] and any("settings are not used" in n for n in inputs.notes)
    assert segmenter_settings("range_aware") is RANGE_AWARE
    with pytest.raises(ValueError, match=r"perception.segmenter must be one of \('fixed', 'range_aware'\), got 'sideways'"):
        run_data(NICE_SLAM, 1, "never", "tiny", 0, tmp_path, segmenter="sideways")
    base = ["run", "--preset", "tiny", "--out", str(tmp_path)]
    assert main(base + ["--data", str(NICE_SLAM), "--segmenter", "sideways"]) == 2
    assert "--segmenter (perception.segmenter) must be one of ('fixed', 'range_aware'), got 'sideways'" in \
        capsys.readouterr().err
    assert main(base + ["--scene", "room0", "--segmenter", "range_aware"]) == 2
    assert "(--segmenter) is for --data" in capsys.readouterr().err
    assert not (tmp_path / "metrics.json").exists()


# --------------------------------------------------------------------------- bad input


def _copy(tmp_path: Path, src: Path = REPLICA) -> Path:
    dst = tmp_path / src.name
    shutil.copytree(src, dst)
    return dst


def test_corrupt_image_missing_frame_and_bad_pose_name_the_file(tmp_path):
    data = _copy(tmp_path)
    (data / "rgb" / "rgb_3.png").write_bytes(b"not a png")
    agents = load_agents(data, "auto", 2)
    with pytest.raises(DatasetError, match="rgb_3.png"):
        [f for seq in agents.values() for f in seq]
    (data / "depth" / "depth_5.png").unlink()
    with pytest.raises(DatasetError, match="rgb_5.png.*no matching frame in depth/"):
        load_agents(data, "auto", 2)
    data = _copy(tmp_path / "b")
    lines = (data / "traj_w_c.txt").read_text().splitlines()
    lines[2] = " ".join(["nan"] * 16)
    (data / "traj_w_c.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DatasetError, match="traj_w_c.txt:pose 2.*non-finite"):
        load_agents(data, "auto", 2)
    with pytest.raises(DatasetError, match="fewer than --agents 20"):
        load_agents(REPLICA, "auto", 20)


def test_wrong_depth_unit_warns_and_names_the_flag():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_sequence(load_agents(REPLICA, "auto", 1, depth_scale=1.0))
    messages = [str(w.message) for w in caught if issubclass(w.category, DatasetWarning)]
    assert any(re.search(r"replica_tiny/depth: median depth is .* implausible.*--depth-scale", m) for m in messages)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_sequence(load_agents(REPLICA, "auto", 2))  # the fixture itself is fine


def test_world_to_camera_poses_warn(tmp_path):
    data = _copy(tmp_path)
    poses = np.loadtxt(data / "traj_w_c.txt").reshape(-1, 4, 4)
    np.savetxt(data / "traj_w_c.txt", np.linalg.inv(poses).reshape(-1, 16))
    with pytest.warns(DatasetWarning, match=r"traj_w_c.txt.*world-to-camera"):
        check_sequence(load_agents(data, "auto", 2))


def test_option_strings_and_meshes_are_checked(tmp_path):
    assert parse_frames("2::3", 12) == range(2, 12, 3) and parse_frames(None, 4) == range(4)
    for bad in ("a:b", "1:2:0", "1:2:3:4"):
        with pytest.raises(ValueError, match="--frames"):
            parse_frames(bad, 10)
    assert parse_intrinsics("40,40,39.5,29.5") == (40.0, 40.0, 39.5, 29.5)
    with pytest.raises(ValueError, match="--intrinsics"):
        parse_intrinsics("40,40,39.5")
    with pytest.raises(DatasetError, match="selection leaves no frame"):
        load_agents(REPLICA, "auto", 1, frames="50:60")
    bad = tmp_path / "broken.ply"
    bad.write_text("ply\nformat nonsense\n")
    with pytest.raises(DatasetError, match="broken.ply"):
        load_gt_mesh(bad)
    with pytest.raises(DatasetError, match="not found"):
        load_gt_mesh(tmp_path / "missing.ply")
    # intrinsics override: four numbers for the images' size
    seq = load_agents(REPLICA, "auto", 1, intrinsics="41,42,39.5,29.5")["agent_0"]
    assert (seq.intrinsics.width, seq.intrinsics.fx, seq.intrinsics.fy) == (80, 41.0, 42.0)


def test_two_frame_sequences_are_checked_without_reading_past_their_end():
    for frames in ("0:6:3", "0:2:1"):
        checks = check_sequence(load_agents(REPLICA, "auto", 1, frames=frames))
        assert [c.pairs for c in checks] == [1]  # the one neighbouring pair, checked


def test_recording_settings_fill_only_what_a_config_left_at_its_default():
    chosen = for_recordings(MappingConfig())
    assert (chosen.loss_weights.free_space, chosen.own_ray_fraction, chosen.free_space_rays) == (10.0, 0.5, "crossing")
    kept = for_recordings(MappingConfig(own_ray_fraction=0.7, loss_weights=DataLossWeights(free_space=2.0)))
    assert (kept.loss_weights.free_space, kept.own_ray_fraction, kept.free_space_rays) == (2.0, 0.7, "crossing")


def test_poses_off_by_centimetres_get_a_note_saying_what_no_map_can_fix(tmp_path):
    checks = check_sequence(load_agents(REPLICA, "auto", 2))
    assert all(c.free_space_conflict < CONFLICT_NOTE_SHARE for c in checks)
    assert pose_conflict_note(checks, "replica_tiny") is None  # exact poses and depth
    data = _copy(tmp_path)
    poses = np.loadtxt(data / "traj_w_c.txt").reshape(-1, 4, 4)
    turn = np.eye(4)
    turn[:3, :3] = Rotation.from_euler("x", 3, degrees=True).as_matrix()  # 3 degrees about the camera's x
    poses[1::2] = poses[1::2] @ turn  # every other frame: still camera-to-world, a few centimetres off at 1-2 m
    np.savetxt(data / "traj_w_c.txt", poses.reshape(-1, 16))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DatasetWarning)
        checks = check_sequence(load_agents(data, "auto", 2))
    assert all(c.free_space_conflict > CONFLICT_NOTE_SHARE for c in checks if c.pairs)
    assert re.search(r"tiny: under the given poses, [0-9.]+ % of a frame's points land more than 5 cm in front",
                     pose_conflict_note(checks, str(data)))
