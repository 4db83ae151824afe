"""OpenMulti environment: the PettingZoo env, the simulated world it runs in, and the CLI.

``from openmulti_env import parallel_env, env, raw_env`` (imported on first use, so that the CLI and the
world stay light); importing the package registers ``openmulti/openmulti-v0`` in PettingZoo's registry
(``pettingzoo.make("parallel", "openmulti/openmulti-v0", preset="rl_tiny")``).
"""

from __future__ import annotations

import importlib

ENV_ID = "openmulti/openmulti-v0"
_ENV_NAMES = ("parallel_env", "env", "raw_env", "OpenMultiParallelEnv")


def __getattr__(name: str):
    if name in _ENV_NAMES:
        return getattr(importlib.import_module("openmulti_env.environment.parallel_env"), name)
    if name == "openmulti_v0":
        return importlib.import_module("openmulti_env.openmulti_v0")
    raise AttributeError(f"module 'openmulti_env' has no attribute {name!r}")


def _register() -> None:
    """Register the AEC and parallel forms where PettingZoo has a registry (1.27 and later)."""
    try:
        from pettingzoo import aec_registry, parallel_registry, register  # noqa: PLC0415
    except ImportError:
        return
    if ENV_ID not in parallel_registry:
        register("parallel", ENV_ID, entry_point="openmulti_env.openmulti_v0:parallel_env")
    if ENV_ID not in aec_registry:
        register("aec", ENV_ID, entry_point="openmulti_env.openmulti_v0:env")


_register()
__all__ = ["ENV_ID", *_ENV_NAMES]
