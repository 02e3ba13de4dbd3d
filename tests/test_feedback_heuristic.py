"""The size-free heuristic (``hingelab.heuristic.feedback``), ToolPick-v0's observed object centre,
and a train-high prior spread over the pick table's shapes and sizes."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

from hingelab.envs import TOOL_PICK_ID
from hingelab.policies.baselines import FeedbackScriptedPolicy
from hingelab.seeds import eval_high_seed
from hingelab.training.prior import PICK_SETS, prior_parts


def _run(object: str, size: float, seed: int):
    """One scripted-feedback episode over the shipped low-level policy; the heuristic, the perceived
    openings and hinge commands of its close phase, and the last info."""
    env = gym.make(TOOL_PICK_ID, object=object, size=size, low_level="policy",
                   max_episode_steps=200)
    policy = FeedbackScriptedPolicy()
    obs, info = env.reset(seed=seed)
    policy.reset(env, seed)
    heuristic = policy.heuristic
    close = []
    for _ in range(200):
        closing, opening = heuristic.phase == "close", heuristic.perceived_opening()
        action = policy.act(env, obs)
        if closing:  # a feedback step: the command from the opening perceived now
            close.append((opening, heuristic.hinge_cmd))
        obs, _, terminated, truncated, info = env.step(action)
        if terminated or truncated:
            break
    env.close()
    return heuristic, np.array(close), info


@pytest.mark.parametrize("object,size", [("cylinder", 0.015), ("cylinder", 0.025)])
def test_feedback_heuristic_picks_without_the_size(object, size):
    # three episodes, at least two picked: one episode's outcome hangs on the last bits of the arithmetic, which
    # differ between CPUs (seed 3's first 1.5 cm cylinder is picked on one machine and missed on another)
    runs = [_run(object, size, eval_high_seed(3, k)) for k in range(3)]
    assert sum(info["is_success"] == 1.0 for _, _, info in runs) >= 2
    for heuristic, close, _ in runs:
        # one opening for every object
        assert heuristic.open_theta == pytest.approx(min(np.arcsin(heuristic.config.open_width / 0.124),
                                                         heuristic.synergy.theta_range[1]))
        assert len(close) % heuristic.config.close_steps == 0  # per attempt
        # the first close: the command falls at most 0.015 rad a step, and only while it is less than
        # the squeeze below the opening perceived in that step (it stops where the object stops the tips)
        opening, command = close[: heuristic.config.close_steps].T
        fall = -np.diff(command)
        assert np.all(fall >= 0) and np.all(fall <= 0.015 + 1e-9)
        falling = fall > 1e-9
        assert np.all(command[1:][falling] >= opening[1:][falling] - heuristic.config.feedback_squeeze - 1e-9)


def test_the_settled_command_follows_the_object_width():
    """Closed on a wide object the command settles higher than on a narrow one."""
    small = _run("cylinder", 0.015, eval_high_seed(3, 1))[1][-1, 1]
    large = _run("cylinder", 0.025, eval_high_seed(3, 1))[1][-1, 1]
    assert large > small + 0.04


def test_observed_object_position_is_the_centre():
    """A tetrahedron's body origin is on its base; the high level observes its centre (as a camera would)."""
    env = gym.make(TOOL_PICK_ID, object="tetrahedron", size=0.02, low_level="privileged", randomize=False)
    env.reset(seed=1)
    pick = env.unwrapped
    lift = pick.observed_object_centre() - pick.state.object_pos_world
    assert lift == pytest.approx([0.0, 0.0, pick.object.height / 2], abs=1e-4)
    sphere = gym.make(TOOL_PICK_ID, object="sphere", size=0.02, low_level="privileged", randomize=False).unwrapped
    sphere.reset(seed=1)
    assert np.array_equal(sphere.observed_object_centre(), sphere.state.object_pos_world)


def test_prior_parts_share_episodes_over_the_pick_sets():
    from hingelab.learners.sac.high_level_config import HighLevelTrainConfig

    parts = prior_parts(HighLevelTrainConfig(prior_objects="all", prior_episodes=26))
    assert [(o, s) for _, o, s, _ in parts] == list(PICK_SETS)
    assert [n for *_, n in parts] == [3, 3] + [2] * 10
    assert parts[0][0] == "sphere_1.5cm" and len({folder for folder, *_ in parts}) == 12
    assert prior_parts(HighLevelTrainConfig())[0] == ("", "sphere", 0.02, 100)
    from hingelab.errors import ConfigError

    with pytest.raises(ConfigError, match="prior_episodes"):
        HighLevelTrainConfig(prior_objects="all", prior_episodes=5)
