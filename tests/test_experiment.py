"""The configuration tree: one tree per experiment, written whole, read back strictly, replayed exactly, the
records of older versions read in one place, and the command line generated from it."""

from __future__ import annotations

import json
from dataclasses import asdict, replace

import pytest
import yaml

from mapping.pipeline.records import as_record
from openmulti_env.experiment import (ConfigError, Experiment, checkpoint_identity, experiment, read_checkpoint_identity,
                                      read_config, resolved_team, tree_record, write_config)
from openmulti_env.experiment.options import tree_fields
from openmulti_env.experiment.presets import PRESET_NAMES, get_preset
from openmulti_env.runs.cli import build_parser, main


@pytest.mark.parametrize("preset", PRESET_NAMES)
def test_every_preset_round_trips_through_yaml_and_json(preset, tmp_path):
    tree = experiment(preset, policy="bernoulli:0.5", float16=True, comm_budget_mb=3.0)
    assert tree.channel.success_probability == 0.5 and tree.channel.budget_bytes == 3e6
    assert read_config(write_config(tree, tmp_path)) == tree
    (tmp_path / "c.json").write_text(json.dumps(tree_record(tree)))
    assert read_config(tmp_path / "c.json") == tree


def test_short_spellings_and_dotted_paths_set_the_same_field():
    assert experiment("tiny", float16=True) == experiment("tiny", **{"team.exchange.float16": True})
    assert experiment("tiny", alignment="none").team.alignment is False
    tree = experiment("tiny", keyframe_every=2)  # the minimums follow the mapping they were derived from
    assert tree.team.min_keyframes == 24 // 2 and tree.team.min_local_steps == 12 * 10
    assert experiment("tiny", **{"team.min_keyframes": 3}, keyframe_every=2).team.min_keyframes == 3


def test_bad_options_name_the_field_and_the_nearest_valid_ones():
    with pytest.raises(ConfigError, match="did you mean float16"):
        experiment("tiny", flaot16=True)
    with pytest.raises(ConfigError, match="did you mean team.exchange.float16"):
        experiment("tiny", **{"team.exchange.flaot16": True})
    with pytest.raises(ConfigError, match="team.mapping.keyframe_every takes an integer, got 'often'"):
        experiment("tiny", keyframe_every="often")
    with pytest.raises(ConfigError, match="oracle"):
        experiment("tiny", alignment="oracle")
    with pytest.raises(ConfigError, match="world.num_agents must be an integer >= 1 and <= 8, got 9"):
        experiment("tiny", agents=9)
    with pytest.raises(ConfigError, match="policy 'budget' needs a budget"):
        experiment("tiny", policy="budget")


def test_config_files_with_unknown_fields_or_another_version_are_refused(tmp_path):
    record = tree_record(get_preset("tiny"))
    path = tmp_path / "config.yaml"
    path.write_text(yaml.safe_dump({**record, "team": {**record["team"], "flaot16": True}}))
    with pytest.raises(ConfigError, match="unknown field 'team.flaot16'"):
        read_config(path)
    path.write_text(yaml.safe_dump({**record, "version": 99}))
    with pytest.raises(ConfigError, match="another version of openmulti"):
        read_config(path)
    path.write_text("- just\n- a list\n")
    with pytest.raises(ConfigError, match="not a mapping"):
        read_config(path)
    with pytest.raises(ConfigError, match="does not exist"):
        read_config(tmp_path / "missing.yaml")


def test_every_field_of_the_tree_has_its_help_and_an_option():
    fields = tree_fields(Experiment)
    undocumented = [path for path, _, doc, _ in fields if not doc]
    assert not undocumented, f"fields without a docstring (their --help): {undocumented}"
    import argparse

    subcommands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    options = set(subcommands.choices["run"]._option_string_actions)
    for path, *_ in fields:
        if "." in path and not path.startswith("env."):
            assert "--" + path.replace("_", "-") in options, path


def test_a_run_record_of_the_version_before_the_tree_reads_as_the_same_run():
    """``checkpoints/run_settings.json`` as ``openmulti run`` wrote it before the tree (a flat dict and the
    team): the folder resumes under the tree."""
    tree = experiment("tiny", scene="tiny", agents=2, policy="bernoulli:0.5", alignment="paper", comm_budget_mb=2.0)
    team = as_record(asdict(resolved_team(tree, tree.team.mapping)))
    old = {"scene": "tiny", "agents": 2, "policy": "bernoulli:0.5", "preset": "tiny", "seed": 0, "alignment": "paper",
           "segmentation_errors": True, "clip_checkpoint": None, "comm_budget_mb": 2.0, "consistency": "consensus",
           "cross_rendering": True, "float16": False, "changed_only": None, "team": team}
    assert read_checkpoint_identity(old) == {**checkpoint_identity(tree, {}), "team": team}
    assert read_checkpoint_identity({**old, "segmentation_errors": False}) != {**checkpoint_identity(tree, {}), "team": team}


