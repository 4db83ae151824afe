"""The reproduction grid as Ray tasks: every missing run of a table is one task with its CPU share,
on this machine (``local``) or on a cluster (its address); the driver writes each row into the same
keyed ``OUT/rows/`` as the sequential runner as soon as the run comes back.

What survives what (Ray's own task retries do the work, no scheduler of ours):
- a lost worker (a killed process, a node gone): Ray runs the task again, up to ``MAX_RETRIES`` times;
  a run that checkpointed in a shared ``OUT/runs/<key>/`` resumes from its checkpoint;
- a killed driver: every row written so far stays; started again, ``reproduce`` skips those and runs
  the rest, so at most the runs in flight are lost;
- a run that raises: the grid goes on, the error is named at the end and the command fails.

A cluster needs every worker to import this package (``ray job submit --working-dir .`` with the
package installed in the workers' environment) and, for a scene's world cache, a writable disk;
rows come back to the driver, so only the driver needs ``OUT``.
"""

from __future__ import annotations

from typing import Callable

from tqdm import tqdm

from openmulti_env.runs.reproduce.runner import GridJob, make_row
from openmulti_env.runs.reproduce.tables import RunSpec

MAX_RETRIES = 3
"""Times Ray runs a task again after its worker died (system failures, not exceptions of the run)."""


class GridError(RuntimeError):
    """Some runs of the grid failed (each named with its error); the rows of the others were written."""


def run_on_ray(specs: list[RunSpec], job: GridJob, finished: Callable[[RunSpec, dict], None], address: str = "local",
               done_before: int = 0, progress: bool = True) -> None:
    """Run every spec as a Ray task (``job.threads`` CPUs each) and call ``finished(spec, row)`` on the
    driver as each comes back, in completion order.

    Args:
        address: ``local`` (start Ray on this machine, or join the one already running in this process)
            or a cluster's address (``ray://host:10001``, ``host:6379`` or ``auto``).
        done_before: runs of the table already finished (the progress bar starts there).
    """
    try:
        import ray  # noqa: PLC0415
    except ImportError:
        raise ImportError("--ray needs Ray: pip install 'openmulti[ray]'") from None
    started_here = not ray.is_initialized()
    if started_here:  # "local" starts a Ray here even when RAY_ADDRESS names a cluster
        ray.init(address=address, include_dashboard=False, log_to_driver=False, configure_logging=False)
    try:
        cpus = max(job.threads or 1, 1)  # threads=None: 1 CPU asked, as a run's torch threads default to
        largest = max((n["Resources"].get("CPU", 0) for n in ray.nodes() if n.get("Alive")), default=0)
        if cpus > largest:
            raise ValueError(f"each run asks for {cpus} CPUs (--threads) but the largest Ray node has {largest:g}: "
                             "no task could ever start")
        make = ray.remote(num_cpus=cpus, max_retries=MAX_RETRIES, retry_exceptions=False)(make_row)
        pending = {make.remote(spec, job): spec for spec in specs}
        failures: list[str] = []

        def collect(ref) -> None:
            spec = pending.pop(ref)
            try:
                finished(spec, ray.get(ref))
            except ray.exceptions.RayError as exc:  # the run raised, its worker died too often, out of memory...
                cause = getattr(exc, "cause", None) or exc  # the run's own exception, not Ray's wrapper
                failures.append(f"{spec.key(job.preset)}: {type(cause).__name__}: {cause}")

        try:
            with tqdm(total=done_before + len(specs), initial=done_before, desc="runs (ray)", unit="run",
                      disable=not progress) as bar:
                while pending:
                    ready, _ = ray.wait(list(pending), num_returns=1)
                    key = pending[ready[0]].key(job.preset)
                    collect(ready[0])
                    bar.set_postfix_str(key)
                    bar.update(1)
        except BaseException:  # interrupted: keep what already came back, stop the rest
            done, _ = ray.wait(list(pending), num_returns=len(pending), timeout=0) if pending else ([], [])
            for ref in done:
                collect(ref)
            for ref in pending:
                ray.cancel(ref, force=True)
            raise
    finally:
        if started_here:
            ray.shutdown()
    if failures:
        raise GridError(f"{len(failures)} of {len(specs)} runs failed (the others' rows are written):\n  "
                        + "\n  ".join(failures))
