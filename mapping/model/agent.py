"""One agent's instance-level mapper (vMAP-style): ingest frames, train the batched instance fields on
keyframe rays, mesh the instances. Knows nothing of other agents; the team code adds the exchange.

The training step reads top to bottom: sample rays per instance from the keyframe buffer -> sample
points along them -> evaluate every instance's field in one batched call -> render termination
weights -> data loss (eq. 8-11) -> one AdamW step on the stacked parameters.
"""

from __future__ import annotations

from dataclasses import asdict
from pathlib import Path
from typing import Callable

import numpy as np
import torch
import trimesh

from mapping.model.agent_config import MappingConfig
from mapping.model.bounds import InstanceBound
from mapping.model.checkpoint import load_checkpoint, save_checkpoint
from mapping.data import Frame, Intrinsics
from mapping.evaluate import colour_vertices, extract_instance_mesh
from mapping.model.field import FieldOutput, LiveRows
from mapping.model.training_batch import TrainingBatch
from mapping.model.banks import instance_banks
from mapping.model.instance_frames import refit_frames
from mapping.model.instances import ExportedInstance, InstanceFrame, InstanceSlot
from mapping.model.optim import AdamConfig, StackedAdam
from mapping.model.keyframes import KeyframeBuffer
from mapping.model.losses import data_loss, free_space_loss
from mapping.model.observed_field import ObservedRows, ReachSamples, observed_faces
from mapping.model.observed_map import ObservedMaps
from mapping.model.sdf_field import SdfBatch, SdfFieldBank, sdf_batch
from mapping.runtime import flushed_denormals, resolve_device
from mapping.model.render import (CompositeConfig, CompositeRender, RayBundle, ray_aabb, render_image,
                            render_occupancy, sample_along_rays)


