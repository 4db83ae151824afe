"""The experiments: every method runs on the tiny world and gives a row; writers; resume; bad names;
each culling on a hand-made mesh."""

from __future__ import annotations

import json
import threading

import numpy as np
import pytest
import trimesh

from mapping.data.frame import Intrinsics
from mapping.evaluate.culling import cull_to_frustums
from mapping.model.sdf_loss import SdfConfig
from mapping.team.global_map import GLOBAL_ENCODING_SCALE
from openmulti_env.runs.reproduce.command import reproduce
from openmulti_env.runs.reproduce.methods import METHODS, TABLE_I_METHODS, get_method
from openmulti_env.runs.reproduce.runner import GridJob, make_row, run_claim, run_table, write_row
from openmulti_env.runs.reproduce.tables import RunSpec, table_runs
from openmulti_env.runs.reproduce.writers import markdown_table, mean_sd, write_table


def test_design_method_names_are_all_presets():
    assert set(TABLE_I_METHODS) == {"single", "dsgd_instance", "dinno_instance", "dinerf_global", "macim_global",
                                    "openmulti_no_cross", "openmulti_global", "openmulti"}
    assert set(TABLE_I_METHODS) <= set(METHODS)
    assert get_method("dinerf_global").global_map and get_method("dinerf_global").consistency == "dinno"
    assert not get_method("openmulti_no_cross").cross_rendering and get_method("openmulti").cross_rendering


@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_runs_two_rounds_on_the_tiny_world_and_writes_a_row(method, tmp_path, monkeypatch):
    run_fn = None
    if METHODS[method].global_form == "published":  # MACIM's width-256 SDF: the path, at a test's size
        from openmulti_env.runs.run import run

        small = SdfConfig(width=32, rays=64, iterations_first=150, iterations_after=2)  # a room-sized surface
        run_fn = lambda *args, **options: run(*args, sdf=small, **options)  # noqa: E731
    spec = RunSpec(method, "tiny", 0, METHODS[method].agents or 2)
    (row,) = run_table([spec], "tiny", tmp_path, threads=1, three_cullings=False, max_rounds=2, progress=False,
                       run_fn=run_fn)
    assert row["method"] == method and (tmp_path / "rows" / f"{spec.key('tiny')}.json").is_file()
    assert row["rounds"] == 2 and row["comp_ratio"] >= 0 and row["time_per_round_s"] > 0
    assert row["acc_cm"] is None or row["acc_cm"] > 0
    if method == "single":
        assert row["bytes_per_round"] == 0
    if method == "single_agent":
        assert row["agents"] == 1
    if method == "dinerf_global":
        assert row["map"]["kind"] == "global" and row["map"]["form"] == "published" and row["f_miou"] is None
        assert row["map"]["network"] == "MACIM scene SDF" and row["map"]["width"] == 32
    if method == "dinerf_global_equal_compute":
        assert row["map"]["kind"] == "global" and row["map"]["encoding_scale"] == GLOBAL_ENCODING_SCALE
    if method == "openmulti":
        assert row["map"]["kind"] == "instance" and row["f_miou"] is not None
    # point clouds grow with the explored area; a global map sends one network of a fixed size
    if method == "pointcloud_sharing":
        clouds = row["bytes_per_round_series"]
        assert clouds[1] > clouds[0] > 0
    if method == "macim_global":
        single_net = row["bytes_per_round_series"]
        assert single_net[0] == single_net[1] > 0


def test_every_method_is_exercised_with_its_own_assertions():
    """The per-method test above names these methods: a renamed one must not pass silently."""
    assert {"single", "single_agent", "dinerf_global", "openmulti", "pointcloud_sharing", "macim_global",
            "dinerf_global_equal_compute"} <= set(METHODS)


