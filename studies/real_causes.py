"""Why maps of real RGB-D data are poor: each cause's share, measured (issue: real data as clean as the simulator).

Runs ``openmulti run --data`` on each given sequence once per variant, a variant changing one setting of the
mapper from the preset's, and prints the depth check (median error, share of valid pixels off by > 5 cm or
without surface, on the seen and on held-out frames) per variant, averaged over the agents. A variant's
share of a cause is how much of the baseline's "off" it removes.

Variants (``--variants`` picks some; the default runs all):

| name | what changes | the cause it tests |
|---|---|---|
| `fixed` | a keyframe every `keyframe_every` frames, nothing after the last (before the short-stream rules) | |
| `fixed_iters_x5` | `fixed`, 5x iterations per keyframe | training length |
| `fixed_keyframes_all` | `fixed`, every frame a keyframe (5x keyframes and iterations) | keyframe selection + length |
| `fixed_free_x5` | `fixed`, 5 stratified samples per ray instead of 1 | free space inside a box no sample supervises |
| `fixed_other_half` | `fixed`, half of each instance's rays on other surfaces in its 2D box (default 20 %) | free space in the box |
| `base` | today's defaults (`TeamConfig.min_keyframes`, `min_local_steps` from the preset; a recording also gets `mapping.model.agent_config.for_recordings`: carving, then also crossing free-space rays on half the rays; the `base` rows of docs/real_data_study were made before each) | |
| `other_half` | vMAP's mapper, half of the rays on other surfaces | free space in the box |
| `crossing` | `base`, free-space rays from every keyframe ray that crosses the 3D box | free space in the box |
| `crossing_half` | `crossing`, half of the rays free-space ones | free space in the box |
| `carve` | vMAP's mapper, every sample in front of an observed surface asked to be empty (weight 10) | free space in the box |
| `carve_half` | `carve` and `other_half` | |
| `planes_4cm` | `base`, the geometric segmenter's plane inlier distance 4 cm (was 2 cm) | segments at range |
| `segmenter_range_aware` | `base` with the segmenter's `RANGE_AWARE` thresholds (planes and clusters widen with depth noise) | segments at range |
| `segmenter_range_aware_core6` | `segmenter_range_aware` with DBSCAN's core rule (6 of 8 grid neighbours) | segments at range |
| `segmenter_range_aware_3m5` | `segmenter_range_aware`, no masks beyond 3.5 m | segments at range |
| `carve_crossing_half` | `carve` and `crossing_half` (on a recording: `base`; for ``--scene``) | free space in the box |
| `crossing_half_range_aware` | `crossing_half` with `segmenter_range_aware`'s segmenter | both |
| `split_1m` | `base`, object clusters wider than 1 m cut along a 1 m world lattice (`max_object_extent_m`; the default since 2026-12-06, so today the same as `base`, whose rows of that day are uncut) | segments spanning a counter |
| `unmasked` | `base` without observed spaces (`observed_cell_m=None`: surface drawn wherever a network says, as before issue 44) | surface no ray saw |
| `segmenter_range_aware_unmasked` | `segmenter_range_aware` without observed spaces | both |
| `kinect_noise` | (``--scene``) the simulator's depth with Kinect v1's noise, 1.5 mm x depth^2 | depth noise at range |
| `kinect_holes` | (``--scene``) 12 % of the depth pixels dropped at random | depth holes |
| `kinect` | (``--scene``) both | |
| `kinect_crossing_half` | `kinect` with `crossing_half`'s mapper | |

On recordings a variant's mapper goes through ``for_recordings`` after its change, which fills in every
setting the variant left at ``MappingConfig``'s default (so today ``crossing`` and ``crossing_half`` equal ``base``),
except for the `fixed*`, `other_half`, `carve` and `carve_half` variants: they change vMAP's mapper alone
(``Variant.recording_mapper``), as when their rows were made.

``--scene`` runs the variants on simulated scenes instead (the sensor variants only run there: the
controlled set). Each row also holds ``team_coverage_pct``: the share of the ground truth's (or TSDF
reference's) surface within 5 cm of some agent's unculled map. Rows are written to ``OUT/rows.json`` as they finish (atomically); a second call with the same ``--out``
skips the rows it has. Run: `.venv/bin/python -m studies.real_causes --data /path/7scenes50
/path/tum_cabinet58 [--preset fast] [--agents 2] [--holdout-every 10] [--out runs/study_real_causes]`
(``scripts/real_data.py`` writes the two public sequences).

Figures: docs/real_data.md#why-each-cause-measured
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable

import numpy as np
import trimesh

import mapping.pipeline.data_source as data_source
from mapping.model.agent_config import MappingConfig
from mapping.evaluate.geometry import surface_classes
from mapping.perception.geometric_segmenter import RANGE_AWARE, GeometricSegmenterConfig
from mapping.pipeline.records import write_json_atomic
from openmulti_env.experiment import Experiment, check, experiment
from openmulti_env.runs.run import run_experiment

KEYS = ("depth_median_cm", "depth_off_pct", "depth_no_surface_pct", "depth_heldout_median_cm",
        "depth_heldout_off_pct", "acc_cm", "comp_ratio")


def _sampler(config: MappingConfig, **fields) -> MappingConfig:
    return replace(config, sampler=replace(config.sampler, **fields))


FIXED = {"min_keyframes": 0, "min_local_steps": 0}
"""Before the short-stream rules: a keyframe every ``keyframe_every`` frames and nothing after the last frame."""
KINECT_NOISE = {"depth_noise_std_m": 0.0015}
"""Kinect v1's depth noise, about 1.5 mm at 1 m growing with the square of depth (Khoshelham and Elberink 2012)."""
KINECT_HOLES = {"missing_depth_prob": 0.12}
"""The share of pixels without depth in the 7-Scenes sequence (12 %), dropped at random."""