def test_one_short_spelling_per_field_and_older_spellings_only_in_older_records():
    """Each field has its dotted path and at most one short spelling (the env's keyword; the short option where
    ``openmulti run`` lists it); the second spellings of older versions are read from their records only."""

    from openmulti_env.experiment.overrides import ALIASES, OLD_SPELLINGS
    from openmulti_env.runs.cli import RUN_SHORT

    twice = {path: names for path, names in _spellings(ALIASES).items() if len(names) > 1}
    assert not twice, f"fields with more than one short spelling: {twice}"
    assert not set(OLD_SPELLINGS) & set(ALIASES)
    for name in OLD_SPELLINGS:
        with pytest.raises(ConfigError, match=f"unknown option {name!r}"):
            experiment("tiny", **{name: 2})
    tree = experiment("tiny", scene="tiny", agents=3, workers=2)
    team = as_record(asdict(resolved_team(tree, tree.team.mapping)))
    old = {"scene": "tiny", "num_agents": 3, "agent_workers": 2, "preset": "tiny", "team": team}
    assert read_checkpoint_identity(old) == {**checkpoint_identity(tree, {}), "team": team}
    import argparse

    subcommands = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    options = set(subcommands.choices["run"]._option_string_actions)
    assert {"--" + n.replace("_", "-") for n in RUN_SHORT} <= options
    assert not {"--float16", "--perfect-masks", "--changed-only", "--num-agents"} & options


def _spellings(aliases: dict[str, str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for name, path in aliases.items():
        out.setdefault(path, []).append(name)
    return out


def test_a_record_written_before_a_neutral_setting_existed_still_resumes():
    """A record of this version that lacks a ``neutral_default`` setting (``channel.link_success``, added after
    runs were recorded) reads as the same run; one lacking any other setting is not trusted."""
    tree = experiment("tiny", scene="tiny", agents=2, policy="always")
    team = as_record(asdict(resolved_team(tree, tree.team.mapping)))
    now = {**checkpoint_identity(tree, {}), "team": team}
    before = json.loads(json.dumps(now))
    del before["experiment"]["channel"]["link_success"]
    assert before != now and read_checkpoint_identity(before) == now
    del before["team"]["exchange"]["codec"]  # a team resolved before the codec existed: the same run
    assert read_checkpoint_identity(before) == now
    other_team = json.loads(json.dumps(before))
    del other_team["team"]["exchange"]["float16"]
    assert read_checkpoint_identity(other_team) is None
    lacking_other = json.loads(json.dumps(before))
    del lacking_other["experiment"]["channel"]["success_probability"]
    assert read_checkpoint_identity(lacking_other) is None
    other_seed = json.loads(json.dumps(before))
    other_seed["experiment"]["seed"] = 7
    assert read_checkpoint_identity(other_seed) != now


def test_a_run_replays_from_its_config_file(tmp_path, capsys):
    first, second = tmp_path / "first", tmp_path / "second"
    args = ["run", "--preset", "rl_tiny", "--scene", "tiny", "--agents", "2", "--out", str(first), "--no-evaluation",
            "--run.max-rounds", "2", "--team.exchange.float16", "--team.consistency.rho", "0.5"]
    assert main(args) == 0
    tree = read_config(first / "config.yaml")
    assert tree.team.exchange.float16 and tree.team.consistency.rho == 0.5 and tree.run.max_rounds == 2
    assert main(["run", "--config", str(first / "config.yaml"), "--out", str(second)]) == 0
    assert read_config(second / "config.yaml") == replace(tree, run=replace(tree.run, out=str(second)))
    rounds = [json.loads((d / "rounds.json").read_text())["rounds"] for d in (first, second)]
    assert [r["bytes_sent"] for r in rounds[0]] == [r["bytes_sent"] for r in rounds[1]]
    metrics = json.loads((second / "metrics.json").read_text())
    assert metrics["config"] == json.loads(json.dumps(tree_record(read_config(second / "config.yaml"))))
    assert main(["run", "--config", str(first / "config.yaml"), "--preset", "tiny"]) == 2
    assert "not both" in capsys.readouterr().err
    assert main(["run", "--preset", "tiny", "--team.exchange.flaot16"]) == 2
    assert "did you mean --team.exchange.float16" in capsys.readouterr().err


def test_the_env_takes_dotted_paths_and_whole_trees():
    from openmulti_env import parallel_env

    env = parallel_env(preset="rl_tiny", team__exchange__float16=True, rays_per_object=7)
    assert env.config.team.exchange.float16 and env.config.team.mapping.rays_per_object == 7
    assert env.config.run.threads == 1  # the env's own default
    tree = experiment("rl_tiny", map_size=32)
    assert parallel_env(preset="rl_tiny", config=tree).config.env.map_size == 32
    with pytest.raises(ValueError, match="did you mean rays_per_object"):
        parallel_env(preset="rl_tiny", rays_per_objetc=7)


def test_a_record_with_keys_of_its_own_is_not_trusted():
    tree = experiment("tiny", scene="tiny", agents=2, policy="always")
    team = as_record(asdict(resolved_team(tree, tree.team.mapping)))
    now = {**checkpoint_identity(tree, {}), "team": team}
    assert read_checkpoint_identity({**json.loads(json.dumps(now)), "extra": 1}) is None
    assert read_checkpoint_identity({k: v for k, v in now.items() if k != "source"}) is None


def test_a_config_file_that_leaves_settings_out_takes_its_presets(tmp_path):
    """A hand-written file names its preset and a few settings: the rest are the preset's, not ``fast``'s."""
    path = tmp_path / "config.yaml"
    path.write_text("format: openmulti.experiment\nversion: 1\npreset: tiny\nseed: 3\n"
                    "team:\n  exchange:\n    float16: true\n")
    tree = read_config(path)
    tiny = get_preset("tiny")
    assert tree.seed == 3 and tree.team.exchange.float16
    assert tree.world == tiny.world and tree.team.mapping == tiny.team.mapping  # tiny's 24 frames at 160x120
    assert read_config(path).world.path.frames_per_agent == 24 != get_preset("fast").world.path.frames_per_agent
    write_config(tiny, tmp_path)
    assert read_config(tmp_path / "config.yaml") == tiny  # a whole file reads back as written
