"""The env's settings: the configuration tree (``openmulti_env.experiment``) of a preset with keyword overrides,
the same table ``openmulti run`` uses, so a name means the same episode in both.

``rl`` (the default) and ``rl_tiny`` are the RL-sized presets; ``tiny``, ``demo``, ``fast`` and ``full`` are the
runs' episodes. Any field of the tree can be overridden by keyword, by its short spelling
(``parallel_env(..., rays_per_object=100)``, ``openmulti_env.experiment.overrides.ALIASES``) or by its dotted path
with the dots as double underscores (``team__exchange__float16=True``); an unknown keyword names the nearest
known ones.
"""

from __future__ import annotations

from mapping.runtime import available_cores
from openmulti_env.experiment import ALIASES, ConfigError, Experiment, experiment
from openmulti_env.experiment.overrides import leaf_paths
from openmulti_env.experiment.presets import PRESET_NAMES
from openmulti_env.experiment.tree import DEFAULT_PRESETS

DEFAULT_PRESET = DEFAULT_PRESETS["env"]
ENV_THREADS = 1
"""The env's torch threads unless given (``run.threads``): its batches are small, several envs often share a
machine, and a second thread waiting on a busy core slowed a ``tiny`` step 30x here."""

FIELD_NAMES = tuple(sorted(set(ALIASES) | set(leaf_paths(Experiment))))
"""Every keyword ``parallel_env`` takes besides its named arguments (short spellings and dotted paths)."""


def env_config(preset: str = DEFAULT_PRESET, **overrides) -> Experiment:
    """The preset's tree (or ``config=``, a whole tree such as a run's ``config.yaml`` read back) with ``overrides`` applied (``None`` values keep the preset's, except for the fields
    whose None means something: horizon, comm_budget_mb, changed_only, cache_dir, ...). ValueError (a
    ``ConfigError``) naming the bad option."""
    if preset not in PRESET_NAMES:
        raise ConfigError(f"unknown preset {preset!r}; choose one of {PRESET_NAMES}")
    base = overrides.pop("config", None)
    if base is not None and not isinstance(base, Experiment):
        raise ConfigError(f"config must be an openmulti_env.experiment.Experiment (e.g. read_config(PATH)), got "
                          f"{type(base).__name__}")
    given = {k.replace("__", "."): v for k, v in overrides.items()}
    if base is None:
        given.setdefault("threads", ENV_THREADS)
    tree = experiment(preset, given, base=base)
    if tree.num_agents < 2:
        raise ConfigError(f"num_agents must be between 2 and 8 in the env (agents talk to peers), got {tree.num_agents}")
    return tree


def pettingzoo_arguments(num_agents: int | None, max_cycles: int | None, overrides: dict) -> tuple[int | None, dict]:
    """PettingZoo's ``num_agents`` and ``max_cycles`` beside the tree's short spellings ``agents`` and ``horizon``:
    the team size and the overrides with the horizon set; ValueError when a pair disagrees."""
    overrides = dict(overrides)
    if max_cycles is not None and overrides.get("horizon") is not None and overrides["horizon"] != max_cycles:
        raise ValueError(f"max_cycles={max_cycles} and horizon={overrides['horizon']} disagree; give one")
    if max_cycles is not None:
        overrides["horizon"] = max_cycles
    if "agents" in overrides:
        if num_agents is not None and overrides["agents"] != num_agents:
            raise ValueError(f"num_agents={num_agents} and agents={overrides['agents']} disagree; give one")
        num_agents = overrides.pop("agents")
    return num_agents, overrides


def env_workers(tree: Experiment) -> int:
    """Agent worker threads of the env: ``run.workers``, or one per core up to one per agent."""
    return tree.run.workers or max(1, min(tree.num_agents, available_cores()))
