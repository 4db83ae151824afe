"""The bank's forward written the plain way: a Python loop over instances with vMAP's concatenating
layers. The reference that tests and ``benchmarks/bench_field.py`` compare the batched form with; not
for training.
"""

from __future__ import annotations

import torch
from torch import Tensor

from mapping.model.encoding import encode_positions
from mapping.model.field import FieldOutput, InstanceFieldBank
from mapping.model.instance_mlp import occupancy_logit


def looped_forward(bank: InstanceFieldBank, points: Tensor, with_colour: bool = True) -> FieldOutput:
    """``bank.forward(points)`` computed with a Python loop over instances and vMAP's concatenating
    layers."""
    w = bank.config.hidden_width
    occupancies, colours = [], []
    for i in range(bank.num_instances):
        p = bank.split_params(bank.params[i])
        unit = bank.to_unit(points[i : i + 1], torch.tensor([i], device=bank.device))[0]
        geometry, colour_in = encode_positions(unit, bank.directions, bank.config.encoding_scale)
        b_in, b_skip = p["b_enc"][:w], p["b_enc"][w:]
        w_in, w_skip = p["w_enc"][:, :w], torch.cat([p["w_skip"], p["w_enc"][:, w:]])
        w_col, b_col = torch.cat([p["w_head"][:, :w], p["w_col_enc"]]), p["b_head"][:w]
        w_occ, b_occ = p["w_head"][:, w:], p["b_head"][w:]
        h = torch.relu(geometry @ w_in + b_in)
        h = torch.relu(h @ p["w_mid1"] + p["b_mid1"])
        h = torch.relu(torch.cat([h, geometry], -1) @ w_skip + b_skip)
        h = torch.relu(h @ p["w_mid2"] + p["b_mid2"])
        occupancies.append(torch.sigmoid(occupancy_logit((h @ w_occ + b_occ)[:, 0], bank.config.occupancy_sharpness)))
        if with_colour:
            c = torch.relu(torch.cat([h, colour_in], -1) @ w_col + b_col)
            colours.append(torch.sigmoid(c @ p["w_rgb"] + p["b_rgb"]))
    occupancy = torch.stack(occupancies) if occupancies else points.new_zeros(0, points.shape[1])
    colour = (torch.stack(colours) if colours else points.new_zeros(0, points.shape[1], 3)) if with_colour else None
    return FieldOutput(occupancy, colour)
