"""The encoder's element-wise passes for one cloud, compiled (numba).

``ToolEncoder._small_batch_latent_mean`` runs the point MLP's products in OpenBLAS; between
them numpy takes two passes per layer (add the bias, then ReLU) and three for the max pool
(max, bias, ReLU), each a few microseconds of call cost on arrays of ~200 x 128. One pass
each here, with the same float32 operations in the same order, so the same numbers.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True)
def add_bias_relu(x, bias):
    """x (N, C) float32 <- max(x + bias, 0) in place (``x += bias; np.maximum(x, 0, out=x)``)."""
    zero = np.float32(0.0)
    for i in range(x.shape[0]):
        for j in range(x.shape[1]):
            v = x[i, j] + bias[j]
            x[i, j] = v if v >= zero else zero  # as np.maximum: -0.0 stays -0.0


@njit(cache=True)
def max_pool_bias_relu(x, bias):
    """(C,) float32 max(max_i x[i] + bias, 0): the max pool over the points (N, C), then the
    last point layer's bias and ReLU (``np.maximum(x.max(axis=0) + bias, 0.0)``)."""
    out = x[0].copy()
    for i in range(1, x.shape[0]):
        for j in range(x.shape[1]):
            if x[i, j] > out[j]:
                out[j] = x[i, j]
    zero = np.float32(0.0)
    for j in range(x.shape[1]):
        v = out[j] + bias[j]
        out[j] = v if v >= zero else zero
    return out
