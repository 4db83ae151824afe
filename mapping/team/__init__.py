"""The collaborative learner: agents in rounds, the channel between them, eq. 12-13.

    messages      what travels (to_bytes / from_bytes; bytes counted as their length)
    channel       per-link success draws, byte budget, counters
    arrival       Cross-Agent Instance Alignment on arrival (match / merge / adopt)
    consistency   parameter consistency, eq. 12: consensus, DiNNO, DSGD
    cross_rendering  Cross Rendering Supervision, eq. 13
    member        one agent: online fusion, mapper, what it holds of its peers
    team          Team.round(plan) -> RoundReport, checkpoints
"""

from mapping.team.channel import Channel, Delivery
from mapping.team.member import (AgentStream, ConsistencyConfig, ExchangeConfig, TeamConfig, TeamMember,
                                 Vocabulary)
from mapping.team.messages import InstancePayload, MessageError, ParameterMessage, RayMessage, from_bytes, to_bytes
from mapping.team.team import ChannelConfig, PlanError, RoundPlan, RoundReport, Team

__all__ = ["AgentStream", "Channel", "ChannelConfig", "ConsistencyConfig", "Delivery", "ExchangeConfig",
           "InstancePayload", "MessageError", "ParameterMessage", "PlanError", "RayMessage", "RoundPlan",
           "RoundReport", "Team", "TeamConfig", "TeamMember", "Vocabulary", "from_bytes", "to_bytes"]
