"""A delay line for observations: read what the sensors said ``delay`` seconds ago."""

from __future__ import annotations

from collections import deque

import numpy as np


class DelayLine:
    """Keeps the last few samples of a vector taken every ``period`` s; reads between them.

    ``read(delay)`` interpolates linearly between the two samples around ``now - delay``;
    before enough history exists it returns the oldest sample (the episode's first).
    """

    def __init__(self, period: float, max_delay: float):
        self.period = period
        self.samples: deque[np.ndarray] = deque(maxlen=int(np.ceil(max_delay / period)) + 2)

    def reset(self, first: np.ndarray) -> None:
        self.samples.clear()
        self.samples.append(np.array(first, float))

    def push(self, sample: np.ndarray) -> None:
        self.samples.append(np.array(sample, float))

    def read(self, delay: float) -> np.ndarray:
        if delay <= 0:
            return self.samples[-1].copy()
        steps = delay / self.period
        k = int(np.floor(steps))
        frac = steps - k
        newest = len(self.samples) - 1
        i_new = max(newest - k, 0)
        i_old = max(newest - k - 1, 0)
        return (1 - frac) * self.samples[i_new] + frac * self.samples[i_old]
