"""The communication channel: per-link success draws, an optional byte budget, and byte counts.

Bytes are the length of each message's serialised form (``messages.to_bytes``). A message that is sent
costs its sender its bytes whether it arrives or not (the radio spent them); only an arrived message
counts as received. A sender whose budget would be exceeded does not send (``over_budget``, no bytes).
Success draws come from one seeded generator, drawn in the order messages are offered, so a seed gives
the same episode.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from mapping.team.messages import Message, MessageError, MessageRules, from_bytes, to_bytes

DELIVERED, DROPPED, OVER_BUDGET = "delivered", "dropped", "over_budget"


@dataclass
class Delivery:
    """What happened to one message: ``status`` (delivered, dropped, over_budget), its bytes, and the
    message as the receiver decodes it (None unless delivered)."""

    sender: int
    receiver: int
    kind: str
    status: str
    bytes: int
    message: Message | None


class Channel:
    """Links between ``num_agents`` agents.

    Args:
        num_agents: N.
        success_probability: one probability for every link, or an (N, N) matrix (i -> j).
        budget_bytes: bytes each agent may send over the episode (None: unlimited).
        seed: drives the success draws.
        rules: what the receivers can use (``MessageRules``; its ``num_agents`` is set to N): a message
            outside them is dropped, never applied.
    """

    def __init__(self, num_agents: int, success_probability: float | np.ndarray = 1.0,
                 budget_bytes: float | None = None, seed: int = 0, rules: MessageRules | None = None):
        p = np.broadcast_to(np.asarray(success_probability, np.float64), (num_agents, num_agents)).copy()
        if np.any(~np.isfinite(p)) or np.any(p < 0) or np.any(p > 1):
            raise ValueError("success probabilities must lie in [0, 1]")
        if budget_bytes is not None and not budget_bytes >= 0:
            raise ValueError(f"budget_bytes must be >= 0 or None, got {budget_bytes}")
        self.num_agents = num_agents
        self.success = p
        self.budget_bytes = budget_bytes
        self.rules = replace(rules or MessageRules(), num_agents=num_agents)
        self.rng = np.random.default_rng(seed)
        self.bytes_sent = np.zeros(num_agents, np.int64)
        self.bytes_received = np.zeros(num_agents, np.int64)
        self.link_bytes = np.zeros((num_agents, num_agents), np.int64)

    def budget_left(self, agent: int) -> float:
        """Bytes ``agent`` may still send (inf without a budget)."""
        if self.budget_bytes is None:
            return float("inf")
        return max(0.0, self.budget_bytes - float(self.bytes_sent[agent]))

    def transmit(self, message: Message, accept: Callable[[Message], str | None] | None = None) -> Delivery:
        """Serialise, charge the sender, draw success, and decode on arrival."""
        return self.transmit_bytes(message.sender, message.receiver, message.kind, to_bytes(message), accept)

    def transmit_bytes(self, sender: int, receiver: int, kind: str, data: bytes,
                       accept: Callable[[Message], str | None] | None = None) -> Delivery:
        """``transmit`` for a message already serialised (e.g. by another process). Bytes that do not
        decode, or whose fields are outside ``rules`` or name another link (``MessageError``), or that the
        receiver cannot apply (``accept`` returns why: a delta to a copy it does not hold), cost their sender
        as sent and count as dropped: never applied."""
        i, j = sender, receiver
        if not (0 <= i < self.num_agents and 0 <= j < self.num_agents) or i == j:
            raise ValueError(f"message from {i} to {j}: agents are 0..{self.num_agents - 1} and differ")
        if len(data) > self.budget_left(i):
            return Delivery(i, j, kind, OVER_BUDGET, 0, None)
        self.bytes_sent[i] += len(data)
        self.link_bytes[i, j] += len(data)
        if self.rng.random() >= self.success[i, j]:
            return Delivery(i, j, kind, DROPPED, len(data), None)
        try:
            message = from_bytes(data, self.rules)
            if (message.sender, message.receiver) != (i, j):
                raise MessageError(f"fields sender, receiver: {message.sender} -> {message.receiver} on the link "
                                   f"{i} -> {j}")
            if message.kind != kind:
                raise MessageError(f"a {message.kind} message sent as {kind}")
            problem = None if accept is None else accept(message)
            if problem is not None:
                raise MessageError(problem)
        except MessageError as exc:
            warnings.warn(f"message {kind} from agent_{i} to agent_{j} refused: {exc}", stacklevel=2)
            return Delivery(i, j, kind, DROPPED, len(data), None)
        self.bytes_received[j] += len(data)
        return Delivery(i, j, kind, DELIVERED, len(data), message)

    def state(self) -> dict:
        return {"rng": self.rng.bit_generator.state, "bytes_sent": self.bytes_sent.tolist(),
                "bytes_received": self.bytes_received.tolist(), "link_bytes": self.link_bytes.tolist()}

    def restore(self, state: dict) -> None:
        self.rng.bit_generator.state = state["rng"]
        self.bytes_sent = np.asarray(state["bytes_sent"], np.int64)
        self.bytes_received = np.asarray(state["bytes_received"], np.int64)
        self.link_bytes = np.asarray(state["link_bytes"], np.int64)
