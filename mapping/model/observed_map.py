"""An agent's observed spaces, one per instance: marked from its keyframes, merged when instances merge or
a peer's copy of one arrives, taken whole with an adopted instance, written in its checkpoint.

Apart from ``MappingAgent`` so that the agent reads as ingest -> train -> outputs; the agent calls these
at the same places it updates an instance's box.
"""

from __future__ import annotations

import warnings
from typing import Mapping

import numpy as np
import torch

from mapping.data import Frame
from mapping.model.observed import ObservedSpace, ObservedSpaceError, observe_frame

OWN_PIXEL_STRIDE = 4
"""Every n-th of an instance's own pixels also marks its ray free (its box's front, seen at any stride)."""


class ObservedMaps:
    """Instance id -> ``ObservedSpace`` of one agent (empty and inert when ``cell_m`` is None).

    Args:
        cell_m: lattice spacing (``MappingConfig.observed_cell_m``), None to keep none.
        ray_stride: every n-th valid pixel of a keyframe casts a free-space ray.
    """

    def __init__(self, cell_m: float | None, ray_stride: int = 16):
        self.cell_m, self.ray_stride = cell_m, ray_stride
        self.spaces: dict[int, ObservedSpace] = {}

    @property
    def enabled(self) -> bool:
        return self.cell_m is not None

    def observe_keyframe(self, frame: Frame, instance: np.ndarray, boxes: dict[int, tuple[np.ndarray, np.ndarray]],
                         seen: set[int]) -> None:
        """Mark one keyframe: in the space of every instance in ``boxes`` (id -> its box now: the map's live
        instances, adopted ones too) free along the frame's rays that cross it up to their depth, and for the
        instances the frame shows (``seen``) surface at their own depth points."""
        if not self.enabled or not boxes:
            return
        camera = np.asarray(frame.pose, np.float64)[:3, 3]
        valid = np.isfinite(frame.depth) & (frame.depth > 0)
        rays = frame.backproject(mask=valid)[::self.ray_stride]
        empty = np.zeros((0, 3))
        for iid, (lo, hi) in boxes.items():
            if iid not in seen and iid not in self.spaces:
                continue  # nothing seen of it yet: its grid starts with its first sight
            points = frame.backproject(mask=valid & (instance == iid)) if iid in seen else empty
            space = self.spaces.setdefault(iid, ObservedSpace.empty(self.cell_m))
            observe_frame(space, points, camera, lo, hi, free_ends=np.concatenate([rays, points[::OWN_PIXEL_STRIDE]]))

    def merge(self, source: int, target: int) -> None:
        """``source`` became part of ``target``: its observations join ``target``'s."""
        space = self.spaces.pop(source, None)
        if space is not None:
            self.add(target, space)

    def add(self, iid: int, space: ObservedSpace | None) -> None:
        """Add ``space`` (a peer's observations of this instance) to the instance's own; ignored when this
        agent keeps none or the peer sent none. A peer's grid that cannot join this one (another cell, or
        together more than ``MAX_CELLS``: a box far from the instance's own) is left out with a warning, the
        own grid unchanged: an arrived message is applied, never a reason to stop mapping."""
        if not self.enabled or space is None:
            return
        own = self.spaces.get(iid, ObservedSpace.empty(self.cell_m))
        try:
            own.merge(space)  # checks before it changes anything
        except ObservedSpaceError as exc:
            warnings.warn(f"a peer's observed space of instance {iid} left out: {exc}", stacklevel=2)
            return
        self.spaces[iid] = own

    def export(self, iid: int, lo: np.ndarray, hi: np.ndarray) -> ObservedSpace | None:
        """A copy of the instance's space grown to its box [lo, hi] (what a peer receives), or None."""
        if not self.enabled:
            return None
        space = self.spaces.get(iid, ObservedSpace.empty(self.cell_m)).copy()
        space.cover(lo, hi)
        return space

    def get(self, iid: int) -> ObservedSpace | None:
        return self.spaces.get(iid)

    def numbered(self, ids: Mapping[int, int]) -> dict[int, ObservedSpace]:
        """Number -> space of ``ids`` (number -> instance id, e.g. a bank's rows), for those that have one."""
        return {k: self.spaces[iid] for k, iid in ids.items() if iid in self.spaces}

    def state(self) -> dict[int, torch.Tensor]:
        """Each space's wire form as a uint8 tensor (a checkpoint holds tensors, not bytes)."""
        return {iid: torch.frombuffer(bytearray(s.to_bytes()), dtype=torch.uint8) for iid, s in self.spaces.items()}

    def restore(self, state: dict[int, torch.Tensor]) -> None:
        self.spaces = {int(iid): ObservedSpace.from_bytes(bytes(t.numpy().tobytes()), self.cell_m)
                       for iid, t in state.items()} if self.enabled else {}
