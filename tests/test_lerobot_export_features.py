"""The LeRobot export's features: a trial's frames and depth images, names, float32, quantile statistics,
no NaN in any exported column, a continuous tool rotation, hingelab's facts outside info.json, and (when
LeRobot is installed) the export loading in LeRobot itself."""

from __future__ import annotations

import io
import json
import os
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
from PIL import Image
from scipy.spatial.transform import Rotation

from hingelab.camera import DepthIntrinsics
from hingelab.episodes import EpisodeWriter, create_dataset
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.errors import DatasetError
from hingelab.episodes.export import export_lerobot
from hingelab.episodes.export_state import ARM_JOINT_INFOS
from hingelab.episodes.export_stats import STAT_KEYS
from hingelab.episodes.synthetic import tweezer_cloud, write_synthetic_episode
from hingelab.sim.arm_kinematics import default_kinematics

DT = 0.05
STEPS = 7
DEPTH_HW = (6, 8)
DEPTH_EVERY = 2
INTRINSICS = DepthIntrinsics("recorded", DEPTH_HW[1], DEPTH_HW[0], 5.0, 5.0, 4.0, 3.0, 0.0, 65.535)
ARM_Q = np.array([0.0, 1.2, -1.6, 0.4, 1.57, 0.0])  # rad: any angles place a hand


def _depth(k: int) -> np.ndarray:
    """(H, W) metres, whole millimetres, 0 (no return) in one corner."""
    depth = 0.5 + 0.001 * (np.arange(DEPTH_HW[0] * DEPTH_HW[1]).reshape(DEPTH_HW) + 10 * k)
    depth[0, 0] = 0.0
    return depth


def _euler(k: int) -> np.ndarray:
    """The tool's Euler angles: x crosses +pi at step 3 and wraps to -pi (a tool held upside down)."""
    return np.array([np.pi - 0.1 + 0.05 * k, 0.2, -0.3])


def write_trial(root, seed: int = 0) -> dict:
    """A stand-in trial as ``hingelab trial`` records it: topics, no /step; depth every other step."""
    create_dataset(root, name="trial", source="stand_in", config={"robot": "sim"}, seed=seed)
    rng = np.random.default_rng(seed)
    written = {"position": [], "euler": [], "z": [], "object": [], "target": [], "action": [], "clouds": []}
    with EpisodeWriter(root, source="stand_in", task="ToolPick trial", object="sphere", seed=seed,
                       action_level="high") as writer:
        for k in range(STEPS):
            euler = np.array(Rotation.from_euler("xyz", _euler(k)).as_euler("xyz"))  # wrapped to (-pi, pi]
            position, z = np.array([0.02, 0.04, 0.1 + 0.001 * k]), np.array([0.2 + 0.01 * k, 0.01])
            obj, target, action = np.array([0.0, 0.01, 0.13]), np.array([-0.1, 0.01, 0.13]), rng.uniform(-1, 1, 5)
            cloud = tweezer_cloud(rng, 0.3)
            writer.write_step(k * DT, points_hand=cloud, tool_pose_hand=(position, Rotation.from_euler(
                "xyz", euler).as_quat()), joint_position=np.zeros(9), latent_z=z, latent_z_smoothed=z,
                action=action, goal_z=action[:2], object_position_hand=obj, target_position_hand=target)
            if k % DEPTH_EVERY == 0:
                writer.write_camera(k * DT, _depth(k), INTRINSICS, np.eye(3), np.zeros(3), calibration=k == 0)
            for name, value in zip(written, (position, euler, z, obj, target, action, cloud)):
                written[name].append(value)
        writer.set_outcome(success=True)
    return {k: np.stack(v) for k, v in written.items()}