def _fake_run(calls):
    def run(scene, agents, policy, preset, seed, out, **kwargs):
        calls.append((scene, policy, seed, kwargs.get("global_map")))
        quiet = {"never": 0.0, "every:2": 0.5}.get(policy, 1.0)  # share of always's bytes
        return {"mean": {"acc_cm": 2.0 + seed, "comp_cm": 3.0, "comp_ratio": 80.0 - 10 * kwargs["global_map"]
                         - 30 * (1 - quiet) - seed, "comp_ratio_nice": 90.0 - 20 * (1 - quiet) - seed,
                         "f_miou": 50.0, "f_macc": 60.0},
                "bytes_sent_total": int(24000 * quiet),
                "team": {"f_miou": 55.0, "f_macc": 65.0}, "config": {"agents": agents}, "rounds": 4,
                "bytes_per_round": [4000, 4000, 8000, 8000], "fleet_s": 8.0, "compute_s": {"agent_0": 3.0},
                "agents": {"agent_0": {"instances": 5}}, "wall_s": 1.0, "map": {"kind": "x"}}
    return run


def test_resume_skips_finished_runs_and_redoes_a_half_written_one(tmp_path):
    specs = table_runs("comm-failure", ["tiny"], [0, 1])
    calls = []
    run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)
    assert len(calls) == len(specs) == 2 * 3 * 4  # 2 seeds x (dinerf_global, its stale form, openmulti) x 4 rates
    calls.clear()
    run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)
    assert calls == []
    half = tmp_path / "rows" / f"{specs[3].key('tiny')}.json"
    half.write_text(half.read_text()[:40])  # interrupted while writing
    rows = run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)
    assert len(calls) == 1 and calls[0][1] == specs[3].policy and rows[3]["method"] == specs[3].method
    calls.clear()
    run_table(specs, "fast", tmp_path, run_fn=_fake_run(calls), progress=False)  # other settings: runs again
    assert len(calls) == len(specs)


def test_processes_sharing_an_out_make_each_run_once(tmp_path):
    """A run claimed by another process is skipped, then waited for and its row taken, not made twice."""
    specs = table_runs("comm-failure", ["tiny"], [0])[:3]
    first, calls, result = specs[0], [], {}
    with run_claim(tmp_path, first.key("tiny"), wait=False) as mine:  # "another process" is making the first run
        assert mine
        worker = threading.Thread(target=lambda: result.update(
            rows=run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)))
        worker.start()
        for _ in range(600):  # until it has made the two runs nobody holds
            if len(calls) == 2:
                break
            worker.join(0.05)
        assert len(calls) == 2 and worker.is_alive()  # it waits for the held one instead of making it
        job = GridJob("tiny", tmp_path, run_fn=_fake_run([]))
        elsewhere = {**make_row(first, job), "made": "elsewhere"}
        write_row(first, job, elsewhere)
    worker.join(30)
    assert not worker.is_alive()
    assert len(calls) == 2 and result["rows"][0] == elsewhere  # taken from the row file, not made again
    assert [row["success_rate"] for row in result["rows"]] == [spec.success_rate for spec in specs]
    calls.clear()  # a lock file left behind (its holder gone) blocks nothing
    assert (tmp_path / "runs" / f"{first.key('tiny')}.lock").exists()
    for row_file in (tmp_path / "rows").glob("*.json"):
        row_file.unlink()
    run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)
    assert len(calls) == 3


def test_a_row_made_under_other_library_defaults_is_redone(tmp_path, monkeypatch):
    import openmulti_env.runs.reproduce.runner as runner

    specs = table_runs("geometric", ["tiny"], [0])[:2]
    calls = []
    run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)
    calls.clear()
    made = runner.library_defaults
    monkeypatch.setattr(runner, "library_defaults",
                        lambda preset: {**made(preset), "consistency": {**made(preset)["consistency"], "render_weight": 1.0}})
    run_table(specs, "tiny", tmp_path, run_fn=_fake_run(calls), progress=False)  # eq. 13's weight changed since
    assert len(calls) == len(specs)


