import json

import pytest

from openmulti_env.runs.cli import main


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


def test_bad_input_gives_clear_errors(capsys, tmp_path):
    assert main(["run", "--scene", "kitchen9", "--preset", "tiny"]) == 2
    assert "unknown scene 'kitchen9'" in capsys.readouterr().err
    assert main(["run", "--scene", "tiny", "--policy", "sometimes"]) == 2
    assert "unknown policy" in capsys.readouterr().err
    assert main(["run", "--scene", "tiny", "--policy", "bernoulli:1.5"]) == 2
    assert "[0, 1]" in capsys.readouterr().err
    assert main(["run", "--scene", "tiny", "--policy", "runs/nowhere/best.json"]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["train", "--scenes", "room0", "random:3", "--out", str(tmp_path / "t")]) == 2
    assert "held-out" in capsys.readouterr().err
    assert main(["query", "--run", str(tmp_path / "missing"), "the bed"]) == 2
    assert "missing" in capsys.readouterr().err


def test_team_run_writes_metrics_answers_queries_and_resumes(capsys, tmp_path):
    out = tmp_path / "map"
    args = ["run", "--scene", "tiny", "--agents", "2", "--preset", "tiny", "--policy", "always", "--out", str(out),
            "--device", "cpu"]
    assert main(args) == 0
    first = capsys.readouterr().out
    assert "comp ratio" in first and "mean" in first and "fleet time" in first
    metrics = json.loads((out / "metrics.json").read_text())
    assert set(metrics["agents"]) == {"agent_0", "agent_1"}
    for m in list(metrics["agents"].values()) + [metrics["mean"]]:
        assert {"acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc"} <= set(m)
        assert 0.0 < m["comp_ratio"] <= 100.0 and m["acc_cm"] > 0
        assert 0.0 < m["f_miou"] <= 100.0 and 0.0 < m["f_macc"] <= 100.0
        # the depth check: the meshed map from the agent's input poses against its sensor depth
        assert 0.0 < m["depth_median_cm"] < 5.0 and 0.0 <= m["depth_no_surface_pct"] <= m["depth_off_pct"] < 60.0
    assert "depth err [cm]" in first and (out / "plots" / "rendered_views_agent_0.png").is_file()
    assert 0.0 < metrics["team"]["f_miou"] <= 100.0 and metrics["team"]["per_class"]
    assert metrics["bytes_sent_total"] == sum(metrics["bytes_per_round"]) > 0 and metrics["wall_s"] > 0
    assert metrics["rounds"] == len(metrics["bytes_per_round"]) == 6 and metrics["fleet_s"] > 0
    assert metrics["config"]["run"]["policy"] == "always" and metrics["messages"]["delivered"] == 4 * 6
    rounds = json.loads((out / "rounds.json").read_text())["rounds"]
    assert [r["round"] for r in rounds] == list(range(6))
    assert (out / "meshes" / "agent_0.ply").exists() and (out / "plots" / "reconstruction_top_down.png").exists()
    assert (out / "plots" / "rendered_views_agent_1.png").stat().st_size > 10_000
    assert (out / "plots" / "bytes_per_round.png").stat().st_size > 10_000
    assert (out / "plots" / "semantic_per_class.png").exists() and (out / "codebook" / "agent_1.json").exists()
    # the run's code books answer open-vocabulary queries
    assert main(["query", "--run", str(out), "the floor", "--top", "2"]) == 0
    printed = capsys.readouterr().out
    hits = json.loads(printed[printed.index("{"):])
    assert hits["results"][0]["category"] == "floor"
    # the checkpoints are kept with the team settings, library defaults included (a changed default maps again)
    kept = json.loads((out / "checkpoints" / "run_settings.json").read_text())
    assert kept["team"]["consistency"]["render_weight"] == metrics["config"]["team"]["consistency"]["render_weight"]
    # a second run in the same directory resumes after the last saved round
    assert main(args) == 0
    assert "resumed the team after round 6" in capsys.readouterr().out
    again = json.loads((out / "metrics.json").read_text())
    assert again["agents"] == metrics["agents"] and again["bytes_per_round"] == metrics["bytes_per_round"]
    # other settings in the same directory: the old team is not reused (what is said before the rounds: unscored)
    assert main(args + ["--no-cross-rendering", "--no-evaluation"]) == 0
    printed = capsys.readouterr().out
    assert "settings differ" in printed and "resumed" not in printed


