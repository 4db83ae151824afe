"""Where torch runs: the device a mapper asks for, and the one place that sets how many CPU threads
torch uses.

OpenMP threads of two torch processes on one machine stall each other (a 10 ms step measured at
670 ms with 2 + 2 threads on 2 cores), so a library that several envs or agents share must not leave
torch's default: callers say how many threads each worker may use.
"""

from __future__ import annotations

import os
from contextlib import contextmanager
from typing import Iterator

import torch


def resolve_device(device: str | torch.device = "auto") -> torch.device:
    """``"auto"`` -> CUDA when available, else CPU; anything else is passed to ``torch.device``. A CUDA
    device always carries its index (``cuda`` -> ``cuda:0``), so that devices compare equal when they are
    the same one (``torch.device("cuda") != torch.device("cuda:0")``)."""
    if isinstance(device, str) and device == "auto":
        device = "cuda" if torch.cuda.is_available() else "cpu"
    resolved = torch.device(device)
    if resolved.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"device {str(device)!r} asked for, but this torch build sees no CUDA device "
                             "(use 'cpu' or 'auto')")
        if resolved.index is None:
            resolved = torch.device("cuda", torch.cuda.current_device())
    return resolved


def same_device(a: torch.device, b: torch.device) -> bool:
    """Whether two devices are one (``cuda`` and ``cuda:0`` are, on a one-GPU machine)."""
    a, b = torch.device(a), torch.device(b)
    if a.type != b.type:
        return False
    if a.type != "cuda":
        return True
    current = torch.cuda.current_device() if torch.cuda.is_available() else 0
    return (a.index if a.index is not None else current) == (b.index if b.index is not None else current)


def available_cores() -> int:
    """Cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def cores_each(workers: int) -> int:
    """This machine's cores shared among ``workers`` (at least 1 each)."""
    return max(1, available_cores() // max(1, workers))


def set_threads(threads: int | None = None, workers: int = 1) -> int:
    """Set torch's intra-op threads: ``threads``, or the machine's cores shared among ``workers``
    processes (at least 1 each). Returns the number set."""
    if threads is not None and threads < 1:
        raise ValueError(f"threads must be >= 1, got {threads}")
    n = threads if threads is not None else cores_each(workers)
    if torch.get_num_threads() != n:
        torch.set_num_threads(n)
    return n


@contextmanager
def torch_threads(threads: int | None = None, workers: int = 1) -> Iterator[int]:
    """``set_threads`` inside the block, the caller's thread count again after it: a library called
    from someone else's process (an env inside a trainer) keeps its thread setting to itself."""
    before = torch.get_num_threads()
    try:
        yield set_threads(threads, workers)
    finally:
        if torch.get_num_threads() != before:
            torch.set_num_threads(before)


@contextmanager
def flushed_denormals() -> Iterator[None]:
    """Flush denormal floats to zero (x86 SSE / ARM) inside the block: for training only.

    Measured on this project's mapper: a training step of room0's instances took 1003 ms instead of
    24 ms once gradients of saturated occupancies decayed into denormal floats, which the CPU handles
    ~100x slower; flushed to zero they change nothing that matters (|x| < 1.2e-38). Not global:
    scipy's cKDTree crashed (segmentation fault) building a tree of ground-truth points with the
    flag on, so it is switched off again when the block ends (torch has no getter for it).
    """
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)
