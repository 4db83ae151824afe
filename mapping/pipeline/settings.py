"""How a run goes (the ``run`` node of the configuration tree): the schedule's name, where outputs go, threads
and processes, checkpoints, scoring. The pipeline reads it as it is (``RunConfig.job``), so every setting and its
default is written here once."""

from __future__ import annotations

from dataclasses import dataclass, field

from mapping.config_fields import bounded


@dataclass(frozen=True)
class RunSettings:
    """How the job runs: the schedule, where outputs go, threads and processes, checkpoints, scoring.
    Nothing here changes the maps but ``policy``."""

    policy: str = "always"
    """Communication policy: always, never, round_robin, budget, every:K, at:R1,R2,..., rate:Q, bernoulli:P,
    novelty[:k=v,...], instance_novelty, learned, or a trained policy file (.json beside its .safetensors)."""
    out: str = "runs/demo"
    """Output folder (the same folder and settings resume a run)."""
    device: str = "auto"
    """Learner device: cpu, cuda or auto (cuda when available)."""
    threads: int | None = field(default=None, metadata=bounded(1, 1024))
    """Torch threads (None: all cores, shared by the workers)."""
    workers: int | None = field(default=None, metadata=bounded(1, 1024))
    """Agents trained side by side on threads (None: one per core with 1 torch thread each, or 1 when
    ``threads`` is given); results do not depend on it."""
    processes: str | None = None
    """``ray``: every agent maps in a Ray actor of its own, exchanging only serialised messages."""
    learner: str = "per_agent"
    """``per_agent`` or ``fleet`` (every agent's steps batched into one computation; the same maps to float
    tolerance)."""
    checkpoint_every: int = field(default=5, metadata=bounded(0, 1_000_000))
    """Save the team every this many rounds (an interrupted run resumes from it)."""
    max_rounds: int | None = field(default=None, metadata=bounded(0, 1_000_000))
    """Stop after this many rounds (None: when the paths end), e.g. for smoke tests."""
    three_cullings: bool = False
    """Also score every map NICE-SLAM-culled and unculled."""
    culling_viewpoint_stride: int = field(default=1, metadata=bounded(1, 1_000_000))
    """Cull each map to what every this-many-th free-space viewpoint sees (1: all, the published figures; 2
    culls in 0.58x the time and moved completion ratio by at most 0.08 points on make demo's and fast maps, 4
    in 0.40x by at most 0.19: docs/profile.md). The ground truth keeps every viewpoint."""
    plots: bool = True
    """Write the pictures."""
    evaluate: bool = True
    """False: map only (rounds, bytes, the final checkpoint); the same run again with it scores the maps."""
    progress: bool = True
    """Progress bars."""
