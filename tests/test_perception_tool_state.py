"""ToolState: differencing, the moving average, resets, batching, the state vectors."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from hingelab.errors import ConfigError
from hingelab.perception.clouds import IDEAL, CloudSynthesizer, ToolGeometry
from hingelab.perception.encoder import EncoderConfig, PointNetVAE, ToolEncoder
from hingelab.perception.registration import CanonicalRegistration
from hingelab.perception.synthetic_dataset import nominal_tool_pose
from hingelab.perception.tool_state import ToolState

TINY = EncoderConfig(widths=(8, 16), head_width=8, decoder_widths=(16,), decoder_points=32)


@pytest.fixture(scope="module")
def parts():
    torch.manual_seed(0)
    return ToolEncoder(PointNetVAE(TINY)), CanonicalRegistration(ToolGeometry.default())


def _clouds(rot, pos, theta=0.12, seed=0):
    return CloudSynthesizer(ToolGeometry.default(), IDEAL, seed=seed).from_tool_pose(rot, pos, theta)


def test_velocities_by_differencing_and_the_average(parts):
    encoder, registration = parts
    state = ToolState(encoder, registration, n_tools=1, dt=0.05)
    rot0, pos0 = nominal_tool_pose()
    spin = Rotation.from_rotvec([0.0, 0.0, 0.1]).as_matrix()  # 0.1 rad per step about hand z
    samples = []
    for k in range(6):
        rot = np.linalg.matrix_power(spin, k) @ rot0
        samples.append(state.update(_clouds(rot, pos0 + [0.002 * k, 0.0, 0.0], seed=k)))
    first, last = samples[0], samples[-1]
    np.testing.assert_array_equal(first.velocity, 0.0)  # nothing to difference yet
    # differencing amplifies the per-frame registration error (~1-2 degrees of roll on a
    # fresh 256-point draw), hence the mean over steps and the tolerances
    velocity = np.mean([s.velocity[0] for s in samples[2:]], axis=0)
    omega = np.mean([s.angular_velocity[0] for s in samples[2:]], axis=0)
    np.testing.assert_allclose(velocity, [0.04, 0.0, 0.0], atol=0.01)  # 2 mm / 50 ms
    np.testing.assert_allclose(omega, [0.0, 0.0, 2.0], atol=0.5)  # 0.1 rad / 50 ms
    # EMA: s_bar_k = 0.9 s_k + 0.1 s_bar_(k-1), starting at s_0
    expected = samples[0].z[0]
    for sample in samples[1:]:
        expected = 0.9 * sample.z[0] + 0.1 * expected
    np.testing.assert_allclose(last.z_smoothed[0], expected, rtol=1e-9)
    assert last.low_level().shape == (1, 8) and last.high_level().shape == (1, 8)
    np.testing.assert_allclose(last.high_level()[0, :3], last.position[0])


def test_batched_tools_and_partial_reset(parts):
    encoder, registration = parts
    state = ToolState(encoder, registration, n_tools=3)
    rot0, pos0 = nominal_tool_pose()
    rots = np.stack([rot0] * 3)
    state.update(_clouds(rots, np.stack([pos0] * 3)))
    state.reset(np.array([False, True, False]))
    moved = state.update(_clouds(rots, np.stack([pos0 + [0.003, 0, 0]] * 3)))
    assert np.abs(moved.velocity[[0, 2], 0] - 0.06).max() < 0.015
    np.testing.assert_array_equal(moved.velocity[1], 0.0)  # restarted: no velocity
    with pytest.raises(ConfigError, match="made for 3 tools"):
        state.update(_clouds(rots[:2], np.stack([pos0] * 2)))
    with pytest.raises(ConfigError, match="reset mask"):
        state.reset(np.ones(2, bool))
