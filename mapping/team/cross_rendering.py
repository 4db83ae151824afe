"""Cross Rendering Supervision (paper eq. 13): render a peer's rays with my map and with the peer's.

Peer j shares the camera poses of its current frames and a pixel-sampling seed (``RayMessage``); I
replay the same pixels, render depth along those rays twice, with my own fields (D_k, with gradient)
and with the parameters I hold from j (D_j, detached), and minimise sum_r |D_k(r) - D_j(r)| over the
rays on which j's map renders a surface. No depth crosses the channel. The peer's rays run through
the parts of the room j is looking at now, which are mostly my blind zones: there parameter
closeness alone does not make my (non-convex) networks render j's surface, the rendering does.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import torch
from torch import Tensor

from mapping.render import CompositeConfig, InstanceField, RayBundle, camera_rays, composite_instances
from mapping.data.frame import Intrinsics
from mapping.team.messages import RayMessage, replay_pixels


def rays_of_message(message: RayMessage, device: torch.device | str = "cpu") -> RayBundle:
    """The (M,) world rays a ray message stands for (unit-z camera directions, as everywhere)."""
    pose_index, u, v = replay_pixels(message)
    fx, fy, cx, cy, w, h = message.intrinsics
    intrinsics = Intrinsics(fx=fx, fy=fy, cx=cx, cy=cy, width=int(w), height=int(h))
    poses = torch.as_tensor(np.asarray(message.poses, np.float32)[pose_index], device=device)
    return camera_rays(poses, intrinsics, torch.as_tensor(u, dtype=torch.float32, device=device),
                       torch.as_tensor(v, dtype=torch.float32, device=device))


def render_consistency_loss(own_fields: Sequence[InstanceField], peer_fields: Sequence[InstanceField],
                            rays: RayBundle, samples_per_box: int = 16, min_peer_occupancy: float = 0.5,
                            free_space_weight: float = 0.0, free_space_margin_m: float = 0.05
                            ) -> tuple[Tensor, int]:
    """Eq. 13 on (M,) rays: mean |D_own - D_peer| over rays where the peer renders occupancy above
    ``min_peer_occupancy``; the peer side carries no gradient. Returns (loss, rays used).

    ``free_space_weight`` > 0 adds the termination weight my map puts more than
    ``free_space_margin_m`` in front of the peer's depth (mean over the rays): the peer saw free space
    there, so an occluder of mine in its view is removed directly instead of through the L1 on the
    composited depth, whose gradient may as well add occupancy behind (an option, off by default)."""
    config = CompositeConfig(samples_per_box=samples_per_box)
    with torch.no_grad():
        peer = composite_instances(peer_fields, rays, config, with_colour=False)
    use = peer.occupancy > min_peer_occupancy
    if not bool(use.any()):
        device = rays.origins.device
        return torch.zeros((), device=device), 0
    own = composite_instances(own_fields, rays[use], config, with_colour=False)
    loss = (own.depth - peer.depth[use]).abs().mean()
    if free_space_weight > 0 and own.weights is not None:
        target = peer.depth[use].reshape(-1, 1)
        in_front = own.sample_depths < target - free_space_margin_m
        loss = loss + free_space_weight * (own.weights * in_front).sum(-1).mean()
    return loss, int(use.sum())