def _rows():
    rows = []
    for method, cr in (("openmulti", 80.0), ("dinerf_global", 60.0)):
        for seed in (0, 1, 2):
            rows.append({"method": method, "scene": "room0", "seed": seed, "agents": 4, "success_rate": 1.0,
                         "acc_cm": 2.0 + seed, "comp_cm": 3.0, "comp_ratio": cr + seed, "acc_cm_nice": 1.5,
                         "comp_cm_nice": 3.1, "comp_ratio_nice": cr, "acc_cm_unculled": None, "comp_cm_unculled": 4.0,
                         "comp_ratio_unculled": cr, "bytes_per_round": 2e6, "time_per_round_s": 5.0,
                         "bytes_per_round_series": [1e6, 2e6, 3e6], "f_miou": None, "f_macc": None})
    return rows


def test_json_and_markdown_writers_on_a_hand_made_row_set(tmp_path):
    rows = _rows()
    paths = write_table(tmp_path, "geometric", rows, notes="hand-made")
    data = json.loads(paths["json"].read_text())
    assert data == {"table": "geometric", "rows": rows}
    md = paths["md"].read_text()
    line = next(l for l in md.splitlines() if l.startswith("| openmulti |"))
    cells = [c.strip() for c in line.strip("|").split("|")]
    assert cells[3] == "3"  # n runs
    assert cells[4] == "3.00 ± 1.00"  # acc over seeds 2, 3, 4
    assert cells[6] == "81.00 ± 1.00"
    assert cells[-1] == "2.47 / 3.52 / 81.52"  # the paper's Table I
    assert "| - |" in line or " - " in line  # all-None unculled accuracy
    assert paths["png"].stat().st_size > 1000
    assert "hand-made" in md
    m, sd = mean_sd([1.0, None, 3.0])
    assert m == 2.0 and sd == pytest.approx(np.sqrt(2.0))
    assert "comp_ratio" in markdown_table("comm-failure", rows)
    write_table(tmp_path, "transmission", rows)
    assert "| openmulti | 100 % | 4 | 3 | 2.00 ± 0.00 | 1.00 ± 0.00 | 3.00 ± 0.00 |" in (tmp_path / "transmission.md").read_text()




def test_tables_only_writes_the_finished_runs_and_makes_none(tmp_path, capsys):
    calls = []
    reproduce("comm-failure", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run(calls), progress=False,
              methods=["openmulti"])
    assert len(calls) == 4
    written = reproduce("comm-failure", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run(calls), progress=False,
                        run_missing=False)
    assert len(calls) == 4  # nothing more was run
    assert [r["method"] for r in written["comm-failure"]] == ["openmulti"] * 4
    said = capsys.readouterr().out
    assert "8 of 12 runs not made yet" in said and "dinerf_global_tiny_s0_a4_p020_tiny" in said
    assert json.loads((tmp_path / "comm-failure.json").read_text())["rows"] == written["comm-failure"]

def test_several_scenes_get_a_per_scene_section():
    rows = _rows() + [{**r, "scene": "office0", "comp_ratio": 50.0} for r in _rows() if r["method"] == "openmulti"]
    md = markdown_table("geometric", rows)
    section = md[md.index("Per scene"):]
    assert "| method | success | agents | office0 | room0 (settings chosen here) |" in section
    # openmulti: office0 50 (all seeds), room0 80-82 free space; 80 NICE-SLAM and unculled in both
    assert "| openmulti | 100 % | 4 | 50.00 ± 0.00 / 80.00 ± 0.00 / 80.00 ± 0.00 | 81.00 ± 1.00 / 80.00 ± 0.00 / 80.00 ± 0.00 |" in section
    assert "| dinerf_global | 100 % | 4 | - / - / - | 61.00 ± 1.00 / 60.00 ± 0.00 / 60.00 ± 0.00 |" in section
    assert "Per scene" not in markdown_table("geometric", _rows())


