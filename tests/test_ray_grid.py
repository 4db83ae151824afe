"""The reproduction grid as Ray tasks (``openmulti reproduce --ray``): rows land in the same keyed
``rows/`` as the sequential runner, a killed worker's run is made again, a run that fails is named and
the others still land, and a grid resumes from the rows on disk."""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

import pytest
import ray

from openmulti_env.runs.reproduce.ray_grid import GridError
from openmulti_env.runs.reproduce.runner import run_table
from openmulti_env.runs.reproduce.tables import table_runs

ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])  # workers cannot import a test module


def _metrics(agents: int, seed: int) -> dict:
    return {"mean": {"acc_cm": 2.0 + seed, "comp_cm": 3.0, "comp_ratio": 80.0 - seed, "f_miou": 50.0, "f_macc": 60.0},
            "bytes_sent_total": 24000, "team": {"f_miou": 55.0, "f_macc": 65.0}, "config": {"agents": agents},
            "rounds": 4, "bytes_per_round": [4000, 4000, 8000, 8000], "fleet_s": 8.0, "compute_s": {"agent_0": 3.0},
            "agents": {"agent_0": {"instances": 5}}, "wall_s": 1.0, "map": {"kind": "x"}}


def _attempts(out: Path) -> list[str]:
    path = Path(out) / "attempts"
    return path.read_text().split() if path.exists() else []


def _recording_run(scene, agents, policy, preset, seed, out, **kwargs):
    """A stand-in run that books each attempt (its process id) in its run folder; the first attempt of
    seed 1 under ``bernoulli:0.5`` waits long enough to be killed, the one under ``bernoulli:0.2`` fails."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    first = not _attempts(out)
    with (out / "attempts").open("a") as fh:
        fh.write(f"{os.getpid()}\n")
    if seed == 1 and policy == "bernoulli:0.5" and first and not kwargs.get("global_map"):
        time.sleep(60)
    if seed == 1 and policy == "bernoulli:0.2" and not kwargs.get("global_map"):
        raise RuntimeError("the scene's world cache is unreadable")
    return _metrics(agents, seed)


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False)
    yield
    ray.shutdown()


def test_ray_grid_survives_a_killed_worker_and_names_a_failed_run(tmp_path, local_ray):
    specs = [s for s in table_runs("comm-failure", ["tiny"], [0, 1]) if s.method == "openmulti"]  # 8 runs
    victim = next(s for s in specs if s.seed == 1 and s.policy == "bernoulli:0.5")
    victim_dir = tmp_path / "runs" / victim.key("tiny")

    def kill_first_attempt():
        deadline = time.time() + 900  # Ray's workers start slowly on a loaded 2-core machine (120 s was missed twice)
        while time.time() < deadline and not _attempts(victim_dir):
            time.sleep(0.05)
        os.kill(int(_attempts(victim_dir)[0]), signal.SIGKILL)  # the worker dies mid-run

    killer = threading.Thread(target=kill_first_attempt, daemon=True)
    killer.start()
    with pytest.raises(GridError, match="(?s)1 of 8 runs failed.*p020.*RuntimeError: the scene.s world cache is unreadable"):
        run_table(specs, "tiny", tmp_path, run_fn=_recording_run, progress=False, ray_address="local")
    killer.join()
    attempts = _attempts(victim_dir)
    assert len(attempts) == 2 and attempts[0] != attempts[1]  # made again, by another worker
    written = sorted(p.stem for p in (tmp_path / "rows").glob("*.json"))
    failed = next(s for s in specs if s.seed == 1 and s.policy == "bernoulli:0.2").key("tiny")
    assert written == sorted(s.key("tiny") for s in specs if s.key("tiny") != failed)


def test_ray_grid_resumes_from_rows_on_disk_and_matches_the_sequential_rows(tmp_path, local_ray):
    specs = [s for s in table_runs("comm-failure", ["tiny"], [0]) if s.method == "openmulti"]  # 4 runs, seed 0
    sequential = run_table(specs[:2], "tiny", tmp_path / "seq", run_fn=_recording_run, progress=False)
    for spec in specs[:2]:  # half the grid was made on another machine: copy its rows
        name = f"{spec.key('tiny')}.json"
        (tmp_path / "grid" / "rows").mkdir(parents=True, exist_ok=True)
        (tmp_path / "grid" / "rows" / name).write_text((tmp_path / "seq" / "rows" / name).read_text())
    rows = run_table(specs, "tiny", tmp_path / "grid", run_fn=_recording_run, progress=False, ray_address="local")
    made = [s for s in specs if _attempts(tmp_path / "grid" / "runs" / s.key("tiny"))]
    assert made == specs[2:]  # only the missing half ran
    strip = lambda row: {k: v for k, v in row.items() if k != "run_s"}  # noqa: E731
    assert [strip(r) for r in rows[:2]] == [strip(r) for r in sequential]
    assert [r["policy"] for r in rows] == [s.policy for s in specs] and all(r is not None for r in rows)
