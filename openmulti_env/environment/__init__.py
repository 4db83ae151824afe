"""The PettingZoo env: the parallel env (``parallel_env.py``: ``OpenMultiParallelEnv``, ``parallel_env``, the AEC
forms ``raw_env`` and ``env``), its settings (``config``), observations (``observation``, laid out as
``layout`` says), actions and pictures.

The env's names load on first use: ``layout``, the observation contract policies import, stays a leaf that
loads neither the simulator nor the team. ``openmulti_env.environment.parallel_env`` is the module; the
function is ``openmulti_env.parallel_env`` (or ``openmulti_env.openmulti_v0.parallel_env``).
"""

from __future__ import annotations

import importlib

__all__ = ["INFO_KEYS", "RENDER_MODES", "OpenMultiParallelEnv", "env", "raw_env"]


def __getattr__(name: str):
    if name in __all__:
        return getattr(importlib.import_module("openmulti_env.environment.parallel_env"), name)
    raise AttributeError(f"module 'openmulti_env.environment' has no attribute {name!r}")
