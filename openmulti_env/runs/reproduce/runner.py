"""Running a table: one ``openmulti_env.runs.run.run`` per ``RunSpec``, keyed, atomic and resumable.

Each run lives in ``OUT/runs/<key>/`` (``run`` checkpoints its team there every few rounds and resumes
from it) and, once finished, leaves its row in ``OUT/rows/<key>.json``, written atomically together
with the settings that made it. Started again, ``reproduce`` skips every run whose row file holds the
same settings, resumes a run that was interrupted (its checkpoint), and redoes one whose row file is
unreadable or was made with other settings. A tqdm bar counts the runs. Each row says when it was made
(``made_at``: the commit of the code and the UTC date, ``openmulti_env.runs.made_at``); that is not a setting, so
it decides nothing about reuse.

Several processes can share one ``OUT`` (e.g. the same command started twice on one machine; across
machines only on a file system whose ``flock`` works between them): each run is claimed with an
exclusive lock on ``OUT/runs/<key>.lock`` while it is made, a process skips a run another holds and
comes back to it at the end (waiting for the holder, then reading its row), and a lock dies with its
holder, so a killed process leaves nothing stuck.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Iterator

from tqdm import tqdm

from mapping.pipeline.records import write_json_atomic
from mapping.safe_parse import load_json
from openmulti_env.runs.made_at import made_at
from openmulti_env.runs.reproduce.methods import METHODS
from openmulti_env.runs.reproduce.tables import RunSpec


def check_scenes(scenes: list[str]) -> None:
    """ValueError naming an unknown scene and listing the known ones (presets, random:SEED, a manifest)."""
    from openmulti_env.world.presets import list_presets  # noqa: PLC0415

    known = list_presets()
    for scene in scenes:
        if scene in known or scene.startswith("random:") or Path(scene).is_file():
            continue
        raise ValueError(f"unknown scene {scene!r}; known scenes: {', '.join(known)}, random:SEED, "
                         "or the path of a scene manifest")


def run_settings(spec: RunSpec, preset: str, three_cullings: bool, max_rounds: int | None) -> dict:
    """Everything that decides a run's row (its key on disk is derived from the same): the method's
    options and the library's defaults of what it learns with (consistency, messages, the preset's
    mapper), so that a row made before a default changed is redone, not mixed into a new table."""
    return {"method": spec.method, "scene": spec.scene, "seed": spec.seed, "agents": spec.agents,
            "success_rate": spec.success_rate, "preset": preset, "policy": spec.policy,
            "options": {**METHODS[spec.method].run_options(), **spec.options}, "three_cullings": three_cullings,
            "max_rounds": max_rounds,
            "defaults": library_defaults(preset), **policy_identity(spec.policy), **published_map_identity(spec.method),
            **global_init_identity(spec.method)}


def global_init_identity(method: str) -> dict:
    """For a global baseline, whether its agents' networks start alike (``TeamConfig.shared_global_init``):
    the rows made before it existed (each agent its own draw) are redone. Instance-level rows carry
    nothing of it, so their keys stay as they were."""
    if not METHODS[method].global_map:
        return {}
    from mapping.team import TeamConfig  # noqa: PLC0415

    return {"shared_global_init": TeamConfig().shared_global_init}


def published_map_identity(method: str) -> dict:
    """For a global baseline in its published form, MACIM's settings (``SdfConfig``): a row made with
    others is redone. Other methods' rows carry nothing of it, so their keys stay as they were."""
    if METHODS[method].global_form != "published":
        return {}
    from mapping.pipeline.records import settings_record  # noqa: PLC0415
    from mapping.model.sdf_loss import SdfConfig  # noqa: PLC0415

    return {"published_map": settings_record(SdfConfig())}


def policy_identity(policy: str) -> dict:
    """For a trained policy, the SHA-256 of its weights: a row made with other weights is redone."""
    from policies import parse_policy  # noqa: PLC0415
    from policies.learned import SHIPPED  # noqa: PLC0415

    spec = parse_policy(policy)
    if spec.rule not in ("learned", "file"):
        return {}
    path = SHIPPED if spec.rule == "learned" else Path(spec.settings["path"])
    return {"policy_sha256": load_json(path).get("sha256")}


