"""Process settings for torch on the CPU that every learner applies before it trains (``configure_torch``)."""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import Any

import torch as th

_M_TRIM_THRESHOLD = -1  # glibc mallopt parameter numbers (malloc.h)
_M_MMAP_THRESHOLD = -3


def configure_torch(threads: int = 1, *, keep_heap: bool = True, flush_denormal: bool = False) -> dict[str, Any]:
    """Apply the process settings measured fastest for SAC updates here; returns what was set.

    threads: intra-op threads (``torch.set_num_threads``). Inter-op threads are set to 1 when
        torch still allows it (only before the first parallel op; SAC has no inter-op work).
    keep_heap: glibc only. Raise the mmap threshold to 64 MiB and the trim threshold to 512 MiB
        so freed activation/gradient buffers stay in the heap: the largest single gain measured
        (see analysis/bench/history/sac_updates.md). Costs up to a few hundred MB of RSS kept mapped.
    flush_denormal: flush denormals to zero. Off by default: with it set, scipy's cKDTree
        (used by the registration's voxel map) segfaults in this environment, and it gained
        nothing measurable on SAC updates.
    """
    applied: dict[str, Any] = {}
    th.set_num_threads(threads)
    applied["num_threads"] = th.get_num_threads()
    try:
        th.set_num_interop_threads(1)
    except RuntimeError:  # already set, or parallel work already started
        pass
    applied["num_interop_threads"] = th.get_num_interop_threads()
    if flush_denormal:
        applied["flush_denormal"] = bool(th.set_flush_denormal(True))
    if keep_heap:
        applied["keep_heap"] = _keep_heap()
    return applied


def one_torch_thread() -> None:
    """``configure_torch(1)``: the setup of a run's worker processes (``hingelab.workers.job_pool``), one per core."""
    configure_torch(1)


def _keep_heap() -> bool:
    """``mallopt`` so the heap is neither trimmed nor bypassed with mmap; False if not glibc."""
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, 64 << 20)) and bool(mallopt(_M_TRIM_THRESHOLD, 512 << 20))


__all__ = ["configure_torch", "one_torch_thread"]
