"""Studies: what OpenMulti's choices are worth (schedules, alignment, retrieval, real data, baselines), each run
as ``python -m studies.<name>`` and writing result rows; and the modules they share (``cells``, ``episodes``,
``fast_runs``, ``fronts``, ``rows``, ``settings``, the batch alignment ``batch_alignment``).

Timing benchmarks (speed, memory, profiles) are scripts in ``benchmarks/``. ``python -m studies.index`` writes
the table of both in docs/benchmarks.md from the modules' docstrings. Nothing in ``mapping``, ``openmulti_env``
or ``policies`` imports this package.
"""
