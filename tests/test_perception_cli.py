"""``hingelab generate clouds`` -> ``hingelab train encoder`` end to end at toy scale, and bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hingelab.cli.main import main
from hingelab.episodes.dataset import Dataset
from hingelab.perception.encoder import load_encoder
from hingelab.perception.synthetic_dataset import SOURCE, load_cloud_dataset


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: ")
    return err[-1]


def test_generate_then_train(tmp_path, capsys):
    data = tmp_path / "clouds"
    assert main(["generate", "clouds", "--n", "120", "--per-episode", "50", "--out", str(data), "--seed", "3",
                 "--no-progress"]) == 0
    assert "Wrote 120 tweezer clouds in 3 episode files" in capsys.readouterr().out
    dataset = Dataset(data)
    assert len(dataset) == 3 and set(dataset.index["source"]) == {SOURCE}
    clouds = load_cloud_dataset(data)
    assert clouds["points"].shape == (120, 256, 3) and clouds["points"].dtype == np.float32
    assert clouds["hinge_angle"].min() >= 0.0 and clouds["hinge_angle"].max() <= 0.3
    # the same seed writes the same clouds
    again = tmp_path / "again"
    main(["generate", "clouds", "--n", "50", "--per-episode", "50", "--out", str(again), "--seed", "3",
          "--no-progress"])
    np.testing.assert_array_equal(load_cloud_dataset(again)["points"], clouds["points"][:50])

    out = tmp_path / "encoder_test.pt"
    assert main(["train", "encoder", "--data", str(data), "--epochs", "1", "--batch-size", "32", "--out", str(out),
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert '"epoch": 1' in text and "Trained the tool encoder for 1 epochs" in text
    encoder = load_encoder(out)
    assert encoder.info["data"]["clouds"] == 120 and encoder.info["seed"] == 0
    assert len(encoder.info["history"]) == 1 and "git_commit" in encoder.info["code_version"]
    assert encoder.calibration is not None and encoder.encode(clouds["points"][:4]).shape == (4, 2)
    raw = torch.load(out, weights_only=False)
    assert raw["train_config"]["epochs"] == 1 and raw["registration_config"]["articulated"] is True
    assert encoder.calibration.reader_coef is not None  # new trainings fit the reader too

    # --recalibrate: a checkpoint from before readers gets one; weights, curve and fingerprint stay
    raw["calibration"] = {k: v for k, v in raw["calibration"].items() if k not in ("reader_coef", "reader_r2_opening")}
    torch.save(raw, out)
    before = load_encoder(out)
    assert before.calibration.reader_coef is None
    assert main(["train", "encoder", "--data", str(data), "--recalibrate", "--out", str(out), "--no-progress"]) == 0
    assert "(unchanged)" in capsys.readouterr().out
    after = load_encoder(out)
    assert after.fingerprint == before.fingerprint and after.calibration.reader_coef is not None
    assert after.calibration.z_coef == before.calibration.z_coef and "reader" in after.info
    z = after.encode(clouds["points"][:16])
    np.testing.assert_array_equal(after.calibration.project_opening(z), before.calibration.opening_rad(z))
    lo, hi = after.calibration.opening_range
    assert ((after.calibration.opening_rad(z) >= lo) & (after.calibration.opening_rad(z) <= hi)).all()
    assert main(["train", "encoder", "--data", str(again), "--recalibrate", "--out", str(out)]) == 1
    assert "is not the dataset" in _one_line_error(capsys)


def test_generate_refuses_a_used_folder_and_train_a_missing_dataset(tmp_path, capsys):
    data = tmp_path / "clouds"
    main(["generate", "clouds", "--n", "10", "--out", str(data), "--no-progress"])
    capsys.readouterr()
    assert main(["generate", "clouds", "--n", "10", "--out", str(data), "--no-progress"]) == 1
    assert "already holds 1 episodes" in _one_line_error(capsys)
    assert main(["train", "encoder", "--data", str(tmp_path / "missing"), "--out", str(tmp_path / "e.pt")]) == 1
    assert str(tmp_path / "missing") in _one_line_error(capsys)
    with pytest.raises(SystemExit):
        main(["generate", "clouds"])  # --out is required


@pytest.mark.slow
def test_bench_perception_quick(tmp_path, capsys):
    pytest.importorskip("open3d")
    from hingelab.perception.encoder import SHIPPED_CHECKPOINT

    if not SHIPPED_CHECKPOINT.exists():
        pytest.skip("no shipped encoder checkpoint")
    assert main(["bench", "perception", "--quick", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "perception.md").read_text()
    assert "Open3D point-to-point ICP" in text and "rot_median ours/open3d" in text
    assert "tool state, 64 clouds per update" in text
    assert "camera pipeline filters, Open3D" in text and "env steps/s, camera / synthesized" in text


@pytest.mark.parametrize("failure, advice", [
    ("No module named 'open3d'", r"pip install 'hingelab\[bench\]'"),
    ("libusb-1.0.so.0: cannot open shared object file: No such file or directory", "apt-get install libusb-1.0-0"),
])
def test_bench_perception_without_open3d_says_how_to_install(monkeypatch, failure, advice):
    import builtins

    from hingelab.bench import perception
    from hingelab.errors import ConfigError

    real_import = builtins.__import__

    def no_open3d(name, *args, **kwargs):
        if name == "open3d":
            raise ImportError(failure)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_open3d)
    with pytest.raises(ConfigError, match=advice):
        perception._require_open3d()


def test_recalibrate_curve_fits_the_tracked_latents_and_keeps_old_policies(tmp_path, capsys):
    """--recalibrate-curve: the curve moves onto the latents the envs perceive (closer at the shut
    end than the training curve), the weights stay, and the old fingerprint is still accepted."""
    import shutil

    from hingelab.perception.encoder import SHIPPED_CHECKPOINT
    from hingelab.perception.sim_calibration import curve_offsets, tracked_sweep_latents

    out = tmp_path / "encoder.pt"
    shutil.copy(SHIPPED_CHECKPOINT, out)
    before = load_encoder(out)
    assert main(["train", "encoder", "--recalibrate-curve", "--sweeps", "10", "--seed", "100", "--out", str(out),
                 "--no-progress"]) == 0
    assert "Refitted the calibration curve" in capsys.readouterr().out
    after = load_encoder(out)
    for name, tensor in before.model.state_dict().items():
        assert torch.equal(tensor, after.model.state_dict()[name])
    assert after.fingerprint != before.fingerprint
    assert after.accepts(before.fingerprint) and after.accepts(after.fingerprint) and not after.accepts("0" * 16)
    assert before.fingerprint in after.info["curve"]["replaces"] and after.info["curve"]["seed"] == 100
    # 10 sweeps neither curve saw: fewer leave the shut-end mean to a sweep or two's pose error
    check = tracked_sweep_latents(after, sweeps=10, seed=900, progress=False)
    old_shut, new_shut = (curve_offsets(c, check)[0]["offset"] for c in (before.calibration, after.calibration))
    assert new_shut < 0.5 * old_shut, (old_shut, new_shut)
    assert main(["train", "encoder", "--out", str(out)]) == 1
    assert "needs --data" in _one_line_error(capsys)
