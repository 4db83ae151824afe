"""Results rendered from rows (``studies.results``): stamps from the rows or from git, staleness computed from the
commits after them (neutral and documentation-only commits aside), no crash without git, ``made_at`` written by
``openmulti reproduce`` and kept out of row reuse, the demo rows file, and the committed pages are today's."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from openmulti_env.runs.made_at import code_commit, made_at
from openmulti_env.runs.reproduce.runner import run_table
from openmulti_env.runs.reproduce.tables import table_runs
from openmulti_env.runs.reproduce.tradeoff import tradeoff_lines
from studies import demo_results, results
from studies.staleness import Git, RowsStamp, Stamp, jsonl_rows, read_neutral, stamp_rows, staleness

ROOT = Path(__file__).resolve().parents[1]
HAS_HISTORY = Git(ROOT).available and Git(ROOT).commit("63896a5") is not None
CODE = ("mapping/",)


def git(repo: Path, *args: str) -> str:
    return subprocess.run(["git", "-C", str(repo), "-c", "user.name=t", "-c", "user.email=t@t", "-c",
                           "commit.gpgsign=false", *args], capture_output=True, text=True, check=True).stdout.strip()


def commit(repo: Path, files: dict[str, str], message: str) -> str:
    for name, text in files.items():
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        (repo / name).write_text(text)
    git(repo, "add", "-A")
    git(repo, "commit", "-q", "-m", message)
    return git(repo, "rev-parse", "HEAD")


@pytest.fixture()
def repo(tmp_path: Path) -> Path:
    git(tmp_path, "init", "-q")
    commit(tmp_path, {"mapping/team.py": "A = 1\n"}, "code")
    return tmp_path


def table_staleness(repo: Path, neutral: dict[str, str] | None = None):
    g = Git(repo)
    rows, stamps = jsonl_rows(g, repo, "docs/rows.jsonl")
    return staleness(g, [stamp_rows(g, "docs/rows.jsonl", rows, stamps)], CODE, neutral or {})


def test_rows_go_stale_when_a_later_commit_changes_the_code_they_measure(repo):
    made = commit(repo, {"docs/rows.jsonl": '{"completion": 50.0}\n\n{"completion": 51.0}\n'}, "rows")
    g = Git(repo)
    rows, stamps = jsonl_rows(g, repo, "docs/rows.jsonl")
    assert rows == [{"completion": 50.0}, {"completion": 51.0}] and {s.commit for s in stamps} == {made}
    assert table_staleness(repo).known and not table_staleness(repo).stale

    commit(repo, {"docs/notes.md": "words\n", "mapping/README.md": "what the code does\n"}, "docs only")
    assert not table_staleness(repo).stale  # documentation, even inside a measured folder, measures nothing

    code = commit(repo, {"mapping/team.py": "A = 2\n"}, "code changed")
    found = table_staleness(repo)
    assert found.stale and [c.hash for c in found.commits] == [code] and found.commits[0].subject == "code changed"
    assert results.stale_text(found).startswith(f"**Stale:** 1 commit since these rows changed the code they measure "
                                                f"(first: `{code[:7]}` ")

    neutral_file = repo / "neutral.txt"
    neutral_file.write_text(f"# checked\n{code} a rename, the same figures\n")
    assert not table_staleness(repo, read_neutral(neutral_file)).stale

    later = commit(repo, {"docs/rows.jsonl": '{"completion": 50.0}\n\n{"completion": 51.0}\n{"completion": 52.0}\n'},
                   "one more row")
    rows, stamps = jsonl_rows(Git(repo), repo, "docs/rows.jsonl")
    assert [s.commit for s in stamps] == [made, made, later]  # each row its own line's commit
    assert table_staleness(repo).stale  # the older rows still predate the code change


def test_a_rows_own_made_at_is_its_stamp_and_a_version_is_an_unknown_one(repo):
    first = git(repo, "rev-parse", "HEAD")
    commit(repo, {"mapping/team.py": "A = 3\n"}, "code after")
    g = Git(repo)
    stamp = stamp_rows(g, "docs/table.json", [{"made_at": {"commit": first, "date": "2026-12-01"}}])
    assert stamp.stamps == (Stamp(first, "2026-12-01"),)
    assert staleness(g, [stamp], CODE, {}).stale
    packaged = stamp_rows(g, "docs/table.json", [{"made_at": {"commit": "openmulti 0.1.0", "date": "2026-12-01"}}])
    found = staleness(g, [packaged], CODE, {})
    assert not found.known and "openmulti 0.1.0" in found.reason
    assert "stamp unknown" in results.stamp_text(packaged)
    elsewhere = RowsStamp("x", 1, (Stamp("f" * 40, "2026-12-01"),))
    assert "not in this history" in staleness(g, [elsewhere], CODE, {}).reason


def test_without_git_stamps_are_unknown_and_nothing_crashes(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "rows.jsonl").write_text('{"completion": 50.0}\n')
    ctx = results.Context(tmp_path, Git(tmp_path), {})
    assert not ctx.git.available
    section = results.Section("A table", ("docs/rows.jsonl",), CODE, lambda files: [f"{len(files[0])} row"])
    text = "\n".join(results.render_section(ctx, section))
    assert "1 row, stamp unknown (no git history here)" in text and "Staleness unknown: no git history here." in text
    kept = stamp_rows(ctx.git, "x.json", [{"made_at": {"commit": "a" * 40, "date": "2026-12-01"}}])
    assert kept.stamps == (Stamp("a" * 40, "2026-12-01"),)  # a row's own stamp needs no git
    assert code_commit(tmp_path).startswith("openmulti ")  # not a checkout: the package version
    assert results.check(ctx, tmp_path) == [results.PAGE, results.README]  # cannot be checked: said, every time


def fake_run(calls: list):
    def run(scene, agents, policy, preset, seed, out, **kwargs):
        calls.append(policy)
        return {"mean": {"acc_cm": 2.0, "comp_cm": 3.0, "comp_ratio": 80.0, "f_miou": 50.0, "f_macc": 60.0},
                "bytes_sent_total": 24000, "team": {"f_miou": 55.0, "f_macc": 65.0}, "config": {"agents": agents},
                "rounds": 2, "bytes_per_round": [4000, 8000], "fleet_s": 8.0, "compute_s": {"agent_0": 3.0},
                "agents": {"agent_0": {"instances": 5}}, "wall_s": 1.0, "map": {"kind": "x"}}
    return run


def test_reproduce_rows_carry_made_at_which_decides_nothing_about_reuse(tmp_path):
    specs = table_runs("comm-failure", ["tiny"], [0])[:2]
    calls: list = []
    rows = run_table(specs, "tiny", tmp_path, run_fn=fake_run(calls), progress=False)
    assert len(calls) == 2
    for row in rows:
        assert row["made_at"]["commit"] == code_commit() and re.fullmatch(r"\d{4}-\d\d-\d\d", row["made_at"]["date"])
    if Git(ROOT).available:
        assert re.fullmatch(r"[0-9a-f]{40}", rows[0]["made_at"]["commit"])
    row_file = tmp_path / "rows" / f"{specs[0].key('tiny')}.json"
    data = json.loads(row_file.read_text())
    assert "made_at" in data["row"] and "made_at" not in json.dumps(data["settings"])
    del data["row"]["made_at"]  # a row made before made_at existed
    row_file.write_text(json.dumps(data))
    again = run_table(specs, "tiny", tmp_path, run_fn=fake_run(calls), progress=False)
    assert len(calls) == 2 and "made_at" not in again[0]  # reused as it is, not redone
    assert made_at()["commit"] == code_commit()


def test_the_demo_rows_file_is_recorded_from_a_run_and_rendered_as_the_readmes_table(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    agent = {"comp_ratio": 88.0, "instances": 3}
    (run / "metrics.json").write_text(json.dumps({
        "evaluated": True, "agents": {"agent_0": agent, "agent_1": {**agent, "comp_ratio": 90.0}},
        "mean": {"acc_cm": 1.5, "comp_cm": 4.0, "comp_ratio": 89.0, "f_miou": 90.0, "f_macc": 94.0,
                 "depth_median_cm": 0.5, "depth_off_pct": 5.0},
        "bytes_sent_total": 48_000_000, "bytes_per_round_per_agent_mean": 2_000_000.0,
        "messages": {"delivered": 24, "dropped": 0, "over_budget": 0}, "wall_s": 360.0,
        "config": {"scene": "room0", "preset": "demo", "seed": 0, "run": {"policy": "always"}}}))
    assert results.main(["--record-demo", str(run)], root=tmp_path) == 0
    demo = demo_results.read(tmp_path / results.DEMO_ROWS)
    assert demo.command == "openmulti run --scene room0 --agents 2 --policy always --preset demo --seed 0"
    assert demo.made_at.commit == code_commit()
    assert demo_results.table_lines(demo)[2] == "| mean of 2 agents | 1.50 | 4.00 | 89.00 | 90.00 | 94.00 | 0.50 | 5.00 | 2.00 | 24 |"
    assert demo_results.details(demo) == "per agent: completion ratio 88.00 / 90.00 %; 48.00 MB sent; 6 minutes"
    with pytest.raises(ValueError, match="README.md: expected one"):
        results.with_block("no markers\n", "block\n", "README.md")


def test_the_trade_off_table_rendered_here_is_the_one_reproduce_wrote():
    rows = json.loads((ROOT / "docs/reproduce/fast/tradeoff.json").read_text())["rows"]
    assert "\n".join(tradeoff_lines(rows)) in (ROOT / "docs/reproduce/fast/tradeoff.md").read_text()


@pytest.fixture(scope="module")
def generated() -> list[results.Page]:
    return results.pages(results.context(ROOT))


@pytest.mark.skipif(not HAS_HISTORY, reason="needs the repository's git history")
def test_the_committed_pages_are_what_the_rows_render(generated, capsys):
    assert results.differing(generated, ROOT) == [], "run python -m studies.results --write"
    assert results.main(["--check"]) == 0
    assert capsys.readouterr().out == ""


@pytest.mark.skipif(not HAS_HISTORY, reason="needs the repository's git history")
def test_check_names_the_page_whose_generated_text_was_edited(generated, tmp_path, capsys):
    for page in generated:
        (tmp_path / page.path).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / page.path).write_text(page.text)
    readme = tmp_path / results.README
    readme.write_text(readme.read_text().replace("| mean of", "| the mean of", 1))
    ctx = results.context(ROOT)
    assert results.check(ctx, tmp_path) == [results.README]
    assert "README.md: not what the rows files render" in capsys.readouterr().out
    page = tmp_path / results.PAGE
    page.write_text(page.read_text().replace("**Stale:**", "Fresh:", 1))
    assert results.check(ctx, tmp_path) == [results.PAGE, results.README]
    shutil.rmtree(tmp_path / "docs")
    assert results.PAGE in results.check(ctx, tmp_path)


@pytest.mark.skipif(not HAS_HISTORY, reason="needs the repository's git history")
def test_issue_44s_observed_spaces_make_the_rows_made_before_them_stale():
    ctx = results.context(ROOT)
    observed = Git(ROOT).commit("63896a5")
    by_title = {s.title: s for s in results.sections(ctx)}
    table = by_title["Table I (geometric), preset `fast`"]
    found = staleness(ctx.git, [results.read_rows_file(ctx, f).stamp for f in table.files], table.measures, ctx.neutral)
    assert found.stale and observed.hash in {c.hash for c in found.commits}
    for neutral in read_neutral(ROOT / results.NEUTRAL):  # every neutral commit is one of this history's
        assert ctx.git.commit(neutral) is not None
