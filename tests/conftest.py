"""Shared fixtures: small worlds built once per test session (building is the slow part)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("OPENMULTI_GL", "egl")


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
