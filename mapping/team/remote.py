"""Team members as processes: each agent's map, fusion and inbox live in a Ray actor of its own (on this
machine or any node of a cluster), and only serialised messages cross.

``RemoteMember`` stands in for a ``TeamMember`` in ``Team``: the same calls, each run in the agent's actor
(``MemberProcess``). What crosses a process boundary:
- the round's frames and segmentations, driver -> actor (the streams stay with the driver: renderer and
  encoders are not duplicated per agent);
- every message as its wire bytes (``messages.to_bytes``), decoded and validated on the other side by
  ``messages.from_bytes`` (a malformed one is refused with ``MessageError``, never applied); the channel on
  the driver counts and draws them exactly as in-process, so bytes are the same;
- reports, snapshots and probe results back.
A member never reads another member's state. ``Team(processes="ray")`` builds these; on CPU a team gives
the same maps and bytes either way (``tests/test_remote_members.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from mapping.perception.vocabulary import Vocabulary
from mapping.team.config import TeamConfig
from mapping.team.member import AgentStream, LocalReport, StreamReader, TeamMember
from mapping.team.message_checks import team_rules
from mapping.team.messages import Message, MessageRules, from_bytes, to_bytes
from mapping.team.report import AgentSnapshot, AlignmentCounts, ConsistencyTerms
from mapping.model.topdown import ColumnGrid, ColumnMap


@dataclass(frozen=True)
class HandedView:
    """What a member process keeps of a frame it was handed: its pose and intrinsics (all that a ray
    message, the one later reader of past frames, takes from it)."""

    pose: np.ndarray
    intrinsics: object


class HandedFrames:
    """The stream as a member process sees it: its length, and the views of the frames handed to it (the
    frames themselves are read on the driver; their images are not kept)."""

    def __init__(self, length: int):
        self.length = int(length)
        self.views: dict[int, HandedView] = {}

    def __len__(self) -> int:
        return self.length

    def hand(self, first: int, views: Sequence[HandedView]) -> None:
        for k, view in enumerate(views):
            self.views[first + k] = view

    def read(self, index: int) -> tuple[HandedView, None]:
        if index not in self.views:
            raise RuntimeError(f"frame {index} was never handed to this member process (it reads no stream)")
        return self.views[index], None


def views_of(frames: Sequence) -> list[HandedView]:
    """The views a member process keeps of ``frames`` (``Frame`` objects, or views already)."""
    return [HandedView(np.asarray(f.pose), f.intrinsics) for f in frames]


def _wire(message: Message | None) -> bytes | None:
    return None if message is None else to_bytes(message)


def _unwire(data: bytes | None, rules: MessageRules) -> Message | None:
    return None if data is None else from_bytes(data, rules)


class MemberProcess:
    """The body of one agent's actor: a ``TeamMember`` and the calls ``RemoteMember`` forwards to it."""

    def __init__(self, index: int, frames: int, config: TeamConfig, vocabulary: Vocabulary, seed: int,
                 device: str, threads: int | None = None, init_seed: int | None = None):
        if threads:
            import torch  # noqa: PLC0415

            torch.set_num_threads(threads)
        self.frames = HandedFrames(frames)
        self.member = TeamMember(index, self.frames, config, vocabulary, seed=seed, device=device, init_seed=init_seed)
        self.rules = team_rules(config.mapping, config.exchange, vocabulary.features.shape[1])

    def local_round(self, read: tuple[list, float]) -> LocalReport:
        self.frames.hand(self.member.next_frame, views_of([frame for frame, _ in read[0]]))
        return self.member.local_round(read)

    def hand(self, first: int, views: Sequence[HandedView]) -> None:
        """Views of frames read before a restore (what a ray message of mapped views reads)."""
        self.frames.hand(first, views)

    def parameter_message(self, receiver: int, round_index: int, degree: int, only=None,
                          max_bytes: float | None = None, new: bool = False) -> bytes | None:
        return _wire(self.member.parameter_message(receiver, round_index, degree, only, max_bytes, new))

    def point_cloud_message(self, receiver: int, round_index: int) -> bytes:
        return _wire(self.member.point_cloud_message(receiver, round_index))

    def ray_message(self, receiver: int, round_index: int, seed: int) -> bytes | None:
        return _wire(self.member.ray_message(receiver, round_index, seed))

    def acknowledge(self, receiver: int, kind: str, delivered: bool, round_index: int) -> None:
        self.member.acknowledge(receiver, kind, delivered, round_index)

    def note_rays(self, data: bytes) -> None:
        self.member.note_rays(_unwire(data, self.rules))

    def receive_parameters(self, data: bytes) -> AlignmentCounts:
        return self.member.receive_parameters(_unwire(data, self.rules))

    def arrival_problem(self, data: bytes) -> str | None:
        return self.member.arrival_problem(_unwire(data, self.rules))

    def degree_messages(self, round_index: int) -> list[bytes]:
        return [_wire(m) for m in self.member.degree_messages(round_index)]

    def consistency_round(self, rays: Sequence[bytes], round_index: int, listings: Sequence[bytes],
                          acknowledged: frozenset) -> ConsistencyTerms:
        return self.member.consistency_round([_unwire(d, self.rules) for d in rays], round_index,
                                             [_unwire(d, self.rules) for d in listings], acknowledged)

    def snapshot(self, rounds: int, new_frames: Sequence, budget_left_bytes: float,
                 link_bytes: np.ndarray) -> AgentSnapshot:
        return self.member.snapshot(rounds, new_frames, budget_left_bytes, link_bytes)

    def surface_coverage(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        return self.member.surface_coverage(points, normals)

    def column_map(self, grid: ColumnGrid) -> ColumnMap:
        return self.member.column_map(grid)

    def state(self) -> dict:
        from mapping.team.state import member_state  # noqa: PLC0415

        return member_state(self.member)

    def restore(self, state: dict) -> None:
        from mapping.team.state import restore_member  # noqa: PLC0415

        restore_member(self.member, state)

    def copy(self) -> TeamMember:
        return self.member


@dataclass(frozen=True)
class MemberPlacement:
    """Where the member processes run: the device each maps on and what each actor asks Ray for."""

    device: str
    num_cpus: float
    num_gpus: float


def start_member_processes(count: int, device: str = "cpu", threads: int = 1, wait_s: float = 20.0) -> MemberPlacement:
    """Make sure a Ray is there for ``count`` member processes and say what each asks for.

    Joins the cluster ``RAY_ADDRESS`` names, or starts a Ray on this machine when this process has none
    (with at least ``count * threads`` CPUs: a member computes only while the team calls it). ``cuda``
    shares the cluster's GPUs between the members (ValueError without any); ``auto`` uses them when there
    are any, else the CPU. ValueError when the CPUs or GPUs asked for have not been free for ``wait_s``
    seconds (the actors would wait for them forever, e.g. while another team's processes live)."""
    try:
        import ray  # noqa: PLC0415
    except ImportError:
        raise ImportError("team members as processes need Ray: pip install 'openmulti[ray]'") from None
    import os  # noqa: PLC0415
    import time  # noqa: PLC0415

    if not ray.is_initialized():
        local = {} if os.environ.get("RAY_ADDRESS") else {"num_cpus": max(os.cpu_count() or 1, count * threads)}
        ray.init(include_dashboard=False, log_to_driver=False, configure_logging=False, **local)
    gpus = ray.cluster_resources().get("GPU", 0.0)
    if str(device).startswith("cuda") and gpus <= 0:
        raise ValueError(f"device {device!r} for member processes, but the Ray cluster has no GPU")
    on_gpu = str(device).startswith("cuda") or (device == "auto" and gpus > 0)
    placement = MemberPlacement("cuda" if on_gpu else "cpu", float(threads),
                                min(1.0, gpus / count) if on_gpu else 0.0)
    wanted = {"CPU": count * placement.num_cpus, "GPU": count * placement.num_gpus}
    deadline = time.monotonic() + wait_s  # the processes of a team just released take a moment to end
    while True:
        free = ray.available_resources()
        short = {k: (v, free.get(k, 0.0)) for k, v in wanted.items() if v > 0 and free.get(k, 0.0) < v - 1e-9}
        if not short or time.monotonic() > deadline:
            break
        time.sleep(0.2)
    if short:
        raise ValueError(f"a team of {count} member processes asks for "
                         + ", ".join(f"{v:g} {k}s but the Ray cluster has {f:g} free" for k, (v, f) in short.items())
                         + " (another team still alive, or too small a cluster)")
    return placement


class RemoteMember(StreamReader):
    """A ``TeamMember`` whose state lives in a Ray actor; every call blocks until the actor answers (the
    team's worker threads call several members at once). The stream and its read position stay here."""

    def __init__(self, index: int, stream: AgentStream, config: TeamConfig, vocabulary: Vocabulary, seed: int,
                 placement: MemberPlacement = MemberPlacement("cpu", 1.0, 0.0), init_seed: int | None = None):
        import ray  # noqa: PLC0415

        self._ray = ray
        self.index, self.stream, self.config = index, stream, config
        self.rules = team_rules(config.mapping, config.exchange, vocabulary.features.shape[1])
        self.next_frame = 0
        self.actor = ray.remote(MemberProcess).options(num_cpus=placement.num_cpus, num_gpus=placement.num_gpus).remote(
            index, len(stream), config, vocabulary, seed, placement.device, max(1, int(placement.num_cpus)), init_seed)

    def _call(self, method: str, *args):
        return self._ray.get(getattr(self.actor, method).remote(*args))

    def local_round(self, read: tuple[list, float] | None = None) -> LocalReport:
        read = self.read_round() if read is None else read
        report = self._call("local_round", read)
        self.next_frame += len(read[0])
        return report

    def parameter_message(self, receiver: int, round_index: int, degree: int, only=None,
                          max_bytes: float | None = None, new: bool = False) -> Message | None:
        return _unwire(self._call("parameter_message", receiver, round_index, degree,
                                  None if only is None else tuple(only), max_bytes, bool(new)), self.rules)

    def point_cloud_message(self, receiver: int, round_index: int) -> Message:
        return _unwire(self._call("point_cloud_message", receiver, round_index), self.rules)

    def ray_message(self, receiver: int, round_index: int, seed: int) -> Message | None:
        return _unwire(self._call("ray_message", receiver, round_index, seed), self.rules)

    def acknowledge(self, receiver: int, kind: str, delivered: bool, round_index: int) -> None:
        self._call("acknowledge", receiver, kind, delivered, round_index)

    def note_rays(self, message: Message) -> None:
        self._call("note_rays", _wire(message))

    def receive_parameters(self, message: Message) -> AlignmentCounts:
        return self._call("receive_parameters", _wire(message))

    def arrival_problem(self, message: Message) -> str | None:
        return self._call("arrival_problem", _wire(message))

    def degree_messages(self, round_index: int) -> list[Message]:
        return [_unwire(d, self.rules) for d in self._call("degree_messages", round_index)]

    def consistency_round(self, ray_messages: Sequence[Message], round_index: int, listings: Sequence[Message] = (),
                          acknowledged: frozenset = frozenset()) -> ConsistencyTerms:
        return self._call("consistency_round", [_wire(m) for m in ray_messages], round_index,
                          [_wire(m) for m in listings], acknowledged)

    def snapshot(self, rounds: int, new_frames: Sequence, budget_left_bytes: float,
                 link_bytes: np.ndarray) -> AgentSnapshot:
        """The member's snapshot; the frames it read stay here (only their views cross)."""
        snap = self._call("snapshot", rounds, tuple(views_of(new_frames)), budget_left_bytes, np.asarray(link_bytes))
        return replace(snap, new_frames=tuple(new_frames))

    def surface_coverage(self, points: np.ndarray, normals: np.ndarray) -> np.ndarray:
        return self._call("surface_coverage", points, normals)

    def column_map(self, grid: ColumnGrid) -> ColumnMap:
        return self._call("column_map", grid)

    def state(self) -> dict:
        return self._call("state")

    def restore(self, state: dict) -> None:
        """Restore the member, and hand its process the views of the frames read before (re-read here)."""
        self._call("restore", state)
        self.next_frame = int(state["next_frame"])
        self._call("hand", 0, views_of([self.stream.read(i)[0] for i in range(self.next_frame)]))

    def copy(self) -> TeamMember:
        """The member as it stands in its actor, brought here (for meshing and scoring after the run)."""
        member = self._call("copy")
        member.stream = self.stream
        return member

    def close(self) -> None:
        self._ray.kill(self.actor)
