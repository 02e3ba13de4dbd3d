"""The PointNet VAE: shapes, permutation invariance, checkpoints refused with one clear line."""

from __future__ import annotations

from dataclasses import asdict

import numpy as np
import pytest
import torch

from hingelab.errors import ConfigError
from hingelab.perception.clouds import IDEAL, CloudSynthesizer, ToolGeometry
from hingelab.perception.encoder import (
    SHIPPED_CHECKPOINT,
    EncoderConfig,
    PointNetVAE,
    chamfer,
    load_encoder,
    save_checkpoint,
    vae_loss,
)

TINY = EncoderConfig(widths=(8, 16), head_width=8, decoder_widths=(16,), decoder_points=32, target_points=64)


@pytest.fixture
def tiny_checkpoint(tmp_path):
    torch.manual_seed(0)
    model = PointNetVAE(TINY)
    path = save_checkpoint(tmp_path / "encoder_tiny.pt", model, geometry_hash=ToolGeometry.default().geometry_hash,
                           registration_config={}, calibration=None, info={"seed": 0})
    return path, model


def test_shapes_and_permutation_invariance():
    torch.manual_seed(0)
    model = PointNetVAE(TINY).eval()
    points = torch.rand(4, 256, 3) * 0.1
    mu, logvar = model.encode(points)
    assert mu.shape == (4, 2) and logvar.shape == (4, 2)
    mu_perm, _ = model.encode(points[:, torch.randperm(256)])
    torch.testing.assert_close(mu, mu_perm)
    assert model.decode(mu).shape == (4, 32, 3)
    loss, rec, kl = vae_loss(model, points, torch.rand(4, 64, 3) * 0.1)
    loss.backward()
    assert torch.isfinite(loss) and rec > 0 and kl >= 0


def test_chamfer_is_zero_on_itself_and_symmetric():
    a, b = torch.rand(2, 50, 3), torch.rand(2, 70, 3)
    torch.testing.assert_close(chamfer(a, a), torch.zeros(2))
    torch.testing.assert_close(chamfer(a, b), chamfer(b, a))


def test_checkpoint_round_trip(tiny_checkpoint):
    path, model = tiny_checkpoint
    encoder = load_encoder(path)
    cloud = CloudSynthesizer(ToolGeometry.default(), IDEAL, seed=0).from_tool_pose(np.eye(3), np.zeros(3), 0.1)
    with torch.no_grad():
        expected = model.encode(torch.from_numpy(cloud[None]))[0].numpy()[0]
    np.testing.assert_allclose(encoder.encode(cloud), expected, rtol=1e-6, atol=1e-6)  # numpy vs torch products
    assert encoder.info["seed"] == 0
    # a batch past the one-thread size: the same latent means as the module
    clouds = np.stack([cloud + 0.001 * k for k in range(12)]).astype(np.float32)
    with torch.no_grad():
        expected = model.encode(torch.from_numpy(clouds))[0].numpy()
    np.testing.assert_allclose(encoder.encode(clouds), expected, rtol=1e-5, atol=1e-6)


def _rewrite(path, **changes):
    raw = torch.load(path, weights_only=False)
    raw.update(changes)
    torch.save(raw, path)


@pytest.mark.parametrize("change, message", [
    ({"format_version": 99}, "format 99"),
    ({"format": "something.else"}, "not a hingelab tool-encoder checkpoint"),
    ({"geometry_hash": "0123456789abcdef"}, "another tweezer geometry"),
    ({"config": {**asdict(TINY), "widths": [8, 32]}}, "weights do not fit"),
    ({"config": {**asdict(TINY), "dropout": 0.1}}, "does not match this hingelab version"),
])
def test_checkpoint_from_another_version_or_config_is_refused(tiny_checkpoint, change, message):
    path, _ = tiny_checkpoint
    _rewrite(path, **change)
    with pytest.raises(ConfigError, match=message) as info:
        load_encoder(path)
    assert "\n" not in str(info.value)