def library_defaults(preset: str) -> dict:
    """The team settings a run takes from the library (JSON-plain), beside its method's options."""
    from mapping.team import ConsistencyConfig, ExchangeConfig  # noqa: PLC0415
    from mapping.pipeline.records import settings_record  # noqa: PLC0415
    from openmulti_env.experiment.presets import mapping_config  # noqa: PLC0415

    consistency = settings_record(ConsistencyConfig())
    consistency.pop("missing_edges")  # a method's option (``Method.run_options``), set by DiNNO's and DSGD's only
    return {"consistency": consistency, "exchange": settings_record(ExchangeConfig()),
            "mapping": settings_record(mapping_config(preset))}


def row_from_metrics(spec: RunSpec, metrics: dict) -> dict:
    """One table row from a run's ``metrics.json``: the means over agents, bytes and time per round."""
    from openmulti_env.experiment.files import recorded_num_agents  # noqa: PLC0415

    mean, n = metrics["mean"], max(recorded_num_agents(metrics["config"]), 1)
    rounds = max(metrics["rounds"], 1)
    per_round = [b / n for b in metrics["bytes_per_round"]]
    is_global = METHODS[spec.method].global_map
    row = {"method": spec.method, "scene": spec.scene, "seed": spec.seed, "agents": spec.agents,
           "success_rate": spec.success_rate, "policy": spec.schedule or spec.policy,
           **({"scenario": spec.scenario} if spec.scenario else {}),
           "mb_total": metrics["bytes_sent_total"] / 1e6,
           **{k: v for k, v in mean.items() if k not in ("f_miou", "f_macc")},
           "f_miou": None if is_global else mean.get("f_miou"), "f_macc": None if is_global else mean.get("f_macc"),
           "team_f_miou": None if is_global else metrics["team"]["f_miou"],
           "team_f_macc": None if is_global else metrics["team"]["f_macc"],
           "bytes_per_round": sum(per_round) / rounds,
           "bytes_per_round_series": per_round,
           "time_per_round_s": metrics["fleet_s"] / rounds,
           "fleet_s": metrics["fleet_s"], "compute_s_max": max(metrics["compute_s"].values(), default=0.0),
           "instances": sum(a["instances"] for a in metrics["agents"].values()) / n,
           "rounds": metrics["rounds"], "wall_s": metrics["wall_s"], "map": metrics.get("map")}
    return row


def load_row(path: Path, settings: dict) -> dict | None:
    """The finished row at ``path`` if it was made with ``settings`` (None: missing, half-written or stale)."""
    try:
        data = load_json(path)
    except (OSError, ValueError):
        return None
    if not isinstance(data, dict) or data.get("settings") != settings or "row" not in data:
        return None
    return data["row"]


@dataclass(frozen=True)
class GridJob:
    """How every run of a grid is made (what ``make_row`` needs besides the spec); plain data, so that
    it travels to Ray workers."""

    preset: str
    out: Path
    threads: int | None = 1
    device: str = "cpu"
    three_cullings: bool = True
    max_rounds: int | None = None
    keep_files: bool = False
    run_fn: Callable[..., dict] | None = None


def make_row(spec: RunSpec, job: GridJob) -> dict:
    """Make one run of the grid and return its table row (the run's folder is ``OUT/runs/<key>``; its
    bulky files are dropped unless ``keep_files``). Writes no row file: the caller does, on the machine
    that holds ``OUT/rows``."""
    run_fn = job.run_fn
    if run_fn is None:
        from openmulti_env.runs.run import run as run_fn  # noqa: PLC0415
    key = spec.key(job.preset)
    start = time.perf_counter()
    metrics = run_fn(spec.scene, spec.agents, spec.policy, job.preset, spec.seed, job.out / "runs" / key,
                     device=job.device, threads=job.threads, progress=False, max_rounds=job.max_rounds,
                     three_cullings=job.three_cullings, plots=False,
                     **{k: v for k, v in {**METHODS[spec.method].run_options(), **spec.options}.items() if k != "policy"})
    row = {**row_from_metrics(spec, metrics), "run_s": time.perf_counter() - start, "preset": job.preset,
           "made_at": made_at()}
    if not job.keep_files:
        _drop_bulky_files(job.out / "runs" / key)
    return row


def write_row(spec: RunSpec, job: GridJob, row: dict) -> None:
    """``OUT/rows/<key>.json``, atomically, with the settings that made it (``load_row`` reads it back)."""
    write_json_atomic(job.out / "rows" / f"{spec.key(job.preset)}.json",
                      {"settings": run_settings(spec, job.preset, job.three_cullings, job.max_rounds), "row": row})