class MappingAgent:
    """Instance-level implicit map of one agent.

    Args:
        config: mapping settings.
        is_structure: tells whether an instance id is a wall/floor/ceiling (wider network, more rays).
        device: "cpu", "cuda" or "auto".
        seed: drives network initialisation and ray sampling.
        init_seed: draws the initial networks instead of ``seed`` (a team's global map: the same for every
            agent, ``TeamConfig.shared_global_init``).
    """

    def __init__(self, config: MappingConfig | None = None, is_structure: Callable[[int], bool] = lambda _: False,
                 device: str = "auto", seed: int = 0, agent_index: int = 0, init_seed: int | None = None):
        self.config = config or MappingConfig()
        self.is_structure = is_structure
        self.device = resolve_device(device)
        self.seed = seed
        self.agent_index = agent_index
        self.rng = np.random.default_rng(seed)
        # Generators live on the device they draw for: ``generator`` samples rays on ``device``;
        # ``init_generator`` (CPU) draws initial networks, so a seed gives the same network anywhere.
        self.generator = torch.Generator(device=self.device).manual_seed(seed)
        self.init_generator = torch.Generator().manual_seed(seed if init_seed is None else init_seed)
        sdf = self.config.structure_sdf
        self.banks = instance_banks(self.config, self.device)
        adam = {name: AdamConfig(lr=self.config.lr) for name in self.banks}
        if sdf is not None:
            adam["structure"] = AdamConfig(lr=sdf.lr, weight_decay=sdf.weight_decay)
        self.optimisers = {name: StackedAdam(bank, adam[name]) for name, bank in self.banks.items()}
        self.slots: dict[int, InstanceSlot] = {}
        self.keyframes = KeyframeBuffer(self.device, self.config.keyframe_capacity, self.config.keyframe_policy,
                                        seed=seed)
        self.observed = ObservedMaps(self.config.observed_cell_m, self.config.observed_ray_stride)
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
        self.observed.observe_keyframe(frame, instance, {i: (s.bound.lo, s.bound.hi) for i, s in self.slots.items()
                                                         if s.alive}, set(seen))
        return True

    def _update_instance(self, iid: int, bound: InstanceBound) -> None:
        slot = self.slots.get(iid)
        if slot is None:
            name = "structure" if self.is_structure(iid) else "object"
            frame = {}
            if self.config.global_frame is not None:
                cx, cy, cz, half = self.config.global_frame
                frame = {"frame_centre": torch.tensor([[cx, cy, cz]]), "frame_half": torch.tensor([half])}
            row = self.banks[name].add_instances(1, torch.as_tensor(bound.lo[None]), torch.as_tensor(bound.hi[None]),
                                                 generator=self.init_generator, **frame)[0]
            self.slots[iid] = InstanceSlot(name, row, bound, frame_origin=self.agent_index)
            return
        grown = slot.bound.union(bound)
        if np.any(grown.lo < slot.bound.lo - 1e-6) or np.any(grown.hi > slot.bound.hi + 1e-6):
            self._set_bound(iid, grown)

    def _set_bound(self, iid: int, bound: InstanceBound) -> None:
        """Grow an instance's box; move it to a larger frame (same provenance, next version) if the box
        left its frame's cube by more than ``frame_limit``."""
        slot = self.slots[iid]
        slot.bound = bound
        bank = self.banks[slot.bank]
        bank.set_bounds([slot.row], torch.as_tensor(bound.lo[None]), torch.as_tensor(bound.hi[None]))
        if float(bank.frame_coverage([slot.row])[0]) > self.config.frame_limit:
            centre, half = bank.default_frame(torch.as_tensor(bound.lo[None], dtype=torch.float32, device=bank.device),
                                              torch.as_tensor(bound.hi[None], dtype=torch.float32, device=bank.device))
            frame = InstanceFrame(tuple(float(c) for c in centre[0]), float(half[0]), slot.frame_origin,
                                  slot.frame_version + 1)
            self.set_frame(iid, frame)

    def frame_of(self, iid: int) -> InstanceFrame:
        """The instance's current frame."""
        slot = self.slots[iid]
        bank = self.banks[slot.bank]
        centre = bank.frame_centre[slot.row].tolist()
        return InstanceFrame((centre[0], centre[1], centre[2]), float(bank.frame_half[slot.row]), slot.frame_origin,
                             slot.frame_version)

    def set_frame(self, iid: int, frame: InstanceFrame) -> None:
        """Move an instance to ``frame`` (its network refit by distillation, its optimiser state reset)."""
        self.set_frames({iid: frame})

    def set_frames(self, frames: dict[int, InstanceFrame]) -> None:
        """Move several instances to new frames: one batched distillation per bank."""
        by_bank: dict[str, list[int]] = {}
        for iid in frames:
            by_bank.setdefault(self.slots[iid].bank, []).append(iid)
        for name, ids in by_bank.items():
            bank = self.banks[name]
            rows = [self.slots[i].row for i in ids]
            with flushed_denormals():
                refit_frames(bank, rows, torch.tensor([frames[i].centre for i in ids]),
                             torch.tensor([frames[i].half for i in ids]), steps=self.config.refit_steps,
                             generator=self.generator)
            self.optimisers[name].reset_rows(rows)
            for i in ids:
                self.slots[i].frame_origin, self.slots[i].frame_version = frames[i].origin, frames[i].version

    # ---- what peers exchange ---------------------------------------------------------------------
    def live_ids(self) -> list[int]:
        """Ids of the instances the map holds (merged ones excluded), sorted."""
        return sorted(i for i, s in self.slots.items() if s.alive)

    def export_instance(self, iid: int) -> ExportedInstance:
        """The instance's network, box and frame, for a peer."""
        slot = self.slots[iid]
        bank = self.banks[slot.bank]
        return ExportedInstance(iid, slot.bank, bank.get_instance_params(slot.row).cpu().numpy(),
                                slot.bound.lo.copy(), slot.bound.hi.copy(), self.frame_of(iid),
                                self.observed.export(iid, slot.bound.lo, slot.bound.hi))

    def adopt_instance(self, iid: int, instance: ExportedInstance) -> None:
        """Take a peer's instance whole under the new id ``iid`` (network, box, frame): it renders at
        once and trains on consistency and shared rays until this agent sees it itself."""
        if iid in self.slots:
            raise ValueError(f"instance id {iid} already exists in this map")
        if instance.bank not in self.banks:
            raise ValueError(f"unknown bank {instance.bank!r} of adopted instance {instance.instance_id}")
        bank = self.banks[instance.bank]
        if instance.params.shape != (bank.param_dim,):
            raise ValueError(f"adopted instance {instance.instance_id}: {instance.params.shape[0]} parameters, "
                             f"this agent's {instance.bank} networks have {bank.param_dim} (widths differ?)")
        f = instance.frame
        row = bank.add_instances(1, torch.as_tensor(instance.bound_lo[None]), torch.as_tensor(instance.bound_hi[None]),
                                 frame_centre=torch.tensor([f.centre]), frame_half=torch.tensor([f.half]),
                                 params=torch.as_tensor(instance.params[None]))[0]
        self.slots[iid] = InstanceSlot(instance.bank, row, InstanceBound(np.asarray(instance.bound_lo, np.float64),
                                                                          np.asarray(instance.bound_hi, np.float64)),
                                        frame_origin=f.origin, frame_version=f.version)
        self.observed.add(iid, instance.observed)

    def merge_instances(self, source: int, target: int) -> None:
        """``source`` is a piece of ``target`` (over-segmentation): its pixels join ``target``'s, the
        box grows to hold both, and ``source``'s network is retired; a ``target`` with no network yet
        (seen in no keyframe so far) takes ``source``'s network over."""
        if source == target:
            return
        self.observed.merge(source, target)
        if target not in self.slots:
            self.slots[target] = self.slots.pop(source)
            self.keyframes.merge_ids(source, target)
            return
        src, dst = self.slots[source], self.slots[target]
        self.keyframes.merge_ids(source, target)
        src.alive = False
        self._set_bound(target, dst.bound.union(src.bound))

    def grow_bound(self, iid: int, bound: InstanceBound) -> None:
        """Union the instance's box with ``bound`` (e.g. a peer's box of the same object)."""
        self._update_instance(iid, bound)

    # ---- training --------------------------------------------------------------------------------
    def train(self, iterations: int | None = None, extra_loss: Callable[[], torch.Tensor] | None = None) -> float:
        """Run optimisation steps on all instances; returns the last total loss.

        ``extra_loss`` (a callable returning a scalar tensor) is added to every step's data loss: the
        team's consistency terms (eq. 12-13)."""
        loss = 0.0
        with flushed_denormals():  # 40x slower steps otherwise (mapping.runtime)
            for _ in range(iterations or self.config.iterations_per_keyframe):
                loss = self.train_step(extra_loss)
        return loss

    def trainable_ids(self, bank: str) -> list[int]:
        """Live instances of ``bank`` that the held keyframes show (adopted, unseen ones have no data)."""
        return [iid for iid, s in sorted(self.slots.items())
                if s.bank == bank and s.alive and self.keyframes.has_pixels(iid)]

    def training_batches(self) -> list[TrainingBatch | SdfBatch]:
        """One step's rays and samples per bank (the keyframe rays of every trainable instance, samples
        inside its box): what ``data_loss`` evaluates the field on, apart so that a fleet can evaluate
        every agent's batches in one computation (``mapping.model.fleet``). A MACIM scene network gets an
        ``SdfBatch`` per row instead."""
        batches: list[TrainingBatch | SdfBatch] = []
        for name, bank in self.banks.items():
            ids = self.trainable_ids(name)
            if not ids:
                continue
            if isinstance(bank, SdfFieldBank):
                batches += [b for b in (self.sdf_batch(name, bank, iid) for iid in ids) if b is not None]
                continue
            rows = torch.as_tensor([self.slots[i].row for i in ids], device=self.device)
            n_rays = self.config.rays_per_structure if name == "structure" else self.config.rays_per_object
            boxes = None
            if self.config.free_space_rays == "crossing":
                boxes = (bank.bound_min[rows].cpu().numpy().astype(np.float64),
                         bank.bound_max[rows].cpu().numpy().astype(np.float64))
            rays = self.keyframes.sample(ids, n_rays, self.config.own_ray_fraction, self.rng, boxes)  # (N, R)
            bundle = RayBundle(rays.origins, rays.directions)
            lo, hi = bank.bound_min[rows][:, None], bank.bound_max[rows][:, None]
            t_near, t_far = ray_aabb(rays.origins, rays.directions, lo, hi)  # (N, R): the instance's box
            near, far = t_near.clamp(min=0.0), t_far.clamp(min=0.0)
            samples = sample_along_rays(bundle, rays.depth, rays.own, self.config.sampler, near=near, far=far,
                                        generator=self.generator)
            batches.append(TrainingBatch(name, rows, rays, samples, near, far))
        return batches

    def sdf_batch(self, name: str, bank: SdfFieldBank, iid: int) -> SdfBatch | None:
        """MACIM's samples of one step for a scene network (``mapping.model.sdf_field.sdf_batch``)."""
        rays = self.keyframes.sample([iid], bank.sdf_config.rays, 1.0, self.rng)
        return sdf_batch(name, self.slots[iid].row, rays, bank.sdf_config, self.generator)

    def add_batch_loss(self, total: torch.Tensor, batch: TrainingBatch | SdfBatch,
                       out: FieldOutput | None) -> torch.Tensor:
        """``total`` + eq. 11 (and the free-space term when weighted) of one bank's batch, given the
        field's output on ``batch.positions``; for an ``SdfBatch``, MACIM's loss (``out`` unused: it needs
        the signed distance and its gradient, evaluated here)."""
        if isinstance(batch, SdfBatch):
            return total + self.banks[batch.bank].batch_loss(batch)
        n, r, s = batch.samples.depths.shape
        rays, samples = batch.rays, batch.samples
        rendered = render_occupancy(out.occupancy.reshape(n, r, s), out.colour.reshape(n, r, s, 3), samples.depths)
        valid = ~samples.occluded & (batch.far > batch.near)  # rays that cross the box in front of the camera
        total = total + data_loss(rendered, rays.depth, rays.rgb, rays.own.float(), valid,
                                  self.config.loss_weights).total
        if self.config.loss_weights.free_space:
            total = total + self.config.loss_weights.free_space * free_space_loss(
                out.occupancy.reshape(n, r, s), samples.depths, rays.depth, valid, self.config.sampler.surface_eps_m)
        return total

    def data_loss(self) -> torch.Tensor:
        """Eq. 11 summed over both banks, on one batch of keyframe rays per instance."""
        total = torch.zeros((), device=self.device)
        for batch in self.training_batches():
            out = None if isinstance(batch, SdfBatch) else self.banks[batch.bank](batch.positions, batch.rows)
            total = self.add_batch_loss(total, batch, out)
        return total

    def step_optimisers(self, loss: torch.Tensor) -> float:
        """AdamW on every bank after ``loss``'s gradient was taken (no step when it has none); counts the step."""
        if loss.requires_grad:
            for optimiser in self.optimisers.values():
                optimiser.step()
        self.steps += 1
        return float(loss.detach())

    def train_step(self, extra_loss: Callable[[], torch.Tensor] | None = None) -> float:
        """One step: sample rays -> samples inside each box -> field -> render -> data loss (+ extra)
        -> AdamW on every bank."""
        loss = self.data_loss()
        if extra_loss is not None:
            loss = loss + extra_loss()
        for optimiser in self.optimisers.values():
            optimiser.zero_grad()
        if loss.requires_grad:
            loss.backward()
        return self.step_optimisers(loss)

    # ---- outputs ---------------------------------------------------------------------------------
    def instance_meshes(self) -> dict[int, trimesh.Trimesh]:
        """Marching cubes of every instance inside its box, faces only near surface it observed (instances
        that learned or saw nothing are left out)."""
        meshes = {}
        for iid, slot in sorted(self.slots.items()):
            if not slot.alive:
                continue
            bank = self.banks[slot.bank]
            voxel = self.config.structure_voxel_m if slot.bank == "structure" else self.config.object_voxel_m
            space = self.observed.get(iid)
            mesh = extract_instance_mesh(bank.occupancy_fn(slot.row), slot.bound.lo, slot.bound.hi,
                                         voxel_size_m=voxel, max_resolution=self.config.max_mesh_resolution,
                                         device=self.device, needed=None if space is None else ReachSamples(space))
            if mesh is not None and space is not None:
                mesh = observed_faces(mesh, space)
            if mesh is not None:  # coloured after the cut: only the vertices kept
                meshes[iid] = colour_vertices(mesh, bank.colour_fn(slot.row), device=self.device)
        return meshes

    @torch.no_grad()
    def render_view(self, pose: np.ndarray, intrinsics: Intrinsics, stride: int = 4,
                    samples_per_box: int = 24) -> CompositeRender:
        """Depth, colour and instance-id images of the whole map from ``pose`` (camera-to-world, OpenCV),
        every ``stride``-th pixel: all instances composited along each ray by depth."""
        fields, labels = [], []
        for name, bank in self.banks.items():
            rows = {s.row: iid for iid, s in self.slots.items() if s.bank == name and s.alive}
            if rows:
                ids = [rows[r] for r in sorted(rows)]
                fields.append(ObservedRows(LiveRows(bank, sorted(rows)), self.observed.numbered(dict(enumerate(ids)))))
                labels.append(torch.as_tensor(ids, device=self.device))
        c2w = torch.as_tensor(pose, dtype=torch.float32, device=self.device)
        return render_image(fields, c2w, intrinsics, CompositeConfig(samples_per_box=samples_per_box), stride=stride,
                            labels=labels)

    def observed_field(self, bank: str) -> ObservedRows:
        """``banks[bank]`` read only near observed surface (``mapping.model.observed_field``): what the env's
        observation and reward query."""
        return ObservedRows(self.banks[bank], self.observed.numbered({s.row: i for i, s in self.slots.items()
                                                                      if s.bank == bank}))

    # ---- checkpoints -----------------------------------------------------------------------------
    def save(self, path: str | Path) -> Path:
        """Parameters, optimiser state, bounds and counters, written atomically."""
        return save_checkpoint(path, self.state())

    def load(self, path: str | Path) -> None:
        """Restore a checkpoint written by ``save`` (the keyframe buffer is not part of it)."""
        self.restore(load_checkpoint(path, map_location="cpu"))

    def state(self) -> dict:
        """Everything ``save`` writes, as a dict of tensors, numbers, strings and lists."""
        return {
            "config": asdict(self.config),
            "banks": {n: {k: v.cpu() if torch.is_tensor(v) else v for k, v in b.state_dict().items()}
                      for n, b in self.banks.items()},
            "optimisers": {n: o.state_dict() for n, o in self.optimisers.items()},
            "slots": {int(iid): [s.bank, s.row, s.bound.lo.tolist(), s.bound.hi.tolist(), s.frame_origin,
                                 s.frame_version, s.alive] for iid, s in self.slots.items()},
            "frames_seen": self.frames_seen, "steps": self.steps, "observed": self.observed.state(),
            "rng": self.rng.bit_generator.state, "generator": self.generator.get_state().cpu(),
            "init_generator": self.init_generator.get_state(),
        }

    def restore(self, data: dict) -> None:
        """Inverse of ``state``."""
        for name, bank in self.banks.items():
            n = data["banks"][name]["params"].shape[0]
            if bank.num_instances < n:
                bank.add_instances(n - bank.num_instances, torch.zeros(n - bank.num_instances, 3),
                                   torch.ones(n - bank.num_instances, 3))
            bank.load_state_dict(data["banks"][name])
            self.optimisers[name].load_state_dict(data["optimisers"][name])
        self.slots = {int(i): InstanceSlot(b, int(r), InstanceBound(np.asarray(lo, np.float64), np.asarray(hi, np.float64)),
                                            int(origin), int(version), bool(alive))
                      for i, (b, r, lo, hi, origin, version, alive) in data["slots"].items()}
        self.frames_seen, self.steps = data["frames_seen"], data["steps"]
        self.observed.restore(data.get("observed", {}))
        self.rng.bit_generator.state = data["rng"]
        self.generator.set_state(data["generator"])
        self.init_generator.set_state(data["init_generator"])