@dataclass(frozen=True)
class Variant:
    """One change from the preset: its mapper, its team settings, the simulator's sensor."""

    mapping: Callable[[MappingConfig], MappingConfig] = lambda m: m
    team: dict = field(default_factory=dict)
    sensor: dict = field(default_factory=dict)
    """``SensorConfig`` fields (simulated scenes only)."""
    segmenter: GeometricSegmenterConfig | None = None
    """The geometric segmenter's settings (recordings without masks only; None: its defaults)."""
    recording_mapper: bool = True
    """On a recording, pass the changed mapper through ``for_recordings``; False: the change on vMAP's mapper
    alone (the variants made before ``for_recordings`` existed, so that their rows keep their meaning)."""


VARIANTS: dict[str, Variant] = {
    "fixed": Variant(team=FIXED, recording_mapper=False),
    "fixed_iters_x5": Variant(lambda m: replace(m, iterations_per_keyframe=5 * m.iterations_per_keyframe), FIXED,
                              recording_mapper=False),
    "fixed_keyframes_all": Variant(lambda m: replace(m, keyframe_every=1), FIXED, recording_mapper=False),
    "fixed_free_x5": Variant(lambda m: _sampler(m, n_stratified=5), FIXED, recording_mapper=False),
    "fixed_other_half": Variant(lambda m: replace(m, own_ray_fraction=0.5), FIXED, recording_mapper=False),
    "base": Variant(),
    "other_half": Variant(lambda m: replace(m, own_ray_fraction=0.5), recording_mapper=False),
    "crossing": Variant(lambda m: replace(m, free_space_rays="crossing")),
    "crossing_half": Variant(lambda m: replace(m, free_space_rays="crossing", own_ray_fraction=0.5)),
    "carve": Variant(lambda m: replace(m, loss_weights=replace(m.loss_weights, free_space=10.0)),
                     recording_mapper=False),
    "carve_half": Variant(lambda m: replace(m, own_ray_fraction=0.5,
                                            loss_weights=replace(m.loss_weights, free_space=10.0)),
                          recording_mapper=False),
    "planes_4cm": Variant(segmenter=GeometricSegmenterConfig(plane_distance_m=0.04)),
    "segmenter_range_aware": Variant(segmenter=RANGE_AWARE),
    "segmenter_range_aware_core6": Variant(segmenter=replace(RANGE_AWARE, cluster_core_neighbours=6)),
    "segmenter_range_aware_3m5": Variant(segmenter=replace(RANGE_AWARE, max_depth_m=3.5)),
    "carve_crossing_half": Variant(lambda m: replace(m, free_space_rays="crossing", own_ray_fraction=0.5,
                                                     loss_weights=replace(m.loss_weights, free_space=10.0))),
    "crossing_half_range_aware": Variant(lambda m: replace(m, free_space_rays="crossing", own_ray_fraction=0.5),
                                         segmenter=RANGE_AWARE),
    "unmasked": Variant(lambda m: replace(m, observed_cell_m=None)),
    "split_1m": Variant(segmenter=GeometricSegmenterConfig(max_object_extent_m=1.0)),
    "segmenter_range_aware_unmasked": Variant(lambda m: replace(m, observed_cell_m=None), segmenter=RANGE_AWARE),
    "kinect_noise": Variant(sensor=KINECT_NOISE),
    "kinect_holes": Variant(sensor=KINECT_HOLES),
    "kinect": Variant(sensor={**KINECT_NOISE, **KINECT_HOLES}),
    "kinect_crossing_half": Variant(lambda m: replace(m, free_space_rays="crossing", own_ray_fraction=0.5),
                                    sensor={**KINECT_NOISE, **KINECT_HOLES}),
}


