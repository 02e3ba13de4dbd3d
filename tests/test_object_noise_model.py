"""The fitted model of the camera's object estimate (``hingelab.perception.object_noise_model``), its fit command's
tables, and ToolPick-v0 drawing from it (``object_noise``)."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import hingelab  # noqa: F401  (registers the envs)
from hingelab.errors import ConfigError
from hingelab.perception import object_noise_model as onm
from hingelab.rollouts import object_noise_fit
from hingelab.tasks import TOOL_PICK_ID

GOLDEN = Path(__file__).parent / "golden" / "tool_pick_observations.npz"
BIAS = {0.015: np.array([3.0, -1.0, 0.5]), 0.025: np.array([5.0, 1.0, -0.5])}  # mm: toward the camera, right, up
SCALE = np.array([1.0, 0.5, 0.8])
DROPOUT = 0.1


def synthetic_rows(n: int = 2000, seed: int = 0) -> list[dict]:
    """A frames table as diagnose object-estimate writes it: one estimator on two sphere sizes with known bias,
    noise and dropout, the extent 4 mm short on x, and a temporal filter's rows."""
    rng = np.random.default_rng(seed)
    rows = []
    for size, bias in BIAS.items():
        for i in range(n):
            spot, frame = divmod(i, 5)
            row = {"shape": "sphere", "size_m": str(size), "spot": str(spot), "frame": str(frame),
                   "estimator": "ray_corrected"}
            if rng.random() < DROPOUT:
                rows.append({**row, "flag": "too_few_points", "ray_bias_mm": "", "across_right_mm": "",
                             "across_up_mm": "", "error_mm": ""})
                continue
            e = bias + SCALE * rng.standard_normal(3)
            extent = np.array([-4.0, -2.0, 0.0]) + 0.3 * rng.standard_normal(3)
            rows.append({**row, "flag": "", "ray_bias_mm": e[0], "across_right_mm": e[1], "across_up_mm": e[2],
                         "error_mm": np.linalg.norm(e), **dict(zip(onm.EXTENT_COLUMNS, extent))})
        for spot in range(n // 5):
            rows.append({"shape": "sphere", "size_m": str(size), "spot": str(spot), "frame": "5",
                         "estimator": "temporal_ray_corrected", "flag": "", "ray_bias_mm": bias[0],
                         "across_right_mm": bias[1], "across_up_mm": bias[2], "error_mm": np.linalg.norm(bias)})
    return rows


@pytest.fixture(scope="module")
def model_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("model") / "model.json"
    return onm.save(onm.fit(synthetic_rows(), source={"path": "synthetic"}), path)


def test_the_fit_recovers_known_bias_noise_and_dropout(model_path):
    model = onm.load(model_path)
    for size, bias in BIAS.items():
        p = model.params("ray_corrected", "sphere", size)
        np.testing.assert_allclose(p["bias_mm"], bias, atol=0.1)
        np.testing.assert_allclose(p["scale_mm"], SCALE, rtol=0.1)
        assert abs(p["dropout"] - DROPOUT) < 0.02 and p["outlier_p"] < 0.02  # Gaussian frames: few outliers
        np.testing.assert_allclose(p["extent_bias_mm"], [-4.0, -2.0, 0.0], atol=0.05)
    middle = model.params("ray_corrected", "sphere", 0.02)  # between the sizes: interpolated
    np.testing.assert_allclose(middle["bias_mm"], (BIAS[0.015] + BIAS[0.025]) / 2, atol=0.1)
    np.testing.assert_allclose(model.params("ray_corrected", "sphere", 0.03)["bias_mm"], BIAS[0.025], atol=0.1)
    pooled = model.params("ray_corrected", "mesh:bunny.stl", 0.02)  # an unknown shape: the pooled entry
    assert pooled["shape"] == onm.POOLED
    assert model.base("temporal_ray_corrected") == ("ray_corrected", 5)
    with pytest.raises(ConfigError, match="no estimator 'centroid'"):
        model.params("centroid", "sphere", 0.02)


def test_the_residuals_match_the_synthetic_data(model_path, tmp_path):
    rows = synthetic_rows(500, seed=1)
    frames = _write_csv(rows, tmp_path / "frames.csv")
    path, model, table = object_noise_fit.fit_and_report(frames, tmp_path / "out", 0, "hingelab diagnose test", {},
                                                         samples=500)
    assert {p.name for p in (tmp_path / "out").iterdir()} == {"object_noise_model.json", "residuals.csv",
                                                              "residuals.md"}
    frame_rows = [r for r in table if r["estimator"] == "ray_corrected"]
    for r in frame_rows:
        assert abs(r["model_p95_mm"] - r["measured_p95_mm"]) < 0.5
        assert abs(r["model_ray_mm"] - r["measured_ray_mm"]) < 0.3
        assert abs(r["model_dropout"] - r["measured_dropout"]) < 0.03
    assert "| ray_corrected |" in path.read_text()


def test_the_fit_command_writes_the_model_and_says_so(tmp_path, capsys):
    from hingelab.cli.main import main

    frames = _write_csv(synthetic_rows(100), tmp_path / "frames.csv")
    out = tmp_path / "fit"
    assert main(["diagnose", "object-noise-fit", "--frames", str(frames), "--out", str(out), "--allow-dirty"]) == 0
    assert onm.load(out / object_noise_fit.MODEL_FILE).data["source"]["rows"] == len(synthetic_rows(100))
    assert "ray_corrected: 95th percentile" in capsys.readouterr().out
    assert main(["diagnose", "object-noise-fit", "--frames", str(tmp_path / "none.csv"), "--out", str(out)]) != 0


def _write_csv(rows: list[dict], path: Path) -> Path:
    import csv

    columns = list(dict.fromkeys(k for r in rows for k in r))
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, columns)
        writer.writeheader()
        writer.writerows(rows)
    return path


