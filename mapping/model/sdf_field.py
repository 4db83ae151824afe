"""A bank of MACIM scene networks (``mapping.model.sdf_network``): an ``InstanceFieldBank`` whose rows are signed
distance functions, so that the agent, the channel, eq. 12, DiNNO, meshing and rendering take them as
they take vMAP's networks.

Its occupancy is sigmoid(-sharpness * sdf): 0.5 on the zero level set, so marching cubes at 0.5 gives
the SDF's surface; training reads the signed distance itself (``sdf``) with MACIM's losses
(``mapping.model.sdf_loss``). It has no colour head: colour queries return mid grey.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from mapping.model.field import FieldConfig, InstanceFieldBank
from mapping.model.instance_mlp import LOGIT_LIMIT
from mapping.model.keyframes import InstanceRays
from mapping.model.sdf_loss import SdfConfig, SdfSamples, sdf_samples, sdf_step_loss
from mapping.model.sdf_network import init_sdf_params, sdf_encoding, sdf_mlp, sdf_param_layout

GREY = 0.5


@dataclass
class SdfBatch:
    """A MACIM scene network's part of a training step (``MappingConfig.structure_sdf``): the samples of
    its rays with valid depth, and their distance bounds (``mapping.model.sdf_loss``)."""

    bank: str
    row: int
    samples: SdfSamples


def sdf_batch(bank: str, row: int, rays: InstanceRays, config: SdfConfig,
              generator: torch.Generator | None = None) -> SdfBatch | None:
    """MACIM's samples of one step on one row's (1, R) keyframe rays: those without valid depth dropped, as
    theirs (None when none has)."""
    valid = torch.isfinite(rays.depth[0]) & (rays.depth[0] > 0)
    if not bool(valid.any()):
        return None
    samples = sdf_samples(rays.origins[0][valid], rays.directions[0][valid], rays.depth[0][valid], config, generator)
    return SdfBatch(bank, row, samples)


class SdfFieldBank(InstanceFieldBank):
    """Rows of MACIM's scene network. ``config.encoding_scale`` divides frame coordinates (u in [-1, 1])
    before the encoding: 1 / (frame half-size * ``SdfConfig.encoding_per_m``) gives MACIM's metres x 0.0594."""

    def __init__(self, config: FieldConfig, sdf: SdfConfig, device: str | torch.device = "auto"):
        self.sdf_config = sdf
        super().__init__(config, device)

    def network_layout(self) -> list[tuple[str, tuple[int, ...]]]:
        return sdf_param_layout(self.config.hidden_width)

    def initial_params(self, k: int, generator: torch.Generator | None = None) -> Tensor:
        return init_sdf_params(self.config.hidden_width, k, generator)

    def signed_distance_unit(self, params: Tensor, unit: Tensor) -> Tensor:
        """(n, P) signed distances (metres) of (n, P, 3) frame coordinates through (n, D) rows."""
        encoding = sdf_encoding(unit / self.config.encoding_scale, self.directions)
        return sdf_mlp(self.split_params(params), encoding, self.config.hidden_width, self.sdf_config.scale_output)

    def sdf(self, points: Tensor, rows: Tensor) -> Tensor:
        """(n, P) signed distances of (n, P, 3) world points, row ``rows[i]`` on ``points[i]``."""
        return self.signed_distance_unit(self.params.index_select(0, rows), self.to_unit(points, rows))

    def batch_loss(self, batch: SdfBatch) -> Tensor:
        """MACIM's loss of one step (``mapping.model.sdf_loss.sdf_step_loss``) on the batch's row."""
        rows = torch.tensor([batch.row], device=self.device)
        return sdf_step_loss(lambda points: self.sdf(points.reshape(1, -1, 3), rows).reshape(points.shape[:-1]),
                             batch.samples, self.sdf_config)

    def evaluate_unit(self, params: Tensor, unit: Tensor, with_colour: bool, logits: bool = False
                      ) -> tuple[Tensor, Tensor | None]:
        """Occupancy sigmoid(-sharpness * sdf) (or its clamped logit) and, when asked, grey colour."""
        logit = (-self.config.occupancy_sharpness * self.signed_distance_unit(params, unit)).clamp(
            -LOGIT_LIMIT, LOGIT_LIMIT)
        occupancy = logit if logits else torch.sigmoid(logit)
        colour = unit.new_full((*unit.shape[:-1], 3), GREY) if with_colour else None
        return occupancy, colour

    def get_extra_state(self) -> dict:
        return {**super().get_extra_state(), "network": "sdf"}

    def set_extra_state(self, state: dict) -> None:
        if state.get("network") != "sdf":
            raise ValueError("checkpoint holds a vMAP occupancy bank, this is a MACIM SDF bank")
        super().set_extra_state({k: v for k, v in state.items() if k != "network"})