def test_scenes_never_used_for_a_choice_are_reported_apart():
    held = [{**r, "scene": "room1", "comp_ratio": 10.0} for r in _rows()]
    md = markdown_table("geometric", _rows() + held)
    main, apart = md.split("## Scenes never used for a choice (room1)")
    assert "Scenes room0 (settings chosen here)" in main and "room1" not in main
    assert "Scenes room1;" in apart and "| 10.00 ± 0.00 |" in apart  # their own means, not mixed into room0's
    assert "10.00" not in main

def test_unknown_names_get_a_clear_error_listing_the_known_ones(tmp_path):
    with pytest.raises(ValueError, match="unknown table 'table9'.*geometric.*comm-failure"):
        reproduce("table9", ["room0"], [0], "tiny", tmp_path)
    with pytest.raises(ValueError, match="unknown method 'vmap'.*openmulti_no_cross"):
        get_method("vmap")
    with pytest.raises(ValueError, match="unknown scene 'kitchen9'.*room0.*office4"):
        reproduce("geometric", ["kitchen9"], [0], "tiny", tmp_path, run_fn=_fake_run([]))
    from openmulti_env.runs.cli import main

    assert main(["reproduce", "--table", "tables", "--out", str(tmp_path)]) == 2



def test_methods_filter_runs_only_those_and_names_the_tables_methods(tmp_path):
    calls = []
    written = reproduce("all", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run(calls), progress=False,
                        methods=["pointcloud_sharing", "single"])
    assert set(written) == {"geometric", "semantic", "transmission"}  # the tables holding either method
    assert sorted({r["method"] for rows in written.values() for r in rows}) == ["pointcloud_sharing", "single"]
    assert len(calls) == 2  # single is in two tables, made once
    with pytest.raises(ValueError, match="not in table 'comm-failure'.*dinerf_global, dinerf_global_stale, openmulti"):
        reproduce("comm-failure", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run([]), methods=["single"])


def test_success_rates_filter_runs_only_that_column_and_names_the_tables_rates(tmp_path):
    calls = []
    written = reproduce("comm-failure", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run(calls), progress=False,
                        methods=["openmulti", "dinerf_global"], success_rates=[0.2])
    assert sorted((r["method"], r["success_rate"]) for r in written["comm-failure"]) == [
        ("dinerf_global", 0.2), ("openmulti", 0.2)]
    assert len(calls) == 2
    with pytest.raises(ValueError, match=r"link success rates \[0.3\] are not in table 'comm-failure'.*0.2, 0.5, 0.8, 1"):
        reproduce("comm-failure", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run([]), success_rates=[0.3])
    with pytest.raises(ValueError, match="link success rates .* not in table 'geometric'.*its rates: 1$"):
        reproduce("geometric", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run([]), success_rates=[0.5])
    from openmulti_env.runs.cli import main

    assert main(["reproduce", "--table", "comm-failure", "--success-rates", "0.3", "--out", str(tmp_path)]) == 2

# ---- each culling on a hand-made mesh -------------------------------------------------------------
def _two_walls():
    """A front wall at z = 2 and a second wall behind it at z = 3 (both 2 x 2 m, facing -z), and a
    square off to the side at x = 5 no camera looks at."""
    def square(cx, z, size=2.0):
        h = size / 2
        v = np.array([[cx - h, -h, z], [cx + h, -h, z], [cx + h, h, z], [cx - h, h, z]])
        return trimesh.Trimesh(v, [[0, 2, 1], [0, 3, 2]], process=False)
    return trimesh.util.concatenate([square(0.0, 2.0), square(0.0, 3.0, 1.0), square(5.0, 2.0)])


def test_nice_slam_culling_keeps_faces_in_a_frustum_and_not_behind_the_observed_depth():
    mesh = _two_walls()
    k = Intrinsics(width=64, height=64, fx=32.0, fy=32.0, cx=31.5, cy=31.5)  # 90 degrees
    pose = np.eye(4)[None]  # at the origin, looking along +z
    depth = np.full((1, 64, 64), 2.0)  # the front wall is what the camera saw
    frustum_only = cull_to_frustums(mesh, pose, k)
    assert len(frustum_only.faces) == 4  # both walls in view, the side square outside
    culled = cull_to_frustums(mesh, pose, k, depth)
    assert len(culled.faces) == 2 and np.allclose(culled.vertices[:, 2], 2.0)  # the hidden wall is gone
    assert len(cull_to_frustums(mesh, pose, k, depth, depth_slack_m=1.5).faces) == 4


