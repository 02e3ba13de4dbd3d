"""The flat baseline env ``hingelab/ToolPickFlat-v0``: API, determinism, parity with ToolPick-v0,
recording, and SB3 on it."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import hingelab  # noqa: F401  (registers the envs)
from hingelab.envs import TOOL_PICK_FLAT_ID, TOOL_PICK_ID
from hingelab.envs.tool_pick_flat import FINGER_SCALE, ToolPickFlatEnv
from hingelab.errors import ConfigError


@pytest.fixture(scope="module")
def flat_env():
    env = gym.make(TOOL_PICK_FLAT_ID)
    yield env
    env.close()


def test_check_env_passes(flat_env):
    check_env(flat_env.unwrapped, skip_render_check=True)


def test_spaces_registry_and_pickling(flat_env):
    env = flat_env.unwrapped
    assert isinstance(env, ToolPickFlatEnv) and flat_env.spec.id == TOOL_PICK_FLAT_ID
    assert env.action_space.shape == (12,) and env.observation_space.shape == (32,)
    assert env.success_verdict == "object_within_1cm" and env.low_level.kind == "none"
    # the finger scale is ToolShape-v0's default action_scale
    import inspect

    from hingelab.envs.tool_shape import ToolShapeEnv
    assert inspect.signature(ToolShapeEnv).parameters["action_scale"].default == FINGER_SCALE
    obs, info = flat_env.reset(seed=4)
    q, qdot = env.sim.hand_observation()
    np.testing.assert_array_equal(obs[14:23], q)
    np.testing.assert_array_equal(obs[23:], qdot)
    assert info["attempt"] == 1 and info["is_success"] == 0.0
    # a pickled env (as for subprocess workers) goes on exactly as the original
    copy = pickle.loads(pickle.dumps(env))
    assert pickle.loads(pickle.dumps(flat_env.spec)).id == TOOL_PICK_FLAT_ID
    rng = np.random.default_rng(1)
    for _ in range(5):
        action = rng.uniform(-0.3, 0.3, 12)
        a, b = env.step(action), copy.step(action)
        np.testing.assert_array_equal(a[0], b[0])
        assert a[1:4] == b[1:4]
    with pytest.raises(ConfigError, match="no low level"):
        gym.make(TOOL_PICK_FLAT_ID, low_level="policy")
    with pytest.raises(ConfigError, match="no privileged commands"):
        env.command_privileged(np.zeros(3), 0.1, np.zeros(9))


def test_same_seed_same_trajectory():
    def run():
        env = gym.make(TOOL_PICK_FLAT_ID)
        obs, _ = env.reset(seed=7)
        rng = np.random.default_rng(0)
        steps = [env.step(rng.uniform(-1, 1, 12)) for _ in range(10)]
        env.close()
        return obs, np.array([s[0] for s in steps]), [s[1:4] for s in steps]

    obs_a, traj_a, rest_a = run()
    obs_b, traj_b, rest_b = run()
    np.testing.assert_array_equal(obs_a, obs_b)
    np.testing.assert_array_equal(traj_a, traj_b)
    assert rest_a == rest_b


def test_bad_actions_are_one_line_errors(flat_env):
    flat_env.reset(seed=0)
    for action in (np.full(12, np.nan), np.zeros(5), np.r_[np.zeros(11), np.inf]):
        with pytest.raises(ConfigError, match="ToolPickFlat-v0 takes 12 finite values") as caught:
            flat_env.step(action)
        assert "\n" not in str(caught.value).split(", got")[0]


class ScriptedFingers:
    """A stand-in low level for ToolPick-v0: moves the fingers by given normalized deltas, the way
    the flat action's first 9 values (and ToolShape-v0's action, and a trained low level) do."""

    kind = "scripted"

    def __init__(self, finger_actions):
        self.finger_actions = iter(finger_actions)

    def reset(self) -> None:
        pass

    def act(self, sim, z_goal, low_obs=None) -> dict:
        return {"hand_action": next(self.finger_actions) * FINGER_SCALE}


def _compare_with_tool_pick(seed: int, sigma: float, n: int, limit: int = 200) -> tuple[list, dict]:
    """Run ToolPick-v0 with scripted finger deltas and ToolPickFlat-v0 with the same deltas and hand
    velocities side by side; assert every step equal; return the rewards and the last info."""
    rng = np.random.default_rng(seed)
    fingers = np.clip(rng.normal(0.0, sigma, (n, 9)), -1, 1)
    velocities = rng.uniform(-1, 1, (n, 3))
    pick, flat = gym.make(TOOL_PICK_ID), gym.make(TOOL_PICK_FLAT_ID)
    pick.unwrapped.low_level = ScriptedFingers(fingers)
    pick.unwrapped.max_episode_steps = flat.unwrapped.max_episode_steps = limit  # the envs' own limit
    obs_p, info_p = pick.reset(seed=seed)
    obs_f, info_f = flat.reset(seed=seed)
    np.testing.assert_array_equal(obs_f[:14], obs_p)
    keys = ("is_success", "reward_terms", "attempt", "first_attempt_success", "object_target_distance",
            "table_collision", "hinge_angle", "tool_drift_m", "tool_dropped", "failure_reason")
    rewards = []
    for k in range(n):
        z_goal = rng.uniform(-1, 1, 2)  # ignored by the scripted low level
        obs_p, r_p, term_p, trunc_p, info_p = pick.step(np.r_[z_goal, velocities[k]])
        obs_f, r_f, term_f, trunc_f, info_f = flat.step(np.r_[fingers[k], velocities[k]])
        np.testing.assert_array_equal(obs_f[:14], obs_p)
        q, qdot = pick.unwrapped.sim.hand_observation()
        np.testing.assert_array_equal(obs_f[14:], np.r_[q, qdot])
        assert (r_f, term_f, trunc_f) == (r_p, term_p, trunc_p)
        assert {key: info_f.get(key) for key in keys} == {key: info_p.get(key) for key in keys}
        np.testing.assert_array_equal(info_f["executed_action"], np.r_[fingers[k], velocities[k]])
        rewards.append(r_f)
        if term_f or trunc_f:
            break
    pick.close()
    flat.close()
    return rewards, info_f


def test_reward_success_and_ends_match_tool_pick_for_the_same_finger_deltas():
    """Exact parity: ToolPick-v0 whose low level commands given finger deltas, and ToolPickFlat-v0
    commanded the same deltas and hand velocities, give bit-equal observations, rewards, reward
    terms, verdicts, attempts, ends and failure reasons (the same code paths on the same physics):
    over a 42-step episode that ends with the tool shaken out of the hand, and one cut by the limit.

    Why not with the privileged low level's commands: PrivilegedLowLevel sets absolute synergy
    targets (jumps of more than 0.05 rad a step) and drives the tweezer's hinge with a privileged
    servo, an actuator the flat action has no channel for, so its physics cannot be replayed
    through the flat action. What it shares with the flat env is checked below: the same reset
    (randomization, object, target, observation). (A trained low level's deltas, replayed as
    delta / 0.05, differ from the product in the last bit, so that parity is close, not exact.)"""
    rewards, info = _compare_with_tool_pick(seed=3, sigma=0.5, n=80)
    assert len(rewards) == 42 and info["failure_reason"] == "tool_drop" and np.ptp(rewards) > 0.01
    rewards, info = _compare_with_tool_pick(seed=4, sigma=0.1, n=20, limit=12)
    assert len(rewards) == 12 and info["failure_reason"] == "timeout"

    # the privileged low level (ToolPick-v0's default): the same reset, randomization included
    pick, flat = gym.make(TOOL_PICK_ID), gym.make(TOOL_PICK_FLAT_ID)
    obs_p, info_p = pick.reset(seed=12)
    obs_f, info_f = flat.reset(seed=12)
    np.testing.assert_array_equal(obs_f[:14], obs_p)
    for name, value in vars(pick.unwrapped.sim.episode).items():
        np.testing.assert_array_equal(getattr(flat.unwrapped.sim.episode, name), value)
    np.testing.assert_array_equal(pick.unwrapped.target, flat.unwrapped.target)
    pick.close()
    flat.close()


def test_recording_wrapper_records_flat_episodes(tmp_path):
    from hingelab.envs.recording import RecordingWrapper
    from hingelab.episodes import create_dataset, read_episode

    create_dataset(tmp_path / "ds", name="flat", source="flat_evaluation", config={"k": 1}, seed=0)
    flat = gym.make(TOOL_PICK_FLAT_ID)
    flat.unwrapped.max_episode_steps = 12  # the env's own limit (gym.make's would add a TimeLimit)
    env = RecordingWrapper(flat, tmp_path / "ds", source="flat_evaluation", action_level="flat")
    env.reset(seed=2)
    rng = np.random.default_rng(0)
    done, steps, rewards = False, 0, []
    while not done:
        _, reward, terminated, truncated, _ = env.step(rng.uniform(-0.2, 0.2, 12))
        done, steps = terminated or truncated, steps + 1
        rewards.append(reward)
    env.close()
    assert len(env.paths) == 1
    episode = read_episode(env.paths[0])
    step = episode["/step"]
    assert step["action"].shape == (steps, 12) and step["observation"].shape == (steps, 32)
    assert episode.length == steps
    assert episode.metadata["action_level"] == "flat" and episode.metadata["task"] == TOOL_PICK_FLAT_ID
    assert episode.metadata["success_verdict"] == "object_within_1cm"
    assert episode.metadata["source"] == "flat_evaluation"
    assert steps == 12 and episode.metadata["success"] is False and episode.metadata["failure_reason"] == "timeout"
    assert episode.metadata["return"] == pytest.approx(sum(rewards))
    # no latent goal: the goal channel holds the latent reached, as in ToolPick-v0's heuristic episodes
    np.testing.assert_array_equal(episode["/goal"]["z_goal"], episode["/tool/latent"]["z_smoothed"])


def test_sb3_sac_learns_on_it():
    from stable_baselines3 import SAC

    env = gym.make(TOOL_PICK_FLAT_ID)
    model = SAC("MlpPolicy", env, learning_starts=100, batch_size=32, policy_kwargs=dict(net_arch=[16]),
                seed=0, verbose=0)
    model.learn(total_timesteps=300)
    assert model.replay_buffer.pos == 300
    assert model.replay_buffer.actions.shape[-1] == 12 and model.replay_buffer.observations.shape[-1] == 32
    env.close()
