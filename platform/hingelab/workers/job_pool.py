"""A run's work items in ``jobs`` worker processes, the results in the items' order (``JobPool``): the ``--jobs N``
of ``train high --learner phase-clone|dagger``.

The workers are spawned interpreters (no forked MuJoCo or torch state), each on one torch thread
(``configure_torch(1)``), started at the first ``map`` and kept for the run (their envs with them), so a run pays
their start once; they die with the run's process. Items and results travel pickled: NumPy arrays and plain
data, never torch tensors (torch would pass those through shared memory). An item that raises stops the map: the
other items are cancelled, the workers stopped, and the item's own error is raised in the caller (a
``HingelabError`` stays the one-line error it is). A worker that dies (killed, out of memory) is a
``WorkerDied``, one line too.
"""

from __future__ import annotations

import ctypes
import multiprocessing as mp
import os
import signal
import sys
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator

from hingelab.errors import HingelabError


class WorkerDied(HingelabError):
    """A worker process of ``--jobs`` ended without finishing its item."""


def _start_worker(parent: int, setup: Callable[[], object] | None) -> None:
    """A worker's setup: it dies with the run's process (Linux: ``PR_SET_PDEATHSIG``), so a run killed outright
    leaves no worker writing into its folder while a ``--resume`` makes that part again; then ``setup()`` (the
    caller's, e.g. one torch thread: this layer knows nothing of torch)."""
    if sys.platform.startswith("linux"):
        try:
            ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, int(signal.SIGKILL))  # PR_SET_PDEATHSIG
        except (OSError, AttributeError):
            pass
    if os.getppid() != parent:  # the run died before the line above
        os._exit(1)
    if setup is not None:
        setup()


class JobPool:
    """``jobs`` spawned worker processes for one run (module doc); a context manager that stops them."""

    def __init__(self, jobs: int, setup: Callable[[], object] | None = None):
        if jobs < 2:
            raise ValueError(f"a JobPool is for 2 or more jobs, not {jobs}: run the items in this process")
        self.jobs = int(jobs)
        self.setup = setup  # run once in each worker as it starts (picklable: a module-level function or partial)
        self._executor: ProcessPoolExecutor | None = None

    def map(self, function: Callable, items: Iterable, done: Callable[[int, object], None] | None = None) -> list:
        """``function(item)`` for every item in the workers; the results in the items' order. ``function`` must
        be importable by name; ``done(index, result)`` is called in this process as each item finishes."""
        items = list(items)
        if not items:
            return []
        if self._executor is None:
            self._executor = ProcessPoolExecutor(self.jobs, mp_context=mp.get_context("spawn"),
                                                 initializer=_start_worker, initargs=(os.getpid(), self.setup))
        futures = {self._executor.submit(function, item): i for i, item in enumerate(items)}
        results: list = [None] * len(items)
        pending = set(futures)
        try:
            while pending:
                finished, pending = wait(pending, return_when=FIRST_COMPLETED)
                for future in sorted(finished, key=futures.get):
                    results[futures[future]] = future.result()  # an item's error is raised here
                    if done is not None:
                        done(futures[future], results[futures[future]])
        except BrokenProcessPool:
            self.close(kill=True)
            raise WorkerDied("a worker process of --jobs ended before its work was done (killed, or out of "
                             "memory?); what the run saved is kept: run the command again with --resume") from None
        except BaseException:
            self.close(kill=True)
            raise
        return results

    def close(self, kill: bool = False) -> None:
        """Stop the workers: at once with ``kill`` (their items cut short; a cut-off episode stays a ``.partial``
        file, which no reader counts), else once they are idle."""
        executor, self._executor = self._executor, None
        if executor is None:
            return
        if kill:
            for process in list((getattr(executor, "_processes", None) or {}).values()):
                process.terminate()
        executor.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> "JobPool":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(kill=exc_type is not None)


@contextmanager
def job_pool(jobs: int, setup: Callable[[], object] | None = None) -> Iterator[JobPool | None]:
    """A ``JobPool`` of ``jobs`` workers for a run (each running ``setup()`` first), stopped at its end; None for 1
    (the run's work in this process, as before there were jobs)."""
    if jobs <= 1:
        yield None
        return
    with JobPool(jobs, setup) as pool:
        yield pool


def chunks(count: int, pieces: int) -> list[range]:
    """``range(count)`` cut into at most ``pieces`` contiguous ranges of nearly equal length (the first longer)."""
    pieces = max(1, min(int(pieces), int(count)))
    share, extra = divmod(int(count), pieces)
    out, start = [], 0
    for k in range(pieces):
        stop = start + share + (k < extra)
        out.append(range(start, stop))
        start = stop
    return out


__all__ = ["JobPool", "WorkerDied", "chunks", "job_pool"]
