"""One agent's instance-level mapper (vMAP-style): ingest frames, train the batched instance fields on
keyframe rays, mesh the instances. Knows nothing of other agents; the team code adds the exchange.

The training step reads top to bottom: sample rays per instance from the keyframe buffer -> sample
points along them -> evaluate every instance's field in one batched call -> render termination
weights -> data loss (eq. 8-11) -> one AdamW step on the stacked parameters.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import trimesh

from mapping.bounds import InstanceBound
from mapping.checkpoint import load_checkpoint, save_checkpoint
from mapping.data import Frame, Intrinsics
from mapping.evaluate import extract_instance_mesh, merge_instance_meshes
from mapping.field import OBJECT_FIELD, STRUCTURE_FIELD, InstanceFieldBank, resolve_device
from mapping.optim import AdamConfig, StackedAdam
from mapping.keyframes import KeyframeBuffer
from mapping.losses import DataLossWeights, data_loss
from mapping.render import (CompositeConfig, CompositeRender, RayBundle, SamplerConfig, ray_aabb, render_image,
                            render_occupancy, sample_along_rays)


@dataclass
class MappingConfig:
    """How one agent maps (vMAP's values unless said otherwise)."""

    keyframe_every: int = 5
    """Every k-th frame becomes a keyframe (the first always does)."""
    iterations_per_keyframe: int = 20
    """Optimisation steps after each keyframe (vMAP: 20 per frame)."""
    rays_per_object: int = 120
    """Rays per object instance per step (vMAP: 120)."""
    rays_per_structure: int = 300
    """Rays per wall / floor / ceiling instance per step (vMAP's background uses 1200 on a GPU; with
    the 128-wide network that alone is ~30 GFLOP a step, too slow for a 2-core CPU)."""
    own_ray_fraction: float = 0.8
    """Share of an instance's rays on its own pixels; the rest on other surfaces in its 2D box."""
    sampler: SamplerConfig = field(default_factory=SamplerConfig)
    """Samples per ray (vMAP: 1 stratified + 9 around the surface), inside each instance's box."""
    loss_weights: DataLossWeights = field(default_factory=DataLossWeights)
    """lambda_1..3 of eq. 11 (vMAP: occupancy 10, depth 1, colour 5)."""
    structure_width: int = 64
    """Hidden width of wall / floor / ceiling networks (vMAP's background: 128 on a GPU; planes need
    less, and at 128 they take 90% of a CPU step)."""
    lr: float = 1e-3
    """AdamW learning rate."""
    object_voxel_m: float = 0.01
    """Marching-cubes voxel for objects."""
    structure_voxel_m: float = 0.02
    """Marching-cubes voxel for walls, floor and ceiling."""
    max_mesh_resolution: int = 256
    """Grid cap per axis (vMAP)."""


@dataclass
class _InstanceSlot:
    bank: str  # "object" or "structure"
    row: int
    bound: InstanceBound


class MappingAgent:
    """Instance-level implicit map of one agent.

    Args:
        config: mapping settings.
        is_structure: tells whether an instance id is a wall/floor/ceiling (wider network, more rays).
        device: "cpu", "cuda" or "auto".
        seed: drives network initialisation and ray sampling.
    """

    def __init__(self, config: MappingConfig | None = None, is_structure: Callable[[int], bool] = lambda _: False,
                 device: str = "auto", seed: int = 0):
        self.config = config or MappingConfig()
        self.is_structure = is_structure
        self.device = resolve_device(device)
        self.seed = seed
        self.rng = np.random.default_rng(seed)
        self.generator = torch.Generator().manual_seed(seed)
        self.banks = {"object": InstanceFieldBank(OBJECT_FIELD, self.device),
                      "structure": InstanceFieldBank(replace(STRUCTURE_FIELD, hidden_width=self.config.structure_width),
                                                     self.device)}
        self.optimisers = {name: StackedAdam(bank, AdamConfig(lr=self.config.lr)) for name, bank in self.banks.items()}
        self.slots: dict[int, _InstanceSlot] = {}
        self.keyframes = KeyframeBuffer(self.device)
        self.frames_seen = 0
        self.steps = 0

    # ---- ingest ----------------------------------------------------------------------------------
    def ingest(self, frame: Frame, instance: np.ndarray | None = None) -> bool:
        """Take one frame (with its instance image, default ``frame.instance``); returns True when it
        became a keyframe. New instances get a network; seen instances' boxes grow."""
        instance = frame.instance if instance is None else instance
        if instance is None:
            raise ValueError(f"frame {frame.index}: the mapper needs an instance image (segmenter output)")
        is_key = self.frames_seen % self.config.keyframe_every == 0
        self.frames_seen += 1
        if not is_key:
            return False
        seen = self.keyframes.add(frame, instance)
        for iid in seen:
            pts = frame.backproject(mask=instance == iid)
            bound = InstanceBound.from_points(pts)
            self._update_instance(iid, bound)
        return True

    def _update_instance(self, iid: int, bound: InstanceBound) -> None:
        slot = self.slots.get(iid)
        if slot is None:
            name = "structure" if self.is_structure(iid) else "object"
            row = self.banks[name].add_instances(1, torch.as_tensor(bound.lo[None]), torch.as_tensor(bound.hi[None]),
                                                 generator=self.generator)[0]
            self.slots[iid] = _InstanceSlot(name, row, bound)
            return
        grown = slot.bound.union(bound)
        if np.any(grown.lo < slot.bound.lo - 1e-6) or np.any(grown.hi > slot.bound.hi + 1e-6):
            slot.bound = grown
            self.banks[slot.bank].set_bounds([slot.row], torch.as_tensor(grown.lo[None]), torch.as_tensor(grown.hi[None]))

    # ---- training --------------------------------------------------------------------------------
    def train(self, iterations: int | None = None) -> float:
        """Run optimisation steps on all instances; returns the last total loss."""
        loss = 0.0
        for _ in range(iterations or self.config.iterations_per_keyframe):
            loss = self.train_step()
        return loss

    def train_step(self) -> float:
        """One step on every bank: sample rays -> samples inside each box -> field -> render -> loss -> AdamW."""
        total = 0.0
        for name, bank in self.banks.items():
            ids = [iid for iid, s in self.slots.items() if s.bank == name]
            if not ids:
                continue
            rows = torch.as_tensor([self.slots[i].row for i in ids], device=self.device)
            n_rays = self.config.rays_per_structure if name == "structure" else self.config.rays_per_object
            rays = self.keyframes.sample(ids, n_rays, self.config.own_ray_fraction, self.rng)  # (N, R)
            bundle = RayBundle(rays.origins, rays.directions)
            lo, hi = bank.bound_min[rows][:, None], bank.bound_max[rows][:, None]
            t_near, t_far = ray_aabb(rays.origins, rays.directions, lo, hi)  # (N, R): the instance's box
            near, far = t_near.clamp(min=0.0), t_far.clamp(min=0.0)
            samples = sample_along_rays(bundle, rays.depth, rays.own, self.config.sampler, near=near, far=far,
                                        generator=self.generator)
            n, r, s = samples.depths.shape
            out = bank(samples.positions.reshape(n, r * s, 3), rows)
            rendered = render_occupancy(out.occupancy.reshape(n, r, s), out.colour.reshape(n, r, s, 3), samples.depths)
            valid = ~samples.occluded & (far > near)  # rays that cross the box in front of the camera
            loss = data_loss(rendered, rays.depth, rays.rgb, rays.own.float(), valid, self.config.loss_weights).total
            self.optimisers[name].zero_grad()
            loss.backward()
            self.optimisers[name].step()
            total += float(loss.detach())
        self.steps += 1
        return total

    # ---- outputs ---------------------------------------------------------------------------------
    def instance_meshes(self) -> dict[int, trimesh.Trimesh]:
        """Marching cubes of every instance inside its box (instances that learned nothing are left out)."""
        meshes = {}
        for iid, slot in sorted(self.slots.items()):
            bank = self.banks[slot.bank]
            voxel = self.config.structure_voxel_m if slot.bank == "structure" else self.config.object_voxel_m
            mesh = extract_instance_mesh(bank.occupancy_fn(slot.row), slot.bound.lo, slot.bound.hi,
                                         voxel_size_m=voxel, max_resolution=self.config.max_mesh_resolution,
                                         color_fn=bank.colour_fn(slot.row), device=self.device)
            if mesh is not None:
                meshes[iid] = mesh
        return meshes

    @torch.no_grad()
    def render_view(self, pose: np.ndarray, intrinsics: Intrinsics, stride: int = 4,
                    samples_per_box: int = 24) -> CompositeRender:
        """Depth, colour and instance-id images of the whole map from ``pose`` (camera-to-world, OpenCV),
        every ``stride``-th pixel: all instances composited along each ray by depth."""
        fields, labels = [], []
        for name, bank in self.banks.items():
            rows = {s.row: iid for iid, s in self.slots.items() if s.bank == name}
            if rows:
                fields.append(bank)
                labels.append(torch.as_tensor([rows[r] for r in range(bank.num_instances)], device=self.device))
        c2w = torch.as_tensor(pose, dtype=torch.float32, device=self.device)
        return render_image(fields, c2w, intrinsics, CompositeConfig(samples_per_box=samples_per_box), stride=stride,
                            labels=labels)

    def scene_mesh(self) -> tuple[trimesh.Trimesh, np.ndarray]:
        """All instance meshes merged, with (n_vertices,) instance ids."""
        return merge_instance_meshes(self.instance_meshes())

    # ---- checkpoints -----------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Parameters, optimiser state, bounds and counters, written atomically."""
        return save_checkpoint(path, {
            "config": asdict(self.config),
            "banks": {n: b.state_dict() for n, b in self.banks.items()},
            "optimisers": {n: o.state_dict() for n, o in self.optimisers.items()},
            "slots": {iid: (s.bank, s.row, s.bound.lo, s.bound.hi) for iid, s in self.slots.items()},
            "frames_seen": self.frames_seen, "steps": self.steps,
            "rng": self.rng.bit_generator.state, "generator": self.generator.get_state(),
        })

    def load(self, path: str | Path) -> None:
        """Restore a checkpoint written by ``save`` (the keyframe buffer is not part of it)."""
        data = load_checkpoint(path, map_location=self.device)
        for name, bank in self.banks.items():
            n = data["banks"][name]["params"].shape[0]
            if bank.num_instances < n:
                bank.add_instances(n - bank.num_instances, torch.zeros(n - bank.num_instances, 3),
                                   torch.ones(n - bank.num_instances, 3))
            bank.load_state_dict(data["banks"][name])
            self.optimisers[name].load_state_dict(data["optimisers"][name])
        self.slots = {int(i): _InstanceSlot(b, int(r), InstanceBound(np.asarray(lo), np.asarray(hi)))
                      for i, (b, r, lo, hi) in data["slots"].items()}
        self.frames_seen, self.steps = data["frames_seen"], data["steps"]
        self.rng.bit_generator.state = data["rng"]
        self.generator.set_state(data["generator"])

