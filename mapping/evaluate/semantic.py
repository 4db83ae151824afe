"""Zero-shot semantic evaluation: label each code-book instance, then F-mIoU / F-mAcc on points.

The map never sees ground-truth classes. Each instance gets the category whose encoded name is most
similar to its features (zero-shot), and the labelled reconstruction is scored against ground-truth
points the way ConceptGraphs and OpenObj (and the paper's Table II) report it: every ground-truth
point takes the label of the nearest reconstructed point, then per-class IoU and accuracy are
averaged with each class weighted by its share of ground-truth points ("frequency-weighted").

No PettingZoo, Gymnasium, pyrender or ``openmulti_env`` imports here.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from mapping.perception.codebook import CodeBook
from mapping.perception.text_encoder import TextEncoder, shared_text_encoder
from mapping.perception.vocabulary import CATEGORY_PROMPT, category_prompts

__all__ = [
    "UNKNOWN_LABEL",
    "ClassRow",
    "SemanticMetrics",
    "ground_truth_semantic_points",
    "per_class_table",
    "score_semantics",
    "semantic_metrics",
    "zero_shot_labels",
]

UNKNOWN_LABEL = "unknown"
"""Label of reconstructed points whose instance has no zero-shot label."""


def _unit_rows(x: np.ndarray, what: str) -> np.ndarray:
    """Rows scaled to unit length (ValueError naming ``what`` for non-finite or zero rows)."""
    x = np.asarray(x, dtype=np.float64)
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if not np.all(np.isfinite(x)) or np.any(norms == 0):
        raise ValueError(f"{what} has non-finite or zero-length feature vectors")
    return x / norms


def zero_shot_labels(
    codebook: CodeBook,
    category_names: Sequence[str],
    text_encoder,
    image_encoder=None,
    visual_weight: float = 0.8,
    prompt: str = CATEGORY_PROMPT,
) -> dict[int, str]:
    """Category of every code-book instance by feature similarity to the encoded category names.

    score(i, c) = cos(caption_feature_i, SBERT(name_c)); when the instance has a visual feature and an
    image-text encoder is given, score = w * cos(visual_feature_i, encode_texts(name_c))
    + (1 - w) * caption score, w = ``visual_weight`` (0.8, as OpenObj's retrieval).

    Args:
        codebook: instance id -> entry with a (384,) caption feature (and maybe a visual feature).
        category_names: the vocabulary, e.g. the dataset's classes; duplicates are ignored.
        text_encoder: has ``encode(texts) -> (n, 384)`` unit vectors (``TextEncoder``).
        image_encoder: None, or has ``encode_texts(texts) -> (n, D)`` in the visual feature space.
        visual_weight: weight of the visual term when it exists, in [0, 1].
        prompt: format string applied to each name (see ``CATEGORY_PROMPT``).

    Returns:
        instance id -> one of ``category_names`` (as given, underscores kept).
    """
    names = list(dict.fromkeys(str(n) for n in category_names))
    if not names:
        raise ValueError("zero_shot_labels needs at least one category name")
    if not 0.0 <= visual_weight <= 1.0:
        raise ValueError(f"visual_weight must be in [0, 1], got {visual_weight}")
    if not codebook:
        return {}
    ids = sorted(codebook)
    texts = category_prompts(names, prompt)
    captions = _unit_rows(np.stack([np.asarray(codebook[i].caption_feature).reshape(-1) for i in ids]),
                          "the code book's caption features")
    names_text = _unit_rows(text_encoder.encode(texts), "the encoded category names")
    if captions.shape[1] != names_text.shape[1]:
        raise ValueError(f"caption features have {captions.shape[1]} dims but the text encoder gives "
                         f"{names_text.shape[1]}")
    scores = captions @ names_text.T  # (instances, categories)

    has_visual = np.array([codebook[i].visual_feature is not None for i in ids])
    if image_encoder is not None and has_visual.any():
        rows = np.flatnonzero(has_visual)
        visual = _unit_rows(np.stack([np.asarray(codebook[ids[r]].visual_feature).reshape(-1) for r in rows]),
                            "the code book's visual features")
        names_visual = _unit_rows(image_encoder.encode_texts(texts), "the image encoder's text features")
        if visual.shape[1] != names_visual.shape[1]:
            raise ValueError(f"visual features have {visual.shape[1]} dims but the image encoder's text "
                             f"features have {names_visual.shape[1]}")
        scores[rows] = visual_weight * (visual @ names_visual.T) + (1.0 - visual_weight) * scores[rows]
    best = scores.argmax(axis=1)
    return {int(i): names[int(b)] for i, b in zip(ids, best)}


@dataclass(frozen=True)
class ClassRow:
    """Scores of one ground-truth class.

    Attributes:
        class_name: the category.
        frequency: share of ground-truth points of this class, in [0, 1].
        iou: TP / (TP + FP + FN) over the ground-truth points, in [0, 1].
        acc: TP / (TP + FN), in [0, 1].
        n_points: ground-truth points of this class.
    """

    class_name: str
    frequency: float
    iou: float
    acc: float
    n_points: int


@dataclass(frozen=True)
class SemanticMetrics:
    """Frequency-weighted semantic scores of a labelled reconstruction.

    Attributes:
        f_miou: sum over classes of frequency x IoU, percent.
        f_macc: sum over classes of frequency x accuracy, percent.
        miou: unweighted mean IoU over the ground-truth classes, percent.
        macc: unweighted mean accuracy, percent.
        per_class: one row per ground-truth class, most frequent first.
    """

    f_miou: float
    f_macc: float
    miou: float
    macc: float
    per_class: list[ClassRow] = field(default_factory=list)

    def as_dict(self) -> dict:
        """JSON-ready (rows keyed ``class``, ``frequency``, ``iou``, ``acc``, ``n_points``)."""
        rows = []
        for r in self.per_class:
            d = asdict(r)
            rows.append({"class": d.pop("class_name"), **d})
        return {"f_miou": self.f_miou, "f_macc": self.f_macc, "miou": self.miou, "macc": self.macc,
                "per_class": rows}


def _points(x: object, name: str, allow_empty: bool) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0 and allow_empty:
        return x.reshape(0, 3)
    if x.ndim != 2 or x.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {x.shape}")
    if len(x) == 0:
        raise ValueError(f"{name} is empty")
    if not np.all(np.isfinite(x)):
        raise ValueError(f"{name} has non-finite coordinates")
    return x


def semantic_metrics(
    gt_points: np.ndarray,
    gt_labels: Sequence[str] | np.ndarray,
    recon_points: np.ndarray,
    recon_instance_ids: np.ndarray,
    instance_labels: Mapping[int, str],
) -> SemanticMetrics:
    """F-mIoU and F-mAcc of a reconstruction whose instances carry zero-shot labels.

    Definition (ConceptGraphs' and OpenObj's evaluation): each ground-truth point p takes the label
    of the instance of its nearest reconstructed point (no distance limit; instance ids missing from
    ``instance_labels`` give "unknown"). Over the ground-truth points, for each class c present in
    the ground truth, TP_c = points of c predicted c, FN_c = points of c predicted otherwise,
    FP_c = points of other classes predicted c; IoU_c = TP_c / (TP_c + FP_c + FN_c),
    Acc_c = TP_c / (TP_c + FN_c), frequency f_c = |points of c| / |points|;
    F-mIoU = 100 * sum_c f_c IoU_c, F-mAcc = 100 * sum_c f_c Acc_c. An empty reconstruction scores 0.

    Args:
        gt_points: (n, 3) float ground-truth surface points, n > 0.
        gt_labels: (n,) str category of each ground-truth point.
        recon_points: (m, 3) float reconstructed points (m may be 0), e.g. mesh vertices.
        recon_instance_ids: (m,) int instance id of each reconstructed point.
        instance_labels: instance id -> category (e.g. from ``zero_shot_labels``).
    """
    gt_points = _points(gt_points, "gt_points", allow_empty=False)
    gt_labels = np.asarray(gt_labels).astype(str).reshape(-1)
    if len(gt_labels) != len(gt_points):
        raise ValueError(f"{len(gt_labels)} ground-truth labels for {len(gt_points)} ground-truth points")
    recon_points = _points(recon_points, "recon_points", allow_empty=True)
    recon_ids = np.asarray(recon_instance_ids).reshape(-1)
    if len(recon_ids) != len(recon_points):
        raise ValueError(f"{len(recon_ids)} instance ids for {len(recon_points)} reconstructed points")

    if len(recon_points):
        _, nearest = cKDTree(recon_points).query(gt_points, k=1)
        ids, inverse = np.unique(recon_ids[nearest], return_inverse=True)
        pred = np.array([instance_labels.get(int(i), UNKNOWN_LABEL) for i in ids], dtype=object)[inverse]
        pred = pred.astype(str)
    else:
        pred = np.full(len(gt_points), UNKNOWN_LABEL)

    classes, gt_idx, counts = np.unique(gt_labels, return_inverse=True, return_counts=True)
    pred_idx = np.searchsorted(classes, pred).clip(max=len(classes) - 1)
    pred_in_gt = classes[pred_idx] == pred  # predicted labels outside the ground-truth classes are never TP/FP
    tp = np.bincount(gt_idx[pred_in_gt & (pred_idx == gt_idx)], minlength=len(classes))
    predicted = np.bincount(pred_idx[pred_in_gt], minlength=len(classes))  # TP + FP
    iou = tp / (counts + predicted - tp)  # counts = TP + FN > 0 for every ground-truth class
    acc = tp / counts
    freq = counts / counts.sum()
    order = np.argsort(-counts, kind="stable")
    rows = [ClassRow(str(classes[k]), float(freq[k]), float(iou[k]), float(acc[k]), int(counts[k])) for k in order]
    return SemanticMetrics(f_miou=100.0 * float(freq @ iou), f_macc=100.0 * float(freq @ acc),
                           miou=100.0 * float(iou.mean()), macc=100.0 * float(acc.mean()), per_class=rows)


def score_semantics(gt_points: np.ndarray, gt_labels: np.ndarray, recon_points: np.ndarray, recon_ids: np.ndarray,
                    codebook: CodeBook, vocabulary: list[str], text_encoder: TextEncoder | None = None) -> SemanticMetrics:
    """F-mIoU / F-mAcc of a reconstruction whose instance ids have meanings in ``codebook``."""
    labels = zero_shot_labels(codebook, vocabulary, text_encoder or shared_text_encoder())
    return semantic_metrics(gt_points, gt_labels, recon_points, recon_ids, labels)


def ground_truth_semantic_points(
    meshes_with_categories: Sequence[tuple[trimesh.Trimesh, str]],
    n_points: int = 200_000,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Area-uniform points over all ground-truth instance meshes, each with its mesh's category.

    Returns:
        points: (n_points, 3) float64.
        labels: (n_points,) str.
    """
    if n_points < 1:
        raise ValueError(f"n_points must be at least 1, got {n_points}")
    meshes = [(m, str(c)) for m, c in meshes_with_categories if m is not None and len(m.faces)]
    if not meshes:
        raise ValueError("ground_truth_semantic_points needs at least one mesh with faces")
    scene = trimesh.util.concatenate([m for m, _ in meshes])
    if not scene.area > 0:
        raise ValueError("the ground-truth meshes have zero total area")
    points, face_index = trimesh.sample.sample_surface(scene, int(n_points), seed=seed)
    first_face = np.cumsum([len(m.faces) for m, _ in meshes])
    mesh_index = np.searchsorted(first_face, face_index, side="right")
    labels = np.array([c for _, c in meshes])[mesh_index]
    return np.asarray(points, dtype=np.float64), labels


def per_class_table(metrics: SemanticMetrics) -> str:
    """Markdown table: one row per class (frequency, IoU, accuracy in percent, points) and the totals."""
    lines = ["| class | frequency [%] | IoU [%] | Acc [%] | points |", "|---|---:|---:|---:|---:|"]
    for r in metrics.per_class:
        lines.append(f"| {r.class_name} | {100 * r.frequency:.1f} | {100 * r.iou:.1f} | {100 * r.acc:.1f} "
                     f"| {r.n_points} |")
    lines.append(f"| **F-mIoU / F-mAcc** | | **{metrics.f_miou:.2f}** | **{metrics.f_macc:.2f}** | "
                 f"{sum(r.n_points for r in metrics.per_class)} |")
    return "\n".join(lines)