def test_a_bad_model_file_is_one_line(tmp_path, model_path):
    corrupt = tmp_path / "corrupt.json"
    corrupt.write_text('{"format": "hingelab.object_noise_model", "ver')
    old = tmp_path / "old.json"
    old.write_text(json.dumps({**json.loads(model_path.read_text()), "version": 0}))
    broken = tmp_path / "broken.json"
    broken.write_text(json.dumps({**json.loads(model_path.read_text()), "entries": [{"estimator": "x"}]}))
    for path, words in ((tmp_path / "missing.json", "no object noise model"), (corrupt, "not readable JSON"),
                        (old, "version 0"), (broken, "corrupt")):
        with pytest.raises(ConfigError, match=words) as error:
            onm.load(path)
        assert "\n" not in str(error.value)
    for bad in ("fitted", "fitted:median", "camera"):
        with pytest.raises(ConfigError, match="object noise"):
            onm.fitted_estimator(bad)


def test_draws_have_the_models_bias_along_the_ray_and_dropouts_keep_the_last(model_path):
    drawer = onm.FittedObjectEstimate(onm.load(model_path), "ray_corrected")
    drawer.new_episode(3, "sphere", 0.025)
    truth, extent = np.array([0.5, 0.0, 0.22]), np.full(3, 0.025)
    frame = onm.ray_frame(drawer.camera_position, truth)
    errors, kept = [], 0
    for _ in range(400):
        before = drawer.estimate
        drawer.observe(truth, extent)
        if drawer.fresh:
            kept += 1
            errors.append(1000 * frame.T @ (drawer.estimate - truth))
        else:  # a dropout: the last estimate stays
            assert drawer.flag == "dropout" and drawer.estimate is before
    errors = np.array(errors)
    np.testing.assert_allclose(errors.mean(axis=0), BIAS[0.025], atol=0.2)
    assert abs(1 - kept / 400 - DROPOUT) < 0.05
    np.testing.assert_allclose(drawer.box, extent + np.array([-4.0, -2.0, 0.0]) / 1000, atol=0.002)
    # toward the camera means nearer it
    drawer.new_episode(3, "sphere", 0.025)
    drawer.observe(truth, extent)
    assert drawer.fresh  # the episode's first frame always gives one
    toward = frame[:, 0]
    assert np.allclose(toward, (drawer.camera_position - truth) / np.linalg.norm(drawer.camera_position - truth))


def test_the_default_observation_is_unchanged():
    """ToolPick-v0's observations (reset and two steps, seed 7) as before the fitted noise came (the golden file
    was written by the code before it)."""
    golden = np.load(GOLDEN)
    for key, extent in (("plain", False), ("extent", True)):
        env = gym.make(TOOL_PICK_ID, observe_extent=extent)
        obs = [env.reset(seed=7)[0]]
        for a in ([0.1, -0.2, 0.3, 0.0, -0.1], [0.0, 0.0, -0.5, 0.2, 0.1]):
            obs.append(env.step(np.array(a))[0])
        env.close()
        # to float32's last bits: a CPU of another instruction set rounds the low level's arithmetic otherwise
        # (6e-8 here between two machines); a change of the observation moves it by far more
        np.testing.assert_allclose(np.array(obs), golden[key], rtol=0, atol=1e-6)


def test_the_env_observes_the_fitted_draw_and_records_it(model_path):
    env = gym.make(TOOL_PICK_ID, object_noise="fitted:temporal_ray_corrected", object_noise_model=str(model_path),
                   observe_extent=True, randomize=False)
    plain = gym.make(TOOL_PICK_ID, observe_extent=True, randomize=False)
    obs, _ = env.reset(seed=5)
    reference, _ = plain.reset(seed=5)
    u = env.unwrapped
    assert u.object_fitted.window == 5
    assert u.last_record["object_estimate"]["estimator"] == "fitted:temporal_ray_corrected"
    np.testing.assert_allclose(obs[8:11], u._to_hand(u.object_fitted.centre))  # no delay at reset
    np.testing.assert_allclose(obs[:8], reference[:8])  # the rest as without it: the env's stream is not shifted
    from hingelab.envs.recording import object_perception_metadata

    facts = object_perception_metadata(u)
    assert facts["object_noise"] == "fitted:temporal_ray_corrected" and len(facts["object_noise_model_sha256"]) == 64
    env.close()
    plain.close()
    with pytest.raises(ConfigError, match="choose one"):
        gym.make(TOOL_PICK_ID, object_noise="fitted:centroid", perception="camera", object_perception="centroid",
                 object_noise_model=str(model_path))
    with pytest.raises(ConfigError, match="object noise 'truth'"):
        gym.make(TOOL_PICK_ID, object_noise="truth")
