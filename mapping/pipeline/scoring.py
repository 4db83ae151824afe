"""Scoring every agent's own map against the whole ground truth, as the paper reports it (per agent,
then the mean), and the team's maps together for semantics.

Accuracy depends on how the reconstruction is culled, so a map is scored three ways:
- free space (the default, no suffix): faces that the free-space viewpoints can see, with the
  reconstruction's own occlusion (``mapping.evaluate.visibility.cull_to_viewpoints``);
- ``_nice``: faces inside some camera frustum of the agents' own poses and not behind the depth that
  camera observed (``mapping.evaluate.culling``; NICE-SLAM's protocol, used by vMAP and MACIM), when the
  source has the cameras and it is asked for;
- ``_unculled``: the whole reconstruction.
The ground truth is the observable surface in all three, so completion changes only by what culling
removes from the reconstruction.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import trimesh

from mapping.evaluate import SampledSurface, evaluate_mesh, export_scene_mesh, merge_instance_meshes
from mapping.data.frame import Frame
from mapping.evaluate.culling import cull_to_frustums
from mapping.evaluate.depth_check import depth_check
from mapping.evaluate.semantic import SemanticMetrics, semantic_metrics, zero_shot_labels
from mapping.evaluate.visibility import cull_to_viewpoints
from mapping.perception import CodeBook
from mapping.pipeline.records import finite_or_none, mean_or_none
from mapping.pipeline.source import CameraViews, GroundTruth
from mapping.team import TeamMember

METRIC_KEYS = ("acc_cm", "comp_cm", "comp_ratio", "f_miou", "f_macc")
CULLING_SUFFIXES = {"free_space": "", "nice_slam": "_nice", "unculled": "_unculled"}
"""Metric keys per culling: ``acc_cm`` (free space), ``acc_cm_nice``, ``acc_cm_unculled``; same for comp."""
CULLING_KEYS = tuple(f"{m}{s}" for s in ("_nice", "_unculled") for m in ("acc_cm", "comp_cm", "comp_ratio"))
"""The same geometry under the other cullings, averaged like the rest."""
DEPTH_KEYS = ("depth_median_cm", "depth_off_pct", "depth_no_surface_pct", "depth_heldout_median_cm",
              "depth_heldout_off_pct")
"""The depth check (``mapping.evaluate.depth_check``): the map ray cast from the agent's input poses against
its sensor depth."""
DEPTH_CHECK_EVERY = 5
"""The depth check uses every this-many-th of the agent's input frames..."""
DEPTH_CHECK_STRIDE = 4
"""...and every this-many-th pixel of them."""
TEAM_ID_STRIDE = 100_000
"""Agent k's instance i is ``k * TEAM_ID_STRIDE + i`` in the union of all agents' maps."""


@dataclass
class MemberMap:
    """One agent's meshed map: the mesh, each vertex's instance id, the instances' zero-shot labels."""

    index: int
    mesh: trimesh.Trimesh
    ids: np.ndarray
    labels: dict[int, str]
    scored: trimesh.Trimesh | None = None
    """The mesh culled as the headline figures score it (free space's viewpoints); None without a mesh."""


def cull_three_ways(mesh: trimesh.Trimesh | None, viewpoints: np.ndarray,
                    views: CameraViews | None) -> dict[str, trimesh.Trimesh | None]:
    """``mesh`` under each culling (``views=None`` skips ``nice_slam``); None values without a mesh."""
    has = mesh is not None and len(mesh.faces) > 0
    meshes = {"free_space": cull_to_viewpoints(mesh, viewpoints) if has else None,
              "unculled": mesh if has else None}
    if views is not None:
        meshes["nice_slam"] = cull_to_frustums(mesh, views.poses, views.intrinsics, views.depths) if has else None
    return meshes


def score_three_ways(mesh: trimesh.Trimesh | None, gt: trimesh.Trimesh, viewpoints: np.ndarray,
                     views: CameraViews | None, seed: int) -> dict[str, float | None]:
    """acc / comp / comp ratio of ``mesh`` under each culling (``views=None`` skips ``nice_slam``)."""
    return score_culled(cull_three_ways(mesh, viewpoints, views), gt, seed)


def score_culled(meshes: dict[str, trimesh.Trimesh | None], gt: trimesh.Trimesh, seed: int,
                 reference: SampledSurface | None = None) -> dict[str, float | None]:
    """acc / comp / comp ratio of each of ``cull_three_ways``'s meshes against ``gt`` (``reference``: its
    points and tree made once for many maps, ``SampledSurface.of(gt, seed=seed)``; made here when None)."""
    reference = reference or SampledSurface.of(gt, seed=seed)
    out: dict[str, float | None] = {}
    for name, culled in meshes.items():
        m = evaluate_mesh(culled if culled is not None and len(culled.faces) else None, gt, seed=seed,
                          reference=reference)
        s = CULLING_SUFFIXES[name]
        out.update({f"acc_cm{s}": finite_or_none(m.acc_cm), f"comp_cm{s}": finite_or_none(m.comp_cm),
                    f"comp_ratio{s}": float(m.comp_ratio)})
    return out


