"""The single-agent mapper end to end on a tiny scene: ingest, train, mesh, evaluate, checkpoint."""

import numpy as np
import pytest
import torch

from mapping.model.agent import MappingAgent
from mapping.model.agent_config import MappingConfig
from mapping.model.checkpoint import CheckpointError
from mapping.evaluate import evaluate_mesh


def _one_instance_agent(world, seed=0):
    """An agent that maps only the first book of the tiny scene (other pixels masked out)."""
    book = next(i for i in world.scene.instances if i.category == "book")
    agent = MappingAgent(MappingConfig(keyframe_every=2), device="cpu", seed=seed)
    for i in range(len(world.agent_poses[0])):
        frame = world.render(0, i)
        agent.ingest(frame, np.where(frame.instance == book.instance_id, book.instance_id, 0))
    return agent, book


def test_a_single_instance_is_learned(tiny_world):
    torch.manual_seed(0)
    agent, book = _one_instance_agent(tiny_world)
    assert list(agent.slots) == [book.instance_id]
    agent.train(400)
    meshes = agent.instance_meshes()
    metrics = evaluate_mesh(meshes[book.instance_id], book.mesh, count=20000)
    # the book is seen from one side only: completion of its whole mesh is bounded by what was seen
    assert metrics.comp_ratio > 80.0, metrics.as_dict()
    assert metrics.acc_cm < 3.0, metrics.as_dict()


def test_same_seed_same_training(tiny_world):
    a, _ = _one_instance_agent(tiny_world, seed=4)
    b, _ = _one_instance_agent(tiny_world, seed=4)
    la, lb = a.train(5), b.train(5)
    assert la == lb
    assert torch.equal(a.banks["object"].params, b.banks["object"].params)


def test_checkpoint_round_trips_exactly(tiny_world, tmp_path):
    agent, _ = _one_instance_agent(tiny_world)
    agent.train(3)
    path = agent.save(tmp_path / "agent.pt")
    restored = MappingAgent(agent.config, device="cpu", seed=99)
    restored.load(path)
    assert torch.equal(restored.banks["object"].params, agent.banks["object"].params)
    assert torch.equal(restored.optimisers["object"].exp_avg, agent.optimisers["object"].exp_avg)
    assert restored.slots.keys() == agent.slots.keys()
    assert np.array_equal(next(iter(restored.slots.values())).bound.lo, next(iter(agent.slots.values())).bound.lo)
    assert restored.steps == agent.steps


def test_bad_checkpoints_and_frames_are_refused(tiny_world, tmp_path):
    agent = MappingAgent(device="cpu")
    with pytest.raises(CheckpointError, match="not found"):
        agent.load(tmp_path / "none.pt")
    (tmp_path / "bad.pt").write_bytes(b"\x00" * 10)
    with pytest.raises(CheckpointError, match="corrupt"):
        agent.load(tmp_path / "bad.pt")
    frame = tiny_world.render(0, 0)
    frame.instance = None
    with pytest.raises(ValueError, match="instance image"):
        agent.ingest(frame)


class _Payload:
    """Stands for any pickled object; loading one could run code."""


def test_a_checkpoint_carrying_a_pickled_object_is_refused(tmp_path):
    path = tmp_path / "evil.pt"
    torch.save({"format": "openmulti-checkpoint", "version": 1, "payload": {"x": _Payload()}}, path)
    with pytest.raises(CheckpointError, match="refused: the checkpoint holds a pickled object"):
        MappingAgent(device="cpu").load(path)


def test_generators_live_on_the_mapping_device():
    agent = MappingAgent(device="cpu")
    assert agent.generator.device == agent.device
    assert agent.init_generator.device.type == "cpu"


def test_the_structure_banks_encoding_scale_is_a_mapper_setting():
    """A global map's one network (in the structure bank, over the scene box) takes a finer encoding."""
    agent = MappingAgent(MappingConfig(structure_encoding_scale=0.5), device="cpu")
    assert agent.banks["structure"].config.encoding_scale == 0.5
    assert agent.banks["object"].config.encoding_scale == MappingAgent(device="cpu").banks["object"].config.encoding_scale
    assert MappingAgent(device="cpu").banks["structure"].config.encoding_scale == 2.0


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_a_training_step_runs_on_cuda(tiny_world):
    agent = MappingAgent(MappingConfig(keyframe_every=1), device="cuda")
    assert agent.generator.device.type == "cuda"
    frame = tiny_world.render(0, 0)
    agent.ingest(frame)
    assert np.isfinite(agent.train(2))


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_training_is_reproducible_with_one_seed(tiny_world):
    """Two agents with one seed on CUDA map the same frames to the same parameters (the seeded CUDA
    generator drives sampling and frame refits, whatever the device's spelling)."""
    maps = []
    for device in ("cuda", "cuda:0"):
        agent = MappingAgent(MappingConfig(keyframe_every=1), device=device, seed=3)
        for i in range(3):
            agent.ingest(tiny_world.render(0, i))
        agent.train(5)
        maps.append({name: bank.params.detach().cpu() for name, bank in agent.banks.items()})
    for name in maps[0]:
        assert torch.allclose(maps[0][name], maps[1][name], atol=1e-5), name


def test_adopted_instances_are_not_trained_on_data_but_render(tiny_world):
    agent, book = _one_instance_agent(tiny_world)
    agent.train(50)
    peer = MappingAgent(MappingConfig(keyframe_every=2), device="cpu", seed=1)
    peer.adopt_instance(7, agent.export_instance(book.instance_id))
    assert peer.trainable_ids("object") == []
    peer.train(2)  # nothing to train on: no error, nothing changes
    assert torch.equal(peer.banks["object"].params[0], agent.banks["object"].params[agent.slots[book.instance_id].row])
    pose = tiny_world.agent_poses[0][0]
    mine = agent.render_view(pose, tiny_world.intrinsics, stride=8)
    theirs = peer.render_view(pose, tiny_world.intrinsics, stride=8)
    assert torch.allclose(mine.depth, theirs.depth, atol=1e-5)
