"""``openmulti_v0``: the versioned env module, as PettingZoo's families name theirs
(``from openmulti_env import openmulti_v0; openmulti_v0.parallel_env(preset="rl_tiny")``)."""

from openmulti_env.environment.parallel_env import OpenMultiParallelEnv, env, parallel_env, raw_env

__all__ = ["OpenMultiParallelEnv", "env", "parallel_env", "raw_env"]
