"""A real RGB-D data set as a ``mapping.pipeline.Source`` (``DataSource``): frames per agent, masks per
frame with caption features, the ground-truth (or reference) mesh, the semantic ground truth and the
viewpoints of the culling. Nothing here fuses, maps or scores: the pipeline's team fuses each agent's
frames online, maps and exchanges, and the pipeline scores it.

Masks come from the data set when it has instance images (Replica ``semantic_instance/``, ScanNet
``instance-filt/``), captioned with the category names of its label file; otherwise from the
geometric segmenter (planes + clusters), whose instances get neutral captions. The ground truth is
``--gt-mesh`` culled to what the cameras can see, or else a TSDF reference fused from the same frames.
"""

from __future__ import annotations

from typing import Callable

import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from tqdm import tqdm

from mapping.data import DatasetError, Frame, RGBDDataset, load_dataset, split_contiguous
from mapping.data.checks import PoseCheck, check_depth_unit, check_poses, pose_conflict_note
from mapping.data.labels import dataset_categories
from mapping.evaluate.reference import TSDFConfig, TSDFReference
from mapping.perception import FrameSegmentation, TextEncoder, Vocabulary
from mapping.perception.front_end import encode_segments
from mapping.perception.geometric_segmenter import GeometricSegmenter, GeometricSegmenterConfig, instance_caption
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.segmenter import DatasetMaskSegmenter
from mapping.pointcloud import voxel_downsample
from mapping.evaluate.visibility import cull_to_viewpoints
from mapping.pipeline.source import CameraViews, GroundTruth, SourceRecord

VIEWPOINT_SPACING_M = 0.25
"""Camera centres closer than this are one viewpoint of the culling (the free-space grid is 0.5 m)."""
SEMANTIC_MATCH_M = 0.05
"""A ground-truth surface point takes the category of the nearest labelled depth point within this."""
POSE_FILES = {"replica": "traj_w_c.txt", "nice_slam": "traj.txt", "scannet": "pose"}
"""Where each layout keeps its poses (named in warnings about them)."""
GT_POINTS = 200_000
"""Ground-truth surface samples for F-mIoU / F-mAcc (as ``openmulti run --scene``)."""


@dataclass
class DataInputs:
    """Everything a run needs from a data set, agent names ``agent_K``."""

    name: str
    kind: str
    root: Path
    frames: dict[str, RGBDDataset]
    segmentations: dict[str, list[FrameSegmentation]]
    masks: str
    """``dataset`` (the data set's instance images) or ``geometric`` (planes + clusters)."""
    vocabulary: list[str]
    """Category names for zero-shot labels (the data set's; the neutral kinds for geometric masks)."""
    gt_mesh: trimesh.Trimesh
    ground_truth: str
    """``given`` (``--gt-mesh``, culled to the viewpoints) or ``tsdf_reference``."""
    viewpoints: np.ndarray
    """(m, 3) camera centres of all agents' frames, 25 cm apart: the culling's viewpoints."""
    semantic_gt: tuple[np.ndarray, np.ndarray] | None
    """(n, 3) ground-truth points and their (n,) categories, or None (no categories)."""
    notes: list[str] = field(default_factory=list)
    timings_s: dict[str, float] = field(default_factory=dict)


def parse_frames(spec: str | None, n: int) -> range:
    """Positions selected by ``A:B:S`` (Python slice syntax, any part may be empty) out of ``n`` frames."""
    if spec is None:
        return range(n)
    parts = spec.split(":")
    try:
        if len(parts) > 3:
            raise ValueError
        values = [int(p) if p.strip() else None for p in parts] + [None] * (3 - len(parts))
    except ValueError:
        raise ValueError(f"--frames {spec!r}: expected A:B:S (e.g. 0:800:2)") from None
    if values[2] is not None and values[2] < 1:
        raise ValueError(f"--frames {spec!r}: the step must be >= 1")
    return range(n)[slice(*values)]


