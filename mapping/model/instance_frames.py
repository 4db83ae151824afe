"""Each instance's fixed frame: the cube its network sees, and moving a network to another frame.

Why a fixed frame per instance: the network sees ``u = (x - frame_centre) / frame_half`` with the
centre and half-size fixed when the instance is created (from its first box), not the box itself. A
box that grows as the instance is seen more (``InstanceFieldBank.set_bounds``) therefore does not
stretch what the network learned, and two agents whose instances share one frame hold parameter
vectors of the SAME function, which is what parameter consistency (eq. 12) and adoption need.
``refit_frames`` moves rows to a new frame by distillation (the box outgrew the frame, or the team
agreed on another frame).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence

import torch
from torch import Tensor, nn

from mapping.runtime import same_device

if TYPE_CHECKING:  # the bank builds its default frames here: a runtime import would be circular
    from mapping.model.field import InstanceFieldBank


def frame_for_box(bound_min: Tensor, bound_max: Tensor, margin: float = 1.0, min_half_m: float = 0.0
                  ) -> tuple[Tensor, Tensor]:
    """The frame of (k, 3) boxes: their centres (k, 3) and half-sizes (k,) = max(margin x largest
    half-side, min_half_m).

    Isotropic (one half-size for all axes), so a box growing along one axis never changes how the
    network sees the others. The margin leaves room to grow: the agent moves an instance to a larger
    frame (a refit) only when its box reaches ``MappingConfig.frame_limit`` of the frame's half-size.
    """
    half = (((bound_max - bound_min) / 2.0).amax(-1) * margin).clamp_min(min_half_m)
    return (bound_min + bound_max) / 2.0, half


def refit_frames(bank: InstanceFieldBank, rows: Sequence[int], frame_centre: Tensor, frame_half: Tensor,
                 steps: int = 150, points: int = 1024, lr: float = 3e-3,
                 generator: torch.Generator | None = None) -> float:
    """Move ``rows`` of ``bank`` to new frames by distillation: fit each row, in its new frame, to what
    it rendered in its old one (occupancy logits and colour at random points of its box), starting
    from its old parameters. Returns the final mean absolute occupancy difference.

    Needed when a box outgrows its frame (``InstanceFieldBank.frame_coverage`` too large) or when the
    team agrees on another instance's frame; callers reset the rows' optimiser state afterwards.
    """
    if len(rows) == 0:
        return 0.0
    idx = torch.as_tensor(rows, dtype=torch.long, device=bank.device)
    centre = torch.as_tensor(frame_centre, dtype=torch.float32, device=bank.device).reshape(len(rows), 3)
    half = torch.as_tensor(frame_half, dtype=torch.float32, device=bank.device).reshape(len(rows))
    lo, hi = bank.bound_min[idx], bank.bound_max[idx]
    gen = generator if generator is not None and same_device(generator.device, bank.device) else None
    old_params = bank.params.detach()[idx].clone()
    old_centre, old_half = bank.frame_centre[idx].clone(), bank.frame_half[idx].clone()

    def sample() -> Tensor:
        u = torch.rand(len(rows), points, 3, device=bank.device, generator=gen)
        return lo[:, None] + (hi - lo)[:, None] * u

    def evaluate(params: Tensor, c: Tensor, h: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
        return bank.evaluate_unit(params, (x - c[:, None]) / h[:, None, None], with_colour=True, logits=True)

    student = nn.Parameter(old_params.clone())
    optimiser = torch.optim.Adam([student], lr=lr)
    diff = 0.0
    for _ in range(steps):
        x = sample()
        with torch.no_grad():
            target_logit, target_colour = evaluate(old_params, old_centre, old_half, x)
        logit, colour = evaluate(student, centre, half, x)
        target_occ, occ = torch.sigmoid(target_logit), torch.sigmoid(logit)
        loss = (occ - target_occ).abs().mean() + 0.2 * ((colour - target_colour).abs().mean(-1)
                                                        * target_occ).mean()
        optimiser.zero_grad()
        loss.backward()
        optimiser.step()
        diff = float((occ - target_occ).abs().mean().detach())
    with torch.no_grad():
        bank.params[idx] = student.detach()
        bank.frame_centre[idx] = centre
        bank.frame_half[idx] = half
    return diff