def test_free_space_culling_and_unculled_scoring_on_a_hand_made_box():
    from mapping.pipeline.scoring import score_three_ways
    from mapping.evaluate.visibility import cull_to_viewpoints

    gt = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    inner = trimesh.creation.box(extents=(0.5, 0.5, 0.5))  # hallucinated inside the box: no viewpoint sees it
    rec = trimesh.util.concatenate([gt.subdivide().subdivide(), inner])
    viewpoints = np.array([[3.0, 0.0, 0.0], [-3.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, -3.0, 0.0],
                           [0.0, 0.0, 3.0], [0.0, 0.0, -3.0]])
    culled = cull_to_viewpoints(rec, viewpoints, group_m=None)
    assert np.abs(culled.vertices).max(axis=1).min() > 0.49  # only the outer box survives
    scores = score_three_ways(rec, gt, viewpoints, None, seed=0)
    assert scores["acc_cm"] < 1.0 < scores["acc_cm_unculled"]  # the inner box costs accuracy unculled only
    assert scores["comp_ratio"] == pytest.approx(100.0) and "acc_cm_nice" not in scores


def test_tradeoff_table_runs_each_policy_on_each_scene_and_marks_the_pareto_front(tmp_path):
    from openmulti_env.runs.reproduce.tradeoff import pareto_front

    calls = []
    written = reproduce("tradeoff", ["tiny"], [0, 1], "tiny", tmp_path, run_fn=_fake_run(calls), progress=False,
                        methods=["always", "never", "every:2"])
    assert sorted({c[1] for c in calls}) == ["always", "every:2", "never"] and len(calls) == 6
    rows = written["tradeoff"]
    assert {r["policy"] for r in rows} == {"always", "never", "every:2"}
    data = json.loads((tmp_path / "tradeoff.json").read_text())
    means = {m["policy"]: m for m in data["policies"]}
    assert means["every:2"]["bytes_vs_always"] == pytest.approx(0.5)
    assert means["every:2"]["delta_vs_always"] == pytest.approx(-15.0)
    md = (tmp_path / "tradeoff.md").read_text()
    assert means["every:2"]["delta_nice_vs_always"] == pytest.approx(-10.0)
    assert "| every:2 | 2 | 64.5 ± 0.7 | 0.0 ± 0.0 | 50 % | -15.0 | yes | 79.5 ± 0.7 | -10.0 | yes |" in md  # sd 0: none
    assert (tmp_path / "tradeoff.png").stat().st_size > 1000
    assert pareto_front([(1.0, 50.0), (2.0, 40.0), (3.0, 60.0)]) == [0, 2]
    reproduce("tradeoff", ["tiny"], [2], "tiny", tmp_path, run_fn=_fake_run([]), progress=False, methods=["always"])
    written = reproduce("tradeoff", ["tiny"], [0, 1, 2], "tiny", tmp_path, run_fn=_fake_run([]), progress=False,
                        run_missing=False)
    md = (tmp_path / "tradeoff.md").read_text()
    assert len(written["tradeoff"]) == 7 and "| always | 2 |" in md  # seed 2 has only always: not in the means
    assert "Left out until every policy has run its cell: 1 runs on tiny seed 2" in md
    with pytest.raises(ValueError, match="not in table 'tradeoff'"):
        reproduce("tradeoff", ["tiny"], [0], "tiny", tmp_path, run_fn=_fake_run([]), methods=["sometimes"])


