"""Cross-agent instance alignment (paper, sec. III-C): what the team's alignment on arrival
(``mapping.team.arrival``) and the fusion's instance confidence need.

The options (``config``), the overlap of two instance clouds, IoU / IoB of eq. 3-4 (``overlap``), the
Instance Collaborative Graph (``graph``), and the instance confidence of eq. 1-2 (``confidence``).
The batch alignment of a whole team's fused instances (split / merge corrections, corrected masks, the
ground-truth oracle) is reached only from ``python -m studies.alignment`` and lives beside it, in
``studies.batch_alignment``.
"""

from mapping.alignment.config import AlignmentConfig
from mapping.alignment.graph import Cluster, InstanceCollaborativeGraph, Node
from mapping.alignment.overlap import iob, iou

__all__ = ["AlignmentConfig", "Cluster", "InstanceCollaborativeGraph", "Node", "iob", "iou"]