def write_real(root, nan_action: bool = False) -> None:
    """Real episodes as ``datasets import-ros2`` writes them: NaN target, NaN reward, arm joints in the infos."""
    create_dataset(root, name="real", source="real", config={}, seed=0)
    rng = np.random.default_rng(1)
    for seed in range(2):
        with EpisodeWriter(root, source="real", task="real_trial", seed=seed, action_level="high") as writer:
            for k in range(STEPS):
                observation = np.concatenate([[0.03, 0.035, 0.1], _euler(k) - 2 * np.pi * (k >= 3), [0.1, 0.02],
                                              [0.18, -0.02, -0.24], np.full(3, np.nan)])
                action = rng.uniform(-1, 1, 5)
                if nan_action and k == 2:
                    action[:] = np.nan
                writer.write_step(k * DT, points_hand=tweezer_cloud(rng, 0.3), transition=dict(
                    observation=observation, action=action, reward=np.nan, terminated=k == STEPS - 1, truncated=False,
                    info={"is_success": float(k == STEPS - 1), **dict(zip(ARM_JOINT_INFOS, ARM_Q + 0.01 * k))}))
            writer.set_outcome(True)


@pytest.fixture(scope="module")
def trial(tmp_path_factory):
    root = tmp_path_factory.mktemp("trial") / "trial"
    written = write_trial(root)
    out = root.parent / "lerobot"
    return written, export_lerobot(Dataset(root), out), out


@pytest.fixture(scope="module")
def real(tmp_path_factory):
    root = tmp_path_factory.mktemp("real") / "real"
    write_real(root)
    out = root.parent / "lerobot"
    return root, export_lerobot(Dataset(root), out), out


@pytest.fixture(scope="module")
def low(tmp_path_factory):
    root = tmp_path_factory.mktemp("low") / "low"
    create_dataset(root, name="low", source="synthetic", config={}, seed=0)
    for seed in range(2):
        write_synthetic_episode(root, seed, n_steps=STEPS, goal_env=True)
    out = root.parent / "lerobot"
    return root, export_lerobot(Dataset(root), out), out


def tables(out: Path):
    info = json.loads((out / "meta" / "info.json").read_text())
    data = pq.ParquetDataset(sorted((out / "data").glob("*/*.parquet"))).read()
    stats = json.loads((out / "meta" / "stats.json").read_text())
    return info, data, stats


def column(data, name) -> np.ndarray:
    values = data.column(name).to_pylist()
    return np.asarray(values, dtype=np.float64)


def assert_clean(out: Path) -> None:
    """Every feature named where it has dimensions, float32 floats, quantile stats finite, no NaN anywhere."""
    info, data, stats = tables(out)
    assert set(info) <= {"codebase_version", "robot_type", "total_episodes", "total_frames", "total_tasks",
                         "chunks_size", "data_files_size_in_mb", "video_files_size_in_mb", "fps", "splits",
                         "data_path", "video_path", "features"}  # LeRobot 0.6's DatasetInfo fields: no warning
    assert list(info["features"]) == data.column_names
    for name, feature in info["features"].items():
        assert feature["dtype"] in ("float32", "int64", "bool", "image"), (name, feature["dtype"])
        if feature["dtype"] == "float32" and len(feature["shape"]) == 1 and feature["shape"] != [1]:
            assert len(feature["names"]) == feature["shape"][0] == len(set(feature["names"])), name
        assert set(stats[name]) == set(STAT_KEYS), name
        for key, value in stats[name].items():
            assert np.isfinite(np.asarray(value, np.float64)).all(), (name, key)
        if feature["dtype"] != "image":
            assert not np.isnan(column(data, name)).any(), f"{name} has NaN"
    for key in ("q01", "q99"):
        assert len(stats["observation.state"][key]) == info["features"]["observation.state"]["shape"][0]


