"""``perception="camera"`` in both envs, a camera that goes blind, and ``hingelab eval perception``."""

from __future__ import annotations

import json
import types

import gymnasium as gym
import numpy as np
import pandas as pd
import pytest

from hingelab.envs import TOOL_PICK_ID, TOOL_SHAPE_ID


@pytest.mark.parametrize("env_id", [TOOL_SHAPE_ID, TOOL_PICK_ID])
def test_camera_perception_drives_both_envs(env_id):
    env = gym.make(env_id, perception="camera")
    try:
        obs, info = env.reset(seed=4)
        env.action_space.seed(4)  # reset does not seed the action space: unseeded, its samples made this test flaky
        for _ in range(4):
            obs, reward, terminated, truncated, info = env.step(env.action_space.sample() * 0.1)
        pick = env.unwrapped
        assert info["perception_flag"] is None and not truncated
        assert pick.perception.cloud.shape == (256, 3)
        frame = pick.perception.camera.frame
        assert frame.depth.shape == (576, 640) and frame.tool_mask.any()
        # the tracked opening is the tweezer's, read from camera clouds
        assert abs(float(pick.sample.opening_rad[0]) - pick.state.hinge_angle) < 0.06
    finally:
        env.close()


def test_unknown_perception_is_one_line():
    from hingelab.errors import ConfigError

    with pytest.raises(ConfigError, match="perception 'lidar' is unknown"):
        gym.make(TOOL_SHAPE_ID, perception="lidar")


def test_a_blind_camera_ends_the_episode_cleanly_and_keeps_it(tmp_path):
    from hingelab.envs.recording import RecordingWrapper
    from hingelab.episodes import create_dataset, read_episode

    root = tmp_path / "blind"
    create_dataset(root, name="blind", source="high_level_evaluation", seed=0, config={})
    env = RecordingWrapper(gym.make(TOOL_PICK_ID, perception="camera", low_level="privileged"), root,
                           source="high_level_evaluation", object_name="sphere", action_level="high")
    try:
        env.reset(seed=1)
        env.step(np.zeros(5))
        # the camera returns nothing from now on (a covered lens, a dead cable)
        env.unwrapped.perception.source.noise = types.SimpleNamespace(apply=lambda depth, k, rng: np.zeros_like(depth))
        obs, reward, terminated, truncated, info = env.step(np.zeros(5))
        assert truncated and not terminated
        assert info["perception_flag"] == "no_depth" and info["failure_reason"] == "no_camera_cloud"
        assert np.isfinite(obs).all()
    finally:
        env.close()
    files = sorted((root / "episodes").glob("*.mcap"))
    assert len(files) == 1
    episode = read_episode(files[0])
    assert episode.length == 2 and episode.metadata["failure_reason"] == "no_camera_cloud"


def test_eval_perception_writes_the_gap_and_the_picture(tmp_path, capsys):
    """``hingelab eval perception`` by ``main`` in this process (a started process only adds its start-up)."""
    from hingelab.cli.main import main

    out = tmp_path / "gap"
    capsys.readouterr()
    assert main(["eval", "perception", "--episodes", "1", "--steps", "24", "--out", str(out), "--no-progress"]) == 0
    result = types.SimpleNamespace(stdout=capsys.readouterr().out)
    gap = pd.read_csv(out / "gap.csv").set_index("perception")
    assert set(gap.index) == {"synthesized", "camera"} and (gap["steps"] == 19).all()
    assert gap.loc["camera", "flagged_share"] == 0
    # the camera sees the true pose up to its calibration error; the synthesized clouds carry the paper's 2 cm one
    assert gap.loc["camera", "position_error_mm_median"] < 25
    steps = pd.read_csv(out / "gap_steps.csv")
    assert len(steps) == 38 and steps["opening_est_rad"].notna().all()
    assert json.loads((out / "gap.json").read_text())["made_by"] == "hingelab eval perception"
    assert (out / "camera_frame.png").stat().st_size > 10_000
    assert "Opening R^2" in result.stdout
