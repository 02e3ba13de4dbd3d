"""Rollout episodes as Ray tasks: ``--ray`` of ``generate heuristic``, ``eval low`` and ``eval high``.

An *episode runner* is a picklable factory (a top-level class or ``functools.partial``) whose
instance, called with one item (an episode seed, a goal, an episode index), runs that episode on
an env that records into the dataset folder and returns a small summary (a dict or dataclass of
scalars). ``fan_out`` sends one task per item; each Ray worker process builds the runner once and
keeps it for the following tasks of the same run (as ``--workers`` processes keep their env), so a
task costs one episode, not one env. Episodes go straight to the dataset folder through the
episode writer (unique names, atomic renames: safe for many processes and nodes on one folder);
only the summaries pass through Ray's object store.

The same items give the same episodes wherever they run: every episode is reset from its own
seed, so the dataset does not depend on the number of workers, nodes or the order they finish.
"""

from __future__ import annotations

import uuid
from typing import Callable, Iterable

from tqdm import tqdm

from hingelab.workers.ray_runtime import describe, ray_session

# per Ray worker process: the runner of the run it served last
_RUNNERS: dict[str, object] = {}


def _runner(key: str, factory: Callable[[], Callable]):
    runner = _RUNNERS.get(key)
    if runner is None:
        for old in _RUNNERS.values():  # a worker reused by a later run: the old env goes
            close = getattr(old, "close", None)
            if close is not None:
                close()
        _RUNNERS.clear()
        runner = _RUNNERS[key] = factory()
    return runner


def run_item(key: str, factory: Callable[[], Callable], item):
    """The Ray task: one episode of the run ``key`` (a runner built by ``factory`` once per worker)."""
    return _runner(key, factory)(item)


def fan_out(factory: Callable[[], Callable], items: Iterable, *, address: str | None = None,
            num_cpus: int | None = None, on_result: Callable | None = None, progress: bool = True,
            desc: str = "episodes on Ray") -> list:
    """Run ``factory()(item)`` for every item as a Ray task (1 CPU each) on ``address`` (None: a local
    Ray of ``num_cpus`` CPUs); returns the summaries in the order of ``items``. ``on_result(summary)``
    is called in this process as each task finishes (a journal, a progress bar)."""

    items = list(items)
    if not items:
        return []
    with ray_session(address, num_cpus) as ray:
        task = ray.remote(num_cpus=1, max_retries=0)(run_item)
        key = uuid.uuid4().hex
        factory_ref = ray.put(factory)  # once, not once per task
        refs = [task.remote(key, factory_ref, item) for item in items]
        position = {ref: k for k, ref in enumerate(refs)}
        results: list = [None] * len(items)
        pending = list(refs)
        with tqdm(total=len(refs), desc=f"{desc} ({describe(address)})", unit="episode",
                  disable=not progress) as bar:
            try:
                while pending:
                    done, pending = ray.wait(pending, num_returns=1, timeout=None)
                    for ref in done:
                        summary = ray.get(ref)
                        results[position[ref]] = summary
                        if on_result is not None:
                            on_result(summary)
                        bar.update()
            except BaseException:
                for ref in pending:  # stop what has not run: a stopped run resumes from its journal
                    ray.cancel(ref, force=True)
                raise
    return results


__all__ = ["fan_out", "run_item"]
