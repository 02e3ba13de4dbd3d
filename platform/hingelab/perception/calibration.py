"""Calibration between the latent z and the tweezer's opening, both ways.

The opening is one number, so the encoder's 2-D latents of clouds across the hinge
range lie near a curve. The calibration fits that curve, z(opening), as a polynomial
per latent dimension (least squares), and reads an opening off a latent by projecting
it onto the curve (the nearest point of the curve, searched on a fine grid of openings),
which works whether the curve is straight or bent. The tip gap (m) is a polynomial of
the opening fitted on the same data, so users and the heuristic can speak in
millimetres: ``z_for_tip_gap_mm(12.0)`` is a latent goal.

**Reading** an opening off a latent: the projection minimizes the distance in latent space,
not the opening's error, and noisy latents scatter off the curve unevenly along it. A
calibration may also carry a *reader*: the opening as a cubic polynomial of z fitted by least
squares (``with_reader``); ``opening_rad`` then uses it (clipped to the fitted range). On held-out
clouds it reads openings better than the projection (``assets/checkpoints/README.md``, "The
reader"). It leaves the curve alone: goals (``z_for_opening``), the env's success threshold
(``project_opening``) and ``ToolEncoder.fingerprint`` do not depend on it.

The principal axis u of the latents (oriented so the opening grows along +u) gives a
coordinate s = u . (z - mean) for plots and for the monotonicity check.

The curve is fitted where the encoder is trained (its training clouds);
``hingelab.perception.sim_calibration`` refits it on the latents the envs perceive, which differ
at the closed end (assets/checkpoints/README.md says why the shipped encoder keeps its own).

``r2_opening``, ``r2_gap``: coefficients of determination of the readings on the data the
calibration was fitted on; ``evaluate`` gives them on other data (the bench: held-out clouds).
"""

from __future__ import annotations

import functools
from dataclasses import asdict, dataclass

import numpy as np

from hingelab.errors import ConfigError

DEGREE = 5  # of the latent curve z(opening)
GAP_DEGREE = 3  # of the tip gap as a function of the opening
GRID = 1024  # openings searched when projecting a latent onto the curve
READER_DEGREE = 3  # of the opening as a polynomial of z (higher degrees gain next to nothing held out)
READER_FIELDS = ("reader_coef", "reader_r2_opening")  # not part of what a latent means (fingerprint)


_READER_POWERS = np.array([(i, j) for i in range(READER_DEGREE + 1) for j in range(READER_DEGREE + 1 - i)], float)


def _monomials(z: np.ndarray) -> np.ndarray:
    """(..., 2) latents -> (..., K) products z0^i z1^j, i + j <= READER_DEGREE (read every env step:
    two array powers, not a stack of K products)."""
    z = np.asarray(z, float)
    return z[..., :1] ** _READER_POWERS[:, 0] * z[..., 1:2] ** _READER_POWERS[:, 1]


def r_squared(truth: np.ndarray, predicted: np.ndarray) -> float:
    """1 - SS_res / SS_tot."""
    truth = np.asarray(truth, float)
    ss_tot = float(((truth - truth.mean()) ** 2).sum())
    return 1.0 - float(((truth - predicted) ** 2).sum()) / max(ss_tot, 1e-300)


