"""What a run maps: a ``Source`` gives the agents' frame streams, the vocabulary, the ground truth (or a
reference) to score against, and the sensor views for pictures. The simulator
(``openmulti_env.runs.sim_source``) and real data sets (``mapping.pipeline.data_source``) are both sources, so one
pipeline (``mapping.pipeline.runner``) runs, scores and writes every run.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

import numpy as np
import trimesh

from mapping.data.frame import Frame, Intrinsics
from mapping.perception.image_encoder import ImageTextEncoder
from mapping.perception.text_encoder import TextEncoder
from mapping.perception.vocabulary import Vocabulary
from mapping.team import AgentStream


@dataclass
class CameraViews:
    """The cameras of the NICE-SLAM culling: (k, 4, 4) poses, (k, H, W) observed depths, intrinsics."""

    poses: np.ndarray
    depths: np.ndarray
    intrinsics: Intrinsics


@dataclass
class GroundTruth:
    """What the maps are scored against."""

    mesh: trimesh.Trimesh
    """The observable surface (or a reference reconstruction when the data set has no mesh)."""
    file_name: str
    """Its name under ``out/meshes/`` (``gt_observable.ply`` or ``gt_reference.ply``)."""
    viewpoints: np.ndarray
    """(m, 3) positions in free space; a map is culled to what they can see (``cull_to_viewpoints``)."""
    categories: list[str]
    """Category names the instances' zero-shot labels are chosen from."""
    semantic: tuple[np.ndarray, np.ndarray] | None
    """(n, 3) surface points and their (n,) categories for F-mIoU / F-mAcc, or None (not scored)."""
    culling_note: str
    """One sentence on how the maps are culled (for ``metrics.json``'s notes)."""

    @property
    def reference_note(self) -> str:
        """What ``mesh`` is, in a few words (pictures' legends)."""
        return "TSDF reference" if self.file_name == "gt_reference.ply" else "ground truth"


class Source(Protocol):
    """Frames, vocabulary and ground truth of one run (see the module docstring)."""

    name: str
    """Scene or data set name (titles)."""
    text_encoder: TextEncoder
    """The caption encoder the streams used (zero-shot labels use it too)."""
    image_encoder: ImageTextEncoder | None

    def streams(self) -> Sequence[AgentStream]:
        """One frame stream per agent (agent ``k`` is ``agent_k``)."""
        ...

    def vocabulary(self) -> Vocabulary:
        """The team's category names (which are structure: walls, floors, ceilings)."""
        ...

    def ground_truth(self, seed: int) -> GroundTruth:
        """What the maps are scored against (``seed`` draws the semantic surface samples)."""
        ...

    def sensor_views(self, agent: int) -> tuple[list[Frame], int]:
        """A few of the agent's frames for the sensor-vs-map pictures, and the pixel stride to render at."""
        ...

    def agent_frames(self, agent: int, every: int, offset: int = 0) -> list[Frame]:
        """The agent's input frames at stream positions ``offset``, ``offset + every``, ... (the depth
        check's views)."""
        ...

    def camera_views(self, stride: int) -> CameraViews | None:
        """The agents' cameras with their observed depth for NICE-SLAM culling (None: not available)."""
        ...


@dataclass
class SourceRecord:
    """What a source adds to a run's record: settings (checkpoints are kept only under the same ones),
    extra result fields and notes."""

    settings: dict
    """The run's settings as recorded in ``metrics.json``'s ``config`` (e.g. the whole configuration tree)."""
    results: dict = field(default_factory=dict)
    """Extra fields of ``metrics.json`` (e.g. ``map``, ``ground_truth``)."""
    notes: list[str] = field(default_factory=list)
    caption: Callable[[int, str], str] | None = None
    """Renames the captions written in the code books (``caption(id, caption)``), e.g. geometric segments."""
    described: dict = field(default_factory=dict)
    """Written in ``metrics.json``'s ``resolved`` beside the team the run resolved, outside the checkpoints' key
    (values that follow from the settings, e.g. the error rates)."""
    identity: dict | None = None
    """What the checkpoints are kept under, besides the team (None: ``settings``)."""
    read_identity: Callable[[dict], dict | None] | None = None
    """Reads a checkpoint record written by an older version as this version's identity (None: compared as
    written)."""
