"""A study's rows file, the setting word its rows carry, and the folders and rows of its `fast` runs: what
lets a stopped study resume where it was."""

import json
import sys

from studies.fast_runs import SCENARIOS, command, row_of, run_folder
from studies.rows import append_row, read_rows
from studies.settings import parse_setting


def test_rows_read_back_in_order_and_a_missing_file_holds_none(tmp_path):
    path = tmp_path / "new" / "rows.jsonl"
    assert read_rows(path) == []
    append_row(path, {"policy": "always", "mb": 1.5})
    append_row(path, {"policy": "never", "mb": 0.0})
    path.write_text(path.read_text() + "\n")  # a blank line (a hand edit) is skipped
    assert read_rows(path) == [{"policy": "always", "mb": 1.5}, {"policy": "never", "mb": 0.0}]


def test_a_setting_is_a_preset_and_typed_overrides():
    assert parse_setting("rl_lite") == ("rl_lite", {})
    preset, overrides = parse_setting("rl,frames_per_agent=60,link_range_m=2.5,scene=office0")
    assert preset == "rl" and overrides == {"frames_per_agent": 60, "link_range_m": 2.5, "scene": "office0"}
    assert type(overrides["frames_per_agent"]) is int and type(overrides["link_range_m"]) is float


def test_a_fast_run_has_a_path_safe_folder_and_its_scenarios_options(tmp_path):
    folder = run_folder(tmp_path, "room1", 3, "range", "instance_novelty:change=1,after=999")
    assert folder == tmp_path / "room1-s3" / "range" / "instance_novelty_change1_after999"
    line = command("room1", 3, "range", "every:4", folder)
    assert line[:3] == [sys.executable, "-m", "openmulti_env.runs.cli"]
    assert line[-len(SCENARIOS["range"]):] == SCENARIOS["range"] and "every:4" in line and str(folder) in line


def test_a_fast_runs_row_exists_only_once_it_has_scores(tmp_path):
    assert row_of(tmp_path, "room1", 3, "unlimited", "always") is None
    (tmp_path / "metrics.json").write_text(json.dumps({"bytes_sent_total": 2e6}))  # run with --no-evaluation
    assert row_of(tmp_path, "room1", 3, "unlimited", "always") is None
    (tmp_path / "metrics.json").write_text(json.dumps({"mean": {"comp_ratio": 80.0, "acc_cm": 2.0},
                                                       "bytes_sent_total": 2e6, "wall_s": 60.0}))
    row = row_of(tmp_path, "room1", 3, "unlimited", "always")
    assert row == {"scene": "room1", "seed": 3, "scenario": "unlimited", "policy": "always", "comp_ratio": 80.0,
                   "acc_cm": 2.0, "mb": 2.0, "wall_s": 60.0}
