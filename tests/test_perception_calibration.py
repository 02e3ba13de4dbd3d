"""Calibration latent <-> opening: fit, both directions, R^2, serialization."""

from __future__ import annotations

import numpy as np
import pytest

from hingelab.errors import ConfigError
from hingelab.perception.calibration import OpeningCalibration, r_squared
from hingelab.perception.clouds import ToolGeometry


@pytest.fixture(scope="module")
def curve():
    """Latents on a bent curve whose coordinate falls as the opening grows, plus a little noise."""
    rng = np.random.default_rng(0)
    opening = rng.uniform(0.0, 0.3, 400)
    s = -(opening - 0.15) * 8
    z = np.stack([s, 0.3 * s ** 2], axis=1) @ np.array([[0.8, 0.6], [-0.6, 0.8]]) + [0.2, -0.1]
    z += rng.normal(0, 0.01, z.shape)
    gap = ToolGeometry.default().tip_gap_m(opening)
    return z, opening, gap


def test_fit_predicts_opening_and_gap(curve):
    z, opening, gap = curve
    calibration = OpeningCalibration.fit(z, opening, gap)
    assert calibration.r2_opening > 0.99 and calibration.r2_gap > 0.97
    assert np.abs(calibration.opening_rad(z) - opening).mean() < 0.005
    # the axis is oriented so that the coordinate grows with the opening
    assert np.corrcoef(calibration.coordinate(z), opening)[0, 1] > 0.99
    metrics = calibration.evaluate(z, opening, gap)  # reads with the least-squares reader
    assert metrics["r2_opening"] == pytest.approx(calibration.reader_r2_opening)
    # r2_opening is the curve projection's; the reader fits the openings at least as well here
    assert r_squared(opening, calibration.project_opening(z)) == pytest.approx(calibration.r2_opening)
    assert calibration.reader_r2_opening >= calibration.r2_opening - 1e-3


def test_a_calibration_without_a_reader_reads_by_projection(curve):
    """Calibrations recorded before readers existed load and read as they did."""
    z, opening, gap = curve
    calibration = OpeningCalibration.fit(z, opening, gap)
    old = {k: v for k, v in calibration.to_dict().items() if k not in ("reader_coef", "reader_r2_opening")}
    legacy = OpeningCalibration.from_dict(old)
    assert legacy.reader_coef is None
    np.testing.assert_array_equal(legacy.opening_rad(z), calibration.project_opening(z))
    again = legacy.with_reader(z, opening)
    assert again.z_coef == legacy.z_coef and again.reader_coef == pytest.approx(calibration.reader_coef)
    with pytest.raises(ConfigError, match="at least 40"):
        legacy.with_reader(z[:10], opening[:10])


def test_inverse_round_trip(curve):
    z, opening, gap = curve
    calibration = OpeningCalibration.fit(z, opening, gap)
    targets = np.array([0.05, 0.1, 0.2, 0.28])
    assert np.abs(calibration.opening_rad(calibration.z_for_opening(targets)) - targets).max() < 0.01
    gap_mm = np.array([5.0, 15.0, 30.0])
    back = calibration.tip_gap_mm(calibration.z_for_tip_gap_mm(gap_mm))
    assert np.abs(back - gap_mm).max() < 1.5


def test_serialization_and_errors(curve):
    calibration = OpeningCalibration.fit(*curve)
    again = OpeningCalibration.from_dict(calibration.to_dict())
    np.testing.assert_allclose(again.opening_rad(curve[0][:5]), calibration.opening_rad(curve[0][:5]))
    with pytest.raises(ConfigError, match="does not match"):
        OpeningCalibration.from_dict({**calibration.to_dict(), "extra": 1})
    with pytest.raises(ConfigError, match="at least"):
        OpeningCalibration.fit(curve[0][:5], curve[1][:5], curve[2][:5])
    assert r_squared(np.arange(5.0), np.arange(5.0)) == 1.0


def test_evaluate_reports_the_signed_bias(curve):
    z, opening, gap = curve
    calibration = OpeningCalibration.fit(z, opening, gap)
    inner = (opening > 0.05) & (opening < 0.25)  # away from the clipped ends of the range
    shifted = calibration.evaluate(z[inner], opening[inner] + 0.01, gap[inner])
    assert shifted["bias_opening_rad"] == pytest.approx(-0.01, abs=0.003)  # it reads 10 mrad too closed
    assert abs(calibration.evaluate(z, opening, gap)["bias_opening_rad"]) < 0.003