def test_a_setting_added_at_its_old_behaviour_leaves_recorded_rows_valid():
    from dataclasses import replace

    from mapping.model.agent_config import MappingConfig
    from mapping.pipeline.records import settings_record
    from openmulti_env.runs.reproduce.runner import library_defaults

    assert "free_space_rays" not in library_defaults("fast")["mapping"]  # rows from before it still match
    assert settings_record(replace(MappingConfig(), free_space_rays="crossing"))["free_space_rays"] == "crossing"
    assert settings_record(MappingConfig())["sampler"]["n_surface"] == 9  # nested configs kept whole


def test_the_papers_orderings_are_weighed_over_paired_runs():
    from openmulti_env.runs.reproduce.orderings import verdicts, weigh

    assert weigh([]) == ("not run", None, None)
    assert weigh([1.5])[0] == "one run"
    assert weigh([2.0, 2.2, 1.8])[0] == "holds"
    assert weigh([-2.0, -2.2, -1.8])[0] == "missed"
    assert weigh([2.0, -0.5, 1.0])[0] == "within noise"  # one pair of the other sign
    assert weigh([0.1, 5.0])[0] == "within noise"  # same sign, mean within two standard errors

    def row(method, seed, comp, rate=1.0, scene="room0"):
        return {"method": method, "scene": scene, "seed": seed, "success_rate": rate, "comp_ratio": comp,
                "comp_ratio_nice": comp + 1.0}
    rows = [row("openmulti", s, 90.0 + s) for s in range(3)] + [row("openmulti_no_cross", s, 89.0 + s * 1.1)
                                                                 for s in range(3)]  # differences 1.0, 0.9, 0.8
    rows.append(row("openmulti_no_cross", 7, 10.0))  # no openmulti run on seed 7: not paired
    cross = [v for v in verdicts("geometric", rows) if "Cross Rendering" in v.claim]
    assert [(v.key, v.pairs, v.verdict) for v in cross] == [("comp_ratio", 3, "holds"), ("comp_ratio_nice", 3, "holds")]
    rows += [row("openmulti", 3, 90.0), row("openmulti_no_cross", 3, 91.5)]  # a fourth pair the other way
    cross = [v for v in verdicts("geometric", rows) if "Cross Rendering" in v.claim]
    assert cross[0].pairs == 4 and cross[0].verdict == "within noise" and cross[0].low == pytest.approx(-1.5)
    failing = [row(m, s, full, 1.0) for m, full in (("openmulti", 90.0), ("dinerf_global", 60.0)) for s in (0, 1)]
    failing += [row("openmulti", s, 81.0 + s, 0.2) for s in (0, 1)] + [row("dinerf_global", s, 30.0, 0.2) for s in (0, 1)]
    loss = [v for v in verdicts("comm-failure", failing) if v.key == "comp_ratio"][0]
    assert loss.pairs == 2 and loss.verdict == "holds"  # openmulti loses 10 / 8.9 %, dinerf_global 50 %
    assert loss.mean == pytest.approx(50.0 - (10.0 + 100 * 8.0 / 90.0) / 2)


def test_the_schedules_table_runs_each_policy_in_each_link_scenario_and_writes_one_tradeoff_each(tmp_path):
    calls, options = [], []
    fake = _fake_run(calls)

    def run(scene, agents, policy, preset, seed, out, **kwargs):
        options.append((policy, {k: v for k, v in kwargs.items() if k in ("link_range_m", "link_mb_per_round",
                                                                         "float16", "changed_only")}))
        return fake(scene, agents, policy, preset, seed, out, **kwargs)

    written = reproduce("schedules", ["tiny"], [0], "tiny", tmp_path, run_fn=run, progress=False)
    rows = written["schedules"]
    assert len(rows) == len(calls) == 3 * 10 and len({r["policy"] for r in rows}) == 10
    assert ("always", {"float16": True, "changed_only": 0.01, "link_range_m": 2.0}) in options  # always+changed
    assert ("every:4", {"link_mb_per_round": 0.25}) in options
    for scenario in ("unlimited", "range", "bandwidth"):
        table = (tmp_path / "schedules" / scenario / "tradeoff.md").read_text()
        assert f"Link scenario `{scenario}`" in table and "always+changed" in table
