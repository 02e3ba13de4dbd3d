"""Feature statistics as LeRobot 0.6 computes and aggregates them (``compute_stats.py``).

Per episode and feature: ``min``, ``max``, ``mean``, ``std``, ``count`` and the quantiles
``q01``, ``q10``, ``q50``, ``q90``, ``q99`` (LeRobot's ``DEFAULT_QUANTILES``; its QUANTILES and
QUANTILE10 normalization modes read q01/q99 and q10/q90). Vectors: per dimension over the
frames; clouds (N, 3): per axis over frames and points, shape (1, 3), over the frames that have
a cloud; depth images: per channel over frames and pixels, shape (1, 1, 1), in the image's own
unit (LeRobot does not divide depth maps by 255), on images strided down to about 150 pixels as
LeRobot's ``auto_downsample_height_width`` does. Over the dataset (``aggregate``): min of mins,
max of maxes, the count-weighted mean, the pooled std, and the count-weighted mean of each
quantile (LeRobot's ``aggregate_feature_stats``). Values are float64 before they are written.
"""

from __future__ import annotations

import numpy as np

QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)
QUANTILE_KEYS = tuple(f"q{round(q * 100):02d}" for q in QUANTILES)
STAT_KEYS = ("min", "max", "mean", "std", "count", *QUANTILE_KEYS)


def _summary(values: np.ndarray, count: int) -> dict:
    """Stats over axis 0 of ``values`` (samples, ...); ``count``: the frames they come from."""
    out = {"min": values.min(0), "max": values.max(0), "mean": values.mean(0), "std": values.std(0),
           "count": np.array([count])}
    quantiles = np.quantile(values, QUANTILES, axis=0)
    out.update({key: quantiles[i] for i, key in enumerate(QUANTILE_KEYS)})
    return out


def vector_stats(values: np.ndarray, shape: list[int], rows: np.ndarray | None = None) -> dict | None:
    """Stats of a frame column (T, *shape); ``rows``: the frames that count (all if None); None if none does."""
    values = np.asarray(values, dtype=np.float64).reshape(len(values), *shape)
    if rows is not None:
        values = values[rows]
    if len(values) == 0:
        return None
    count = len(values)
    if len(shape) == 2:  # clouds: over frames and points, per axis
        values = values.reshape(-1, 1, shape[1])
    return _summary(values, count)


def image_stats(images: np.ndarray, frames: int, target: int = 150, threshold: int = 300) -> dict:
    """Stats of (K, H, W) single-channel images (the ones ``frames`` frames hold), shape (1, 1, 1)."""
    height, width = images.shape[1:]
    if max(height, width) >= threshold:
        step = int(width / target) if width > height else int(height / target)
        images = images[:, ::step, ::step]
    stats = _summary(np.asarray(images, np.float64).reshape(-1, 1), frames)
    return {k: v if k == "count" else v.reshape(1, 1, 1) for k, v in stats.items()}


def aggregate(parts: list[dict]) -> dict:
    """The dataset's stats from the episodes' (LeRobot's ``aggregate_feature_stats``)."""
    counts = np.array([p["count"][0] for p in parts], dtype=np.float64)
    weights = counts.reshape(-1, *[1] * np.ndim(parts[0]["mean"])) / counts.sum()
    means = np.stack([p["mean"] for p in parts])
    mean = (weights * means).sum(0)
    variance = (weights * (np.stack([p["std"] for p in parts]) ** 2 + (means - mean) ** 2)).sum(0)
    out = {"min": np.min([p["min"] for p in parts], axis=0), "max": np.max([p["max"] for p in parts], axis=0),
           "mean": mean, "std": np.sqrt(variance), "count": np.array([int(counts.sum())])}
    out.update({key: (weights * np.stack([p[key] for p in parts])).sum(0) for key in QUANTILE_KEYS})
    return out


def as_lists(stats: dict) -> dict:
    return {k: np.asarray(v).tolist() for k, v in stats.items()}


__all__ = ["QUANTILES", "QUANTILE_KEYS", "STAT_KEYS", "aggregate", "as_lists", "image_stats", "vector_stats"]
