"""``openmulti reproduce``: run the runs of one table (or ``all``) and write its files.

Runs shared between tables (``openmulti`` is in five of them) are made once: every table reads the
same ``OUT/rows/<key>.json``.
"""

from __future__ import annotations

import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from openmulti_env.runs.reproduce.runner import check_scenes, run_table
from openmulti_env.runs.reproduce.tables import (SCHEDULE_SCENARIOS, SCHEDULE_SCENES, SCHEDULES, TABLES, TRADEOFF,
                                                 TRADEOFF_SCENES, RunSpec, table_runs)
from openmulti_env.runs.reproduce.tradeoff import write_tradeoff
from openmulti_env.runs.reproduce.writers import write_table


def reproduce(table: str, scenes: list[str] | None, seeds: list[int], preset: str, out: str | Path, agents: int = 4,
              threads: int | None = 1, device: str = "cpu", three_cullings: bool = True,
              max_rounds: int | None = None, progress: bool = True, run_fn=None,
              methods: list[str] | None = None, run_missing: bool = True,
              ray_address: str | None = None, success_rates: list[float] | None = None) -> dict[str, list[dict]]:
    """Run ``table`` (one of ``TABLES`` or ``all``) and write ``OUT/T.json``, ``.md`` and ``.png``.

    Args:
        methods: run only these of the tables' methods (the trade-off table's: its policies) (e.g. to split one table over two processes
            sharing ``out``: rows are keyed, so each process makes its own and both tables read all).
        run_missing: False writes the tables from the runs already finished and makes none.
        ray_address: run the missing runs as Ray tasks (``local`` or a cluster's address; ``run_table``).
        success_rates: run only the runs at these link success rates (e.g. Table V's 20 % column first, the
            column its ordering is decided on); like ``methods``, the tables then hold those runs only
            (``run_missing=False`` without the filter writes the whole table from every finished run).

    Returns the rows of each table written. Unknown table, method or scene names raise ValueError
    listing the known ones, before any run starts.
    """
    names = list(TABLES) if table == "all" else [table]
    if not scenes:  # the paper's tables on room0; the trade-off and the schedules on their own scenes
        scenes = {TRADEOFF: list(TRADEOFF_SCENES), SCHEDULES: list(SCHEDULE_SCENES)}.get(table, ["room0"])
    specs = {name: table_runs(name, scenes, seeds, agents) for name in names}  # checks the table names
    check_scenes(scenes)
    if methods is not None:
        specs = _select(specs, table, "methods", methods, lambda s: s.schedule or s.method, str)
    if success_rates is not None:
        specs = _select(specs, table, "link success rates", success_rates, lambda s: s.success_rate,
                        lambda r: f"{r:g}")
    if methods is not None or success_rates is not None:
        names = [name for name in names if specs[name]]
    out = Path(out)
    start = time.perf_counter()
    written = {}
    for name in names:
        rows = run_table(specs[name], preset, out, threads=threads, device=device, three_cullings=three_cullings,
                         max_rounds=max_rounds, progress=progress, run_fn=run_fn, run_missing=run_missing,
                         ray_address=ray_address)
        made = sum(r.get("run_s") or 0.0 for r in rows)
        notes = (f"Preset `{preset}`, {agents} agents, machine: {platform.machine()} {platform.processor() or ''}"
                 f" ({_cores()} cores), torch threads {threads}; the table's {len(rows)} runs took {made:.0f} s "
                 f"of wall time in all (each when it was made); this command: {time.perf_counter() - start:.0f} s.")
        if rows and name == TRADEOFF:
            write_tradeoff(out, rows, notes)
        elif rows and name == SCHEDULES:  # one trade-off table per link scenario
            for scenario in SCHEDULE_SCENARIOS:
                mine = [r for r in rows if r.get("scenario") == scenario]
                if mine:
                    write_tradeoff(out / SCHEDULES / scenario, mine, f"Link scenario `{scenario}`. {notes}")
        elif rows:
            write_table(out, name, rows, notes)
        written[name] = rows
    return written


def _select(specs: dict[str, list[RunSpec]], table: str, what: str, wanted: list, key: Callable[[RunSpec], Any],
            show: Callable[[Any], str]) -> dict[str, list[RunSpec]]:
    """The runs whose ``key`` is among ``wanted`` (ValueError naming the unknown ones and the table's own)."""
    offered = sorted({key(s) for runs in specs.values() for s in runs})
    unknown = [w for w in wanted if w not in offered]
    if unknown:
        raise ValueError(f"{what} {unknown} are not in table {table!r}; its {what.split()[-1]}: "
                         f"{', '.join(show(o) for o in offered)}")
    return {name: [s for s in runs if key(s) in wanted] for name, runs in specs.items()}


def _cores() -> int:
    import os  # noqa: PLC0415

    return os.cpu_count() or 1
