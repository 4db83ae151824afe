"""Which runs each of the paper's tables needs, and the paper's own figures to print beside ours.

A table is a list of ``RunSpec`` (method, scene, seed, agents, link success rate); ``openmulti
reproduce --table T`` runs them (``runner``) and writes the rows (``writers``). The figures in
``PAPER`` are the paper's (Replica + ScanNet, RTX 4090), for comparison only.
"""

from __future__ import annotations

from dataclasses import dataclass

from openmulti_env.runs.reproduce.methods import EQUAL_COMPUTE_METHODS, METHODS, TABLE_I_METHODS

TABLES = ("geometric", "multi-vs-single", "semantic", "ablation", "comm-failure", "transmission")
"""The paper's tables: ``all`` runs every one of them (runs shared between tables are made once)."""
TRADEOFF = "tradeoff"
"""Completion against bytes of communication schedules (``openmulti`` with each policy); not in ``all``."""
TRADEOFF_POLICIES = ("always", "never", "every:2", "every:3", "every:4", "rate:0.25", "rate:0.5", "novelty",
                     "novelty:change=0.05", "novelty:change=0.2", "learned")
"""The policies of the trade-off table (``learned`` only when a trained policy ships)."""
TRADEOFF_SCENES = ("room0", "office0", "room2")
SCHEDULES = "schedules"
"""The headroom of schedules: the trade-off in three link scenarios, instance-level policies beside the fixed
ones (docs/schedules.md); made at ``rl_small`` (``--preset rl_small``) on scenes never used for a choice."""
SCHEDULE_POLICIES = ("always", "never", "every:2", "every:4", "rate:0.25", "novelty", "instance_novelty",
                     "instance_novelty:change=0.1", "instance_novelty:change=1,after=999,final=0", "always+changed")
"""``always+changed``: ``always`` with float16 vectors and changed-only sending at 1 %
(``--team.exchange.float16 --team.exchange.changed-only 0.01``); ``instance_novelty:change=1,after=999,final=0``: each network once, at its final state."""
SCHEDULE_SCENARIOS = {"unlimited": (), "range": (("link_range_m", 2.0),), "bandwidth": (("link_mb_per_round", 0.25),)}
"""Link scenarios: a range of 2 m (every pair of the presets' paths comes within 1.6 m at some frame), and a
quarter of what ``always`` sends over a link at ``fast`` (0.25 MB a round)."""
SCHEDULE_SCENES = ("room1",)
"""One scene never used for a choice: 30 runs, about 100-400 s each at ``rl_small`` here (measured beside another
run); more scenes and seeds with ``--scenes`` / ``--seeds``, on a Ray cluster with ``--ray``."""
VARIANTS = {"always+changed": ("always", (("float16", True), ("changed_only", 0.01)))}
"""Policy names of the schedules table that are a policy plus run options."""
FAILURE_RATES = (1.0, 0.8, 0.5, 0.2)
"""Link success rates of Table V."""
TUNING_SCENES = ("room0",)
"""Scenes the method's settings were chosen on (rho, per-step consensus, eq. 13's weight, mapped ray poses)."""
HELD_OUT_SCENES = ("office3", "room1")
"""Scenes never used for any choice: their figures are reported apart from the others'."""


@dataclass(frozen=True)
class RunSpec:
    """One run: a method on a scene with a seed, a number of agents and a link success rate."""

    method: str
    scene: str
    seed: int
    agents: int
    success_rate: float = 1.0
    schedule: str | None = None
    """A communication policy in place of the method's (the trade-off table)."""
    scenario: str | None = None
    """The link scenario of the schedules table (``SCHEDULE_SCENARIOS``)."""

    @property
    def options(self) -> dict:
        """Run options beyond the method's: the scenario's links and the schedule's variant options."""
        out = dict(SCHEDULE_SCENARIOS.get(self.scenario or "", ()))
        if self.schedule in VARIANTS:
            out.update(VARIANTS[self.schedule][1])
        return out

    @property
    def policy(self) -> str:
        if self.schedule is not None:
            return VARIANTS[self.schedule][0] if self.schedule in VARIANTS else self.schedule
        base = METHODS[self.method].policy
        if self.success_rate >= 1.0 or base == "never":
            return base
        return f"bernoulli:{self.success_rate:g}"

    def key(self, preset: str) -> str:
        """The run's name on disk: every setting that changes its result."""
        rate = f"_p{round(self.success_rate * 100):03d}" if self.success_rate < 1.0 else ""
        schedule = "" if self.schedule is None else "_pol-" + self.schedule.replace("=", "").replace(",", "-")
        schedule = schedule.replace("+", "-plus-")
        scenario = "" if self.scenario is None else f"_links-{self.scenario}"  # never a tradeoff run's key
        key = f"{self.method}_{self.scene}_s{self.seed}_a{self.agents}{rate}{schedule}{scenario}_{preset}"
        return key.replace(":", "-").replace("/", "-")


