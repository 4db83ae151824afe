"""The completion estimate probes fields along normals: a surface within 4 cm counts, one farther away or
outside the instance's box does not."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from mapping.evaluate.probe import estimated_completion_ratio, surface_probe_coverage
from mapping.model.field import FieldOutput


class SphereBank:
    """A bank of one instance whose occupancy is a ball of radius ``r`` around ``c`` (1 inside)."""

    def __init__(self, c, r, lo, hi):
        self.c, self.r = torch.tensor(c, dtype=torch.float32), r
        self.bound_min = torch.tensor([lo], dtype=torch.float32)
        self.bound_max = torch.tensor([hi], dtype=torch.float32)

    def query(self, points, rows, with_colour=True, block_size=4096):
        inside = (points - self.c).norm(dim=-1) < self.r
        return FieldOutput(inside.float(), None)


def _mapper(bank):
    return SimpleNamespace(device=torch.device("cpu"), banks={"object": bank},
                           slots={7: SimpleNamespace(bank="object", row=0, alive=True)},
                           observed_field=lambda name: bank)  # no observed space: the field as it is


def test_points_near_the_surface_are_covered_far_ones_are_not():
    mapper = _mapper(SphereBank([0, 0, 0], 0.5, [-1, -1, -1], [1, 1, 1]))
    directions = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [-1, 0, 0]], float)
    on = 0.5 * directions
    near = 0.53 * directions  # the ball's surface is 3 cm below these
    far = 0.60 * directions  # 10 cm away
    points = np.concatenate([on, near, far])
    covered = surface_probe_coverage(mapper, points, np.concatenate([directions] * 3))
    assert covered.tolist() == [True] * 8 + [False] * 4
    assert estimated_completion_ratio(covered) == pytest.approx(100.0 * 8 / 12)


def test_a_surface_cut_by_the_box_is_where_the_mesh_is():
    # the box cuts the ball at x = 0.2: the mesh closes there (zero padding), and the ball's far side is gone
    mapper = _mapper(SphereBank([0, 0, 0], 0.5, [-1, -1, -1], [0.2, 1, 1]))
    points = np.array([[0.5, 0, 0], [0.2, 0, 0], [-0.5, 0, 0]])
    normals = np.array([[1, 0, 0], [1, 0, 0], [-1, 0, 0]], float)
    assert surface_probe_coverage(mapper, points, normals).tolist() == [False, True, True]


def test_dead_instances_and_empty_maps_cover_nothing():
    mapper = _mapper(SphereBank([0, 0, 0], 0.5, [-1, -1, -1], [1, 1, 1]))
    mapper.slots[7].alive = False
    assert not surface_probe_coverage(mapper, np.array([[0.5, 0, 0]]), np.array([[1.0, 0, 0]])).any()
    assert surface_probe_coverage(mapper, np.zeros((0, 3)), np.zeros((0, 3))).shape == (0,)
