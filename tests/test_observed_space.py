"""Observed space per instance: marking from a keyframe, merging two agents' grids, the wire form."""

from __future__ import annotations

import numpy as np
import pytest

from mapping.model.observed import FREE, SURFACE, UNKNOWN, ObservedSpace, ObservedSpaceError, observe_frame


def _wall_seen_from(camera: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 1 m x 1 m wall at x = 2 (points on it), its box, seen from ``camera``."""
    yz = np.stack(np.meshgrid(np.linspace(0.0, 1.0, 41), np.linspace(0.0, 1.0, 41)), -1).reshape(-1, 2)
    points = np.column_stack([np.full(len(yz), 2.0), yz])
    return points, np.array([1.5, -0.1, -0.1]), np.array([2.3, 1.1, 1.1])


def test_a_keyframe_marks_surface_at_its_depth_free_in_front_and_leaves_behind_unknown():
    space = ObservedSpace.empty(0.05)
    points, lo, hi = _wall_seen_from(np.zeros(3))
    observe_frame(space, points, np.array([0.0, 0.5, 0.5]), lo, hi)
    assert np.all(space.state_at(points) == SURFACE)
    assert space.state_at(np.array([[1.7, 0.5, 0.5]]))[0] == FREE  # between the camera and the wall
    assert space.state_at(np.array([[2.2, 0.5, 0.5]]))[0] == UNKNOWN  # behind it: nobody looked
    assert space.state_at(np.array([[9.0, 9.0, 9.0]]))[0] == UNKNOWN  # outside the grid
    assert 0 < space.observed_share < 1
    assert space.near_surface(np.array([[2.04, 0.5, 0.5], [1.6, 0.5, 0.5]])).tolist() == [True, False]


def test_two_agents_grids_merge_cell_by_cell_and_surface_is_never_cleared():
    front, back = ObservedSpace.empty(), ObservedSpace.empty()
    points, lo, hi = _wall_seen_from(np.zeros(3))
    observe_frame(front, points, np.array([0.0, 0.5, 0.5]), lo, hi)
    observe_frame(back, points + [0.1, 0, 0], np.array([4.0, 0.5, 0.5]), lo + [0, 0, 0.5], hi + [0.5, 0, 0.5])
    merged = front.copy()
    merged.merge(back)
    probe = np.array([[1.7, 0.5, 0.5], [2.2, 0.5, 0.5], [2.1, 0.5, 0.5], [2.0, 0.5, 0.5]])
    assert merged.state_at(probe).tolist() == [FREE, FREE, SURFACE, SURFACE]  # each side sees its own half
    assert np.all(merged.state_at(points) >= front.state_at(points))
    grazing = front.copy()
    observe_frame(grazing, np.zeros((0, 3)), np.array([2.0, -1.0, 0.5]), lo, hi,
                  free_ends=np.array([[2.0, 3.0, 0.5]]))  # a ray along the wall's plane
    assert np.all(grazing.state_at(points) == SURFACE)
    with pytest.raises(ValueError, match="do not merge"):
        front.merge(ObservedSpace.empty(0.1))


def test_the_wire_form_round_trips_is_small_and_refuses_what_it_is_not():
    space = ObservedSpace.empty()
    points, lo, hi = _wall_seen_from(np.zeros(3))
    observe_frame(space, points, np.array([0.0, 0.5, 0.5]), lo, hi)
    data = space.to_bytes()
    back = ObservedSpace.from_bytes(data, cell_m=0.05)
    assert np.array_equal(back.states, space.states) and np.array_equal(back.origin, space.origin)
    assert len(data) < space.states.size / 4  # under 2 bits a cell
    with pytest.raises(ObservedSpaceError, match="cell size"):
        ObservedSpace.from_bytes(data, cell_m=0.1)
    with pytest.raises(ObservedSpaceError, match="bytes of cells"):
        ObservedSpace.from_bytes(data[:-5], cell_m=0.05)
    huge = bytearray(data)
    huge[8 + 24:8 + 48] = np.array([1 << 20, 1 << 20, 1 << 20], np.int64).tobytes()  # a shape of 2^60 cells
    with pytest.raises(ObservedSpaceError, match="out of bounds"):
        ObservedSpace.from_bytes(bytes(huge))
    with pytest.raises(ObservedSpaceError, match="shorter than its header"):
        ObservedSpace.from_bytes(b"x")
    bomb = data[:56] + __import__("zlib").compress(bytes(10_000_000))  # far more cells than announced
    with pytest.raises(ObservedSpaceError, match="expected"):
        ObservedSpace.from_bytes(bomb)
