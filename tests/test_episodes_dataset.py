"""Dataset index, filters, iteration, transitions (SB3 buffers, pandas) and exports."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from hingelab.episodes import create_dataset
from hingelab.episodes import schemas as S
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.export import export_lerobot, export_minari, import_lerobot, import_minari
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.episodes.transitions import dataset_frame, dataset_transitions, fill_replay_buffer

N_STEPS = 12


def _make(root, goal_env=False, seeds=range(4)):
    create_dataset(root, name="demo", source="synthetic", config={"goal_env": goal_env}, seed=7)
    steps = {}
    for seed in seeds:
        obj = "sphere" if seed < 2 else "cube"
        path, written = write_synthetic_episode(root, seed=seed, n_steps=N_STEPS, goal_env=goal_env, object=obj)
        steps[path.name] = written
    return steps


def test_index_filter_and_rebuild(tmp_path):
    root = tmp_path / "ds"
    _make(root)
    dataset = Dataset(root)
    index = dataset.index
    assert len(index) == 4 and (root / "index.parquet").exists()
    assert index["length"].tolist() == [N_STEPS] * 4
    assert sorted(index["seed"].tolist()) == [0, 1, 2, 3]
    assert sorted(dataset.filter(success=True).index["seed"].tolist()) == sorted(
        index[index["seed"] % 2 == 0]["seed"].tolist())  # synthetic: even seeds succeed
    cubes = dataset.filter(object="cube", success=False)
    assert cubes.index["seed"].tolist() == [3] and len(list(cubes)) == 1
    # the index is a cache: delete it, add an episode, it is rebuilt from the files
    (root / "index.parquet").unlink()
    write_synthetic_episode(root, seed=9, n_steps=3)
    fresh = Dataset(root).index
    assert len(fresh) == 5 and 9 in fresh["seed"].tolist()
    for path in Dataset(root).paths():
        assert path.exists()


def test_transitions_fill_sb3_replay_buffer(tmp_path):
    from stable_baselines3.common.buffers import ReplayBuffer

    root = tmp_path / "ds"
    written = _make(root)
    dataset = Dataset(root)
    transitions = dataset_transitions(dataset)
    assert len(transitions) == 4 * N_STEPS
    first = written[dataset.index["file"][0]]
    np.testing.assert_array_equal(transitions.observations[0], first[0]["transition"]["observation"])
    np.testing.assert_array_equal(transitions.next_observations[0], first[1]["transition"]["observation"])
    np.testing.assert_array_equal(transitions.next_observations[N_STEPS - 1], first[-1]["transition"]["observation"])
    obs_space = gym.spaces.Box(-np.inf, np.inf, (26,), np.float32)
    act_space = gym.spaces.Box(-1, 1, (9,), np.float32)
    buffer = ReplayBuffer(1000, obs_space, act_space, device="cpu")
    fill_replay_buffer(buffer, transitions)
    assert buffer.size() == 4 * N_STEPS
    np.testing.assert_array_equal(buffer.observations[:4 * N_STEPS, 0], transitions.observations)
    np.testing.assert_array_equal(buffer.actions[:4 * N_STEPS, 0], transitions.actions)
    np.testing.assert_array_equal(buffer.rewards[:4 * N_STEPS, 0], transitions.rewards.astype(np.float32))
    # the last step is a time-limit truncation: done, but flagged as a timeout for bootstrapping
    assert buffer.dones[N_STEPS - 1, 0] == 1 and buffer.timeouts[N_STEPS - 1, 0] == 1


def test_goal_env_transitions_fill_dict_buffer_and_frame(tmp_path):
    from stable_baselines3.common.buffers import DictReplayBuffer

    root = tmp_path / "ds"
    _make(root, goal_env=True, seeds=range(2))
    dataset = Dataset(root)
    transitions = dataset_transitions(dataset)
    assert transitions.is_dict and set(transitions.observations) == {"observation", "achieved_goal", "desired_goal"}
    space = gym.spaces.Dict({"observation": gym.spaces.Box(-np.inf, np.inf, (26,), np.float32),
                             "achieved_goal": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
                             "desired_goal": gym.spaces.Box(-np.inf, np.inf, (2,), np.float32)})
    buffer = DictReplayBuffer(100, space, gym.spaces.Box(-1, 1, (9,), np.float32), device="cpu")
    fill_replay_buffer(buffer, transitions)
    np.testing.assert_array_equal(buffer.observations["desired_goal"][:2 * N_STEPS, 0],
                                  transitions.observations["desired_goal"])
    frame = dataset_frame(dataset)
    assert len(frame) == 2 * N_STEPS
    assert {"observation_25", "desired_goal_1", "reward", "info.is_success", "/sim/privileged:hinge_angle",
            "/reward/terms:goal", "source", "object"} <= set(frame.columns)
    np.testing.assert_array_equal(frame["reward"].to_numpy(), transitions.rewards)


def _rounded(value, fmt):
    """What comes back through ``fmt``: LeRobot's features are float32, so float64 comes back rounded to it."""
    value = np.asarray(value)
    return value.astype(np.float32).astype(value.dtype) if fmt == "lerobot" and value.dtype.kind == "f" else value


@pytest.mark.parametrize("goal_env", [False, True])
@pytest.mark.parametrize("fmt", ["minari", "lerobot"])
def test_export_round_trip(tmp_path, fmt, goal_env):
    root = tmp_path / "ds"
    _make(root, goal_env=goal_env, seeds=range(2))
    dataset = Dataset(root)
    export, back = (export_minari, import_minari) if fmt == "minari" else (export_lerobot, import_lerobot)
    export(dataset, tmp_path / "out")
    back(tmp_path / "out", tmp_path / "back")
    again = Dataset(tmp_path / "back")
    assert len(again) == 2
    copies = {ep.metadata["seed"]: ep for ep in again}  # new files get new ids: pair by seed
    for original in dataset:
        copy = copies[original.metadata["seed"]]
        for field in ("observation", "achieved_goal", "desired_goal", "action", "reward", "terminated",
                      "truncated", "info.is_success"):
            if field in original[S.TOPIC_STEP]:
                np.testing.assert_array_equal(copy[S.TOPIC_STEP][field], _rounded(original[S.TOPIC_STEP][field], fmt))
                assert copy[S.TOPIC_STEP][field].dtype == original[S.TOPIC_STEP][field].dtype
        np.testing.assert_array_equal(copy.points, original.points)
        for key in original.final:
            np.testing.assert_array_equal(copy.final[key], _rounded(original.final[key], fmt))
        for key in ("source", "object", "seed", "success", "length"):
            assert copy.metadata[key] == original.metadata[key]
