"""The simulated world of one episode: a scene, its observable ground truth, and the agents' paths.

``World.build`` does the geometry once (scene, culling, path planning); frames are rendered on demand
by the pyrender sensor, so planning and coverage never need a GL context.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mapping.config_fields import bounded
from mapping.data import Frame, Intrinsics
from openmulti_env.world.coverage import CoverageReport, coverage_report
from openmulti_env.world.paths import PathConfig, plan_agent_paths
from openmulti_env.world.presets import make_scene
from mapping.evaluate.raycast import MeshRaycaster
from openmulti_env.world.scene import Scene
from openmulti_env.world.sensor import RGBDSensor, SensorConfig
from openmulti_env.world.visibility import FreeSpaceConfig, ObservableSurface, compute_observable_surface, free_space_viewpoints

# With one agent, it follows this many region paths in turn (the paper's single-agent "OpenSingle"
# setting sees what the default team sees, with one mapper).
SINGLE_AGENT_REGIONS = 4
MAX_AGENTS = 8


@dataclass(frozen=True)
class WorldConfig:
    """Everything that shapes the simulated world, apart from the scene name and seed."""

    num_agents: int = field(default=4, metadata=bounded(1, MAX_AGENTS))
    """Agents in the team, one path each (each maps its own region)."""
    path: PathConfig = field(default_factory=PathConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    free_space: FreeSpaceConfig = field(default_factory=FreeSpaceConfig)
    culling_edge_m: float = field(default=0.05, metadata=bounded(0.01, 10))
    """Faces are split to this edge length before culling (the granularity of the culled mesh)."""


@dataclass
class World:
    """Scene + observable ground truth + one camera path per agent."""

    scene: Scene
    surface: ObservableSurface
    agent_poses: list[np.ndarray]
    intrinsics: Intrinsics
    config: WorldConfig
    seed: int
    _sensor: RGBDSensor | None = None
    _caster: MeshRaycaster | None = None

    @staticmethod
    def build(scene: str | Scene = "room0", seed: int = 0, config: WorldConfig | None = None) -> "World":
        """Build (or take) the scene, cull its surface, plan the paths."""
        cfg = config or WorldConfig()
        if not 1 <= cfg.num_agents <= MAX_AGENTS:
            raise ValueError(f"num_agents must be between 1 and {MAX_AGENTS}, got {cfg.num_agents}")
        sc = scene if isinstance(scene, Scene) else make_scene(scene, seed)
        viewpoints = free_space_viewpoints(sc, cfg.free_space)
        caster = MeshRaycaster(sc.mesh(), sc.face_instance_ids())
        surface = compute_observable_surface(sc, viewpoints, max_edge_m=cfg.culling_edge_m, caster=caster)
        intrinsics = cfg.sensor.intrinsics()
        n_regions = SINGLE_AGENT_REGIONS if cfg.num_agents == 1 else cfg.num_agents
        paths = plan_agent_paths(surface, caster, n_regions, intrinsics, cfg.path, seed=seed,
                                 spacing_m=cfg.free_space.spacing_m)
        if cfg.num_agents == 1:
            paths = [np.concatenate(paths)]
        return World(sc, surface, paths, intrinsics, cfg, seed, _caster=caster)

    @property
    def num_agents(self) -> int:
        """Number of agents (paths)."""
        return len(self.agent_poses)

    @property
    def caster(self) -> MeshRaycaster:
        """Ray caster on the full scene mesh, labelled by instance id."""
        if self._caster is None:
            self._caster = MeshRaycaster(self.scene.mesh(), self.scene.face_instance_ids())
        return self._caster

    @property
    def sensor(self) -> RGBDSensor:
        """The pyrender camera (created on first use)."""
        if self._sensor is None:
            self._sensor = RGBDSensor(self.scene, self.config.sensor, seed=self.seed)
        return self._sensor

    def render(self, agent: int, index: int) -> Frame:
        """Frame ``index`` of ``agent``'s path."""
        poses = self.agent_poses[agent]
        if not 0 <= index < len(poses):
            raise IndexError(f"agent {agent} has {len(poses)} frames, asked for frame {index}")
        return self.sensor.render(poses[index], index=index)

    def coverage(self, n_points: int = 30000, stride: int = 2) -> CoverageReport:
        """Coverage of the observable surface by each agent and by the team."""
        gt, _, _ = self.surface.sample_points(n_points, seed=self.seed)
        return coverage_report(self.caster, gt, self.agent_poses, self.intrinsics, stride)

    def close(self) -> None:
        """Release the GL context."""
        if self._sensor is not None:
            self._sensor.close()
            self._sensor = None
