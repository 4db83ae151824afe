"""The table a run prints at its end: per agent and mean, then what the rounds cost."""

from __future__ import annotations

from pathlib import Path

from mapping.pipeline.runner import RunResult
from mapping.pipeline.scoring import DEPTH_CHECK_EVERY


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def results_table(result: RunResult, out: Path) -> list[str]:
    """Accuracy, completion, completion ratio, F-mIoU / F-mAcc, instances and compute per agent, their
    mean, all maps' semantics; bytes, messages and fleet time; what was written."""
    if not result.evaluated:
        return [costs_line(result), "Not evaluated: run the same command without --no-evaluation to score the maps "
                "(it resumes after the last round).",
                f"Wrote {out}/metrics.json, {out}/rounds.json, {out}/checkpoints/ in {result.wall_s:.1f} s"]
    lines = [f"{'agent':<10} {'acc [cm]':>9} {'comp [cm]':>10} {'comp ratio [%]':>15} {'F-mIoU':>7} {'F-mAcc':>7} "
             f"{'depth err [cm]':>15} {'depth off [%]':>14} {'instances':>10} {'compute [s]':>12}"]
    for name, m in result.agents.items():
        lines.append(f"{name:<10} {_fmt(m['acc_cm']):>9} {_fmt(m['comp_cm']):>10} {_fmt(m['comp_ratio']):>15} "
                     f"{_fmt(m['f_miou']):>7} {_fmt(m['f_macc']):>7} {_fmt(m.get('depth_median_cm')):>15} "
                     f"{_fmt(m.get('depth_off_pct')):>14} {m['instances']:>10} {result.compute_s[name]:>12.1f}")
    mean, team = result.mean, result.team
    lines.append(f"{'mean':<10} {_fmt(mean['acc_cm']):>9} {_fmt(mean['comp_cm']):>10} {_fmt(mean['comp_ratio']):>15} "
                 f"{_fmt(mean['f_miou']):>7} {_fmt(mean['f_macc']):>7} {_fmt(mean.get('depth_median_cm')):>15} "
                 f"{_fmt(mean.get('depth_off_pct')):>14}")
    lines.append(f"{'all maps':<10} {'':>9} {'':>10} {'':>15} {_fmt(team['f_miou']):>7} {_fmt(team['f_macc']):>7}")
    if "ground_truth" in result.extra:  # a data set: say what the geometry was scored against
        against = ("the given ground-truth mesh (culled to what the cameras see)"
                   if result.extra["ground_truth"] == "given" else "a TSDF REFERENCE of the same frames, not ground truth")
        masks = result.extra.get("masks")
        lines.append(f"geometry scored against {against}; masks: {masks}"
                     + (" (semantics are geometric only)" if masks == "geometric" else ""))
    lines.append(f"depth err / off: each map ray cast from every {DEPTH_CHECK_EVERY}th of its agent's input poses against "
                 "the sensor depth: median error, and % of valid pixels off by > 5 cm or with no surface")
    lines += ["", costs_line(result),
              f"Wrote {out}/metrics.json, {out}/rounds.json, {out}/meshes/, {out}/codebook/, {out}/plots/ in "
              f"{result.wall_s:.1f} s; try: openmulti query --run {out} \"somewhere to sit\""]
    return lines


def costs_line(result: RunResult) -> str:
    """What the rounds cost: rounds, bytes, messages, fleet time."""
    msgs = result.messages
    return (f"{result.rounds} rounds; {result.bytes_sent_total / 1e6:.2f} MB sent "
            f"({result.bytes_per_round_per_agent_mean / 1e6:.2f} MB per round per agent); messages delivered "
            f"{msgs['delivered']}, dropped {msgs['dropped']}, over budget {msgs['over_budget']}; "
            f"fleet time {result.fleet_s:.1f} s")