def table_runs(table: str, scenes: list[str], seeds: list[int], agents: int = 4) -> list[RunSpec]:
    """The runs of ``table`` (ValueError listing the known tables)."""
    if table == TRADEOFF:
        from policies.learned import SHIPPED  # noqa: PLC0415

        policies = [p for p in TRADEOFF_POLICIES if p != "learned" or SHIPPED.is_file()]
        return [RunSpec("openmulti", scene, seed, agents, schedule=p) for scene in scenes for seed in seeds
                for p in policies]
    if table == SCHEDULES:
        return [RunSpec("openmulti", scene, seed, agents, schedule=p, scenario=scenario) for scene in scenes
                for seed in seeds for scenario in SCHEDULE_SCENARIOS for p in SCHEDULE_POLICIES]
    if table not in TABLES:
        raise ValueError(f"unknown table {table!r}; known tables: {', '.join(TABLES)}, all, {TRADEOFF}, {SCHEDULES}")
    methods = {"geometric": (*TABLE_I_METHODS, *EQUAL_COMPUTE_METHODS),
               "multi-vs-single": ("single_agent", "openmulti"),
               "semantic": ("single", "openmulti_no_alignment", "openmulti"),
               "ablation": ("macim_global_equal_compute", "openmulti_global", "openmulti_no_cross", "openmulti"),
               "comm-failure": ("dinerf_global", "dinerf_global_stale", "openmulti"),
               "transmission": ("pointcloud_sharing", "dinerf_global", "macim_global", "openmulti")}[table]
    rates = FAILURE_RATES if table == "comm-failure" else (1.0,)
    return [RunSpec(m, scene, seed, METHODS[m].agents or agents, rate)
            for scene in scenes for seed in seeds for m in methods for rate in rates]


# The paper's figures (sec. IV), keyed by our method names.
PAPER = {
    "geometric": {  # Table I: Acc [cm], Comp [cm], Comp ratio [%]
        "single": (3.32, 33.01, 53.18), "dsgd_instance": (4.41, 8.04, 54.05), "dinerf_global": (3.46, 8.48, 59.09),
        "dinno_instance": (3.66, 8.04, 72.92), "macim_global": (6.93, 7.10, 72.37), "openmulti": (2.47, 3.52, 81.52),
    },
    "ablation": {  # Table IV: Acc, Comp, time per round [s], MB ("neither": a global map in the same framework)
        "macim_global_equal_compute": (4.08, 11.26, 1.18, 2.01), "openmulti_global": (3.53, 8.84, 2.85, None),
        "openmulti_no_cross": (2.75, 3.93, 5.43, 2.13), "openmulti": (2.47, 3.52, 5.71, 2.14),
    },
    "comm-failure": {  # Table V: comp ratio [%] at 100/80/50/20 % link success (room_0)
        "dinerf_global": {1.0: 80.27, 0.8: 71.18, 0.5: 65.23, 0.2: 48.84},
        "openmulti": {1.0: 89.36, 0.8: 84.05, 0.5: 77.30, 0.2: 75.75},
    },
    "transmission": {  # Table VI: MB per frame, first -> last
        "pointcloud_sharing": "6.02 -> 35.08", "macim_global": "1.50", "dinerf_global": "2.01",
        "openmulti": "2.13 -> 3.07",
    },
    "semantic": {"openmulti": (46.18, 51.92), "single": None},  # F-mIoU / F-mAcc (OpenObj 44.10 / 49.65)
    "multi-vs-single": {"single_agent": "OpenObj 12.43 min", "openmulti": "4.76 min"},
}