def parse_intrinsics(spec: str | None) -> tuple[float, float, float, float] | None:
    """``fx,fy,cx,cy`` as four floats (None passes through)."""
    if spec is None:
        return None
    try:
        values = tuple(float(v) for v in spec.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or not all(np.isfinite(values)) or values[0] <= 0 or values[1] <= 0:
        raise ValueError(f"--intrinsics {spec!r}: expected fx,fy,cx,cy (four numbers, fx and fy > 0)")
    return values  # type: ignore[return-value]


def load_agents(path: str | Path, kind: str, agents: int, frames: str | None = None,
                intrinsics: str | None = None, depth_scale: float | None = None) -> dict[str, RGBDDataset]:
    """Load the data set, select ``frames`` and cut it into ``agents`` contiguous sequences."""
    ds = load_dataset(path, kind, intrinsics=parse_intrinsics(intrinsics), depth_scale=depth_scale)
    ds = ds.subset(parse_frames(frames, len(ds)))
    if len(ds) < agents:
        raise DatasetError(f"{ds.root}: {len(ds)} frame(s) selected, fewer than --agents {agents}")
    return {f"agent_{k}": ds.subset(r) for k, r in enumerate(split_contiguous(len(ds), agents))}


def check_sequence(agents: dict[str, RGBDDataset]) -> list[PoseCheck]:
    """Warn (naming the files) about an implausible depth unit or poses that are not camera-to-world;
    returns each agent's pose check (how far neighbouring frames agree)."""
    first = next(iter(agents.values()))
    sample = [first[i] for i in sorted({0, len(first) // 2, len(first) - 1})]
    check_depth_unit(sample, f"{first.files[0].depth.parent}", first.depth_scale)
    checks = []
    for name, seq in agents.items():
        starts = sorted({i for i in (0, len(seq) // 2, len(seq) - 2) if 0 <= i < len(seq) - 1})  # pairs (i, i + 1)
        checks.append(check_poses([(seq[i], seq[i + 1]) for i in starts],
                                  f"{seq.root / POSE_FILES[seq.kind]} ({name}'s frames)"))
    return checks


def prepare_inputs(path: str | Path, kind: str = "auto", agents: int = 1, frames: str | None = None,
                   intrinsics: str | None = None, depth_scale: float | None = None, gt_mesh: str | None = None,
                   text_encoder: TextEncoder | None = None, image_encoder: ImageTextEncoder | None = None,
                   tsdf: TSDFConfig | None = None,
                   culling_edge_m: float = 0.05, seed: int = 0, progress: bool = True,
                   segmenter_config: GeometricSegmenterConfig | None = None) -> DataInputs:
    """Read, check, segment, caption and encode every agent's frames; build the ground truth.

    ``segmenter_config`` sets the geometric segmenter's thresholds for data without instance images (None:
    its defaults); data with instance images ignore it."""
    from mapping.perception import shared_text_encoder  # noqa: PLC0415

    encoder = text_encoder or shared_text_encoder()
    seqs = load_agents(path, kind, agents, frames, intrinsics, depth_scale)
    first = next(iter(seqs.values()))
    pose_checks = check_sequence(seqs)
    has_masks = first.files[0].instance is not None
    categories, label_file = dataset_categories(first.root, first.kind) if has_masks else ({}, None)
    notes = []
    if has_masks:
        segmenter = DatasetMaskSegmenter(categories)
        if segmenter_config not in (None, GeometricSegmenterConfig()):
            notes.append(f"{first.root}: the data set has instance images, which give the masks: the geometric "
                         "segmenter's settings are not used")
        if not categories:
            notes.append(f"{first.root}: instance images but no label file (info_semantic.json / *.aggregation.json): "
                         "instances are class-agnostic, F-mIoU/F-mAcc are not scored")
    else:
        segmenter = GeometricSegmenter(segmenter_config)
        notes.append("no instance masks in the data: masks from the geometric segmenter (planes + Euclidean "
                     "clusters); semantics are geometric only, F-mIoU/F-mAcc are not scored")
    conflict = pose_conflict_note(pose_checks, str(first.root))
    if conflict:
        notes.append(conflict)
    reference = TSDFReference(tsdf) if gt_mesh is None else None
    labelled = _LabelledPoints(categories) if categories else None
    segmentations, seg_time, n_frames = {}, 0.0, 0
    for name, seq in seqs.items():
        segs = []
        for frame in tqdm(seq, total=len(seq), desc=f"{name} perception", unit="frame", disable=not progress):
            t0 = time.perf_counter()
            seg = segmenter.segment(frame)
            seg_time += time.perf_counter() - t0
            n_frames += 1
            segs.append(encode_segments(seg, frame, encoder, image_encoder))
            if reference is not None:
                reference.integrate(frame)
            if labelled is not None:
                labelled.add(frame)
        segmentations[name] = segs
    viewpoints = camera_viewpoints(seqs)
    t0 = time.perf_counter()
    if gt_mesh is not None:
        mesh = observable_mesh(load_gt_mesh(gt_mesh), viewpoints, culling_edge_m)
        ground_truth = "given"
    else:
        mesh = reference.mesh()
        ground_truth = "tsdf_reference"
        notes.append("no --gt-mesh: accuracy, completion and completion ratio are measured against a TSDF "
                     "reconstruction of the same frames (open3d, 1 cm voxels), not against ground truth")
    if len(mesh.faces) == 0:
        raise DatasetError(f"{first.root}: the ground-truth {'mesh' if gt_mesh else 'reference'} has no surface "
                           "the cameras can see (check the poses and the depth unit)")
    gt_time = time.perf_counter() - t0
    semantic_gt = labelled.label_surface(mesh, seed) if labelled is not None else None
    vocabulary = sorted(set(categories.values())) if categories else ["planar surface", "object"]
    return DataInputs(first.name, first.kind, first.root, seqs, segmentations,
                      "dataset" if has_masks else "geometric", vocabulary, mesh, ground_truth, viewpoints,
                      semantic_gt, notes + ([f"categories from {label_file}"] if label_file else []),
                      {"segmenter_per_frame": seg_time / max(n_frames, 1), "ground_truth": gt_time})


def camera_viewpoints(seqs: dict[str, RGBDDataset], spacing_m: float = VIEWPOINT_SPACING_M) -> np.ndarray:
    """Camera centres of every agent's frames, one per ``spacing_m`` voxel: the cameras stood in free
    space, so they play the part the free-space grid plays for simulated worlds."""
    centres = np.concatenate([seq.poses[:, :3, 3] for seq in seqs.values()])
    return voxel_downsample(centres, spacing_m)


def load_gt_mesh(path: str | Path) -> trimesh.Trimesh:
    """A ground-truth mesh file as one triangle mesh (DatasetError naming the file otherwise)."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: --gt-mesh file not found")
    try:
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many types for broken files
        raise DatasetError(f"{path}: cannot read the mesh ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise DatasetError(f"{path}: not a triangle mesh with faces")
    if not np.all(np.isfinite(mesh.vertices)):
        raise DatasetError(f"{path}: mesh has non-finite vertex coordinates")
    return mesh


def observable_mesh(mesh: trimesh.Trimesh, viewpoints: np.ndarray, max_edge_m: float = 0.05) -> trimesh.Trimesh:
    """``mesh`` split into faces of at most ``max_edge_m`` and culled to what the viewpoints can see,
    as the simulated worlds' observable ground truth is (README, Evaluation)."""
    v, f = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=max_edge_m, max_iter=12)
    return cull_to_viewpoints(trimesh.Trimesh(v, f, process=False), viewpoints)


class _LabelledPoints:
    """Depth points of the frames labelled with the data set's categories (2 cm voxels per category)."""

    def __init__(self, categories: dict[int, str], pixel_stride: int = 4, voxel_m: float = 0.02):
        self.names = sorted(set(categories.values()))
        self.lut = np.full(max(categories) + 1, -1, np.int64)  # instance id -> category index (-1: none)
        for i, c in categories.items():
            self.lut[i] = self.names.index(c)
        self.stride, self.voxel_m = pixel_stride, voxel_m
        self.points: list[np.ndarray] = []
        self.labels: list[np.ndarray] = []

    def add(self, frame: Frame) -> None:
        ids = np.where(frame.instance < len(self.lut), frame.instance, 0)
        cat = self.lut[ids]
        points, valid = frame.backproject_pixels(self.stride, mask=cat >= 0)
        pts, grp = voxel_downsample(points, self.voxel_m, cat[::self.stride, ::self.stride][valid])
        self.points.append(pts)
        self.labels.append(grp)

    def label_surface(self, mesh: trimesh.Trimesh, seed: int) -> tuple[np.ndarray, np.ndarray] | None:
        """Surface samples of ``mesh`` with the category of the nearest labelled point within 5 cm."""
        if not self.points or not sum(len(p) for p in self.points):
            return None
        points, labels = np.concatenate(self.points), np.concatenate(self.labels)
        samples, _ = trimesh.sample.sample_surface(mesh, GT_POINTS, seed=seed)
        dist, nearest = cKDTree(points).query(samples, k=1)
        near = dist < SEMANTIC_MATCH_M
        if not near.any():
            warnings.warn("no ground-truth surface point lies within 5 cm of a labelled depth point: "
                          "F-mIoU/F-mAcc are not scored", stacklevel=2)
            return None
        return np.asarray(samples)[near], np.array(self.names)[labels[nearest[near]]]


PLANAR = "planar surface"
"""With geometric masks, the vocabulary name whose instances get the structure networks."""
STRUCTURE = ("wall", "floor", "ceiling")
"""Data-set categories that get the structure networks."""


class DataStream:
    """One agent's frames of a data set as a ``mapping.team.AgentStream``: frame ``i`` (decoded from disk
    when read) and its segmentation (masks with caption features, from ``prepare_inputs``)."""

    def __init__(self, inputs: DataInputs, name: str):
        self.name = name
        self.frames, self.segmentations = inputs.frames[name], inputs.segmentations[name]

    def __len__(self) -> int:
        return len(self.frames)

    def read(self, index: int) -> tuple[Frame, FrameSegmentation]:
        if not 0 <= index < len(self):
            raise IndexError(f"{self.name} has frames 0..{len(self) - 1}, not {index}")
        return self.frames[index], self.segmentations[index]


class DataSource:
    """A data set's ``DataInputs`` as a ``mapping.pipeline.Source``."""

    def __init__(self, inputs: DataInputs, text_encoder: TextEncoder, image_encoder: ImageTextEncoder | None = None):
        self.inputs, self.text_encoder, self.image_encoder = inputs, text_encoder, image_encoder
        self.name = inputs.name

    def streams(self) -> list[DataStream]:
        return [DataStream(self.inputs, name) for name in self.inputs.frames]

    def vocabulary(self) -> Vocabulary:
        """The data set's categories with walls, floors and ceilings as structure; with geometric masks
        "planar surface" / "object", planar surfaces as structure (wider networks)."""
        structure = STRUCTURE if self.inputs.masks == "dataset" else (PLANAR,)
        return Vocabulary.from_encoder(self.inputs.vocabulary, self.text_encoder, structure)

    def ground_truth(self, seed: int) -> GroundTruth:
        given = self.inputs.ground_truth == "given"
        return GroundTruth(self.inputs.gt_mesh, "gt_observable.ply" if given else "gt_reference.ply",
                           self.inputs.viewpoints, self.inputs.vocabulary, self.inputs.semantic_gt,
                           "Meshes are culled to what the cameras' positions (25 cm apart) can see, occlusion "
                           "included;")

    def sensor_views(self, agent: int) -> tuple[list[Frame], int]:
        seq = list(self.inputs.frames.values())[agent]
        return [seq[i] for i in sorted({len(seq) // 3, 2 * len(seq) // 3})], max(1, seq.intrinsics.width // 80)

    def agent_frames(self, agent: int, every: int, offset: int = 0) -> list[Frame]:
        seq = list(self.inputs.frames.values())[agent]
        return [seq[i] for i in range(offset, len(seq), max(1, every))]

    def camera_views(self, stride: int) -> CameraViews | None:
        return None

    def facts(self) -> dict:
        """What the run found of this data set on disk: its layout, name and frames per agent."""
        inputs = self.inputs
        return {"kind": inputs.kind, "scene": inputs.name,
                "frames_per_agent": {a: len(s) for a, s in inputs.frames.items()}}

    def record(self, settings: dict, identity: dict | None = None,
               read_identity: Callable[[dict], dict | None] | None = None) -> SourceRecord:
        """What the run records of this source beside ``settings`` (``SourceRecord``'s fields)."""
        inputs = self.inputs
        caption = (lambda iid, text: instance_caption(text, iid)) if inputs.masks == "geometric" else None
        return SourceRecord(
            settings,
            {"ground_truth": inputs.ground_truth, "masks": inputs.masks,
             "timings_s": {k: round(v, 4) for k, v in inputs.timings_s.items()}},
            list(inputs.notes), caption, described=self.facts(), identity=identity, read_identity=read_identity)