# --- a trial: frames from its topics, depth images -------------------------------------------------
def test_a_trial_exports_one_frame_per_high_level_action(trial):
    written, result, out = trial
    assert result.episodes == 1 and result.frames == STEPS and not result.skipped
    info, data, _ = tables(out)
    raw = column(data, "env.observation")
    np.testing.assert_allclose(raw[:, 6:8], written["z"], rtol=1e-6)
    np.testing.assert_allclose(raw[:, 8:11], written["object"], rtol=1e-6)
    np.testing.assert_allclose(raw[:, 11:14], written["target"], rtol=1e-6)
    np.testing.assert_allclose(raw[0, :6], np.concatenate([written["position"][0], written["euler"][0]]), rtol=1e-6)
    np.testing.assert_allclose(raw[1, :3], 0.9 * written["position"][1] + 0.1 * written["position"][0], rtol=1e-6)
    np.testing.assert_allclose(column(data, "action"), written["action"], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(data.column("observation.points").to_pylist()), written["clouds"])
    assert column(data, "next.terminated")[-1] and column(data, "next.success")[-1]
    assert "next.reward" not in info["features"]  # a trial has no reward: left out, and said so
    assert any("next.reward left out" in note for note in result.notes)
    facts = json.loads((out / "meta" / "hingelab.json").read_text())
    assert "next.reward" in facts["left_out"] and facts["card"]["name"] == "trial"
    assert_clean(out)


def test_a_trials_depth_images_are_present_and_readable(trial):
    _, _, out = trial
    info, data, stats = tables(out)
    feature = info["features"]["observation.images.depth"]
    assert feature["shape"] == [*DEPTH_HW, 1] and feature["names"] == ["height", "width", "channels"]
    assert feature["info"] == {"is_depth_map": True, "depth_unit": "mm"}
    images = data.column("observation.images.depth").to_pylist()
    age = column(data, "info.depth_age_s")
    for k, image in enumerate(images):
        taken = k - k % DEPTH_EVERY  # the latest image at or before the frame
        decoded = Image.open(io.BytesIO(image["bytes"]))
        assert decoded.mode == "I;16" and image["path"].endswith(".tiff")
        np.testing.assert_array_equal(np.array(decoded), np.round(_depth(taken) * 1000).astype(np.uint16))
        assert age[k] == pytest.approx((k - taken) * DT)
    assert stats["observation.images.depth"]["max"] == [[[float(np.round(_depth(STEPS - 1 - (STEPS - 1) % 2).max()
                                                                           * 1000))]]]  # millimetres, not / 255
    assert stats["observation.images.depth"]["min"] == [[[0.0]]]


def test_the_tool_rotation_is_continuous_where_its_euler_angles_wrap(trial):
    written, _, out = trial
    info, data, _ = tables(out)
    names = info["features"]["observation.state"]["names"]
    assert names[3:9] == ["tool_rot_c0_x", "tool_rot_c0_y", "tool_rot_c0_z", "tool_rot_c1_x", "tool_rot_c1_y",
                          "tool_rot_c1_z"] and "tool_euler_x" not in names
    assert np.abs(np.diff(written["euler"][:, 0])).max() > 6  # the recorded angle jumps by 2 pi
    state = column(data, "observation.state")
    rot6d = state[:, 3:9]
    # the smoothed Euler angles swing through the wrap (the controller's EMA); the rotation only moves
    raw = column(data, "env.observation")
    expected = Rotation.from_euler("xyz", raw[:, 3:6]).as_matrix()
    np.testing.assert_allclose(rot6d, np.concatenate([expected[:, :, 0], expected[:, :, 1]], axis=1), atol=1e-6)
    assert np.abs(rot6d).max() <= 1 + 1e-6


# --- real imports: the target by the env's rule, no reward, NaN refused ------------------------------
def test_a_real_trials_nan_target_is_filled_by_the_envs_rule(real):
    root, result, out = real
    info, data, _ = tables(out)
    state, raw = column(data, "observation.state"), column(data, "env.observation")
    episode = column(data, "episode_index")
    rotation, position = default_kinematics().hand_poses(ARM_Q + 0.01 * np.arange(STEPS)[:, None])
    for e in (0, 1):
        rows = raw[episode == e]
        object_world = rotation[0] @ rows[0, 8:11] + position[0]
        target_world = object_world + [0, 0, 0.05]
        np.testing.assert_allclose(rows[:, 11:14], np.einsum("tji,tj->ti", rotation, target_world - position),
                                   atol=1e-6)
    np.testing.assert_array_equal(state[:, -3:], raw[:, -3:])
    assert "next.reward" not in info["features"]
    facts = json.loads((out / "meta" / "hingelab.json").read_text())
    assert sorted(next(iter(facts["filled"].values()))) == sorted(p.name for p in Dataset(root).paths())
    assert_clean(out)


