"""Shared fixtures: small worlds built once per test session (building is the slow part), one world cache
for every xdist worker, and how the session runs on few cores: each worker pinned to its share of the cores,
the slowest tests first, and Python's garbage collector kept off what every test leaves alive."""

from __future__ import annotations

import fcntl
import gc
import os
from contextlib import contextmanager
from pathlib import Path

import pytest

os.environ.setdefault("OPENMULTI_GL", "egl")


def _pin_xdist_worker() -> None:
    """Give each pytest-xdist worker its own share of the cores (``-n auto`` on 2 cores: one core each).

    Torch sizes its OpenMP pool, and ``mapping.runtime.set_threads`` its default, from the cores a process
    may run on: unpinned, two workers run 2 + 2 threads on 2 cores, and OpenMP threads of two processes
    stall each other (mapping/runtime.py measured a 10 ms step at 670 ms). Processes a test starts (Ray,
    multiprocessing) inherit the share. ``OPENMULTI_TEST_PIN=0`` leaves the workers unpinned."""
    worker, count = os.environ.get("PYTEST_XDIST_WORKER", ""), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if os.environ.get("OPENMULTI_TEST_PIN", "1") == "0" or not worker.startswith("gw") or count < 2:
        return
    try:
        cores = sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return
    index = int(worker[2:])
    share = cores[index::count] if len(cores) >= count else [cores[index % len(cores)]]
    os.sched_setaffinity(0, share)
    import torch  # noqa: PLC0415  (its pool may have been sized before the pinning)

    torch.set_num_threads(len(share))


_pin_xdist_worker()


@pytest.fixture(scope="session")
def tiny_scene():
    from openmulti_env.world import make_scene

    return make_scene("tiny")


@pytest.fixture(scope="session")
def tiny_world(tiny_scene):
    from openmulti_env.experiment.presets import world_config
    from openmulti_env.world import World

    world = World.build(tiny_scene, seed=0, config=world_config("tiny", 2))
    yield world
    world.close()


# ---- one world cache for the whole run ------------------------------------------------------------------
@pytest.fixture(scope="session")
def shared_world_cache(tmp_path_factory) -> Path:
    """A world cache folder (``cache_dir``) every test and every xdist worker of this run shares: a world is
    built once per run, not once per module and worker. The session's own temporary folder (each worker's
    basetemp is a folder in it), so every run starts cold. For tests that only read worlds: a test about
    cache misses, corrupt entries or reward baselines played keeps a folder of its own."""
    base = tmp_path_factory.getbasetemp()
    root = base.parent if os.environ.get("PYTEST_XDIST_WORKER") else base
    folder = root / "shared-world-cache"
    folder.mkdir(exist_ok=True)
    return folder