@dataclass(frozen=True)
class OpeningCalibration:
    """Fitted maps z <-> opening. Latents are (..., D); openings rad; tip gaps metres (or mm where named)."""

    z_coef: tuple[tuple[float, ...], ...]  # per latent dim: polynomial opening (rad) -> z (numpy.polyval order)
    gap_coef: tuple[float, ...]  # polynomial opening (rad) -> tip gap (m)
    opening_range: tuple[float, float]  # rad, of the fitting data
    mean: tuple[float, ...]  # latent mean
    axis: tuple[float, ...]  # unit principal axis of the latents, the opening grows along it
    r2_opening: float  # of the curve projection, on the fitting data
    r2_gap: float
    reader_coef: tuple[float, ...] | None = None  # opening = _monomials(z) @ coef (see the module docstring)
    reader_r2_opening: float | None = None  # of the reader, on the data it was fitted on

    @classmethod
    def fit(cls, z: np.ndarray, opening_rad: np.ndarray, tip_gap_m: np.ndarray) -> "OpeningCalibration":
        z = np.asarray(z, float)
        opening = np.asarray(opening_rad, float)
        gap = np.asarray(tip_gap_m, float)
        if z.ndim != 2 or len(z) != len(opening) or len(gap) != len(opening):
            raise ConfigError(f"calibration needs z (M, D) and M openings and gaps, got {z.shape}, "
                              f"{opening.shape}, {gap.shape}")
        if len(z) < 4 * (DEGREE + 1) or np.ptp(opening) <= 0:
            raise ConfigError(f"calibration needs at least {4 * (DEGREE + 1)} latents over a range of openings, "
                              f"got {len(z)}")
        mean = z.mean(axis=0)
        _, _, vt = np.linalg.svd(z - mean, full_matrices=False)
        axis = vt[0] if np.corrcoef((z - mean) @ vt[0], opening)[0, 1] >= 0 else -vt[0]
        partial = cls(z_coef=tuple(tuple(np.polyfit(opening, z[:, d], DEGREE)) for d in range(z.shape[1])),
                      gap_coef=tuple(np.polyfit(opening, gap, GAP_DEGREE)),
                      opening_range=(float(opening.min()), float(opening.max())),
                      mean=tuple(mean), axis=tuple(axis), r2_opening=float("nan"), r2_gap=float("nan"))
        fitted = partial.evaluate(z, opening, gap)
        curve = cls(**{**partial.to_dict(), "r2_opening": fitted["r2_opening"], "r2_gap": fitted["r2_gap"]})
        return curve.with_reader(z, opening) if z.shape[1] == 2 else curve

    def with_reader(self, z: np.ndarray, opening_rad: np.ndarray) -> "OpeningCalibration":
        """A copy with the least-squares reader fitted on (z (M, 2), openings (M,)); the curve is kept."""
        z, opening = np.asarray(z, float), np.asarray(opening_rad, float)
        if z.ndim != 2 or z.shape[1] != 2 or len(z) != len(opening) or len(z) < 40:
            raise ConfigError(f"the reader needs at least 40 2-D latents and as many openings, got {z.shape}, "
                              f"{opening.shape}")
        coef, *_ = np.linalg.lstsq(_monomials(z), opening, rcond=None)
        with_coef = OpeningCalibration(**{**self.to_dict(), "reader_coef": tuple(float(c) for c in coef)})
        r2 = r_squared(opening, with_coef.opening_rad(z))
        return OpeningCalibration(**{**with_coef.to_dict(), "reader_r2_opening": r2})

    # ------------------------------------------------------------------ z -> opening
    def coordinate(self, z) -> np.ndarray:
        """s: the latent's coordinate along the principal axis (grows with the opening)."""
        return (np.asarray(z, float) - np.asarray(self.mean)) @ np.asarray(self.axis)

    def opening_rad(self, z) -> np.ndarray:
        """Opening (hinge angle, rad) read from latents (..., D): the reader's, clipped to the fitted
        range, if the calibration has one, else the nearest point of the curve."""
        if self.reader_coef is None:
            return self.project_opening(z)
        return np.clip(_monomials(z) @ np.asarray(self.reader_coef), *self.opening_range)

    def project_opening(self, z) -> np.ndarray:
        """Opening (rad) of the nearest point of the curve to latents (..., D)."""
        z = np.asarray(z, float)
        grid, curve = self._curve
        dist = ((z[..., None, :] - curve) ** 2).sum(axis=-1)
        return grid[np.argmin(dist, axis=-1)]

    @functools.cached_property
    def _curve(self) -> tuple[np.ndarray, np.ndarray]:
        """(openings (GRID,), the curve's latents there (GRID, D)): computed once, read every step."""
        grid = np.linspace(*self.opening_range, GRID)
        return grid, self.z_for_opening(grid)

    def tip_gap_mm(self, z) -> np.ndarray:
        """Tip gap (mm) read from latents (..., D)."""
        return self.tip_gap_mm_for_opening(self.opening_rad(z))

    def tip_gap_mm_for_opening(self, opening_rad) -> np.ndarray:
        """Tip gap (mm) of an opening in rad (the fitted opening -> gap polynomial)."""
        return 1000.0 * np.polyval(self.gap_coef, np.asarray(opening_rad, float))

    # ------------------------------------------------------------------ opening -> z
    def z_for_opening(self, opening_rad) -> np.ndarray:
        """Latent (..., D) for an opening in rad (clipped to the fitted range)."""
        opening = np.clip(np.asarray(opening_rad, float), *self.opening_range)
        return np.stack([np.polyval(c, opening) for c in self.z_coef], axis=-1)

    def z_for_tip_gap_mm(self, gap_mm) -> np.ndarray:
        """Latent (..., D) for a tip gap in mm: the opening with that gap, then ``z_for_opening``."""
        grid = np.linspace(*self.opening_range, GRID)
        # the gap grows with the opening except right at the closed end; take the monotone part
        gaps = np.maximum.accumulate(np.polyval(self.gap_coef, grid))
        return self.z_for_opening(np.interp(np.asarray(gap_mm, float) / 1000.0, gaps, grid))

    # ------------------------------------------------------------------ checks
    def evaluate(self, z, opening_rad, tip_gap_m) -> dict[str, float]:
        """R^2, mean absolute errors and the mean signed opening error (bias) on other data."""
        pred_open = self.opening_rad(z)
        pred_gap = np.polyval(self.gap_coef, pred_open)
        return {"r2_opening": r_squared(opening_rad, pred_open), "r2_gap": r_squared(tip_gap_m, pred_gap),
                "mae_opening_rad": float(np.abs(pred_open - opening_rad).mean()),
                "bias_opening_rad": float((pred_open - opening_rad).mean()),
                "mae_gap_mm": float(1000 * np.abs(pred_gap - tip_gap_m).mean())}

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, raw: dict) -> "OpeningCalibration":
        try:
            return cls(**{k: (tuple(tuple(x) for x in v) if k == "z_coef" else
                              tuple(v) if isinstance(v, (list, tuple)) else v) for k, v in raw.items()})
            # a calibration recorded before readers existed has no reader fields: it reads by projection
        except TypeError as exc:
            raise ConfigError(f"calibration record does not match this hingelab version ({exc}); retrain the "
                              "encoder with `hingelab train encoder`") from exc


def latent_distance_for_gap(calibration, gap_mm: float) -> float:
    """Latent distance along the calibration curve that spans ``gap_mm`` of tip gap, mid-range."""
    low, high = calibration.opening_range
    mid = 0.5 * (low + high)
    z_a, z_b = calibration.z_for_opening(mid - 0.01), calibration.z_for_opening(mid + 0.01)
    # the curve's own openings (by projection): the threshold does not depend on the reader
    gap_a, gap_b = (calibration.tip_gap_mm_for_opening(calibration.project_opening(z)) for z in (z_a, z_b))
    per_mm = float(np.linalg.norm(np.asarray(z_b) - np.asarray(z_a))) / max(abs(float(gap_b - gap_a)), 1e-9)
    return per_mm * gap_mm


__all__ = ["OpeningCalibration", "READER_FIELDS", "r_squared", "latent_distance_for_gap"]
