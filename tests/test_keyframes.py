"""The keyframe buffer stays bounded and forgets replaced keyframes' pixels."""

import numpy as np
import pytest
import torch

from mapping.data import Frame, Intrinsics
from mapping.keyframes import KeyframeBuffer

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