@pytest.mark.parametrize("policy", ["never", "round_robin", "bernoulli:0.5", "budget", "every:2", "novelty"])
def test_every_scripted_policy_runs_rounds_on_the_tiny_world(policy, tmp_path, capsys):
    from openmulti_env.runs.run import run

    out = tmp_path / policy.replace(":", "_")
    options = dict(device="cpu", comm_budget_mb=1.0 if policy == "budget" else None, progress=False, max_rounds=2,
                   plots=False, learner="fleet" if policy == "round_robin" else "per_agent")  # the fleet's path too
    result = run("tiny", 3, policy, "tiny", 0, out, evaluate=False, **options)  # bytes and messages need no scores
    assert result["rounds"] == 2 and result["evaluated"] is False and result["agents"] == {} == result["mean"]
    assert json.loads((out / "metrics.json").read_text())["evaluated"] is False
    if policy == "never":
        assert result["bytes_sent_total"] == 0
        assert main(["query", "--run", str(out), "the bed"]) == 2  # no code books before scoring, and it says why
        assert "--no-evaluation" in capsys.readouterr().err
        scored = run("tiny", 3, policy, "tiny", 0, out, **options)  # the same call scores: it resumes, maps nothing
        assert "resumed the team after round 2" in capsys.readouterr().out
        assert scored["evaluated"] is True and set(scored["agents"]) == {"agent_0", "agent_1", "agent_2"}
        assert scored["rounds"] == 2 and scored["bytes_per_round"] == result["bytes_per_round"]
        assert 0.0 < scored["mean"]["comp_ratio"] <= 100.0
    if policy == "bernoulli:0.5":
        assert result["messages"]["dropped"] > 0
    if policy == "budget":
        assert result["messages"]["over_budget"] > 0
        assert max(result["bytes_per_round"]) > 0 and result["bytes_sent_total"] <= 3 * 1e6
    if policy == "every:2":
        assert result["bytes_per_round"][0] > 0 and result["bytes_per_round"][1] == 0
    if policy == "novelty":
        assert result["bytes_per_round"][0] > 0  # every peer lacks its instances at first


def test_observation_policies_are_refused_on_data_sets_with_the_reason(tmp_path):
    from openmulti_env.runs.run import run_data

    with pytest.raises(ValueError, match="reads observations"):
        run_data(tmp_path, 2, "novelty", "tiny", 0, tmp_path / "out")


def test_run_without_evaluation_prints_what_the_rounds_cost(capsys, tmp_path):
    args = ["run", "--scene", "tiny", "--agents", "2", "--preset", "tiny", "--policy", "always", "--out",
            str(tmp_path / "map"), "--device", "cpu", "--no-evaluation"]
    assert main(args) == 0
    printed = capsys.readouterr().out
    assert "6 rounds;" in printed and "Not evaluated" in printed and "comp ratio" not in printed
    assert (tmp_path / "map" / "checkpoints" / "team.pt").is_file()
    assert not (tmp_path / "map" / "meshes").exists()


def test_fewer_culling_viewpoints_score_the_same_maps_from_a_subset(tmp_path):
    """``--run.culling-viewpoint-stride K`` culls each map to what every K-th free-space viewpoint sees: the
    same checkpoint scored from one viewpoint keeps no more of the map than from all of them."""
    import json

    out = tmp_path / "map"
    base = ["run", "--scene", "tiny", "--agents", "2", "--preset", "tiny", "--policy", "always", "--out", str(out),
            "--device", "cpu", "--run.max-rounds", "2", "--run.plots", "false"]
    assert main(base) == 0
    every = json.loads((out / "metrics.json").read_text())["mean"]
    assert main(base + ["--run.culling-viewpoint-stride", "100000"]) == 0  # only the first viewpoint
    one = json.loads((out / "metrics.json").read_text())
    assert one["config"]["run"]["culling_viewpoint_stride"] == 100000
    assert one["mean"]["comp_ratio"] < every["comp_ratio"]


def test_members_scored_side_by_side_give_the_figures_and_meshes_of_scoring_in_turn(tmp_path):
    """The evaluation scores members on the run's worker threads: the same metrics and the same mesh files as
    one member after another."""
    import json

    out = tmp_path / "map"
    base = ["run", "--scene", "tiny", "--agents", "3", "--preset", "tiny", "--policy", "always", "--out", str(out),
            "--device", "cpu", "--run.max-rounds", "2", "--run.plots", "false", "--run.threads", "1"]
    assert main(base + ["--run.workers", "1"]) == 0
    in_turn = json.loads((out / "metrics.json").read_text())
    meshes = {p.name: p.read_bytes() for p in (out / "meshes").glob("*.ply")}
    assert main(base + ["--run.workers", "3"]) == 0
    side_by_side = json.loads((out / "metrics.json").read_text())
    assert side_by_side["config"]["run"]["workers"] == 3
    assert side_by_side["agents"] == in_turn["agents"] and side_by_side["mean"] == in_turn["mean"]
    assert {p.name: p.read_bytes() for p in (out / "meshes").glob("*.ply")} == meshes
