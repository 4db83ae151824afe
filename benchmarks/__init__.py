"""Benchmark scripts (run as ``python benchmarks/bench_*.py``) and the code only they need
(``batch_alignment``, the batch alignment behind ``bench_alignment.py``)."""
