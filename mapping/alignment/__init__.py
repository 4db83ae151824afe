"""Cross-agent instance alignment (paper, sec. III-C).

``align_agents`` is the entry point: exchange of down-sampled instance clouds (``overlap``), the
Instance Collaborative Graph (``graph``), the three corrections (``corrections``); ``no_alignment``
and ``oracle_alignment`` give the ablation and the ground-truth upper bound with the same result type;
``align_team`` picks one of the three by name for a whole team's perception (``team_alignment``).
The instance confidence of eq. 1-2 lives in ``confidence``.
"""

from mapping.alignment.align import AgentAlignment, AlignmentResult, align_agents, no_alignment
from mapping.alignment.config import AlignmentConfig
from mapping.alignment.graph import Cluster, InstanceCollaborativeGraph, Node
from mapping.alignment.oracle import id_consistency, id_purity, oracle_alignment
from mapping.alignment.overlap import iob, iou, message_bytes, voxel_downsample
from mapping.alignment.team_alignment import ALIGNMENT_MODES, TeamPerception, align_team, labelled_points

__all__ = [
    "ALIGNMENT_MODES", "AgentAlignment", "AlignmentConfig", "AlignmentResult", "Cluster", "InstanceCollaborativeGraph",
    "Node", "TeamPerception", "align_agents", "align_team", "id_consistency", "id_purity", "iob", "iou",
    "labelled_points", "message_bytes", "no_alignment", "oracle_alignment", "voxel_downsample",
]