def score_member(member: TeamMember, gt: GroundTruth, views: CameraViews | None, seed: int, out: Path,
                 encoder, image_encoder, caption: Callable[[int, str], str] | None = None,
                 frames: Sequence[Frame] = (), heldout: Sequence[Frame] = (),
                 reference: SampledSurface | None = None, viewpoint_stride: int = 1) -> tuple[dict, MemberMap]:
    """Mesh one member's own map (``out/meshes/<name>.ply``), label its code book against the ground
    truth's categories (``out/codebook/<name>``; ``caption(id, caption)`` renames the captions written),
    score it (``score_three_ways``; culled to every ``viewpoint_stride``-th viewpoint), where the ground truth has categories its F-mIoU / F-mAcc, and against
    the sensor depth of ``frames`` (its own input frames: ``depth_check``) and of ``heldout`` (frames kept
    out of its map: ``TeamConfig.holdout_every``; the ``depth_heldout_*`` keys only when given)."""
    name, mapper = member.name, member.mapper
    book = member.codebook()
    labels = zero_shot_labels(book, gt.categories, encoder, image_encoder) if book else {}
    mesh, ids = merge_instance_meshes(mapper.instance_meshes())
    has_mesh = len(mesh.faces) > 0
    if has_mesh:
        export_scene_mesh(out / "meshes" / f"{name}.ply", mesh, ids)
    labelled(book, labels, caption).save(out / "codebook", name)
    semantic = None if gt.semantic is None else semantic_metrics(*gt.semantic, np.asarray(mesh.vertices), ids, labels)
    culled = cull_three_ways(mesh if has_mesh else None, gt.viewpoints[::viewpoint_stride], views)
    scores = score_culled(culled, gt.mesh, seed, reference)
    adopted = sum(1 for i in mapper.live_ids() if not mapper.keyframes.has_pixels(i))
    check = depth_check(mesh if has_mesh else None, frames, stride=DEPTH_CHECK_STRIDE)
    scores.update(depth_median_cm=check.median_cm, depth_off_pct=check.off_pct,
                  depth_no_surface_pct=check.no_surface_pct)
    if heldout:
        unseen = depth_check(mesh if has_mesh else None, heldout, stride=DEPTH_CHECK_STRIDE)
        scores.update(depth_heldout_median_cm=unseen.median_cm, depth_heldout_off_pct=unseen.off_pct)
    return ({**scores, "f_miou": None if semantic is None else semantic.f_miou,
             "f_macc": None if semantic is None else semantic.f_macc,
             "instances": len(mapper.live_ids()), "instances_without_own_pixels": adopted},
            MemberMap(member.index, mesh, ids, labels, culled["free_space"]))


def team_semantics(maps: list[MemberMap], semantic_gt: tuple[np.ndarray, np.ndarray] | None,
                   out: Path) -> SemanticMetrics | None:
    """F-mIoU / F-mAcc of all agents' maps together (agent k's instance i is ``k * TEAM_ID_STRIDE + i``);
    None without ``semantic_gt``. Agents' ids are their own, so no team code book answers queries: an
    older one in ``out/codebook`` is removed."""
    for suffix in (".json", ".npz"):
        (out / "codebook" / f"team{suffix}").unlink(missing_ok=True)
    if semantic_gt is None:
        return None
    meshed = [m for m in maps if len(m.mesh.faces)]
    points = np.concatenate([np.asarray(m.mesh.vertices) for m in meshed]) if meshed else np.zeros((0, 3))
    ids = np.concatenate([m.ids + m.index * TEAM_ID_STRIDE for m in meshed]) if meshed else np.zeros(0, np.int64)
    labels = {iid + m.index * TEAM_ID_STRIDE: lab for m in meshed for iid, lab in m.labels.items()}
    return semantic_metrics(*semantic_gt, points, ids, labels)


def mean_metrics(per_agent: dict[str, dict]) -> dict:
    """The mean over agents of every metric all agents have (``METRIC_KEYS`` and the other cullings')."""
    keys = [k for k in METRIC_KEYS + CULLING_KEYS + DEPTH_KEYS if all(k in m for m in per_agent.values())]
    return {k: mean_or_none([m[k] for m in per_agent.values()]) for k in keys}


def labelled(book: CodeBook, labels: dict[int, str], caption: Callable[[int, str], str] | None = None) -> CodeBook:
    """A copy of ``book`` whose entries carry their zero-shot labels (and ``caption(id, caption)``'s captions)."""
    return CodeBook({i: replace(entry, label=labels.get(i), **({} if caption is None else
                                                                {"caption": caption(i, entry.caption)}))
                     for i, entry in book.items()})
