"""Batch cross-agent instance alignment (paper, sec. III-C) and its offline simulated front end.

The whole team's fused instances are aligned at once: ``align_agents`` (``align``) exchanges
down-sampled instance clouds (bytes counted in ``messages``), builds the Instance Collaborative Graph
(``mapping.alignment.graph``) and applies the three corrections (``corrections``); ``no_alignment``
and ``oracle_alignment`` (``oracle``) give the ablation and the ground-truth upper bound with the same
result type; ``align_team`` picks one of the three by name for a whole team's perception
(``team_alignment``), which ``perceive_team`` (``front_end``) fills from a simulated world.
``front_end`` is not imported here, so the alignment itself loads without the simulator: import it as
``studies.batch_alignment.front_end``.

Only the alignment study (``studies.alignment``) and its tests use this, so it lives beside that study; the
product aligns online, as peers' instances arrive (``mapping.team.arrival``), with the options and
graph kept in ``mapping.alignment``.
"""

from studies.batch_alignment.align import AgentAlignment, AlignmentResult, align_agents, no_alignment
from studies.batch_alignment.messages import message_bytes
from studies.batch_alignment.oracle import id_consistency, id_purity, oracle_alignment
from studies.batch_alignment.team_alignment import ALIGNMENT_MODES, TeamPerception, align_team, labelled_points

__all__ = [
    "ALIGNMENT_MODES", "AgentAlignment", "AlignmentResult", "TeamPerception", "align_agents", "align_team",
    "id_consistency", "id_purity", "labelled_points", "message_bytes", "no_alignment", "oracle_alignment",
]