def study_tree(preset: str, variant: str, **settings) -> Experiment:
    """``preset``'s tree with ``settings`` (short spellings) and the variant's changes to the mapper, the
    sensor and the team (the team's keyframe minimums follow the changed mapper unless the variant sets them)."""
    change = VARIANTS[variant]
    tree = experiment(preset, **settings)
    world = replace(tree.world, sensor=replace(tree.world.sensor, **change.sensor))
    tree = replace(tree, world=world, team=replace(tree.team, mapping=change.mapping(tree.team.mapping)))
    tree = tree.with_team_minimums()
    return check(replace(tree, team=replace(tree.team, **change.team)))


@contextlib.contextmanager
def _segmenter(config: GeometricSegmenterConfig | None):
    """The data source's geometric segmenter with ``config``, for one run (this process only)."""
    original = data_source.GeometricSegmenter
    if config is not None:
        data_source.GeometricSegmenter = lambda *_: original(config)
    try:
        yield
    finally:
        data_source.GeometricSegmenter = original


def team_coverage_pct(run_dir: Path) -> float:
    """Share [%] of the run's ground truth (``meshes/gt_*.ply``) within 5 cm of the union of its agents' maps."""
    gt = trimesh.load(next((run_dir / "meshes").glob("gt_*.ply")), force="mesh")
    maps = [trimesh.load(p, force="mesh") for p in sorted((run_dir / "meshes").glob("agent_*.ply"))]
    count = 100_000
    classes = surface_classes(trimesh.util.concatenate(maps) if maps else None, gt, count=count)
    return 100.0 * (1.0 - len(classes.missed) / count)


def _mean(values: list) -> float | None:
    finite = [v for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(finite)) if finite else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--data", nargs="+", default=[], help="sequence folders (NICE-SLAM layout or any --data)")
    parser.add_argument("--scene", nargs="+", default=[], help="simulated scenes (the sensor variants need one)")
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=list(VARIANTS))
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--agents", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--holdout-every", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default="runs/study_real_causes")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows_path = out / "rows.json"
    rows = json.loads(rows_path.read_text()) if rows_path.exists() else {}
    sources = [(Path(d).name, d, None) for d in args.data] + [(scene, None, scene) for scene in args.scene]
    for name, data, scene in sources:
        for variant in args.variants:
            if VARIANTS[variant].sensor and scene is None:
                continue  # a recording's sensor is what it is
            key = f"{name}/{variant}" + ("" if args.preset == "fast" else f"/{args.preset}") + \
                (f"/seed{args.seed}" if args.seed else "")
            if key in rows:
                continue
            run_dir = out / key.replace("/", "_")
            shutil.rmtree(run_dir, ignore_errors=True)
            where = {"data": data, "recording_mapper": VARIANTS[variant].recording_mapper} if data else {"scene": scene}
            tree = study_tree(args.preset, variant, agents=args.agents, policy="always", seed=args.seed,
                              out=str(run_dir), device="cpu", threads=args.threads,
                              holdout_every=args.holdout_every, **where)
            with _segmenter(VARIANTS[variant].segmenter):
                metrics = run_experiment(tree)
            rows[key] = {k: _mean([a.get(k) for a in metrics["agents"].values()]) for k in KEYS}
            rows[key]["team_coverage_pct"] = team_coverage_pct(run_dir)
            rows[key]["wall_s"] = metrics["wall_s"]
            rows[key]["load"] = os.getloadavg()[0]
            write_json_atomic(rows_path, rows)
    print(f"\npreset {args.preset}, {args.agents} agents, policy always, every {args.holdout_every}th frame held out; "
          "mean over agents")
    print(f"{'sequence/variant':<32} {'err cm':>7} {'off %':>6} {'none %':>7} {'held err':>9} {'held off':>9} "
          f"{'acc cm':>7} {'CR %':>6} {'team cov %':>10}")
    for key, row in rows.items():
        cells = [row.get(k) for k in (*KEYS, "team_coverage_pct")]
        print(f"{key:<32} " + " ".join(f"{'-' if c is None else f'{c:.2f}':>{w}}"
                                       for c, w in zip(cells, (7, 6, 7, 9, 9, 7, 6, 10))))


if __name__ == "__main__":
    main()
