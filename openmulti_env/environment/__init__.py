"""The PettingZoo env: the parallel env (``parallel_env``), its AEC forms (``raw_env``, ``env``), its
settings (``config``), observations, actions and pictures."""

from openmulti_env.environment.parallel_env import (INFO_KEYS, RENDER_MODES, OpenMultiParallelEnv, env, parallel_env,
                                                    raw_env)

__all__ = ["INFO_KEYS", "RENDER_MODES", "OpenMultiParallelEnv", "env", "parallel_env", "raw_env"]
