"""Alignment study (issue targets): 4 agents on each preset with the default error rates.

For every scene: the world's frames go through the simulated front end (segmenter with the seeded error
model, captioner, SBERT, cross-frame fusion per agent); then three alignments of the same fused
instances: ``none`` (each agent alone), ``paper`` (Cross-Agent Instance Alignment) and ``oracle``
(ground-truth ids). Front end and alignments are the batch ones in ``studies/batch_alignment/``
(every frame first, then one alignment), not the team's online path. Reported per scene and alignment:

- id consistency: share of ground-truth instances seen by two or more agents that carry one global id
  across those agents (target >= 95 % for ``paper``); and id purity, the share of global ids whose
  instances are all dominated by one ground-truth object (gluing objects together lowers it);
- team F-mIoU / F-mAcc: the union of all agents' corrected masks back-projected (every 5th frame,
  every 4th pixel) is the reconstruction, each point labelled by zero-shot labelling of its instance's
  code-book entry, scored on 200k points of the observable ground truth (target: ``paper`` beats
  ``none`` by >= 5 points); and the mean of the agents' own F-mIoU;
- the bytes the alignment messages carried.

Run: `.venv/bin/python -m studies.alignment [--scenes room0 ...] [--seed 0] [--preset fast]
[--out runs/bench_alignment]`. Writes `results.json` and `alignment.png` there.

Figures: docs/front_end.md#measured-alignment
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import asdict, replace
from pathlib import Path

import numpy as np
import torch

from mapping.evaluate.semantic import score_semantics
from mapping.perception import shared_text_encoder
from mapping.perception.errors import SegmentationErrorConfig
from mapping.pipeline.records import write_json_atomic
from openmulti_env.experiment.presets import world_config
from openmulti_env.world import World
from openmulti_env.world.semantics import category_vocabulary, semantic_ground_truth
from studies.batch_alignment import ALIGNMENT_MODES, align_team, id_consistency, id_purity, labelled_points
from studies.batch_alignment.front_end import FrontEndConfig, perceive_team

PRESETS = ("room0", "room1", "room2", "office0", "office1", "office2", "office3", "office4")


def bench_scene(scene: str, seed: int, preset: str, encoder, errors: SegmentationErrorConfig) -> dict:
    t0 = time.perf_counter()
    world = World.build(scene, seed=seed, config=world_config(preset, 4))
    t_world = time.perf_counter() - t0
    config = FrontEndConfig(errors=errors)
    t0 = time.perf_counter()
    perception = perceive_team(world, seed, config, encoder, progress=False)
    t_front = time.perf_counter() - t0
    gt_points, gt_labels = semantic_ground_truth(world, 200_000, seed)
    vocabulary = category_vocabulary(world)
    row = {"scene": scene, "seed": seed, "world_s": t_world, "front_end_s": t_front,
           "fused_instances": {a: len(f.instances) for a, f in perception.fused.items()}}
    for mode in ALIGNMENT_MODES:
        t0 = time.perf_counter()
        result = align_team(perception, mode, config.alignment)
        t_align = time.perf_counter() - t0
        team_pts, team_ids, own = [], [], []
        for agent in perception.frames:
            pts, ids = labelled_points(perception, result, agent)
            team_pts.append(pts)
            team_ids.append(ids)
            own.append(score_semantics(gt_points, gt_labels, pts, ids, result.agents[agent].codebook, vocabulary,
                                       encoder).f_miou)
        team = score_semantics(gt_points, gt_labels, np.concatenate(team_pts), np.concatenate(team_ids),
                               result.codebook, vocabulary, encoder)
        row[mode] = {"id_consistency": 100.0 * id_consistency(result, perception.fused),
                     "id_purity": 100.0 * id_purity(result, perception.fused),
                     "team_f_miou": team.f_miou, "team_f_macc": team.f_macc, "agent_f_miou_mean": float(np.mean(own)),
                     "global_ids": len(result.codebook), "bytes_sent_total": int(sum(result.bytes_sent.values())),
                     "align_s": t_align}
    world.close()
    return row


def save_plot(rows: list[dict], path: Path) -> None:
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    fig, axes = plt.subplots(1, 2, figsize=(12, 4))
    x = np.arange(len(rows))
    for k, mode in enumerate(ALIGNMENT_MODES):
        axes[0].bar(x + (k - 1) * 0.27, [r[mode]["id_consistency"] for r in rows], 0.27, label=mode)
        axes[1].bar(x + (k - 1) * 0.27, [r[mode]["team_f_miou"] for r in rows], 0.27, label=mode)
    for ax, title in zip(axes, ("id consistency [%] (instances seen by >= 2 agents)", "team F-mIoU [%]")):
        ax.set_xticks(x, [r["scene"] for r in rows], rotation=30)
        ax.set_title(title)
        ax.legend()
    axes[0].axhline(95, color="k", lw=0.8, ls="--")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scenes", nargs="+", default=list(PRESETS))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--out", default="runs/bench_alignment")
    parser.add_argument("--semantic-rate", type=float, default=None, help="override the default semantic error rate")
    parser.add_argument("--structure-errors", action="store_true",
                        help="let semantic errors and drops reach walls, floor and ceiling (off by default)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    encoder = shared_text_encoder()
    errors = FrontEndConfig().errors
    if args.semantic_rate is not None or args.structure_errors:
        errors = replace(errors, semantic_rate=errors.semantic_rate if args.semantic_rate is None else args.semantic_rate,
                         structure_errors=args.structure_errors)
    print(f"error rates per agent: semantic {errors.semantic_rate:.0%}, over-segmentation "
          f"{errors.over_segmentation_rate:.0%}, under-segmentation {errors.under_segmentation_rate:.0%}, "
          f"mask drop {errors.mask_drop_rate:.0%}; 4 agents, preset {args.preset}, seed {args.seed}")
    rows = []
    out = Path(args.out)
    header = (f"{'scene':<8} | {'consistency none/paper/oracle [%]':>34} | {'team F-mIoU none/paper/oracle':>30} | "
              f"{'agent F-mIoU':>20} | {'purity':>6} | {'MB sent':>7} | {'front s':>7} {'align s':>7}")
    print(header)
    for scene in args.scenes:
        r = bench_scene(scene, args.seed, args.preset, encoder, errors)
        rows.append(r)
        n, p, o = (r[m] for m in ALIGNMENT_MODES)
        print(f"{scene:<8} | {n['id_consistency']:>10.1f} {p['id_consistency']:>10.1f} {o['id_consistency']:>10.1f}"
              f"   | {n['team_f_miou']:>9.1f} {p['team_f_miou']:>9.1f} {o['team_f_miou']:>9.1f}  "
              f"| {n['agent_f_miou_mean']:>6.1f} {p['agent_f_miou_mean']:>6.1f} {o['agent_f_miou_mean']:>6.1f} "
              f"| {p['id_purity']:>6.1f} | {p['bytes_sent_total'] / 1e6:>7.2f} | {r['front_end_s']:>7.1f} {p['align_s']:>7.1f}", flush=True)
        write_json_atomic(out / "results.json", {"rows": rows, "seed": args.seed, "preset": args.preset,
                                                 "errors": asdict(errors)})
    mean = {m: {k: float(np.mean([r[m][k] for r in rows])) for k in ("id_consistency", "id_purity", "team_f_miou", "agent_f_miou_mean")}
            for m in ALIGNMENT_MODES}
    print("mean     | " + "  ".join(f"{m}: consistency {mean[m]['id_consistency']:.1f}, team F-mIoU "
                                     f"{mean[m]['team_f_miou']:.1f}, agent F-mIoU {mean[m]['agent_f_miou_mean']:.1f}"
                                     for m in ALIGNMENT_MODES))
    gain = [r["paper"]["team_f_miou"] - r["none"]["team_f_miou"] for r in rows]
    print(f"targets: paper consistency >= 95 % on every scene: "
          f"{'met' if all(r['paper']['id_consistency'] >= 95 for r in rows) else 'MISSED'}; "
          f"team F-mIoU gain over none >= 5 points: min {min(gain):.1f}, mean {np.mean(gain):.1f}")
    write_json_atomic(out / "results.json", {"rows": rows, "mean": mean, "seed": args.seed, "preset": args.preset,
                                             "errors": asdict(errors)})
    save_plot(rows, out / "alignment.png")
    print(f"wrote {out / 'results.json'} and {out / 'alignment.png'}")


if __name__ == "__main__":
    main()