def test_missing_or_garbage_checkpoint(tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        load_encoder(tmp_path / "nope.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ConfigError, match="not a readable torch checkpoint"):
        load_encoder(tmp_path / "bad.pt")


def test_encoder_refuses_bad_clouds(tiny_checkpoint):
    encoder = load_encoder(tiny_checkpoint[0])
    with pytest.raises(ConfigError, match="shape"):
        encoder.encode(np.zeros((256, 4)))
    with pytest.raises(ConfigError, match="NaN"):
        encoder.encode(np.full((256, 3), np.nan))


@pytest.mark.skipif(not SHIPPED_CHECKPOINT.exists(), reason="no shipped encoder checkpoint")
def test_shipped_checkpoint_loads_with_provenance():
    encoder = load_encoder()
    assert encoder.calibration is not None
    for key in ("data", "seed", "code_version", "metrics", "history", "train_config"):
        assert key in encoder.info


@pytest.mark.skipif(not SHIPPED_CHECKPOINT.exists(), reason="no shipped encoder checkpoint")
def test_shipped_z_moves_monotonically_along_its_main_axis_as_the_hinge_opens():
    """Mean latent of a few noisy, occluded in-hand clouds per opening, registered by the
    pipeline: its coordinate along the calibration's principal axis grows with the opening."""
    from hingelab.perception.clouds import CloudRealism
    from hingelab.perception.registration import CanonicalRegistration, RegistrationConfig
    from hingelab.perception.synthetic_dataset import sample_clouds
    from hingelab.perception.train_encoder import register_to_tool_frame

    encoder = load_encoder()
    geometry = ToolGeometry.default()
    registration = CanonicalRegistration(geometry, RegistrationConfig(**encoder.registration_config))
    openings = np.linspace(0.0, 0.3, 7)
    coordinates = []
    for k, theta in enumerate(openings):
        batch = sample_clouds(np.random.default_rng(100 + k), 12, geometry, CloudRealism(0.003, 0.2, 0.0, 0.0),
                              np.deg2rad(30), 0.02)
        synth = CloudSynthesizer(geometry, CloudRealism(0.003, 0.2, 0.0, 0.0), seed=k)
        clouds = synth.from_tool_pose(batch["rotation"], batch["position"], np.full(12, theta))
        z = encoder.encode(register_to_tool_frame(clouds, registration)[0])
        coordinates.append(encoder.calibration.coordinate(z.mean(axis=0)))
    assert np.all(np.diff(coordinates) > 0), np.round(coordinates, 4)


def test_small_batches_encode_on_one_thread_and_restore_the_setting(tiny_checkpoint, monkeypatch):
    """One cloud per env step runs in numpy on one OpenBLAS thread (worker processes otherwise spin
    against each other), large batches in torch; the caller's thread count is back afterwards and
    the result is the same."""
    from hingelab.perception import encoder as encoder_module

    blas = encoder_module._openblas()
    if blas is None:
        pytest.skip("numpy here does not use OpenBLAS")
    encoder = load_encoder(tiny_checkpoint[0])
    cloud = np.random.default_rng(0).normal(0.06, 0.02, (256, 3))
    before = blas.get_num_threads()
    seen, torch_batches = [], []
    small, large = encoder._small_batch_latent_mean, encoder._latent_mean
    monkeypatch.setattr(encoder, "_small_batch_latent_mean",
                        lambda x: (seen.append(blas.get_num_threads()), small(x))[1])
    monkeypatch.setattr(encoder, "_latent_mean", lambda x: (torch_batches.append(len(x)), large(x))[1])
    blas.set_num_threads(2)
    try:
        z_one = encoder.encode(cloud)
        assert seen == [1] and blas.get_num_threads() == 2 and not torch_batches
        z_big = encoder.encode(np.repeat(cloud[None], encoder_module.ONE_THREAD_BATCH + 1, 0))
        assert torch_batches == [encoder_module.ONE_THREAD_BATCH + 1]
    finally:
        blas.set_num_threads(before)
    np.testing.assert_allclose(z_big[0], z_one, atol=1e-5)
