"""The keyframe buffer stays bounded and forgets replaced keyframes' pixels."""

import numpy as np
import pytest
import torch

from mapping.data import Frame, Intrinsics
from mapping.model.keyframes import KeyframeBuffer

K = Intrinsics(fx=20.0, fy=20.0, cx=15.5, cy=11.5, width=32, height=24)


def _frame(index: int, iid: int) -> tuple[Frame, np.ndarray]:
    rgb = np.full((24, 32, 3), index % 255, np.uint8)
    depth = np.full((24, 32), 2.0, np.float32)
    instance = np.zeros((24, 32), np.int32)
    instance[4:20, 4:20] = iid
    return Frame(index=index, rgb=rgb, depth=depth, pose=np.eye(4), intrinsics=K, instance=instance), instance


@pytest.mark.parametrize("policy", ["window", "reservoir"])
def test_buffer_never_holds_more_than_its_capacity(policy):
    buf = KeyframeBuffer(capacity=3, policy=policy, seed=0)
    for i in range(20):
        frame, inst = _frame(i, 1 + i % 2)
        buf.add(frame, inst)
    assert len(buf) == 3 and buf.rgb.shape[0] == 3
    held = set(buf.frame_indices)
    if policy == "window":
        assert held == {17, 18, 19}
    rays = buf.sample([1, 2], 50, 0.8, np.random.default_rng(0))
    assert rays.origins.shape == (2, 50, 3)
    # colours carry the frame index: every sampled ray comes from a held keyframe
    assert set(np.unique(np.round(rays.rgb[..., 0].numpy() * 255)).astype(int)) <= held


def test_an_evicted_only_view_leaves_no_pixels_and_sampling_says_so():
    buf = KeyframeBuffer(capacity=1, policy="window")
    buf.add(*_frame(0, 5))
    buf.add(*_frame(1, 6))
    assert not buf.has_pixels(5) and buf.has_pixels(6)
    with pytest.raises(KeyError, match="no pixels"):
        buf.sample([5], 10, 0.8, np.random.default_rng(0))


def test_merged_ids_share_their_pixels():
    buf = KeyframeBuffer(capacity=4)
    buf.add(*_frame(0, 5))
    buf.add(*_frame(1, 6))
    buf.merge_ids(6, 5)
    assert not buf.has_pixels(6) and buf.has_pixels(5)
    assert buf.sample([5], 100, 1.0, np.random.default_rng(0)).own.all()


def test_observes_tells_seen_surface_from_blind_zones():
    buf = KeyframeBuffer(capacity=4)
    assert not buf.observes(torch.tensor([[0.0, 0.0, 2.0]])).any()  # nothing held yet
    frame, inst = _frame(0, 5)
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 0.0, 0.0]  # camera at x = 1 looking along +z; the wall of depth 2 is at z = 2
    buf.add(Frame(index=0, rgb=frame.rgb, depth=frame.depth, pose=pose, intrinsics=K, instance=inst), inst)
    points = torch.tensor([[1.0, 0.0, 2.0],   # on the observed wall, image centre
                           [1.3, 0.2, 2.02],  # on it, off-centre, within the tolerance
                           [1.0, 0.0, 3.0],   # behind the wall: never seen
                           [1.0, 0.0, 1.0],   # in front of it: free space, not a seen surface
                           [4.0, 0.0, 2.0],   # outside the image
                           [1.0, 0.0, -2.0]])  # behind the camera
    assert buf.observes(points).tolist() == [True, True, False, False, False, False]
    state = buf.state()
    again = KeyframeBuffer(capacity=4)
    again.restore(state)
    assert again.observes(points).tolist() == [True, True, False, False, False, False]


def test_crossing_rays_enter_the_box_in_front_of_their_surface_and_are_never_its_own_pixels():
    """A wall at 2 m seen with instance 1 on its left half; instance 2's box floats at 1.0-1.5 m on the
    right, never segmented: its free-space rays come from wherever its projection lies."""
    buf = KeyframeBuffer(capacity=4, policy="window")
    frame, inst = _frame(0, 1)
    inst[:] = 0
    inst[:, :16] = 1
    buf.add(frame, inst)
    lo = np.array([[0.0, -0.3, 1.0], [-0.5, -0.5, 1.8]])  # 2: right half, in front; 1: its own wall slab
    hi = np.array([[0.4, 0.3, 1.5], [0.5, 0.5, 2.2]])
    slots, px, ok = buf.crossing_rays([2, 1], lo, hi, 30, np.random.default_rng(0))
    assert ok[0].all()  # the floating box is crossed by many rays in front of the wall
    u, v = px[0] % 32, px[0] // 32
    assert (u >= 15).all() and (u <= 15.5 + 0.4 / 1.0 * 20 + 1).all() and (np.abs(v - 11.5) <= 0.3 / 1.0 * 20 + 1).all()
    # instance 1's box holds its own wall: rays there end on its own pixels (never free space); rays on
    # the right half enter its box in front of the other surface
    assert ok[1].any() and ((px[1][ok[1]] % 32) >= 16).all()
    rays = buf.sample([1], 40, 0.5, np.random.default_rng(1), boxes=(lo[1:], hi[1:]))
    assert rays.own[0, :20].all() and not rays.own[0, 20:].any()
    assert (rays.depth[0, 20:] == 2.0).all()  # free-space rays end on the wall behind the box's front
    # a box in front of the camera but off the image's side is not seen: no ray crosses it
    off_lo, off_hi = np.array([[3.0, -0.3, 1.0]]), np.array([[3.5, 0.3, 1.5]])
    assert not buf.crossing_rays([2], off_lo, off_hi, 10, np.random.default_rng(0))[2].any()
