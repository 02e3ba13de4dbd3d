"""The latent plane's frame: the reachable latent region, from the encoder's calibration.

The hand reaches hinge openings in ``FingerSynergy.load().theta_range`` (rad, what ToolShape-v0 calls
its ``reachable_range``); the shipped encoder's calibration maps them onto the latent curve
``z_for_opening``. ``reachable_latent_curve()`` is that curve (K, 2); ``plane_bounds(...)`` a square
view around it and the episode's own latents and goals, so the region fills the plane whatever the
encoder's scale (the VAE prior's [-3, 3]^2 shrinks it to a short line).
"""

from __future__ import annotations

import functools

import numpy as np

from hingelab.errors import ConfigError

CURVE_POINTS = 64
MARGIN = 0.15  # of the framed span, on each side
MIN_HALF_SPAN = 0.05  # latent units: a single point still gets a readable frame


@functools.cache
def _calibration():
    try:  # torch loads the checkpoint: imported here, only for views with a latent
        from hingelab.perception.encoder import shipped_encoder

        return shipped_encoder().calibration
    except (ImportError, ConfigError):
        return None


@functools.cache
def reachable_latent_curve() -> np.ndarray | None:
    """(K, 2) the shipped encoder's latent over the reachable openings, or None without one."""
    from hingelab.sim.finger_synergy import FingerSynergy

    calibration = _calibration()
    if calibration is None:
        return None
    low, high = FingerSynergy.load().theta_range
    return np.asarray(calibration.z_for_opening(np.linspace(low, high, CURVE_POINTS)), float).reshape(-1, 2)


def latent_opening(z: np.ndarray) -> np.ndarray | None:
    """(T,) hinge openings (rad) read off latents ``z`` (T, 2) by the shipped encoder's calibration, or None."""
    calibration = _calibration()
    return None if calibration is None else np.asarray(calibration.opening_rad(z), float).reshape(-1)


def plane_bounds(*points) -> tuple[list[float], list[float]] | None:
    """(x_range, y_range) of a square frame around every finite point of ``points`` ((N, 2) arrays or None)."""
    parts = [np.asarray(p, float).reshape(-1, 2) for p in points if p is not None and np.size(p)]
    if not parts:
        return None
    allp = np.concatenate(parts)
    allp = allp[np.isfinite(allp).all(axis=1)]
    if not len(allp):
        return None
    low, high = allp.min(axis=0), allp.max(axis=0)
    centre = 0.5 * (low + high)
    half = max(float((high - low).max()) * (0.5 + MARGIN), MIN_HALF_SPAN)
    return [centre[0] - half, centre[0] + half], [centre[1] - half, centre[1] + half]


__all__ = ["reachable_latent_curve", "latent_opening", "plane_bounds"]