def test_a_nan_no_rule_defines_is_refused_in_one_line(tmp_path):
    write_real(tmp_path / "real", nan_action=True)
    with pytest.raises(DatasetError) as caught:
        export_lerobot(Dataset(tmp_path / "real"), tmp_path / "out")
    message = str(caught.value)
    assert "action is NaN" in message and ".mcap" in message and "frame 2" in message and "\n" not in message
    assert not (tmp_path / "out").exists()


# --- names, dtypes, stats -------------------------------------------------------------------------------
def test_a_goal_envs_features_are_named_float32_with_quantile_stats(low):
    _, result, out = low
    info, data, stats = tables(out)
    features = info["features"]
    assert features["observation.state"]["names"][:2] == ["thumb_flexion", "thumb_opposition"]
    assert features["observation.state"]["names"][-2:] == ["z_bar_0", "z_bar_1"]
    assert features["observation.desired_goal"]["names"] == ["z_goal_0", "z_goal_1"]
    assert features["action"]["names"][0] == "thumb_flexion_delta" and "env.observation" not in features
    state, episode = column(data, "observation.state"), column(data, "episode_index")
    counts = np.array([(episode == e).sum() for e in (0, 1)])
    per_episode = np.stack([np.quantile(state[episode == e], 0.01, axis=0) for e in (0, 1)])
    np.testing.assert_allclose(stats["observation.state"]["q01"], counts @ per_episode / counts.sum(), rtol=1e-5,
                               atol=1e-7)  # LeRobot's aggregate: the count-weighted mean of the episodes' quantiles
    assert_clean(out)


DEMOS = Path(os.environ.get("HINGELAB_DEMO_DATASETS", Path(__file__).resolve().parents[1] / "datasets"))
DEMO_NAMES = ["demo_heuristic", "demo_low_level", "demo_scripted_hierarchy", "demo_learned_hierarchy", "demo_real",
              "demo_stand_in_trial"]


@pytest.mark.parametrize("name", DEMO_NAMES)
def test_the_demo_datasets_export_without_nan(name, tmp_path):
    """``hingelab demo``'s datasets (made by ``hingelab demo``; HINGELAB_DEMO_DATASETS points elsewhere)."""
    if not (DEMOS / name / "dataset.json").exists():
        pytest.skip(f"no {DEMOS / name} (run hingelab demo)")
    export_lerobot(Dataset(DEMOS / name), tmp_path / "out")
    assert_clean(tmp_path / "out")


# --- LeRobot itself -----------------------------------------------------------------------------------
@pytest.mark.lerobot
def test_the_exports_load_in_lerobot(trial, real):
    lerobot_dataset = pytest.importorskip("lerobot.datasets.lerobot_dataset")
    torch = pytest.importorskip("torch")
    for out in (trial[2], real[2]):
        dataset = lerobot_dataset.LeRobotDataset("hingelab/test", root=out,
                                                 delta_timestamps={"action": [0.0, DT, 2 * DT]})
        assert len(dataset) == tables(out)[0]["total_frames"]
        item = dataset[0]
        assert item["observation.state"].dtype == torch.float32 and item["action"].shape == (3, 5)
        for key in ("q01", "q99"):
            assert key in dataset.meta.stats["observation.state"]
        batch = next(iter(torch.utils.data.DataLoader(dataset, batch_size=4, shuffle=True)))
        assert batch["observation.state"].shape == (4, 17) and torch.isfinite(batch["observation.state"]).all()
        if "observation.images.depth" in dataset.meta.features:
            depth = batch["observation.images.depth"]
            assert depth.shape == (4, 1, *DEPTH_HW) and depth.dtype == torch.float32 and depth.max() > 500  # mm
