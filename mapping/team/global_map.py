"""The global-map mode of a team member: one network for the whole scene instead of one per instance.

The paper's global baselines (Di-NeRF*, MACIM, and OpenMulti on a global map, Tables I and IV) differ
from the instance-level map in structure only, so they run through the same agent, channel and
consistency code: every pixel any mask covers becomes one instance, ``GLOBAL_INSTANCE_ID``, whose
frame is the scene's box (``MappingConfig.global_frame``, fixed, so every agent's network is a vector
of the same function and eq. 12 pairs them without any alignment), in the structure bank with a wider
network (``MappingConfig.structure_width``) and as many rays per step as buy the instance-level map's
compute (``global_rays_for``). Fusion still runs (its instances are what the front end saw), but the
mapper never sees its ids, so the global map carries no per-instance semantics.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from mapping.model.agent_config import MappingConfig
from mapping.model.instance_params import mlp_flops_per_point
from mapping.perception.codebook import CodeBookEntry
from mapping.model.sdf_loss import SdfConfig

GLOBAL_WIDTH = 128
"""Hidden width of a global map's one network (vMAP's background network)."""
GLOBAL_ENCODING_SCALE = 2.0
"""Its ``FieldConfig.encoding_scale`` over the scene frame (box coordinates in [-1, 1] divided by it)."""
GLOBAL_INSTANCE_ID = 1
"""The one instance of a global map (0 means "no instance" in every instance image)."""
GLOBAL_CAPTION = "the whole scene"


def as_global_image(instance_image: np.ndarray) -> np.ndarray:
    """Every labelled pixel becomes the global instance (unlabelled pixels stay 0)."""
    return np.where(np.asarray(instance_image) > 0, GLOBAL_INSTANCE_ID, 0).astype(np.int32)


def global_entry(feature_dim: int) -> CodeBookEntry:
    """The code-book entry a global map sends with its network (no meaning: a zero feature)."""
    return CodeBookEntry(GLOBAL_CAPTION, np.zeros(feature_dim, np.float32), None, 1.0)


def scene_frame(size_m: tuple[float, float, float], margin_m: float = 0.1) -> tuple[float, float, float, float]:
    """(centre x, y, z, half-size) of the isotropic frame holding the room box [0, size] (plus a margin)."""
    size = np.asarray(size_m, np.float64)
    centre = size / 2.0
    return float(centre[0]), float(centre[1]), float(centre[2]), float(size.max() / 2.0 + margin_m)


def global_rays_for(objects: int, structures: int, rays_per_object: int, rays_per_structure: int,
                    object_width: int, structure_width: int, global_width: int) -> int:
    """Rays per step that give a ``global_width`` network the per-step MLP FLOPs of an instance-level
    map with ``objects`` width-``object_width`` and ``structures`` width-``structure_width`` networks
    (same samples per ray): the global baselines get the same effort, so the comparison is structure."""
    flops = (objects * rays_per_object * mlp_flops_per_point(object_width)
             + structures * rays_per_structure * mlp_flops_per_point(structure_width))
    return max(1, int(round(flops / mlp_flops_per_point(global_width))))


GLOBAL_FORMS = ("equal_compute", "published")
"""A global baseline's map: ``equal_compute``, the width-128 occupancy network above with the instance-level
map's per-step FLOPs, or ``published``, MACIM's scene SDF with its samples, losses, optimiser, iteration
budget and rho (``published_mapping``; docs/baselines.md says what is and is not as published)."""
MACIM_RHO = 0.3
"""MACIM's consistency weight (``loss.rho``): the published form's eq. 12 weight."""


def published_mapping(mapping: MappingConfig, frame: tuple[float, float, float, float],
                      sdf: SdfConfig = SdfConfig()) -> MappingConfig:
    """``mapping`` with MACIM's published map in the structure bank: its scene SDF (frame = the scene box,
    encoded in metres x ``encoding_per_m`` from the box centre), every frame a keyframe trained
    ``iterations_per_frame`` times, ``iterations_first`` more on the first and ``iterations_after`` more
    after the last frame."""
    return replace(mapping, structure_sdf=sdf, structure_width=sdf.width, global_frame=frame,
                   structure_encoding_scale=1.0 / (frame[3] * sdf.encoding_per_m), keyframe_every=1,
                   iterations_per_keyframe=sdf.iterations_per_frame, iterations_first_keyframe=sdf.iterations_first,
                   iterations_after_stream=sdf.iterations_after)
