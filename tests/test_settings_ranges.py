"""Hostile settings and settings files: every number of the tree has a range checked when the tree is built (from
the command line, a config file and the env's keywords alike), the largest allocations are estimated before any is
made, config files must name a preset and hold settings, and every JSON or YAML the package reads is bounded in
size and depth. Nothing here builds a world: each case is refused before one would be."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from mapping.config_fields import range_problem, unbounded_numbers
from mapping.data.files import DatasetError, read_cam_params
from mapping.safe_parse import MAX_DEPTH, ParseError, load_json, load_yaml, parse_yaml
from openmulti_env.experiment import ConfigError, Experiment, experiment, experiment_from_record, read_config, tree_record
from openmulti_env.experiment import memory
from openmulti_env.experiment.options import typed_overrides
from openmulti_env.experiment.presets import PRESET_NAMES, get_preset
from openmulti_env.runs.cli import main
from openmulti_env.world.manifest import ManifestError, load_manifest_scene

DOCS = Path(__file__).resolve().parents[1] / "docs"
DEEP = MAX_DEPTH + 1


def test_every_number_of_the_tree_has_a_range():
    assert unbounded_numbers(Experiment) == []


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_is_in_range_and_fits_a_2_gib_machine(preset, monkeypatch):
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 2 * memory.GIB)
    tree = get_preset(preset)
    assert range_problem(tree) is None and memory.memory_problem(tree) is None
    assert experiment(preset) == tree


@pytest.mark.parametrize("overrides, message", [
    ({"frames_per_agent": 10**11}, r"world.path.frames_per_agent must be an integer >= 1 and <= 100000, got 100000000000"),
    ({"frames_per_agent": 1e11}, r"world.path.frames_per_agent must be an integer .* got 100000000000"),
    ({"map_size": 20000}, r"env.map_size must be an integer >= 8 and <= 4096, got 20000"),
    ({"probe_points": 10**10}, r"env.probe_points must be an integer >= 1 and <= 10000000, got 10000000000"),
    ({"image_width": 10**8}, r"world.sensor.width must be an integer >= 8 and <= 8192, got 100000000"),
    ({"keyframe_every": 0}, r"team.mapping.keyframe_every must be an integer >= 1 .* got 0"),
    ({"cache_max_mb": float("nan")}, r"env.cache_max_mb must be a finite number >= 0 and <= 1e9, got nan"),
    ({"world.path.yaw_steps": 0}, r"world.path.yaw_steps must be an integer >= 1 and <= 360, got 0"),
    ({"world.path.pitches_deg": []}, r"world.path.pitches_deg must hold 1 to 32 values, got 0"),
    ({"world.path.pitches_deg": [10.0, 90.0]}, r"world.path.pitches_deg\[1\] must be a finite number >= -89 and <= 89"),
    ({"team.mapping.lr": float("nan")}, r"team.mapping.lr must be a finite number > 0 and <= 10, got nan"),
    ({"seed": -1}, r"seed must be an integer >= 0"),
])
def test_a_setting_outside_its_range_names_the_field_the_value_and_the_range(overrides, message):
    with pytest.raises(ConfigError, match=message):
        experiment("tiny", overrides)


@pytest.mark.parametrize("overrides, message", [
    ({"world.sensor.min_depth_m": 5.0, "world.sensor.max_depth_m": 4.0}, r"min_depth_m \(5.0\) must be below"),
    ({"team.mapping.sampler.near_m": 9.0}, r"sampler.near_m \(9.0\) must be below team.mapping.sampler.far_m"),
    ({"team.mapping.sampler.n_stratified": 0, "team.mapping.sampler.n_surface": 0}, "at least one sample per ray"),
    ({"rays_per_pose": 65536, "team.consistency.poses_per_message": 64}, "4194304 rays a message, more than the 1048576"),
])
def test_rules_across_fields_are_checked_with_the_ranges(overrides, message):
    with pytest.raises(ConfigError, match=message):
        experiment("tiny", overrides)


def test_the_envs_keywords_are_checked_when_the_env_is_made():
    from openmulti_env import parallel_env

    for bad, field in ((dict(map_size=20000), "env.map_size"), (dict(probe_points=10**10), "env.probe_points"),
                       (dict(frames_per_agent=10**11), "world.path.frames_per_agent"),
                       (dict(keyframe_every=0), "team.mapping.keyframe_every")):
        with pytest.raises(ConfigError, match=field):
            parallel_env(preset="rl_tiny", **bad)


def test_allocations_past_the_memory_share_are_refused_with_their_estimate(monkeypatch):
    monkeypatch.setattr(memory, "physical_memory_bytes", lambda: 8 * memory.GIB)  # a 2 GiB share
    from openmulti_env import parallel_env

    with pytest.raises(ConfigError, match=r"top-down map's query would take an estimated 60.0 GiB \(env.map_size=4096\)"):
        parallel_env(preset="rl_tiny", map_size=4096)
    with pytest.raises(ConfigError, match=r"keyframe buffers would take an estimated [\d.]+ GiB .*world.sensor.width=8192"):
        experiment("tiny", image_width=8192, image_height=8192)
    tree = experiment("tiny")
    problem = memory.memory_problem(replace(tree, env=replace(tree.env, probe_points=10**7)), budget=0.4 * memory.GIB)
    assert problem.startswith("the probe points would take an estimated 0.5 GiB (env.probe_points=10000000, "
                              "world.num_agents=4), more than the 0.4 GiB")
    culling = r"culling's visibility .* GiB \(world.culling_edge_m=0.01, world.free_space.spacing_m=0.05"
    with pytest.raises(ConfigError, match=culling):
        experiment("tiny", culling_edge_m=0.01, **{"world.free_space.spacing_m": 0.05})


def test_numbers_in_exponent_form_are_numbers_in_yaml_and_on_the_command_line(tmp_path, capsys):
    assert parse_yaml("a: 1e12\nb: 1E-3\nc: -2e5\nd: '1e3'") == {"a": 1e12, "b": 0.001, "c": -2e5, "d": "1e3"}
    assert typed_overrides({"team.mapping.lr": "1E-3", "world.path.frames_per_agent": "1e2"}, Experiment) == {
        "team.mapping.lr": 0.001, "world.path.frames_per_agent": 100.0}
    tree = experiment("tiny", typed_overrides({"world.path.frames_per_agent": "1e2"}, Experiment))
    assert tree.world.path.frames_per_agent == 100
    assert main(["run", "--preset", "tiny", "--world.path.frames-per-agent", "1e12", "--out", str(tmp_path / "r")]) == 2
    assert "world.path.frames_per_agent must be an integer >= 1 and <= 100000, got 1000000000000" in capsys.readouterr().err
    path = _config(tmp_path, lambda r: r["world"]["path"].update(frames_per_agent="1e12"), raw=True)
    with pytest.raises(ConfigError, match=r"config.yaml: world.path.frames_per_agent must be .* got 1000000000000"):
        read_config(path)


def test_nan_in_a_yaml_config_fails_at_once_with_the_fields_range(tmp_path):
    path = _config(tmp_path, lambda r: r["team"]["mapping"].update(lr=".nan"), raw=True)
    with pytest.raises(ConfigError, match=r"config.yaml: team.mapping.lr must be a finite number > 0 and <= 10, got nan"):
        read_config(path)
    path = _config(tmp_path, lambda r: r["team"]["mapping"].update(lr="1E-4"), raw=True)
    assert read_config(path).team.mapping.lr == 1e-4


def test_a_config_file_must_name_a_preset_and_hold_settings(tmp_path):
    header = tmp_path / "header.yaml"
    header.write_text("format: openmulti.experiment\nversion: 1\n")
    with pytest.raises(ConfigError, match="header.yaml: holds only its header"):
        read_config(header)
    with pytest.raises(ConfigError, match=r"preset must be one of \('tiny', .*got 'nosuch'"):
        read_config(_config(tmp_path, lambda r: r.update(preset="nosuch")))
    with pytest.raises(ConfigError, match="preset must be one of"):
        experiment_from_record({k: v for k, v in tree_record(get_preset("tiny")).items() if k != "preset"})


def test_duplicated_keys_are_refused_naming_the_key(tmp_path):
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump(tree_record(get_preset("tiny")), sort_keys=False) + "seed: 3\n")
    with pytest.raises(ConfigError, match="config.yaml: key 'seed' appears twice"):
        read_config(path)
    text = json.dumps(tree_record(get_preset("tiny")))
    (tmp_path / "config.json").write_text(text[:-1] + ', "preset": "fast"}')
    with pytest.raises(ConfigError, match="config.json: key 'preset' appears twice"):
        read_config(tmp_path / "config.json")


def test_an_empty_config_option_is_refused(capsys):
    assert main(["run", "--config="]) == 2
    assert "--config names no file" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="names no file"):
        read_config("")


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_deeply_nested_configs_are_refused_naming_the_file_and_the_limit(tmp_path, suffix):
    path = tmp_path / f"config{suffix}"
    path.write_text("[" * 100_000 + "]" * 100_000 if suffix == ".json" else "a:\n" + "".join(
        "  " * i + f"k{i}:\n" for i in range(1, 5000)))
    with pytest.raises(ConfigError, match=rf"{path.name}: nests lists and mappings deeper than {MAX_DEPTH} levels"):
        read_config(path)
    flow = tmp_path / f"flow{suffix}"
    flow.write_text('{"a": ' * DEEP + "1" + "}" * DEEP)
    with pytest.raises(ConfigError, match=f"deeper than {MAX_DEPTH}"):
        read_config(flow)


def test_yaml_aliases_may_not_expand_past_the_bound(tmp_path):
    lines = ["a0: &a0 [1, 2, 3, 4, 5, 6, 7, 8, 9, 10]"] + [
        f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    path = tmp_path / "laughs.yaml"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(ParseError, match="laughs.yaml: expands to more than"):
        load_yaml(path)


def test_a_deep_cam_params_json_is_a_dataset_error_naming_the_file(tmp_path):
    (tmp_path / "cam_params.json").write_text('{"camera": ' + "[" * 50_000 + "]" * 50_000 + "}")
    with pytest.raises(DatasetError, match=rf"cam_params.json: nests lists and mappings deeper than {MAX_DEPTH}"):
        read_cam_params(tmp_path)
    (tmp_path / "cam_params.json").write_text('{"camera": {"w": 1, "w": 2}}')
    with pytest.raises(DatasetError, match="key 'w' appears twice"):
        read_cam_params(tmp_path)


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_a_deep_scene_manifest_is_a_manifest_error_naming_the_file(tmp_path, suffix):
    path = tmp_path / f"room{suffix}"
    path.write_text('{"name": "x", "objects": ' + "[" * 50_000 + "]" * 50_000 + "}")
    with pytest.raises(ManifestError, match=rf"room{suffix}: nests lists and mappings deeper than {MAX_DEPTH}"):
        load_manifest_scene(path)
    path.write_text('{"name": "x", "name": "y"}')
    with pytest.raises(ManifestError, match="key 'name' appears twice"):
        load_manifest_scene(path)


def test_oversized_files_are_refused_before_they_are_read(tmp_path):
    path = tmp_path / "big.json"
    path.write_text(json.dumps({"a": "x" * 2000}))
    with pytest.raises(ParseError, match=r"big.json: \d+ bytes, more than the 1000"):
        load_json(path, max_bytes=1000)


def test_every_config_and_experiment_record_in_the_docs_still_reads():
    """Every ``docs/**/config.yaml`` through ``read_config``, and every tree a record there embeds (training
    settings, policies) through the same reading and the whole tree's check."""
    for path in DOCS.rglob("config.yaml"):
        read_config(path)
    records = [r for p in DOCS.rglob("*.json") for r in _experiment_records(load_json(p))]
    assert len(records) > 10
    for record in records:
        experiment(record["preset"], base=experiment_from_record(record))


def _experiment_records(data) -> list[dict]:
    """The whole experiment records nested anywhere in ``data``."""
    out, stack = [], [data]
    while stack:
        value = stack.pop()
        if isinstance(value, dict) and value.get("format") == "openmulti.experiment" and "world" in value:
            out.append(value)
        elif isinstance(value, (dict, list)):
            stack.extend(value.values() if isinstance(value, dict) else value)
    return out


def _config(tmp_path: Path, change, raw: bool = False) -> Path:
    """``tiny``'s record written as ``config.yaml`` after ``change`` (``raw``: string values written unquoted, as
    a person would type ``1e12`` or ``.nan``)."""
    record = tree_record(get_preset("tiny"))
    change(record)
    text = yaml.safe_dump(record, sort_keys=False)
    if raw:
        for token in ("1e12", ".nan", "1E-4"):
            text = text.replace(f"'{token}'", token)
    path = tmp_path / "config.yaml"
    path.write_text(text)
    return path
