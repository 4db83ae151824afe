"""The keyframe buffer and per-instance ray sampling from it (vMAP's training data).

Each keyframe keeps its RGB-D image, pose and instance image. For every instance the buffer indexes the
pixels where the instance was seen ("own" pixels: target occupancy 1, depth and colour supervised) and
the pixels of other surfaces inside the instance's 2D box ("other" pixels: the space in front of that
surface is free, so the instance must render occupancy 0 up to it).

Memory is bounded: the images live in tensors pre-allocated for ``capacity`` keyframes (RGB as uint8),
and once the buffer is full a new keyframe replaces an old one: the oldest (``policy="window"``, a
sliding set as vMAP's) or a uniformly random one with probability capacity / keyframes seen
(``policy="reservoir"``: the buffer stays a uniform sample of the whole history, so nothing the agent
saw early is forgotten for good). A replaced keyframe's pixels leave every instance's pools.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch

from mapping.data import Frame

MIN_MASK_PIXELS = 100  # OpenObj drops masks under 100 pixels
BOX_MARGIN_PX = 10  # the 2D box of an instance is grown by this much to find "other" pixels
KEYFRAME_POLICIES = ("reservoir", "window")


@dataclass
class InstanceRays:
    """Rays of one training step for a batch of instances, each (N, R, ...) with R rays per instance.

    Attributes:
        origins, directions: (N, R, 3) world; directions have unit z in the camera (depth = t).
        depth: (N, R) observed depth (metres; 0 = none).
        rgb: (N, R, 3) in [0, 1].
        own: (N, R) bool, the pixel belongs to the instance (target occupancy 1).
    """

    origins: torch.Tensor
    directions: torch.Tensor
    depth: torch.Tensor
    rgb: torch.Tensor
    own: torch.Tensor


@dataclass
class _InstancePixels:
    """Per keyframe slot, the flat pixel indices of one instance (own) and of other surfaces in its box."""

    own: dict[int, np.ndarray] = field(default_factory=dict)
    other: dict[int, np.ndarray] = field(default_factory=dict)
    _packed: tuple | None = None
    _keys: tuple | None = None

    def put(self, slot: int, own: np.ndarray, other: np.ndarray) -> None:
        self.own[slot], self.other[slot] = own.astype(np.int64), other.astype(np.int64)
        self._packed = None

    def drop(self, slot: int) -> None:
        if self.own.pop(slot, None) is not None:
            self.other.pop(slot, None)
            self._packed = None

    def absorb(self, other: "_InstancePixels") -> None:
        """Add another instance's pixels (two ids found to be one object)."""
        for slot in set(self.own) | set(other.own):
            own = np.concatenate([self.own.get(slot, np.zeros(0, np.int64)), other.own.get(slot, np.zeros(0, np.int64))])
            rest = np.concatenate([self.other.get(slot, np.zeros(0, np.int64)),
                                   other.other.get(slot, np.zeros(0, np.int64))])
            self.own[slot], self.other[slot] = np.unique(own), np.setdiff1d(rest, own)
        self._packed = None

    def packed(self) -> tuple:
        """(slots, own offsets, own sizes, own pixels, other offsets, other sizes, other pixels), cached."""
        if self._packed is None:
            slots = np.asarray(sorted(self.own), np.int64)
            parts = []
            for pools in (self.own, self.other):
                sizes = np.asarray([len(pools[s]) for s in slots], np.int64)
                offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) if len(sizes) else sizes
                pixels = np.concatenate([pools[s] for s in slots]) if len(slots) else np.zeros(0, np.int64)
                parts += [offsets, sizes, pixels]
            self._packed = (slots, *parts)
        return self._packed

    def own_keys(self, image_size: int) -> np.ndarray:
        """Sorted ``slot * image_size + pixel`` of every own pixel (to test candidates for membership),
        cached with ``packed``'s tuple."""
        packed = self.packed()
        if self._keys is None or self._keys[0] is not packed:
            slots, _, own_size, own_px = packed[:4]
            self._keys = (packed, np.repeat(slots, own_size) * image_size + own_px)  # sorted: slots, then pixels
        return self._keys[1]


