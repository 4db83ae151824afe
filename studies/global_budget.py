"""Why MACIM's published map is weak here: iterations, consensus or initialisation (issue: fair baselines).

At MACIM's per-frame budget (200 iterations on the first frame, 3 on each after it, 200 after the last)
the published scene SDF of a 4-agent team reached a completion ratio of 17-18 % on room0 at `fast`, where
the paper reports 72 %. This study maps one scene three ways per call, all with the same agents, paths and
schedule: the instance-level map (``instance``, OpenMulti's), MACIM's SDF at its published budget
(``sdf_after_200``) and MACIM's SDF with more iterations after the last frame (``sdf_after_N``, ``--after``).
``--policy never`` (the default) leaves each agent alone, so consensus plays no part; ``--policy always``
adds eq. 12 at MACIM's rho every iteration, as in the tables (``--consistency dinno``: DiNNO's ADMM instead,
Di-NeRF*'s form); ``--own-init`` gives each agent's scene
network its own initial draw (the rows before 2026-12-05) instead of agent 0's copied to all (MACIM's).
The SDF runs without Cross Rendering (MACIM has none), and so does every DiNNO run (DiNNO_I has none).

Rows go to ``OUT/rows.json`` as each run finishes (atomically); a second call with the same ``--out``
skips finished rows and resumes an unfinished run from its checkpoint. Each run's pictures are in
``OUT/runs/<variant>/plots``. Run (on `tiny` a few minutes per variant; at `fast` about an hour per SDF
variant of 4 agents on one core):
`.venv/bin/python -m studies.global_budget --scene room0 --preset fast --agents 4 --policy always --after 2000 --out runs/study_global_budget`

Figures: docs/baselines.md#measured
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass
from pathlib import Path

from mapping.pipeline.records import write_json_atomic
from mapping.model.sdf_loss import SdfConfig
from openmulti_env.runs.run import run

PUBLISHED_AFTER = SdfConfig().iterations_after


@dataclass(frozen=True)
class Variant:
    """One way to map the scene: the instance-level map, or MACIM's SDF with ``after`` iterations after the stream."""

    name: str
    after: int | None


def variants(after: list[int]) -> list[Variant]:
    """The instance-level map, the published budget, then each longer budget asked for."""
    longer = sorted({a for a in after if a != PUBLISHED_AFTER})
    return ([Variant("instance", None), Variant(f"sdf_after_{PUBLISHED_AFTER}", PUBLISHED_AFTER)]
            + [Variant(f"sdf_after_{a}", a) for a in longer])


def run_variant(variant: Variant, args: argparse.Namespace) -> dict:
    """One run; the row: the mean of the agents' scores, the budget and the wall time."""
    start = time.time()
    published = variant.after is not None
    sdf = SdfConfig(iterations_after=variant.after) if published else None
    metrics = run(args.scene, args.agents, args.policy, args.preset, args.seed, args.out / "runs" / variant.name,
                  consistency=args.consistency, global_map=published,
                  global_form="published" if published else "equal_compute", sdf=sdf,
                  cross_rendering=not published and args.consistency == "consensus", three_cullings=True,
                  workers=1, threads=1, shared_global_init=not (published and args.own_init))
    mean = metrics["mean"]
    iterations = (sdf.iterations_first + sdf.iterations_per_frame * args.frames + sdf.iterations_after) if sdf else None
    return {"variant": variant.name, "scene": args.scene, "preset": args.preset, "seed": args.seed,
            "agents": args.agents, "policy": args.policy, "consistency": args.consistency,
            "own_init": bool(published and args.own_init),
            "iterations_after": variant.after, "iterations_per_agent": iterations,
            **{k: mean.get(k) for k in ("acc_cm", "comp_cm", "comp_ratio", "comp_ratio_nice", "depth_median_cm",
                                         "depth_off_pct")},
            "wall_s": round(time.time() - start, 1)}


def table(rows: list[dict]) -> str:
    """Markdown: one line per variant."""
    lines = ["| variant | iterations per agent | acc / comp [cm] | CR [%] | CR, NICE-SLAM culling [%] | "
             "depth median [cm] / off [%] | wall [s] |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['variant']} | {r['iterations_per_agent'] or '(instance-level)'} | "
                     f"{r['acc_cm']:.2f} / {r['comp_cm']:.2f} | {r['comp_ratio']:.2f} | {r['comp_ratio_nice']:.2f} | "
                     f"{r['depth_median_cm']:.2f} / {r['depth_off_pct']:.1f} | {r['wall_s']:.0f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="room0")
    parser.add_argument("--preset", default="fast")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--agents", type=int, default=1, help="agents, each mapping alone (default: one, the whole scene)")
    parser.add_argument("--policy", default="never",
                        help="the team's schedule (default never: each agent alone, so consensus plays no part; "
                             "always: eq. 12 at MACIM's rho every iteration, as in the table)")
    parser.add_argument("--consistency", choices=("consensus", "dinno"), default="consensus",
                        help="parameter consistency under --policy always: consensus (eq. 12, MACIM's) or dinno "
                             "(DiNNO's ADMM, Di-NeRF*'s)")
    parser.add_argument("--own-init", action="store_true",
                        help="each agent's scene network its own draw (the rows before 2026-12-05) instead of "
                             "agent 0's copied to every agent (MACIM's)")
    parser.add_argument("--after", type=int, nargs="+", default=[2000],
                        help=f"iterations after the last frame to try besides MACIM's {PUBLISHED_AFTER}")
    parser.add_argument("--out", type=Path, default=Path("runs/study_global_budget"))
    args = parser.parse_args(argv)
    if min(args.after) < 0:
        parser.error("--after takes iteration counts >= 0")
    from openmulti_env.experiment.presets import get_preset

    args.frames = get_preset(args.preset).world.path.frames_per_agent
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "rows.json"
    rows = json.loads(path.read_text()) if path.exists() else []
    done = {r["variant"] for r in rows}
    for variant in variants(args.after):
        if variant.name in done:
            continue
        print(f"[study_global_budget] {variant.name}", flush=True)
        rows.append(run_variant(variant, args))
        write_json_atomic(path, rows)
    text = table(rows)
    (args.out / "table.md").write_text(text + "\n")
    print(text)


if __name__ == "__main__":
    main()
