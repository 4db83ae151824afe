"""Evaluation: meshes from instance fields and the vMAP/MACIM geometric metrics.

No PettingZoo, Gymnasium, pyrender or `openmulti_env` imports here.
"""

from mapping.evaluate.geometry import (
    COMPLETION_RATIO_THRESHOLD_M,
    GeometricMetrics,
    accuracy_completion,
    empty_metrics,
    evaluate_mesh,
    evaluate_per_instance,
    sample_points,
)
from mapping.evaluate.meshing import (
    INSTANCE_ID_PROPERTY,
    export_scene_mesh,
    extract_instance_mesh,
    grid_for_bound,
    instance_color,
    load_scene_mesh,
    merge_instance_meshes,
)

__all__ = [
    "COMPLETION_RATIO_THRESHOLD_M",
    "GeometricMetrics",
    "INSTANCE_ID_PROPERTY",
    "accuracy_completion",
    "empty_metrics",
    "evaluate_mesh",
    "evaluate_per_instance",
    "export_scene_mesh",
    "extract_instance_mesh",
    "grid_for_bound",
    "instance_color",
    "load_scene_mesh",
    "merge_instance_meshes",
    "sample_points",
]

from mapping.evaluate.retrieval import RetrievalHit, score_instances  # noqa: E402
from mapping.evaluate.semantic import (  # noqa: E402
    ClassRow,
    SemanticMetrics,
    ground_truth_semantic_points,
    per_class_table,
    semantic_metrics,
    zero_shot_labels,
)

__all__ += [
    "ClassRow",
    "RetrievalHit",
    "SemanticMetrics",
    "ground_truth_semantic_points",
    "per_class_table",
    "score_instances",
    "semantic_metrics",
    "zero_shot_labels",
]