def run_table(specs: list[RunSpec], preset: str, out: Path, threads: int | None = 1, device: str = "cpu",
              three_cullings: bool = True, max_rounds: int | None = None, progress: bool = True,
              run_fn: Callable[..., dict] | None = None, keep_files: bool = False,
              run_missing: bool = True, ray_address: str | None = None) -> list[dict]:
    """Run (or reuse) every spec; returns their rows in the specs' order.

    Args:
        run_missing: False makes nothing: the rows already finished are returned (in order) and the
            missing runs are only named (e.g. to write a table while other runs are still going).
        keep_files: keep each finished run's team checkpoint and meshes (by default they are deleted
            once its row is written: a ``fast`` team checkpoint is ~0.3 GB, the meshes ~0.2 GB, and a
            table needs tens of runs; ``metrics.json`` and ``rounds.json`` stay).
        run_fn: the run function (default ``openmulti_env.runs.run.run``; tests pass a stand-in).
        ray_address: run the missing runs as Ray tasks (``openmulti_env.runs.reproduce.ray_grid``):
            ``local`` starts Ray on this machine, anything else is a cluster's address; None runs them
            one at a time here.
    """
    check_scenes(sorted({s.scene for s in specs}))
    rows, todo, settings = [], [], {}
    for spec in specs:
        settings[spec.key(preset)] = run_settings(spec, preset, three_cullings, max_rounds)
        rows.append(load_row(out / "rows" / f"{spec.key(preset)}.json", settings[spec.key(preset)]))
        if rows[-1] is None:
            todo.append(spec)
    if not run_missing:
        if todo:
            print(f"[reproduce] {len(todo)} of {len(specs)} runs not made yet, left out: "
                  + ", ".join(spec.key(preset) for spec in todo))
        return [row for row in rows if row is not None]
    job = GridJob(preset, out, threads, device, three_cullings, max_rounds, keep_files, run_fn)
    index = {spec.key(preset): i for i, spec in enumerate(specs)}

    def finished(spec: RunSpec, row: dict) -> None:
        write_row(spec, job, row)
        rows[index[spec.key(preset)]] = row

    if ray_address is not None and todo:
        from openmulti_env.runs.reproduce.ray_grid import run_on_ray  # noqa: PLC0415

        run_on_ray(todo, job, finished, address=ray_address, done_before=len(specs) - len(todo), progress=progress)
        return rows

    def claim_and_make(spec: RunSpec, wait: bool) -> bool:
        """Make ``spec`` under its claim (or take the row another process finished); False: claimed elsewhere."""
        key = spec.key(preset)
        with run_claim(out, key, wait=wait) as mine:
            if not mine:
                return False
            made_elsewhere = load_row(out / "rows" / f"{key}.json", settings[key])
            if made_elsewhere is not None:
                rows[index[key]] = made_elsewhere
            else:
                finished(spec, make_row(spec, job))
            return True

    with tqdm(total=len(specs), initial=len(specs) - len(todo), desc="runs", unit="run", disable=not progress) as bar:
        held_elsewhere = []
        for spec in todo:
            bar.set_postfix_str(spec.key(preset))
            if claim_and_make(spec, wait=False):
                bar.update(1)
            else:
                held_elsewhere.append(spec)
        for spec in held_elsewhere:
            bar.set_postfix_str(f"{spec.key(preset)} (waiting for the process that holds it)")
            claim_and_make(spec, wait=True)
            bar.update(1)
    return rows


@contextmanager
def run_claim(out: Path, key: str, wait: bool) -> Iterator[bool]:
    """Hold the exclusive lock ``OUT/runs/<key>.lock`` (``flock``: released when the holder exits or is
    killed); yields False, holding nothing, when another process holds it and ``wait`` is False."""
    try:
        import fcntl  # noqa: PLC0415  (POSIX only; elsewhere every run is simply made)
    except ImportError:
        yield True
        return
    path = out / "runs" / f"{key}.lock"
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            yield False
            return
        try:
            yield True
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _drop_bulky_files(run_dir: Path) -> None:
    """Delete a finished run's checkpoints and meshes (its metrics and round reports stay)."""
    for pattern in ("checkpoints/*.pt", "meshes/*.ply"):
        for path in run_dir.glob(pattern):
            path.unlink(missing_ok=True)
