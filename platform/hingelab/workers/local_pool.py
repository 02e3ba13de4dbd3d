"""Work items in local worker processes: ``map_unordered`` (``--workers N`` of ``generate heuristic``).

Each worker is a fresh spawned interpreter (no forked MuJoCo or torch state) that runs ``initializer``
once (to build its env) and then the items it is sent; results come back as they finish.
"""

from __future__ import annotations

import multiprocessing as mp
from typing import Callable, Iterable, Iterator


def map_unordered(function: Callable, items: Iterable, workers: int, initializer: Callable | None = None,
                  initargs: tuple = ()) -> Iterator:
    """``function(item)`` for every item in ``workers`` spawned processes, each set up by ``initializer``;
    the results in the order they finish. ``function`` and ``initializer`` must be importable by name."""
    with mp.get_context("spawn").Pool(workers, initializer=initializer, initargs=initargs) as pool:
        yield from pool.imap_unordered(function, items)


__all__ = ["map_unordered"]
