"""Local data loss of one agent (paper eq. 8-11), as plain functions of rendered rays.

Reduction, as vMAP: each term is a masked mean over the LAST axis (the rays of one instance) and a
sum over any leading axes (the instances). With rays laid out (N, R) every instance's gradient is
then independent of how many instances are trained together; a flat (R,) input is a plain mean.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import Tensor

from mapping.config_fields import NEUTRAL_DEFAULT, bounded
from mapping.model.render import RenderedRays

DEPTH_UNCERTAINTY_EPS = 1e-4
"""vMAP's depth weight 1 / (sqrt(var) + 1e-4): bounded at 1e4 where the rendered depth is certain."""


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of (..., R) ``values`` over the entries where (..., R) ``mask`` holds, per leading index,
    summed over the leading axes (an instance with no masked rays contributes 0)."""
    mask = mask.to(values.dtype)
    return ((values * mask).sum(-1) / mask.sum(-1).clamp_min(1.0)).sum()


def occupancy_loss(rendered_occupancy: Tensor, instance_mask: Tensor, valid: Tensor | None = None) -> Tensor:
    """Eq. 8: |O_hat(r) - m_bar(p)|, the rendered occupancy against the corrected instance mask.

    Args:
        rendered_occupancy: (..., R) O_hat.
        instance_mask: (..., R) m_bar, 1 where the pixel belongs to the instance.
        valid: (..., R) bool, rays to use (e.g. vMAP skips pixels of unknown state); default all.
    """
    valid = torch.ones_like(rendered_occupancy, dtype=torch.bool) if valid is None else valid
    return masked_mean((rendered_occupancy - instance_mask.to(rendered_occupancy.dtype)).abs(), valid)


def depth_loss(rendered_depth: Tensor, depth: Tensor, instance_mask: Tensor, variance: Tensor | None = None) -> Tensor:
    """Eq. 9: m_bar(p) |D_hat(r) - I_d(p)| on the instance's pixels with a depth reading.

    With ``variance`` (the rendered depth variance) each ray is weighted by 1 / (sqrt(var) + 1e-4)
    (detached), as vMAP: rays whose rendering is already sharp count more.

    Args:
        rendered_depth: (..., R) D_hat.
        depth: (..., R) observed depth (0 = none).
        instance_mask: (..., R) m_bar.
        variance: (..., R) rendered depth variance, or None for the plain L1 of the paper.
    """
    use = instance_mask.to(torch.bool) & (depth > 0)
    error = (rendered_depth - depth).abs()
    if variance is not None:
        error = error / (variance.detach().sqrt() + DEPTH_UNCERTAINTY_EPS)
    return masked_mean(error, use)


def colour_loss(rendered_colour: Tensor, rgb: Tensor, instance_mask: Tensor) -> Tensor:
    """Eq. 10: m_bar(p) |C_hat(r) - I_c(p)| (mean over the three channels) on the instance's pixels.

    Args:
        rendered_colour: (..., R, 3) C_hat in [0, 1].
        rgb: (..., R, 3) observed colour in [0, 1].
        instance_mask: (..., R) m_bar.
    """
    return masked_mean((rendered_colour - rgb).abs().mean(-1), instance_mask.to(torch.bool))


@dataclass(frozen=True)
class DataLossWeights:
    """lambda_1..3 of eq. 11 (vMAP's values)."""

    occupancy: float = field(default=10.0, metadata=bounded(0, 1e6))
    """lambda_1 (vMAP: opacity x10)."""
    depth: float = field(default=1.0, metadata=bounded(0, 1e6))
    """lambda_2 (vMAP: depth x1)."""
    colour: float = field(default=5.0, metadata=bounded(0, 1e6))
    """lambda_3 (vMAP: colour x5)."""
    depth_uncertainty: bool = True
    """Weight depth errors by 1 / (sqrt(var) + 1e-4) as vMAP (False: the paper's plain L1)."""
    free_space: float = field(default=0.0, metadata=bounded(0, 1e6, also=NEUTRAL_DEFAULT))
    """Weight of ``free_space_loss`` (0: off, vMAP's loss). Eq. 8 asks only that a ray's summed occupancy be
    1 on the instance's pixels, which an occupied blob anywhere in front of the surface also gives; this
    term asks every sample in front of an observed surface to be empty (empty-space carving)."""


def free_space_loss(occupancy: Tensor, sample_depths: Tensor, depth: Tensor, valid: Tensor, margin_m: float) -> Tensor:
    """Mean occupancy of the samples in front of an observed surface (depth < d - ``margin_m``), per leading
    index over its rays' such samples, summed over the leading axes (as ``masked_mean``).

    Args:
        occupancy: (..., R, S) o_p.
        sample_depths: (..., R, S) the samples' depths.
        depth: (..., R) observed depth (0 = none: nothing is known in front of it).
        valid: (..., R) bool rays to supervise at all.
        margin_m: samples this close in front of the surface are left alone (the surface band).
    """
    front = (sample_depths < (depth - margin_m)[..., None]) & ((depth > 0) & valid)[..., None]
    flat = front.shape[:-2] + (front.shape[-2] * front.shape[-1],)
    return masked_mean(occupancy.reshape(flat), front.reshape(flat))


@dataclass
class DataLoss:
    """Eq. 11 and its terms (the terms unweighted)."""

    total: Tensor
    occupancy: Tensor
    depth: Tensor
    colour: Tensor


def data_loss(rendered: RenderedRays, depth: Tensor, rgb: Tensor, instance_mask: Tensor,
              valid: Tensor | None = None, weights: DataLossWeights = DataLossWeights()) -> DataLoss:
    """Eq. 11: L_data = l1 L_occ + l2 L_depth + l3 L_colour for rays rendered through one instance each.

    Args:
        rendered: renderings of (..., R) rays (``render_occupancy`` output; colour required when
            ``weights.colour`` is not 0).
        depth: (..., R) observed depth (0 = none).
        rgb: (..., R, 3) observed colour in [0, 1].
        instance_mask: (..., R) m_bar, 1 on the instance's pixels (corrected masks, Sec. IV-B).
        valid: (..., R) bool rays to supervise at all (default all); depth and colour use
            ``instance_mask & valid``.
        weights: lambda_1..3.
    """
    occ = occupancy_loss(rendered.occupancy, instance_mask, valid)
    # depth and colour are supervised only on valid rays too (a ray that misses the box or whose
    # surface lies before it says nothing about the instance's surface)
    supervised = instance_mask.to(torch.bool) if valid is None else instance_mask.to(torch.bool) & valid
    dep = depth_loss(rendered.depth, depth, supervised,
                     rendered.depth_variance if weights.depth_uncertainty else None)
    col = colour_loss(rendered.colour, rgb, supervised) if rendered.colour is not None else occ.new_zeros(())
    total = weights.occupancy * occ + weights.depth * dep + weights.colour * col
    return DataLoss(total, occ, dep, col)
