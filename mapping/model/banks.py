"""An agent's two banks of instance networks, and what one instance's parameter vector holds per bank
(what a message's ``params`` must have: ``mapping.team.message_checks``)."""

from __future__ import annotations

from dataclasses import replace

import torch

from mapping.model.agent_config import MappingConfig
from mapping.model.field import OBJECT_FIELD, STRUCTURE_FIELD, InstanceFieldBank
from mapping.model.sdf_field import SdfFieldBank


def instance_banks(config: MappingConfig, device: torch.device | str = "cpu") -> dict[str, InstanceFieldBank]:
    """The agent's two banks of instance networks, empty: objects at vMAP's width, walls / floor /
    ceiling at ``config.structure_width`` (or MACIM's SDF network with ``config.structure_sdf``)."""
    structure = replace(STRUCTURE_FIELD, hidden_width=config.structure_width,
                        encoding_scale=config.structure_encoding_scale)
    sdf = config.structure_sdf
    return {"object": InstanceFieldBank(OBJECT_FIELD, device),
            "structure": InstanceFieldBank(structure, device) if sdf is None else SdfFieldBank(
                replace(structure, hidden_width=sdf.width, occupancy_sharpness=sdf.occupancy_sharpness), sdf, device)}


def param_counts(config: MappingConfig) -> dict[str, int]:
    """Per bank, the length of one instance's parameter vector (what a message's ``params`` must have)."""
    return {name: int(bank.params.shape[1]) for name, bank in instance_banks(config).items()}
