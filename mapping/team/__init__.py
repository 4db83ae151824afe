"""The collaborative learner: agents in rounds, the channel between them, eq. 12-13.

    messages      what travels (to_bytes / from_bytes; bytes counted as their length)
    channel       per-link success draws, byte budget, counters
    arrival       Cross-Agent Instance Alignment on arrival (match / merge / adopt)
    consistency   parameter consistency, eq. 12: consensus, DiNNO, DSGD
    cross_rendering  Cross Rendering Supervision, eq. 13
    config        TeamConfig, ConsistencyConfig, ExchangeConfig
    global_map    the global-map mode (one network for the scene: the global baselines)
    member        one agent: online fusion, mapper, what it holds of its peers; composed of
      outbox      what it sends (parameter, ray, point-cloud messages) and what each peer holds of it
      inbox       what arrives: alignment and adoption
      agreement   its consistency iterations: eq. 12 and eq. 13
    report        RoundReport, AgentSnapshot (what each agent knows after a round) and their parts
    team          Team.round(plan) -> RoundReport, checkpoints
"""

from mapping.team.channel import Channel, Delivery
from mapping.team.config import ConsistencyConfig, ExchangeConfig, TeamConfig
from mapping.team.member import AgentStream, TeamMember
from mapping.team.messages import (InstancePayload, MessageError, MessageRules, ParameterMessage, PointCloudMessage,
                                   RayMessage, from_bytes, to_bytes)
from mapping.team.report import (AgentSnapshot, AlignmentCounts, ConsistencyTerms, DeliveryRecord, LinkState, LossTerms,
                                 PeerKnowledge, RoundReport)
from mapping.team.team import ChannelConfig, PlanError, RoundPlan, Team

__all__ = ["AgentSnapshot", "AlignmentCounts", "ConsistencyTerms", "DeliveryRecord", "LinkState", "LossTerms", "PeerKnowledge",
           "AgentStream", "Channel", "ChannelConfig", "ConsistencyConfig", "Delivery", "ExchangeConfig",
           "InstancePayload", "MessageError", "MessageRules", "ParameterMessage", "PlanError", "PointCloudMessage", "RayMessage", "RoundPlan",
           "RoundReport", "Team", "TeamConfig", "TeamMember", "from_bytes", "to_bytes"]
