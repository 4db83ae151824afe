"""What several test modules build: a tiny team on the tiny world, and a message with its header rewritten."""

from __future__ import annotations

import json
import struct
from dataclasses import replace

from mapping.team import ChannelConfig, ConsistencyConfig, Team, TeamConfig


def rewrite_header(data: bytes, change) -> bytes:
    """``data`` with its JSON header passed through ``change`` (what a faulty or hostile sender could send)."""
    start = len(b"OMMSG") + 1
    (n,) = struct.unpack("<I", data[start:start + 4])
    header = change(json.loads(data[start + 4:start + 4 + n]))
    blob = json.dumps(header).encode()
    return data[:start] + struct.pack("<I", len(blob)) + blob + data[start + 4 + n:]


class CountingStream:
    def __init__(self, inner):
        self.inner, self.max_read = inner, -1

    def __len__(self):
        return len(self.inner)

    def read(self, i):
        self.max_read = max(self.max_read, i)
        return self.inner.read(i)


def tiny_team(tiny_world, **overrides):
    from openmulti_env.experiment.presets import mapping_config
    from openmulti_env.world.stream import world_streams, world_vocabulary

    streams = [CountingStream(s) for s in world_streams(tiny_world, seed=0, segmentation_errors=False)]
    channel = overrides.pop("channel", ChannelConfig())
    mapping = replace(mapping_config("tiny"), iterations_per_keyframe=2, refit_steps=10,
                      global_frame=overrides.pop("global_frame", None))
    overrides.setdefault("consistency", ConsistencyConfig(iterations=2, rays_per_pose=64))
    config = TeamConfig(mapping=mapping, frames_per_round=4, **overrides)
    return Team(streams, config, world_vocabulary(tiny_world), seed=0, channel=channel, device="cpu"), streams
