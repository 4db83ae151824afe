"""Evaluation: meshes from instance fields, the vMAP/MACIM geometric metrics, semantics, retrieval.

Names are imported on first use (PEP 562): ``mapping.evaluate.retrieval`` must not pay for torch,
trimesh and scipy (meshing, geometry) when a one-shot ``openmulti query`` imports it.

No PettingZoo, Gymnasium, pyrender or `openmulti_env` imports here.
"""

from importlib import import_module

_WHERE = {
    "geometry": ("COMPLETION_RATIO_THRESHOLD_M", "GeometricMetrics", "accuracy_completion", "empty_metrics",
                 "evaluate_mesh", "evaluate_per_instance", "sample_points", "SampledSurface"),
    "meshing": ("INSTANCE_ID_PROPERTY", "colour_vertices", "export_scene_mesh", "extract_instance_mesh", "grid_for_bound",
                "instance_color", "load_scene_mesh", "merge_instance_meshes"),
    "retrieval": ("RetrievalHit", "score_instances"),
    "semantic": ("ClassRow", "SemanticMetrics", "ground_truth_semantic_points", "per_class_table",
                 "score_semantics", "semantic_metrics", "zero_shot_labels"),
}
_MODULE_OF = {name: module for module, names in _WHERE.items() for name in names}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str):
    if name in _MODULE_OF:
        value = getattr(import_module(f"mapping.evaluate.{_MODULE_OF[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'mapping.evaluate' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
