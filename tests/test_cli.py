import json

from openmulti_env.cli import main


def test_scenes_lists_presets(capsys):
    assert main(["scenes"]) == 0
    out = capsys.readouterr().out
    for name in ("room0", "room1", "room2", "office0", "office1", "office2"):
        assert name in out


def test_scenes_json_describes_instances_and_coverage(capsys, tmp_path):
    assert main(["scenes", "tiny", "--agents", "2", "--preset", "tiny", "--json", "--render", str(tmp_path)]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["name"] == "tiny" and info["agents"] == 2
    assert {"id", "category", "caption"} <= set(info["instances"][0])
    cov = info["coverage"]
    assert len(cov["per_agent_pct"]) == 2 and 0 < cov["union_pct"] <= 100
    assert (tmp_path / "top_down.png").stat().st_size > 10_000
    assert (tmp_path / "frames_agent_1.png").exists()


def test_run_writes_world_results_and_says_what_it_ran(capsys, tmp_path):
    out = tmp_path / "run"
    assert main(["run", "--scene", "tiny", "--agents", "2", "--preset", "tiny", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "Not run: mapping" in text and "team" in text
    world = json.loads((out / "world.json").read_text())
    assert world["frames_rendered"] == 48 and "coverage" in world
    assert (out / "meshes" / "gt_observable.ply").stat().st_size > 0
    assert (out / "plots" / "top_down.png").exists()
    assert not (out / "metrics.json").exists()  # no mapper yet: no pretend metrics


def test_bad_input_gives_clear_errors(capsys, tmp_path):
    assert main(["run", "--scene", "kitchen9", "--preset", "tiny"]) == 2
    assert "unknown scene 'kitchen9'" in capsys.readouterr().err
    assert main(["run", "--scene", "tiny", "--policy", "sometimes"]) == 2
    assert "unknown policy" in capsys.readouterr().err
    assert main(["run", "--scene", "tiny", "--policy", "bernoulli:1.5"]) == 2
    assert "[0, 1]" in capsys.readouterr().err
    assert main(["query", "--run", str(tmp_path / "missing"), "the bed"]) == 2
    assert "missing" in capsys.readouterr().err


def test_mapping_run_writes_metrics_and_resumes(capsys, tmp_path):
    out = tmp_path / "map"
    args = ["run", "--scene", "tiny", "--agents", "2", "--preset", "tiny", "--policy", "never", "--out", str(out),
            "--device", "cpu"]
    assert main(args) == 0
    first = capsys.readouterr().out
    assert "comp ratio" in first and "mean" in first
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["agents"]) == {"agent_0", "agent_1"}
    for m in list(metrics["agents"].values()) + [metrics["mean"]]:
        assert {"acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc"} <= set(m)
        assert 0.0 < m["comp_ratio"] <= 100.0 and m["acc_cm"] > 0
        assert 0.0 < m["f_miou"] <= 100.0 and 0.0 < m["f_macc"] <= 100.0
    assert 0.0 < metrics["team"]["f_miou"] <= 100.0 and metrics["team"]["per_class"]
    assert metrics["bytes_sent_total"] == 0 and metrics["wall_s"] > 0
    assert metrics["config"]["policy"] == "never"
    assert (out / "meshes" / "agent_0.ply").exists() and (out / "plots" / "reconstruction_top_down.png").exists()
    assert (out / "plots" / "rendered_views_agent_1.png").stat().st_size > 10_000
    assert (out / "plots" / "semantic_per_class.png").exists() and (out / "codebook" / "agent_1.json").exists()
    # the run's code books answer open-vocabulary queries
    assert main(["query", "--run", str(out), "the floor", "--top", "2"]) == 0
    printed = capsys.readouterr().out
    hits = json.loads(printed[printed.index("{"):])
    assert hits["results"][0]["category"] == "floor"
    # a second run in the same directory reloads the finished maps instead of mapping again
    assert main(args) == 0
    assert capsys.readouterr().out.count("resumed its finished map") == 2
    again = json.loads((out / "metrics.json").read_text())
    assert again["agents"] == metrics["agents"]
    # other settings in the same directory: the old maps are not reused, and the team ids answer queries
    assert main(args + ["--alignment", "paper"]) == 0
    printed = capsys.readouterr().out
    assert "settings differ" in printed and "resumed" not in printed
    aligned = json.loads((out / "metrics.json").read_text())
    assert aligned["config"]["alignment"] == "paper" and aligned["bytes_sent_total"] > 0
    assert (out / "codebook" / "team.json").exists()