@contextmanager
def _file_lock(path: Path):
    with open(path, "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def warm_world_cache(**env_kwargs) -> None:
    """Put the world ``parallel_env(**env_kwargs)`` resets into its ``cache_dir`` (built by one worker while
    the others wait for it, instead of each building it at once; the env then reads it as any warm env)."""
    from openmulti_env import parallel_env
    from openmulti_env.world.cache import cached_world, world_cache_dir, world_cache_key

    env = parallel_env(**env_kwargs)
    cfg = env.config
    folder = world_cache_dir(cfg.env.cache_dir)
    folder.mkdir(parents=True, exist_ok=True)
    with _file_lock(folder / f".{world_cache_key(cfg.scene, env.world_seed, cfg.world)}.lock"):
        world, _ = cached_world(cfg.scene, env.world_seed, cfg.world, cfg.env.cache_dir, cfg.env.cache_max_mb)
        world.close()
    env.close()


@pytest.fixture(scope="session")
def warm_env_kwargs(shared_world_cache):
    """``warm_env_kwargs(**kwargs)``: ``kwargs`` with the run's shared world cache as ``cache_dir`` (unless they
    name one), after that env's world was put in it (``warm_world_cache``)."""
    def warm(**kwargs):
        kwargs = {"cache_dir": str(shared_world_cache), **kwargs}
        warm_world_cache(**kwargs)
        return kwargs
    return warm


# ---- the garbage collector ----------------------------------------------------------------------------------
# What a test leaves alive (imported modules: torch, transformers, Ray; caches; session fixtures) is frozen
# (gc.freeze) once the test is torn down, after a collection of its garbage: a full collection then scans only
# what later tests make. Unfrozen, every full collection walked millions of objects (pyrender collects at each
# renderer's delete, twice per world closed): 14 % of the env tests' time went to it.
def pytest_collection_finish(session):
    gc.collect()
    gc.freeze()


@pytest.hookimpl(trylast=True)
def pytest_runtest_teardown(item, nextitem):
    gc.collect()
    gc.freeze()


# ---- the slowest tests first ---------------------------------------------------------------------------------
# pytest-xdist's worksteal hands each worker an equal share of the collection, in order, and an idle worker
# steals the tail of a busy one's queue. So each share is made of about equal estimated seconds, its modules
# ordered by their slowest test (each module's tests in file order): the long tests start first on every
# worker and the run ends on short ones. A module stays in one share (its module fixtures, a Ray cluster say,
# set up once) unless it is long or large. Estimates are the last run's durations (kept in pytest's cache,
# .pytest_cache), else per-module guesses from a measured run.
DURATIONS_KEY = "openmulti/durations"
MODULE_SECONDS = {  # seconds per test, measured on 2 cores (a module's mean; its slowest tests first anyway)
    "test_train_rllib.py": 17.0, "test_remote_members.py": 14.0, "test_paths_coverage.py": 10.0,
    "test_cli.py": 10.0, "test_reproduce.py": 8.0, "test_env_api.py": 6.0, "test_ray_grid.py": 6.0,
    "test_depth_check.py": 4.5, "test_data_run.py": 4.0, "test_reward_front.py": 3.5, "test_env_clients.py": 3.5,
    "test_env_behaviour.py": 3.0, "test_learning.py": 2.0, "test_fleet.py": 2.0, "test_env_observation.py": 4.0,
    "test_policy_files.py": 1.0, "test_team.py": 0.8, "test_links_and_instances.py": 0.8, "test_codec.py": 1.5,
}
DEFAULT_SECONDS = 0.3
SPLIT_MODULE_SECONDS, SPLIT_MODULE_TESTS = 60.0, 100  # a module longer or larger than this is shared out by test


def pytest_collection_modifyitems(config, items):
    workers = int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1"))
    if workers < 2 or len(items) < 2 * workers:
        return
    cache = getattr(config, "cache", None)
    known = cache.get(DURATIONS_KEY, {}) if cache is not None else {}
    seconds = [float(known.get(item.nodeid, MODULE_SECONDS.get(item.path.name, DEFAULT_SECONDS))) for item in items]

    modules: dict[Path, list[int]] = {}
    for index, item in enumerate(items):
        modules.setdefault(item.path, []).append(index)
    units = []  # lists of item indices that go to one share
    for tests in modules.values():
        whole = sum(seconds[i] for i in tests) <= SPLIT_MODULE_SECONDS and len(tests) <= SPLIT_MODULE_TESTS
        units += [tests] if whole else [[i] for i in tests]
    units.sort(key=lambda unit: -sum(seconds[i] for i in unit))  # longest first, each to the lightest share

    sizes, left = [], len(items)  # the shares worksteal hands out: what is left // workers left
    for remaining in range(workers, 0, -1):
        sizes.append(left // remaining)
        left -= sizes[-1]
    shares: list[list[int]] = [[] for _ in sizes]
    load = [0.0] * workers
    while units:
        unit = units.pop(0)
        room = [s for s in range(workers) if len(shares[s]) + len(unit) <= sizes[s]]
        if not room:  # too many tests for what is left of any share: its tests one by one
            units[:0] = [[i] for i in unit]
            continue
        share = min(room, key=lambda s: load[s])
        shares[share] += unit
        load[share] += sum(seconds[i] for i in unit)
    order = []
    for share in shares:
        slowest: dict[Path, float] = {}
        for index in share:
            slowest[items[index].path] = max(slowest.get(items[index].path, 0.0), seconds[index])
        order += sorted(share, key=lambda i: (-slowest[items[i].path], str(items[i].path), i))
    items[:] = [items[i] for i in order]


_durations: dict[str, float] = {}


def pytest_runtest_logreport(report):
    _durations[report.nodeid] = _durations.get(report.nodeid, 0.0) + report.duration  # setup, call, teardown


def pytest_sessionfinish(session):
    cache = getattr(session.config, "cache", None)
    if cache is None or os.environ.get("PYTEST_XDIST_WORKER") or not _durations:
        return  # the controller (or a run without xdist) writes; workers only read
    cache.set(DURATIONS_KEY, {**cache.get(DURATIONS_KEY, {}), **{k: round(v, 3) for k, v in _durations.items()}})
