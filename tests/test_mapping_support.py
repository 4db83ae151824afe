"""Instance bounds, checkpoints and keyframe ray sampling (the mapper's plumbing)."""

import numpy as np
import pytest
import torch
import trimesh

from mapping.model.bounds import InstanceBound
from mapping.model.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from mapping.model.keyframes import KeyframeBuffer


def test_bound_is_padded_robust_and_at_least_10cm():
    pts = np.random.default_rng(0).uniform([1, 1, 1], [1.02, 1.5, 1.01], size=(1000, 3))
    pts[0] = [9.0, 9.0, 9.0]  # one flying pixel
    b = InstanceBound.from_points(pts)
    assert np.all(b.size >= 0.10 - 1e-12)
    assert b.hi.max() < 2.0
    assert b.contains(pts[1:]).mean() > 0.98
    grown = b.union(InstanceBound.from_points(pts[1:] + [0.5, 0, 0]))
    assert np.all(grown.lo <= b.lo) and np.all(grown.hi >= b.hi)
    with pytest.raises(ValueError, match="non-empty"):
        InstanceBound.from_points(np.zeros((0, 3)))


def test_checkpoint_round_trip_and_errors(tmp_path):
    payload = {"w": torch.randn(3, 4), "step": 7, "nested": {"bounds": [np.ones(3).tolist()]}}
    path = save_checkpoint(tmp_path / "ckpt.pt", payload)
    back = load_checkpoint(path)
    assert torch.equal(back["w"], payload["w"]) and back["step"] == 7
    assert not (tmp_path / "ckpt.pt.tmp").exists()
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match="corrupt"):
        load_checkpoint(tmp_path / "bad.pt")
    save_checkpoint(tmp_path / "numpy.pt", {"bounds": np.ones(3)})  # not tensors: refused on load
    with pytest.raises(CheckpointError, match="refused"):
        load_checkpoint(tmp_path / "numpy.pt")
    torch.save({"something": 1}, tmp_path / "other.pt")
    with pytest.raises(CheckpointError, match="not an OpenMulti checkpoint"):
        load_checkpoint(tmp_path / "other.pt")


def test_keyframe_rays_hit_their_instance(tiny_world):
    buf = KeyframeBuffer()
    for i in range(0, 24, 4):
        frame = tiny_world.render(0, i)
        buf.add(frame, frame.instance)
    ids = sorted(buf.index)
    rays = buf.sample(ids, 64, 0.75, np.random.default_rng(0))
    assert rays.origins.shape == (len(ids), 64, 3) and rays.depth.shape == (len(ids), 64)
    assert rays.own.float().mean() >= 0.75
    points = rays.origins + rays.directions * rays.depth[..., None]
    for n, iid in enumerate(ids):
        own = points[n][rays.own[n]].numpy()
        _, dist, _ = trimesh.proximity.closest_point(tiny_world.scene.instance(iid).mesh, own)
        assert dist.max() < 0.01
        assert np.all(rays.depth[n].numpy() > 0)
