"""The README's demo run as a rows file (docs/results/demo.json): recorded from a finished ``openmulti run`` folder
(``python -m studies.results --record-demo RUN_DIR``) and rendered as the README's table by ``studies.results``.

The file holds the run's mean metrics over agents, each agent's completion ratio, the megabytes and messages it
sent, its wall time, the command and machine, and ``made_at`` (the commit of the checkout that records it and the
UTC date: record from the checkout that made the run).
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import asdict, dataclass
from pathlib import Path

from mapping.safe_parse import load_json
from openmulti_env.runs.made_at import made_at

FORMAT = "openmulti.demo_run"
COLUMNS = (("acc [cm]", "acc_cm"), ("comp [cm]", "comp_cm"), ("comp ratio [%]", "comp_ratio"), ("F-mIoU", "f_miou"),
           ("F-mAcc", "f_macc"), ("depth err [cm]", "depth_median_cm"), ("depth off [%]", "depth_off_pct"))
"""The README table's metric columns (header, key of the mean), before MB / round / agent and messages."""


@dataclass(frozen=True)
class DemoMeans:
    """The mean over agents of each metric the README shows (None: not scored)."""

    acc_cm: float | None
    comp_cm: float | None
    comp_ratio: float | None
    f_miou: float | None
    f_macc: float | None
    depth_median_cm: float | None
    depth_off_pct: float | None


@dataclass(frozen=True)
class MadeAt:
    """When the figures were made, as the producers write it (``openmulti_env.runs.made_at``): a commit (or, from an
    installed package, its version) and the UTC date."""

    commit: str
    date: str


@dataclass(frozen=True)
class DemoRun:
    """What the README says of the demo run."""

    command: str
    machine: str
    agents: int
    mean: DemoMeans
    per_agent_comp_ratio: tuple[float, ...]
    mb_sent: float
    mb_per_round_per_agent: float
    messages: int
    wall_minutes: tuple[float, float]
    """Low and high of the runs the figures stand for (one run: both its own)."""
    made_at: MadeAt
    recorded_from: str


def from_metrics(run_dir: Path, note: str = "") -> DemoRun:
    """The demo run of ``RUN_DIR/metrics.json`` (ValueError naming what is missing), stamped now."""
    metrics = load_json(run_dir / "metrics.json")
    if not isinstance(metrics, dict) or not metrics.get("evaluated", True) or not metrics.get("mean"):
        raise ValueError(f"{run_dir}/metrics.json holds no scored run (run it without --no-evaluation)")
    config = metrics.get("config", {})
    agents = metrics.get("agents", {})
    command = (f"openmulti run --scene {config.get('scene')} --agents {len(agents)} --policy "
               f"{config.get('run', {}).get('policy')} --preset {config.get('preset')} --seed {config.get('seed')}")
    machine = f"{os.cpu_count() or 1}-core {platform.machine()} CPU machine" + (f" ({note})" if note else "")
    minutes = float(metrics["wall_s"]) / 60.0
    return DemoRun(command=command, machine=machine, agents=len(agents),
                   mean=DemoMeans(**{key: metrics["mean"].get(key) for _, key in COLUMNS}),
                   per_agent_comp_ratio=tuple(float(a["comp_ratio"]) for a in agents.values()),
                   mb_sent=metrics["bytes_sent_total"] / 1e6,
                   mb_per_round_per_agent=metrics["bytes_per_round_per_agent_mean"] / 1e6,
                   messages=int(metrics["messages"]["delivered"]), wall_minutes=(minutes, minutes),
                   made_at=MadeAt(**metrics.get("made_at", made_at())),  # the run's own, else this checkout's
                   recorded_from=f"{run_dir}/metrics.json")


def write(demo: DemoRun, path: Path) -> None:
    """``path`` as JSON (the folder made when missing)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"format": FORMAT, "version": 1, **asdict(demo)}, indent=1) + "\n")


def read(path: Path) -> DemoRun:
    """The demo run recorded in ``path`` (ValueError when it is not one)."""
    data = load_json(path)
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} file")
    fields = {k: v for k, v in data.items() if k not in ("format", "version")}
    return DemoRun(**{**fields, "mean": DemoMeans(**fields["mean"]),
                      "per_agent_comp_ratio": tuple(fields["per_agent_comp_ratio"]),
                      "wall_minutes": tuple(fields["wall_minutes"]), "made_at": MadeAt(**fields["made_at"])})


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}"


def table_lines(demo: DemoRun) -> list[str]:
    """The README's table: the means over agents, MB a round per agent, messages delivered."""
    head = [*(name for name, _ in COLUMNS), "MB / round / agent", "messages"]
    cells = [f"mean of {demo.agents} agents", *(_number(getattr(demo.mean, key)) for _, key in COLUMNS),
             _number(demo.mb_per_round_per_agent), str(demo.messages)]
    return ["| | " + " | ".join(head) + " |", "|" + "---|" * (len(head) + 1), "| " + " | ".join(cells) + " |"]


def details(demo: DemoRun) -> str:
    """Per agent completion, MB sent, wall time (``5-12 minutes``)."""
    low, high = demo.wall_minutes
    minutes = f"{low:.0f}" if round(low) == round(high) else f"{low:.0f}-{high:.0f}"
    return (f"per agent: completion ratio {' / '.join(f'{c:.2f}' for c in demo.per_agent_comp_ratio)} %; "
            f"{demo.mb_sent:.2f} MB sent; {minutes} minutes")
