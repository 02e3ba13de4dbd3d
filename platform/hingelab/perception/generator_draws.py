"""Two of numpy's ``Generator`` draws, compiled, with the same streams.

A cloud per env step draws its distinct bank points (``rng.choice(pop, k, replace=False)``)
and its occlusion refill (``rng.integers(0, k, size)``); numpy's Python-level argument
handling makes those two calls a large share of a cloud's time. These kernels take the generator's
bit generator (``rng.bit_generator.ctypes``: its ``next_uint32`` function and state) and run
numpy 2's algorithms on it: Lemire's bounded integers, Floyd's sampling without replacement
followed by a Fisher-Yates shuffle (``Generator.choice`` for populations up to 10,000), so a
seed gives the same clouds as numpy's calls, draw for draw (tests/test_perception_clouds.py compares
them with numpy's own calls), and the generator's state moves on exactly as numpy's would.
"""

from __future__ import annotations

import numpy as np
from numba import njit

FLOYD_MAX_POPULATION = 10_000  # numpy's Generator.choice samples larger populations otherwise


@njit(cache=True, inline="always")
def _bounded(next_uint32, state, high):
    """Uniform in [0, high] (high < 2**32 - 1): numpy's ``buffered_bounded_lemire_uint32``."""
    span = np.uint64(high) + np.uint64(1)
    m = np.uint64(next_uint32(state)) * span
    leftover = m & np.uint64(0xFFFFFFFF)
    if leftover < span:
        threshold = (np.uint64(0xFFFFFFFF) - np.uint64(high)) % span
        while leftover < threshold:
            m = np.uint64(next_uint32(state)) * span
            leftover = m & np.uint64(0xFFFFFFFF)
    return np.int64(m >> np.uint64(32))


@njit(cache=True)
def choice_without_replacement(next_uint32, state, population, size, batch):
    """(batch, size) int64: for each row, ``rng.choice(population, size, replace=False)``
    (Floyd's algorithm, then a shuffle of the sample), rows drawn one after the other."""
    out = np.empty((batch, size), np.int64)
    taken = np.zeros(population, np.bool_)  # Floyd's set
    for b in range(batch):
        row = out[b]
        for j in range(population - size, population):
            value = _bounded(next_uint32, state, j) if j > 0 else np.int64(0)
            if taken[value]:
                value = j
            taken[value] = True
            row[j - population + size] = value
        for i in range(size):
            taken[row[i]] = False
        for i in range(size - 1, 0, -1):
            j = _bounded(next_uint32, state, i)
            row[i], row[j] = row[j], row[i]
    return out


@njit(cache=True)
def integers_below(next_uint32, state, high, rows, columns):
    """(rows, columns) int64 uniform in [0, high): ``rng.integers(0, high, (rows, columns))``."""
    out = np.empty((rows, columns), np.int64)
    for r in range(rows):
        for c in range(columns):
            out[r, c] = _bounded(next_uint32, state, high - 1)
    return out


def choice(rng: np.random.Generator, population: int, size: int, batch: int = 1) -> np.ndarray:
    """``batch`` rows of ``rng.choice(population, size, replace=False)``: (batch, size) int64."""
    if not 0 <= size <= population:
        raise ValueError(f"cannot draw {size} of {population} without replacement")
    if population > FLOYD_MAX_POPULATION or size == 0:
        return np.stack([rng.choice(population, size, replace=False) for _ in range(batch)]).reshape(batch, size)
    bits = rng.bit_generator.ctypes
    return choice_without_replacement(bits.next_uint32, bits.state_address, population, size, batch)


def integers(rng: np.random.Generator, high: int, shape: tuple[int, int]) -> np.ndarray:
    """``rng.integers(0, high, shape)`` for 1 <= high < 2**32 and a 2-D shape: int64."""
    if not 2 <= high < 2**32 - 1:  # numpy draws nothing for high 1 and uses other paths past 32 bits
        return rng.integers(0, high, shape)
    bits = rng.bit_generator.ctypes
    return integers_below(bits.next_uint32, bits.state_address, high, *shape)


__all__ = ["choice", "integers"]