def _draw(offsets: np.ndarray, sizes: np.ndarray, pixels: np.ndarray, entries: np.ndarray,
          generator: np.random.Generator) -> np.ndarray:
    """One random pixel of each listed entry (entries with an empty pool give -1)."""
    size = sizes[entries]
    if len(pixels) == 0:  # no pool has a pixel (a global map's "other surfaces": every pixel is its own)
        return np.full(len(entries), -1, np.int64)
    pick = offsets[entries] + np.floor(generator.random(len(entries)) * size).astype(np.int64)
    return np.where(size > 0, pixels[np.minimum(pick, max(len(pixels) - 1, 0))], -1)


class KeyframeBuffer:
    """At most ``capacity`` keyframes in pre-allocated tensors, with per-instance pixel indices.

    Args:
        device: where the images live.
        capacity: keyframes kept at once.
        policy: which keyframe a new one replaces when full: ``reservoir`` or ``window``.
        seed: drives the reservoir's choices.
    """

    def __init__(self, device: torch.device | str = "cpu", capacity: int = 100, policy: str = "reservoir",
                 seed: int = 0):
        if capacity < 1:
            raise ValueError(f"keyframe capacity must be >= 1, got {capacity}")
        if policy not in KEYFRAME_POLICIES:
            raise ValueError(f"unknown keyframe policy {policy!r}; choose one of {KEYFRAME_POLICIES}")
        self.device = torch.device(device)
        self.capacity, self.policy = capacity, policy
        self.rng = np.random.default_rng(seed)
        self.rgb: torch.Tensor | None = None  # (capacity, H*W, 3) uint8
        self.depth: torch.Tensor | None = None  # (capacity, H*W) metres
        self.poses = torch.zeros(capacity, 4, 4, device=self.device)  # camera-to-world
        self.rays_cam: torch.Tensor | None = None  # (H*W, 3) camera directions, z = 1
        self._camera: tuple | None = None  # ``camera()``, read from rays_cam
        self.index: dict[int, _InstancePixels] = {}
        self.slot_frame: list[int] = []  # frame index held by each used slot
        self.slot_instances: list[list[int]] = []
        self.seen = 0  # keyframes ever offered

    def __len__(self) -> int:
        return len(self.slot_frame)

    @property
    def frame_indices(self) -> list[int]:
        """Frame indices of the keyframes held now."""
        return list(self.slot_frame)

    def has_pixels(self, instance_id: int) -> bool:
        """True when some held keyframe shows the instance (else it cannot be trained on data)."""
        entry = self.index.get(instance_id)
        return entry is not None and any(len(p) for p in entry.own.values())

    def _allocate(self, h: int, w: int, k) -> None:
        v, u = np.mgrid[0:h, 0:w]
        cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, dtype=np.float64)], -1)
        self.rays_cam = torch.as_tensor(cam.reshape(-1, 3), dtype=torch.float32, device=self.device)
        self._camera = None
        self.rgb = torch.zeros(self.capacity, h * w, 3, dtype=torch.uint8, device=self.device)
        self.depth = torch.zeros(self.capacity, h * w, device=self.device)

    def _slot_for_new(self) -> int | None:
        """The slot a new keyframe goes to (None: the reservoir keeps its sample unchanged)."""
        if len(self.slot_frame) < self.capacity:
            self.slot_frame.append(-1)
            self.slot_instances.append([])
            return len(self.slot_frame) - 1
        if self.policy == "window":
            return int(np.argmin(self.slot_frame)) if self.slot_frame else 0
        j = int(self.rng.integers(self.seen))  # reservoir sampling (Algorithm R)
        return j if j < self.capacity else None

    def add(self, frame: Frame, instance: np.ndarray) -> list[int]:
        """Store a keyframe with its (corrected) instance image; returns the instance ids it indexed
        (empty when the reservoir kept its sample and the keyframe was not stored)."""
        k = frame.intrinsics
        h, w = frame.depth.shape
        if self.rays_cam is None:
            self._allocate(h, w, k)
        elif self.rays_cam.shape[0] != h * w:
            raise ValueError(f"frame {frame.index}: image size {w}x{h} differs from the earlier keyframes")
        self.seen += 1
        slot = self._slot_for_new()
        if slot is None:
            return []
        for iid in self.slot_instances[slot]:  # the replaced keyframe's pixels leave the pools
            if iid in self.index:
                self.index[iid].drop(slot)
        self.rgb[slot] = torch.as_tensor(np.ascontiguousarray(frame.rgb).reshape(-1, 3), device=self.device)
        self.depth[slot] = torch.as_tensor(frame.depth.reshape(-1), dtype=torch.float32, device=self.device)
        self.poses[slot] = torch.as_tensor(frame.pose, dtype=torch.float32, device=self.device)
        self.slot_frame[slot] = frame.index
        valid = frame.depth > 0
        seen = []
        ids, counts = np.unique(instance[valid], return_counts=True)
        for iid, n in zip(ids.tolist(), counts.tolist()):
            if iid == 0 or n < MIN_MASK_PIXELS:
                continue
            mask = (instance == iid) & valid
            rows, cols = np.nonzero(mask)
            r0, r1 = max(rows.min() - BOX_MARGIN_PX, 0), min(rows.max() + BOX_MARGIN_PX + 1, h)
            c0, c1 = max(cols.min() - BOX_MARGIN_PX, 0), min(cols.max() + BOX_MARGIN_PX + 1, w)
            box = np.zeros_like(mask)
            box[r0:r1, c0:c1] = True
            other = box & ~mask & valid
            self.index.setdefault(iid, _InstancePixels()).put(slot, np.flatnonzero(mask), np.flatnonzero(other))
            seen.append(iid)
        self.slot_instances[slot] = seen
        return seen

    def merge_ids(self, source: int, target: int) -> None:
        """Re-label ``source``'s pixels as ``target``'s (two ids found to be one object)."""
        entry = self.index.pop(source, None)
        if entry is None:
            return
        self.index.setdefault(target, _InstancePixels()).absorb(entry)
        for ids in self.slot_instances:
            if source in ids:
                ids[:] = sorted(set(ids) - {source} | {target})

    def sample(self, instance_ids: list[int], n_rays: int, own_fraction: float, generator: np.random.Generator,
               boxes: tuple[np.ndarray, np.ndarray] | None = None) -> InstanceRays:
        """``n_rays`` rays per instance from random keyframes that saw it: ``own_fraction`` of them on the
        instance, the rest on other surfaces inside its 2D box. With ``boxes`` ((N, 3) lo and hi of the
        instances' 3D boxes) the rest are rays of any held keyframe that cross the 3D box before their
        surface (``crossing_rays``), where there are enough of them: free space wherever a ray went."""
        n_own = int(round(n_rays * own_fraction))
        crossing = None if boxes is None else self.crossing_rays(instance_ids, *boxes, n_rays - n_own, generator)
        kf_all, px_all, own_all = [], [], []
        for i, iid in enumerate(instance_ids):
            if not self.has_pixels(iid):
                raise KeyError(f"instance {iid} has no pixels in the held keyframes (adopted or evicted); "
                               "check has_pixels before sampling")
            slots, own_off, own_size, own_px, oth_off, oth_size, oth_px = self.index[iid].packed()
            picks = generator.integers(len(slots), size=n_rays)
            own_draw = _draw(own_off, own_size, own_px, picks, generator)
            other_draw = _draw(oth_off, oth_size, oth_px, picks, generator)
            own = (np.arange(n_rays) < n_own) | (other_draw < 0)  # every kept slot has own pixels
            px = np.where(own, own_draw, other_draw)
            kf = slots[picks]
            if crossing is not None:
                c_kf, c_px, c_ok = (c[i] for c in crossing)
                kf[n_own:] = np.where(c_ok, c_kf, kf[n_own:])
                px[n_own:] = np.where(c_ok, c_px, px[n_own:])
                own[n_own:] &= ~c_ok
            kf_all.append(kf)
            px_all.append(px)
            own_all.append(own)
        kf = torch.as_tensor(np.stack(kf_all), device=self.device)  # (N, R)
        px = torch.as_tensor(np.stack(px_all), device=self.device)  # (N, R)
        poses = self.poses[kf]  # (N, R, 4, 4)
        directions = (poses[..., :3, :3] @ self.rays_cam[px].unsqueeze(-1)).squeeze(-1)  # (N, R, 3)
        return InstanceRays(
            origins=poses[..., :3, 3],
            directions=directions,
            depth=self.depth[kf, px],
            rgb=self.rgb[kf, px].float() / 255.0,
            own=torch.as_tensor(np.stack(own_all), device=self.device),
        )

    def camera(self) -> tuple[int, int, float, float, float, float]:
        """(height, width, fx, fy, cx, cy) of the held keyframes, read back once from the camera rays."""
        if self._camera is None:
            cam = self.rays_cam  # (H*W, 3): ((u - cx) / fx, (v - cy) / fy, 1), row-major
            w = int((cam[:, 1] == cam[0, 1]).sum())
            h = cam.shape[0] // w
            fx = 1.0 / float(cam[1, 0] - cam[0, 0]) if w > 1 else 1.0
            fy = 1.0 / float(cam[w, 1] - cam[0, 1]) if h > 1 else 1.0
            self._camera = (h, w, fx, fy, -float(cam[0, 0]) * fx, -float(cam[0, 1]) * fy)
        return self._camera

    @torch.no_grad()
    def crossing_rays(self, instance_ids: list[int], lo: np.ndarray, hi: np.ndarray, n_rays: int,
                      generator: np.random.Generator, candidates: int = 4) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Per instance, ``n_rays`` pixels of held keyframes whose rays enter its 3D box (``lo``, ``hi``:
        (N, 3)) in front of the surface they observed and are not its own pixels: each says the box is
        empty up to that surface, wherever the instance was segmented or not (vMAP only uses the pixels
        of the 2D box around the instance's mask, so a box seen without its mask keeps whatever it
        invents there). Candidates are drawn in the box's projection into each keyframe.

        Returns:
            (N, n_rays) keyframe slots, pixels, and whether the entry holds such a ray (too few found: False).
        """
        n, k = len(instance_ids), len(self.slot_frame)
        out = (np.zeros((n, n_rays), np.int64), np.zeros((n, n_rays), np.int64), np.zeros((n, n_rays), bool))
        if n == 0 or k == 0 or n_rays == 0:
            return out
        h, w, fx, fy, cx, cy = self.camera()
        poses = self.poses[:k].cpu().numpy().astype(np.float64)
        corners = np.stack(np.meshgrid([0, 1], [0, 1], [0, 1], indexing="ij"), -1).reshape(8, 3)
        corners = np.where(corners[None], hi[:, None], lo[:, None])  # (N, 8, 3)
        local = np.einsum("nkcj,kji->nkci", corners[:, None] - poses[None, :, None, :3, 3], poses[:, :3, :3])
        z = local[..., 2]
        front = z > 1e-2
        zs = np.where(front, z, 1.0)
        u, v = local[..., 0] / zs * fx + cx, local[..., 1] / zs * fy + cy
        big = np.inf  # a box partly behind the camera may project anywhere: its whole image is a candidate
        u0 = np.ceil(np.where(front.all(-1), np.where(front, u, big).min(-1), 0.0))
        u1 = np.floor(np.where(front.all(-1), np.where(front, u, -big).max(-1), w - 1.0))
        v0 = np.ceil(np.where(front.all(-1), np.where(front, v, big).min(-1), 0.0))
        v1 = np.floor(np.where(front.all(-1), np.where(front, v, -big).max(-1), h - 1.0))
        # the projection must overlap the image before it is clipped to it (an off-screen box is not seen)
        visible = front.any(-1) & (u0 <= w - 1) & (u1 >= 0) & (v0 <= h - 1) & (v1 >= 0) \
            & (u0 <= u1) & (v0 <= v1)  # (N, K)
        u0, u1, v0, v1 = u0.clip(0, w - 1), u1.clip(0, w - 1), v0.clip(0, h - 1), v1.clip(0, h - 1)
        c = candidates * n_rays
        weights = visible / np.maximum(visible.sum(-1, keepdims=True), 1)
        slot = (weights.cumsum(-1)[:, None, :] < generator.random((n, c, 1))).sum(-1).clip(0, k - 1)  # (N, C)
        rows = np.arange(n)[:, None]
        uu = u0[rows, slot] + np.floor(generator.random((n, c)) * (u1 - u0 + 1)[rows, slot])
        vv = v0[rows, slot] + np.floor(generator.random((n, c)) * (v1 - v0 + 1)[rows, slot])
        px = (np.minimum(vv, h - 1) * w + np.minimum(uu, w - 1)).astype(np.int64)
        slot_t, px_t = torch.as_tensor(slot, device=self.device), torch.as_tensor(px, device=self.device)
        depth = self.depth[slot_t, px_t].cpu().numpy().astype(np.float64)
        direction = np.einsum("ncij,ncj->nci", poses[slot, :3, :3], self.rays_cam[px_t].cpu().numpy())
        origin = poses[slot, :3, 3]
        with np.errstate(divide="ignore", invalid="ignore"):
            inv = 1.0 / np.where(np.abs(direction) < 1e-12, 1e-12, direction)
            t0, t1 = (lo[:, None] - origin) * inv, (hi[:, None] - origin) * inv
        t_near = np.maximum(np.minimum(t0, t1).max(-1), 0.0)
        t_far = np.maximum(t0, t1).min(-1)
        ok = visible[rows, slot] & (depth > 0) & (t_far > t_near) & (t_near < depth)
        for i, iid in enumerate(instance_ids):  # never the instance's own pixels
            entry = self.index.get(iid)
            keys = entry.own_keys(h * w) if entry is not None and ok[i].any() else np.zeros(0, np.int64)
            if len(keys):
                cand = slot[i] * (h * w) + px[i]
                ok[i] &= keys[np.searchsorted(keys, cand).clip(max=len(keys) - 1)] != cand
        first = np.argsort(~ok, axis=1, kind="stable")[:, :n_rays]  # the valid candidates first
        return slot[rows, first], px[rows, first], ok[rows, first]

    @torch.no_grad()
    def observes(self, points: torch.Tensor, tolerance_m: float = 0.05) -> torch.Tensor:
        """Which (M, 3) world points some held keyframe saw: the point projects into the image in front of
        the camera and the depth there is within ``tolerance_m`` of its own. (M,) bool; all False
        before the first keyframe. What is not observed is this agent's blind zone."""
        n = len(self.slot_frame)
        seen = torch.zeros(points.shape[0], dtype=torch.bool, device=points.device)
        if n == 0 or self.rays_cam is None or points.shape[0] == 0:
            return seen
        h, w, fx, fy, cx, cy = self.camera()
        pts = points.to(self.device, torch.float32)
        for slot in range(n):
            pose = self.poses[slot]
            local = (pts - pose[:3, 3]) @ pose[:3, :3]  # world -> camera (rotation transposed)
            z = local[:, 2]
            front = z > 1e-3
            zs = torch.where(front, z, torch.ones_like(z))
            u = torch.round(local[:, 0] / zs * fx + cx).long()
            v = torch.round(local[:, 1] / zs * fy + cy).long()
            inside = front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
            pixel = (v.clamp(0, h - 1) * w + u.clamp(0, w - 1))
            d = self.depth[slot][pixel]
            seen |= (inside & (d > 0) & ((d - z).abs() < tolerance_m)).to(seen.device)
        return seen

    # ---- checkpoints -------------------------------------------------------------------------------
    def state(self) -> dict:
        """Images, poses and pixel pools as tensors and lists (for a weights-only checkpoint)."""
        n = len(self.slot_frame)
        return {
            "capacity": self.capacity, "policy": self.policy, "seen": self.seen, "rng": self.rng.bit_generator.state,
            "rgb": None if self.rgb is None else self.rgb[:n].cpu(), "depth": None if self.depth is None else self.depth[:n].cpu(),
            "poses": self.poses[:n].cpu(), "rays_cam": None if self.rays_cam is None else self.rays_cam.cpu(),
            "slot_frame": list(self.slot_frame), "slot_instances": [list(x) for x in self.slot_instances],
            "index": {int(iid): {"own": {int(k): torch.as_tensor(v) for k, v in e.own.items()},
                                 "other": {int(k): torch.as_tensor(v) for k, v in e.other.items()}}
                      for iid, e in self.index.items()},
        }

    def restore(self, state: dict) -> None:
        """Inverse of ``state``."""
        if state["capacity"] != self.capacity:
            raise ValueError(f"checkpoint keyframe capacity {state['capacity']} differs from {self.capacity}")
        self.policy, self.seen = state["policy"], state["seen"]
        self.rng.bit_generator.state = state["rng"]
        self.slot_frame, self.slot_instances = list(state["slot_frame"]), [list(x) for x in state["slot_instances"]]
        n = len(self.slot_frame)
        if state["rays_cam"] is not None:
            self.rays_cam = state["rays_cam"].to(self.device)
            self._camera = None
            hw = self.rays_cam.shape[0]
            self.rgb = torch.zeros(self.capacity, hw, 3, dtype=torch.uint8, device=self.device)
            self.depth = torch.zeros(self.capacity, hw, device=self.device)
            self.rgb[:n], self.depth[:n] = state["rgb"].to(self.device), state["depth"].to(self.device)
        self.poses = torch.zeros(self.capacity, 4, 4, device=self.device)
        self.poses[:n] = state["poses"].to(self.device)
        self.index = {}
        for iid, e in state["index"].items():
            entry = _InstancePixels()
            for k in e["own"]:
                entry.put(int(k), e["own"][k].numpy(), e["other"][k].numpy())
            self.index[int(iid)] = entry
